//! Templates (one clean image per part type and face) and the compiled library the estimator
//! correlates against.

use super::boundary;
use super::correlate::{Alignment, Correlator, Key, Spectrum};
use super::detect::{self, DetectParams};
use super::frame::{FrameError, GrayView};
use super::geometry::{Pt, Similarity, area_centroid, bounds};
use super::lines::{self, Segment};
use super::params::Params;
use super::part::Face;
use super::register::OutlineIndex;
use super::shape::ShapeModel;
use super::signal::log_radius_signal;
use super::workers::each;

/// What the estimator knows about one face of one part type.
#[derive(Debug, Clone, PartialEq)]
pub struct Template {
    /// The part type's name.
    pub type_name: String,
    /// Numeric id served to the PLC (1..=65535; 0 means "no type").
    pub type_id: u16,
    /// Which face of the part the template shows.
    pub face: Face,
    /// Width of the image it was enrolled from.
    pub image_width: usize,
    /// Height of the image it was enrolled from.
    pub image_height: usize,
    /// The point reported as the part's position, template pixels. By default the centre of the
    /// template image: like a vision tool's model origin, it is rigidly attached to the part, so a
    /// robot program taught on it stays valid whatever point the user chose.
    pub origin: Pt,
    /// Centroid of the filled outline, template pixels.
    pub centroid: Pt,
    /// Area enclosed by the outline, template pixels.
    pub area: f64,
    /// Sub-pixel outline, template pixels.
    pub outline: Vec<Pt>,
    /// Line segments (frame of the template image).
    pub segments: Vec<Segment>,
    /// Edges inside the part (holes, pockets, bosses): points and the unit normal from the
    /// brighter side to the darker, template pixels (see [`super::shape::interior_edges`]). They
    /// tell which of two overlapping parts lies on top. Empty (a knowledge base from an earlier
    /// build, a featureless part): the outlines alone tell it.
    pub interior: Vec<(Pt, Pt)>,
    /// The gripper's keep-out footprint, template pixels: material of anything else inside it
    /// rejects the part (`no clearance`). Empty: no check.
    pub keep_out: Vec<KeepOut>,
}

/// One circle of a gripper's keep-out footprint, in the template's pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeepOut {
    /// Centre.
    pub c: Pt,
    /// Radius.
    pub r: f64,
}

/// Why an image cannot become a template.
#[derive(Debug, thiserror::Error)]
pub enum TemplateError {
    /// The template image is not a usable frame.
    #[error(transparent)]
    Frame(#[from] FrameError),
    /// Nothing in the image stands out as a part.
    #[error("no part found in the template image (nothing larger than {min_area:.0} px^2 stands out from the background)")]
    NoPart {
        /// The least area of a part, px^2.
        min_area: f64,
    },
    /// The part reaches the image's edge.
    #[error("the part in the template image touches the image border; crop the template with a margin around the part")]
    AtBorder,
    /// Type id 0 (it means "no type").
    #[error("type id {0} is reserved; use 1..=65535")]
    ReservedId(u16),
    /// The type name is empty.
    #[error("type name is empty")]
    EmptyName,
}

/// Material of a template image that is not the part: touching the image's edge, joined to the
/// part by the scenes' coarse closing, and left out.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LeftOut;

impl std::fmt::Display for LeftOut {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("small material touching the image border (a stain or speck of the belt) lay within the closing's reach of the part and was left out")
    }
}

