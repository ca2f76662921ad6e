//! The estimator's tunables, below every stage that reads them.

use super::boundary::RefineParams;
use super::detect::DetectParams;
use super::lines::LineDetector;

/// Tunables of the estimator. Defaults follow the method; the decision thresholds were set on
/// the built-in simulator's scenes (README, "Measured accuracy").
#[derive(Debug, Clone)]
pub struct Params {
    /// Frame pixels per pixel of the decimated frame the coarse stages run on.
    pub coarse_factor: usize,
    /// Gaussian blur before Canny, decimated pixels (the study's 1.5).
    pub blur_sigma: f64,
    /// Canny's low threshold as a fraction of the automatic high one (the study's 0.4).
    pub canny_low_ratio: f64,
    /// Closing element diameter, decimated pixels.
    pub closing: i32,
    /// Minimum part area, frame pixels (None: a quarter of the smallest template's area).
    pub min_area: Option<f64>,
    /// Line segment detector for the line features.
    pub line_detector: LineDetector,
    /// Segments shorter than this fraction of the part's bounding-box diagonal are dropped.
    pub min_segment_fraction: f64,
    /// Edge level between the belt (0) and the part (1): low, so that the darker, rounded
    /// margins of forged parts count as part, yet clear of the belt's texture and noise.
    pub edge_level: f64,
    /// Bins of the r(phi) signal.
    pub signal_bins: usize,
    /// Templates refined by ICP per part (the best by correlation distance).
    pub candidates: usize,
    /// Outline distance (template pixels) within which a point counts as fitting, at zero noise;
    /// grows with the measured noise.
    pub fit_tolerance: f64,
    /// Tolerance growth with the template's size (fraction of its RMS radius).
    pub fit_tolerance_rel: f64,
    /// Minimum fit (fraction of outline explained, both ways) to name a type. 0.8: the lowest
    /// fit of a known part accepted on the single-part path is 0.88 (a glare frame of
    /// `samples`; samples-hard 0.905, samples-catalog 0.94, the simulator's sets 0.97 and
    /// above); an unknown fork of another shape fitted a known one 0.76 and
    /// 0.77 at 0.92 of its scale, departing nowhere by twice the separation (unseen catalogue
    /// of seed 83). A part below it is searched as a region, where it must still follow its
    /// template alone as a clean outline does.
    pub min_fit: f64,
    /// A different type or face fitting within this margin of the best is a rival ...
    pub ambiguity_margin: f64,
    /// ... that makes the part ambiguous unless the best's confidence beats the rival's by this.
    pub confidence_margin: f64,
    /// Largest fraction of outline that may be foreign (extra) or unseen (missing).
    pub max_foreign: f64,
    /// Accepted scale range relative to the template.
    pub scale_range: (f64, f64),
    /// A region larger than this multiple of the largest template's area is several parts.
    pub touching_area_ratio: f64,
    /// A region whose r(phi) lies farther than this correlation distance from every template
    /// (RMS of log-radius, the signature test) has no template near: two-thirds of the way from
    /// a rival type's distance (0.1-0.3) to an unknown part's (0.5-0.6). Too small to hold two
    /// parts as well, it is one part of a type not enrolled, and the region search is not run
    /// on it (the search found nothing in such a region in any set: it only cost 10 ms).
    pub far_signature: f64,
    /// Separate material of at least this fraction of the smallest template's area (and below
    /// the minimum part area) counts as debris.
    pub debris_fraction: f64,
    /// Least fraction of a template's outline the image must explain for a part found in a
    /// region of several parts to count as whole (the rest is contact with its neighbour).
    pub min_support: f64,
    /// A part told from a tied sibling by where the two differ must not depart from the best
    /// template elsewhere by this many times the separation that counts as apart (the outlines'
    /// noise, see `differ::separation`), seen in the frame: twice it, six times the tight
    /// tolerance, deeper than the outline's noise and shallower than a design revision's change
    /// of a few millimetres.
    pub departure_depth: f64,
    /// ... and at least this many times it wide (the area between the outlines over the
    /// depth): three times, two to five millimetres, a notch or lug rather than a slit the
    /// outline ran further into than the template's.
    pub departure_width: f64,
    /// Threads a frame of several regions is estimated on (each region on one): 2 uses the
    /// second core of the appliance's machine; 1 keeps every frame on the calling thread.
    pub threads: usize,
    /// Confidence: lambda = lambda0 (1 - alpha noise).
    pub lambda0: f64,
    /// Noise's weight in lambda (the study's 0.5).
    pub alpha: f64,
    /// Confidence at or above which a part is accepted.
    pub accept_threshold: f64,
}

impl Default for Params {
    fn default() -> Self {
        Self {
            coarse_factor: 4,
            blur_sigma: 1.5,
            canny_low_ratio: 0.4,
            closing: 5,
            min_area: None,
            line_detector: LineDetector::Fld,
            min_segment_fraction: 0.05,
            edge_level: 0.1,
            signal_bins: 1024,
            candidates: 3,
            fit_tolerance: 2.0,
            fit_tolerance_rel: 0.015,
            min_fit: 0.8,
            ambiguity_margin: 0.1,
            confidence_margin: 0.15,
            max_foreign: 0.06,
            scale_range: (0.85, 1.18),
            touching_area_ratio: 1.3,
            far_signature: 0.35,
            debris_fraction: 0.01,
            min_support: 0.93,
            departure_depth: 2.0,
            departure_width: 3.0,
            threads: 2,
            lambda0: 25.0,
            alpha: 0.5,
            accept_threshold: 0.5,
        }
    }
}

impl Params {
    pub(crate) fn detect_params(&self, min_area: f64, min_debris_area: f64) -> DetectParams {
        DetectParams {
            min_debris_area,
            factor: self.coarse_factor,
            blur_sigma: self.blur_sigma,
            canny_low_ratio: self.canny_low_ratio,
            closing: self.closing,
            min_area,
            drop_border_specks: false,
        }
    }
    pub(crate) fn refine_params(&self, factor: usize) -> RefineParams {
        // The closing leaves the coarse outline within about one decimated pixel of the edge.
        RefineParams { spacing: 2.5, search: 3.0 * factor as f64 + 4.0, profile_sigma: self.blur_sigma, across: 2, level: self.edge_level }
    }
}
