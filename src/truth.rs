//! Ground truth (`truth.jsonl`) and estimate (`estimate --json`) line formats.
//!
//! Other tools read and write these; field names and meanings are fixed by the vision-core issue.

use serde::{Deserialize, Serialize};

/// One image's ground truth. Unknown fields (renderer metadata) are kept out of the way.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TruthRecord {
    /// Path relative to the truth file's directory.
    pub image: String,
    /// Scene kind ("clean", "touching", ...).
    pub condition: String,
    /// Gaussian noise sigma added, gray levels.
    pub noise_sigma: f64,
    /// The parts, in no particular order.
    pub parts: Vec<TruthPart>,
}

/// One part as it truly lies.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TruthPart {
    /// Its type name (`type` in the file).
    #[serde(rename = "type")]
    pub type_name: String,
    /// "up" or "down".
    pub face: String,
    /// Rotation from its template, degrees.
    pub angle_deg: f64,
    /// Its template origin in the frame, pixels.
    pub x_px: f64,
    /// See `x_px`.
    pub y_px: f64,
    /// Fraction of the part's material that nothing lies on (1.0: whole, the default when a
    /// truth file predates the field; below 1: partly covered by another part).
    #[serde(default = "whole")]
    pub visible_fraction: f64,
    /// Where the robot finds the part, robot millimetres (scenes of a simulated cell with a
    /// camera model and a robot frame; absent otherwise).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub x_mm: Option<f64>,
    /// See `x_mm`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub y_mm: Option<f64>,
    /// The part's angle in the robot frame, degrees counter-clockwise from robot +X towards +Y
    /// (with `x_mm`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub robot_angle_deg: Option<f64>,
}

fn whole() -> f64 {
    1.0
}

/// A part counts as uncovered (a robot may pick it) at or above this visible fraction.
pub const UNCOVERED: f64 = 0.98;

/// One image's estimate, as `estimate --json` prints it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EstimateRecord {
    /// The image, as given.
    pub image: String,
    /// Estimate time, ms.
    pub elapsed_ms: f64,
    /// One per part region.
    pub parts: Vec<EstimatePart>,
}

/// One part's estimate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EstimatePart {
    /// Its type, if one was named (`type` in the file).
    #[serde(rename = "type")]
    pub type_name: Option<String>,
    /// TYPE_ID (0 unknown).
    pub type_id: u16,
    /// "up" or "down", if a type was named.
    pub face: Option<String>,
    /// Rotation from the template, degrees.
    pub angle_deg: f64,
    /// Template origin in the frame, pixels.
    pub x_px: f64,
    /// See `x_px`.
    pub y_px: f64,
    /// 0..1.
    pub confidence: f64,
    /// The robot may pick it.
    pub accepted: bool,
    /// REASON as text.
    pub reason: String,
}

impl EstimatePart {
    /// The record of an estimator's part.
    pub fn from_estimate(p: &crate::vision::PartEstimate) -> Self {
        let r3 = |v: f64| (v * 1000.0).round() / 1000.0;
        Self {
            type_name: p.type_name.clone(),
            type_id: p.type_id,
            face: p.face.map(|f| f.as_str().to_string()),
            angle_deg: (p.angle_deg * 10000.0).round() / 10000.0,
            x_px: r3(p.x),
            y_px: r3(p.y),
            confidence: r3(p.confidence),
            accepted: p.accepted,
            reason: p.reason.as_str().to_string(),
        }
    }
}

/// What a catalogue says of its types (`catalog.json` beside a catalogue's `truth.jsonl`): which
/// are enrolled, and which are design revisions of which.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Catalog {
    /// Every type of the catalogue, enrolled or not.
    pub types: Vec<CatalogType>,
}

/// One type of a catalogue.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CatalogType {
    /// Its type name, as in the truth.
    pub name: String,
    /// Enrolled (false: a type the product must reject, e.g. an unseen revision).
    pub known: bool,
    /// The revision family it belongs to, if any.
    #[serde(default)]
    pub family: Option<String>,
    /// Its revision within the family (0: the first).
    #[serde(default)]
    pub revision: Option<u32>,
    /// The type it is a revision of.
    #[serde(default)]
    pub parent: Option<String>,
    /// How it differs from its parent.
    #[serde(default)]
    pub change: Option<CatalogChange>,
}

/// A revision's one local change of outline.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CatalogChange {
    /// What kind of change (`add_notch`, `longer_lug`, ...).
    pub kind: String,
    /// In words.
    pub what: String,
    /// How far the outline moves, millimetres.
    pub delta_mm: f64,
}

/// Parses a catalogue's `catalog.json`; errors name the file.
pub fn parse_catalog(text: &str, origin: &str) -> Result<Catalog, String> {
    serde_json::from_str(text).map_err(|e| format!("{origin}: {e}"))
}

/// Parses a truth file's text; errors name the line.
pub fn parse_truth(text: &str, origin: &str) -> Result<Vec<TruthRecord>, String> {
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| serde_json::from_str::<TruthRecord>(l).map_err(|e| format!("{origin}:{}: {e}", i + 1)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_the_shared_format_with_extra_fields() {
        let line = r#"{"image": "images/a.png", "condition": "clean", "noise_sigma": 0.79, "parts": [{"type": "A", "face": "down", "angle_deg": 6.28, "x_px": 2054.182, "y_px": 1212.841, "visible_fraction": 1.0}], "width": 2592}"#;
        let t = parse_truth(line, "t").unwrap();
        assert_eq!(t[0].parts[0].type_name, "A");
        let e = parse_truth("{}\n", "truth.jsonl").unwrap_err();
        assert!(e.starts_with("truth.jsonl:1:"), "{e}");
    }
}