/// The part's coarse region in a template image: the largest region, which must lie inside the
/// image. The closing made for scenes can reach a stain or speck of the belt at the image's edge
/// and join it to the part; so when the largest region touches the border, the edges of small
/// material touching the border are dropped and the part is taken when its region then lies
/// inside and keeps at least 80 % of the joined region's area. A part really cut by the border
/// leaves a long edge chain at the border and is refused, whether or not the largest region
/// touches it.
fn part_region(image: GrayView<'_>, params: &Params, min_area: f64) -> Result<(detect::Coarse, usize, Option<LeftOut>), TemplateError> {
    let largest = |c: &detect::Coarse| (0..c.blobs.len()).max_by(|&a, &b| c.blobs[a].area.total_cmp(&c.blobs[b].area));
    let dp = params.detect_params(min_area, min_area);
    let coarse = detect::detect(image, &dp)?;
    let i = largest(&coarse).ok_or(TemplateError::NoPart { min_area })?;
    if !coarse.blobs[i].touches_border {
        if detect::cut_by_border(&coarse, dp.closing)? {
            return Err(TemplateError::AtBorder);
        }
        return Ok((coarse, i, None));
    }
    let joined = coarse.blobs[i].area;
    let apart = detect::detect(image, &DetectParams { drop_border_specks: true, ..dp })?;
    match largest(&apart) {
        Some(j) if !apart.blobs[j].touches_border && apart.blobs[j].area >= 0.8 * joined && !detect::cut_by_border(&apart, dp.closing)? => {
            Ok((apart, j, Some(LeftOut)))
        }
        _ => Err(TemplateError::AtBorder),
    }
}

impl Template {
    /// Learns a template from one clean image showing one part.
    pub fn from_image(
        image: GrayView<'_>,
        type_name: &str,
        type_id: u16,
        face: Face,
        origin: Option<Pt>,
        params: &Params,
    ) -> Result<Self, TemplateError> {
        Self::learn(image, type_name, type_id, face, origin, params).map(|(t, _)| t)
    }

    /// [`Template::from_image`], and the material of the image that was left out, for the
    /// enrolment to report.
    pub fn learn(
        image: GrayView<'_>,
        type_name: &str,
        type_id: u16,
        face: Face,
        origin: Option<Pt>,
        params: &Params,
    ) -> Result<(Self, Option<LeftOut>), TemplateError> {
        if type_name.trim().is_empty() {
            return Err(TemplateError::EmptyName);
        }
        if type_id == 0 {
            return Err(TemplateError::ReservedId(0));
        }
        let min_area = 0.01 * (image.width() * image.height()) as f64;
        let noise = boundary::noise_sigma(image, &[]);
        let (coarse, i, left_out) = part_region(image, params, min_area)?;
        let blob = &coarse.blobs[i];
        let refined = boundary::refine(image, &blob.outline, noise, &params.refine_params(coarse.factor));
        let interior = super::shape::interior_edges(&coarse, &refined.outline, noise, refined.contrast);
        let outline = refined.outline;
        let (area, centroid) = area_centroid(&outline);
        let (lo, hi) = bounds(&outline);
        let diag = (hi - lo).norm();
        let segments = lines::part_segments(
            params.line_detector,
            &coarse.small,
            &coarse.edges,
            coarse.factor,
            blob,
            params.min_segment_fraction * diag,
        )?;
        let origin = origin.unwrap_or(Pt::new((image.width() as f64 - 1.0) / 2.0, (image.height() as f64 - 1.0) / 2.0));
        let template = Self {
            type_name: type_name.trim().to_string(),
            type_id,
            face,
            image_width: image.width(),
            image_height: image.height(),
            origin,
            centroid,
            area: area.abs(),
            outline,
            segments,
            interior,
            keep_out: Vec::new(),
        };
        Ok((template, left_out))
    }

    /// Root-mean-square distance of the outline from the centroid: the part's size.
    pub fn rms_radius(&self) -> f64 {
        let n = self.outline.len().max(1) as f64;
        (self.outline.iter().map(|p| (*p - self.centroid).dot(*p - self.centroid)).sum::<f64>() / n).sqrt()
    }
}

/// A template prepared for matching: its signal's spectrum and its outline's spatial index.
#[derive(Debug, Clone)]
pub struct Compiled {
    /// The template.
    pub template: Template,
    /// Its r(phi) signal in the frequency domain.
    pub spectrum: Spectrum,
    /// Its spectrum's key: the shortlist's bound on the correlation distance.
    pub key: Key,
    /// Its outline's nearest-segment index.
    pub index: OutlineIndex,
    /// Diagonal of its outline's bounding box, px.
    pub diag: f64,
    /// Voting and verification points for regions holding several parts.
    pub shape: ShapeModel,
}

/// All enrolled templates, compiled once when the estimator is built.
#[derive(Debug, Clone)]
pub struct Library {
    /// Every template, in enrolment order.
    pub entries: Vec<Compiled>,
    /// The correlator sized to the signals.
    pub correlator: Correlator,
    /// For each template, the others whose signal lies within [`ALIKE_CORR`] of its own (another
    /// face of a symmetric part, a revision sibling), each with its pose relative to it:
    /// (entry, template pixels of the other to this one's).
    pub alike: Vec<Vec<(usize, Similarity)>>,
    /// For each template, the others whose signal lies within [`RESEMBLE_CORR`] of its own (a
    /// superset of `alike`), each with its pose relative to it: what a region search holds a
    /// part it finds against.
    pub resembles: Vec<Vec<(usize, Similarity)>>,
    /// The smallest template's rms radius, template pixels: what sets the decimation and how
    /// near two glance peaks are one part's.
    pub smallest_radius: f64,
}

/// Correlation distance within which two templates are look-alikes: revision siblings of the
/// catalogues measure 0.04-0.07 and two faces of one type 0.03-0.13, different types 0.09 and
/// more (simulated catalogue of seed 41); a look-alike is looked at wherever a region search
/// finds its twin, so that the two are always held against each other.
pub const ALIKE_CORR: f64 = 0.1;

/// Correlation distance within which a region search holds a part it finds against another
/// template, looked at at the part's pose. The search's glance ranks templates by a vote from a
/// quarter of the region's outline, which does not tell apart shapes this close when another
/// part's outline fills the region too: on the unseen catalogue of seed 97 a link of a ring and
/// an arm (T010) ranked 29th of 80 beside a larger part and was left out, and a longer link
/// (T033, at 0.23) was accepted for it at scale 0.94. Between 0.1 and this, shapes of other
/// types are a few per template (the six nearest are looked for); a look that the image does
/// not support ends at the cheap first test.
pub const RESEMBLE_CORR: f64 = 0.25;

impl Library {
    /// Compiles `templates` with signals of `bins` bins.
    pub fn new(templates: &[Template], bins: usize) -> Self {
        Self::on(templates, bins, None)
    }

    /// [`Library::new`], the templates compiled side by side on `pool` (the same library: each
    /// template's tables are its own). Most of loading a knowledge base is here: each
    /// template's pruned nearest-segment grid, its verification points, its six nearest.
    pub fn on(templates: &[Template], bins: usize, pool: Option<&rayon::ThreadPool>) -> Self {
        let correlator = Correlator::new(bins);
        let entries = each(pool, templates, |t| {
            let signal = log_radius_signal(&t.outline, t.centroid, bins);
            let (lo, hi) = bounds(&t.outline);
            let spectrum = correlator.spectrum(&signal);
            Compiled {
                template: t.clone(),
                key: Key::of(&spectrum),
                spectrum,
                index: OutlineIndex::new(&t.outline),
                diag: (hi - lo).norm(),
                shape: ShapeModel::new(&t.outline, t.centroid),
            }
        });
        // The six nearest of each (itself among them), with their rank: look-alikes are looked
        // for among the four nearest.
        let numbered: Vec<(usize, &Compiled)> = entries.iter().enumerate().collect();
        let near: Vec<Vec<(usize, usize, Similarity, f64)>> = each(pool, &numbered, |&(i, e)| {
            nearest_of(&entries, &correlator, &e.spectrum, 6)
                .into_iter()
                .enumerate()
                .filter(|&(_, (j, al))| j != i && al.rms <= RESEMBLE_CORR)
                .map(|(rank, (j, al))| {
                    // The other's outline placed on this one's, as a part's would be.
                    (rank, j, placed(&correlator, &al, entries[j].template.centroid, e.template.centroid), al.rms)
                })
                .collect()
        });
        let within = |ranks: usize, corr: f64| -> Vec<Vec<(usize, Similarity)>> {
            near.iter().map(|r| r.iter().filter(|x| x.0 < ranks && x.3 <= corr).map(|x| (x.1, x.2)).collect()).collect()
        };
        let alike = within(4, ALIKE_CORR);
        let resembles = within(6, RESEMBLE_CORR);
        let smallest_radius = entries.iter().map(|e| e.template.rms_radius()).fold(f64::INFINITY, f64::min);
        Self { entries, correlator, alike, resembles, smallest_radius }
    }

    /// Every template by correlation distance to `part` (best first): the slow way, for
    /// [`Library::nearest`]'s tests and benches.
    pub fn align_all(&self, part: &Spectrum) -> Vec<(usize, Alignment)> {
        let mut aligned: Vec<(usize, Alignment)> =
            self.entries.iter().enumerate().map(|(i, e)| (i, self.correlator.align(part, &e.spectrum))).collect();
        aligned.sort_by(|a, b| a.1.rms.total_cmp(&b.1.rms).then(a.0.cmp(&b.0)));
        aligned
    }

    /// The `need` templates nearest to `part` by correlation distance (best first), exactly as
    /// the first `need` of [`Library::align_all`], correlating only the templates whose key's
    /// bound ([`Key::bound`]) could still place them there. The bound holds for whole-bin shifts;
    /// the sub-bin refinement of [`Correlator::align`] may land below it by a little, so a
    /// template is passed over only when its bound exceeds the `need`-th distance by
    /// [`SHORTLIST_SLACK`] (relative) plus 0.001.
    pub fn nearest(&self, part: &Spectrum, need: usize) -> Vec<(usize, Alignment)> {
        nearest_of(&self.entries, &self.correlator, part, need)
    }
}

/// [`Library::nearest`] over `entries`.
fn nearest_of(entries: &[Compiled], correlator: &Correlator, part: &Spectrum, need: usize) -> Vec<(usize, Alignment)> {
    let n = correlator.bins();
    let key = Key::of(part);
    let mut order: Vec<(usize, f64)> = entries.iter().enumerate().map(|(i, e)| (i, key.bound(&e.key, n))).collect();
    order.sort_by(|a, b| a.1.total_cmp(&b.1));
    let mut aligned: Vec<(usize, Alignment)> = Vec::with_capacity(need + 4);
    for (i, bound) in order {
        if aligned.len() >= need {
            aligned.sort_by(|a, b| a.1.rms.total_cmp(&b.1.rms));
            let kth = aligned[need - 1].1.rms;
            if bound > kth * (1.0 + SHORTLIST_SLACK) + 0.001 {
                break;
            }
        }
        aligned.push((i, correlator.align(part, &entries[i].spectrum)));
    }
    aligned.sort_by(|a, b| a.1.rms.total_cmp(&b.1.rms).then(a.0.cmp(&b.0)));
    aligned.truncate(need.max(1));
    aligned
}

/// The pose that places a template's outline (centroid `from`) on a signal it was aligned with
/// by `al` (centroid `to`): the start of a registration, whether the signal is a part's or
/// another template's.
pub fn placed(correlator: &Correlator, al: &Alignment, from: Pt, to: Pt) -> Similarity {
    Similarity { from, to, angle_rad: al.shift / correlator.bins() as f64 * std::f64::consts::TAU, scale: al.scale }
}

/// How far (relative) the sub-bin refinement of a correlation may land below its whole-bin
/// bound: a parabola through three samples of a smooth distance moves the minimum by a fraction
/// of the samples' spread. `tests/shortlist.rs` checks the shortlist against every template on
/// the simulator's catalogue at every noise level.
pub const SHORTLIST_SLACK: f64 = 0.05;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vision::frame::GrayImage;

    /// A bright plate (radius 150) on a dark belt with a dark hole (radius 40) off its centre.
    fn plate_with_hole() -> (GrayImage, Pt, Pt) {
        let (c, hole) = (Pt::new(200.0, 200.0), Pt::new(240.0, 180.0));
        let mut img = GrayImage::new(400, 400, 50);
        for y in 0..400 {
            for x in 0..400 {
                let p = Pt::new(x as f64, y as f64);
                if (p - c).norm() <= 150.0 && (p - hole).norm() > 40.0 {
                    img.data[y * 400 + x] = 180;
                }
            }
        }
        (img, c, hole)
    }

    #[test]
    fn interior_edges_are_the_rims_of_features_with_normals_towards_the_dark_side() {
        let (img, c, hole) = plate_with_hole();
        let t = Template::from_image(img.view().unwrap(), "plate", 1, Face::Up, None, &Params::default()).unwrap();
        assert!(t.interior.len() >= 20, "{} interior edge points", t.interior.len());
        for &(p, n) in &t.interior {
            // On the hole's rim (the decimated grid is 4 px), never on the outline.
            let r = (p - hole).norm();
            assert!((r - 40.0).abs() <= 6.0, "interior point {p:?} is {r:.1} px from the hole's centre");
            assert!((p - c).norm() < 150.0 - 12.0);
            // From the bright plate into the dark hole.
            let inward = (hole - p).scale(1.0 / r);
            assert!(n.dot(inward) > 0.8, "normal {n:?} at {p:?} does not point into the hole");
        }
        // The rim all round: points in every quarter of it.
        for q in 0..4 {
            let from = q as f64 * std::f64::consts::FRAC_PI_2;
            let quarter = |p: Pt| (p - hole).display_angle().rem_euclid(std::f64::consts::TAU);
            assert!(
                t.interior.iter().any(|&(p, _)| (from..from + std::f64::consts::FRAC_PI_2).contains(&quarter(p))),
                "no rim point in quarter {q}"
            );
        }
    }

    /// A bright disc (radius 220) on the belt and, `gap` px beside it, a small blob of
    /// brightness `blob` (radius 14), joined to the disc by a bridge of the same brightness
    /// `bridge` px wide (0: none).
    fn disc_and_blob(blob: u8, gap: f64, bridge: f64) -> (GrayImage, Pt, f64) {
        let (c, r) = (Pt::new(350.0, 350.0), 220.0);
        let b = Pt::new(350.0 + r + gap + 14.0, 350.0);
        let mut img = GrayImage::new(700, 700, 55);
        for y in 0..700 {
            for x in 0..700 {
                let p = Pt::new(x as f64, y as f64);
                if (p - c).norm() <= r {
                    img.data[y * 700 + x] = 165;
                } else if (p - b).norm() <= 14.0 || (bridge > 0.0 && p.x > c.x && p.x < b.x && (p.y - 350.0).abs() <= bridge / 2.0) {
                    img.data[y * 700 + x] = blob;
                }
            }
        }
        (img, c, r)
    }

    #[test]
    fn a_faint_stain_beside_the_part_stays_out_of_its_outline() {
        // A stain a fifth of the part's contrast, 6 px from its edge: within the coarse
        // closing's reach (5 decimated px of 4), so the coarse region runs round it.
        let (img, c, r) = disc_and_blob(78, 6.0, 0.0);
        let t = Template::from_image(img.view().unwrap(), "disc", 1, Face::Up, None, &Params::default()).unwrap();
        let far = t.outline.iter().map(|p| (*p - c).norm()).fold(0.0, f64::max);
        // The outline crosses the stain's neck a few px out (the profiles there meet the stain
        // first); the stain itself reaches r + 34.
        assert!(far < r + 6.0, "the outline reaches {far:.1} px from the centre (disc radius {r})");
        // The same disc alone on the belt.
        let (alone, _, _) = disc_and_blob(55, 6.0, 0.0);
        let disc = Template::from_image(alone.view().unwrap(), "disc", 1, Face::Up, None, &Params::default()).unwrap().area;
        assert!((t.area - disc).abs() < 0.002 * disc, "area {:.0} px^2, the disc alone's {disc:.0}", t.area);
    }

    #[test]
    fn a_lug_of_the_part_on_a_narrow_neck_stays_in_its_outline() {
        // The same shape in the part's own brightness: a lug, kept.
        let (img, c, r) = disc_and_blob(165, 6.0, 8.0);
        let t = Template::from_image(img.view().unwrap(), "disc", 1, Face::Up, None, &Params::default()).unwrap();
        let far = t.outline.iter().map(|p| (*p - c).norm()).fold(0.0, f64::max);
        assert!(far > r + 6.0 + 26.0, "the lug's far side at {far:.1} px from the centre is missing");
    }

    #[test]
    fn a_plain_part_has_no_interior_edges() {
        let mut img = GrayImage::new(400, 400, 50);
        for y in 100..300 {
            for x in 80..330 {
                img.data[y * 400 + x] = 180;
            }
        }
        let t = Template::from_image(img.view().unwrap(), "block", 1, Face::Up, None, &Params::default()).unwrap();
        assert!(t.interior.is_empty(), "{} interior edge points on a plain block", t.interior.len());
    }
}
