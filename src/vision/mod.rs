//! The vision core: frame in, part estimates out.
//!
//! Pure and synchronous: no files, sockets, clocks other than stage timers, or threads. The
//! pipeline per frame (see ARCHITECTURE.md for the data flow):
//!
//! 1. [`detect`]: decimate, blur, Canny with automatic hysteresis, external contours, closing;
//!    every region above the minimum area is a part candidate ("dispersed parts").
//! 2. [`boundary`]: the outline refined to sub-pixel on the full frame.
//! 3. [`lines`]: LSD segments in the part, the orientation axis, the LFI descriptor.
//! 4. [`signal`] + [`correlate`]: log-polar r(phi) and FFT circular cross-correlation against every
//!    template of every type and face: type, face, angle and scale in one step.
//! 5. [`register`]: the best candidates refined by point-to-line ICP, giving the final pose and
//!    how well each template explains the outline.
//! 6. Confidence (adaptive tolerance over the line features) and the accept/reject decision.

pub mod boundary;
pub mod clump;
pub mod correlate;
pub mod decide;
pub mod detect;
pub mod differ;
pub mod fld;
pub mod frame;
pub mod geometry;
pub mod lines;
pub mod params;
pub mod part;
pub mod register;
pub mod shape;
pub mod signal;
pub mod template;
mod workers;

use std::sync::Arc;
use std::time::Instant;

pub use frame::{FrameError, GrayImage, GrayView, MIN_SIDE};
pub use geometry::Pt;
pub use lines::{LineDetector, LineFeature, Segment};
pub use params::Params;
pub use part::{Face, Reason};
pub use template::{KeepOut, LeftOut, Library, Template, TemplateError};

use decide::{Bounds, Decision, Follows, Local, Measured, Named, NextFit, Order, OutlineFit, RegionFit, Rival};
pub use geometry::Similarity;
use geometry::{area_centroid, bounds};
use register::OutlineIndex;

/// Wall time of each stage, milliseconds, summed over the frame's regions: with regions on two
/// threads ([`Params::threads`]) the stages may add up to more than `total`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Timings {
    /// Coarse regions on the decimated frame.
    pub detect: f64,
    /// Outline refinement on the full frame.
    pub boundary: f64,
    /// Line segments.
    pub lines: f64,
    /// Log-polar correlation against every template.
    pub correlate: f64,
    /// ICP registration of the candidates.
    pub register: f64,
    /// Line-feature confidence and the rival test.
    pub confidence: f64,
    /// Regions of several parts: voting, verification, overlap order.
    pub clump: f64,
    /// Of `clump`: the vote for part poses.
    pub vote: f64,
    /// The whole estimate.
    pub total: f64,
}

/// Stage times add up over a frame's regions (`total` is the frame's own).
impl std::ops::AddAssign for Timings {
    fn add_assign(&mut self, t: Timings) {
        self.detect += t.detect;
        self.boundary += t.boundary;
        self.lines += t.lines;
        self.correlate += t.correlate;
        self.register += t.register;
        self.confidence += t.confidence;
        self.clump += t.clump;
        self.vote += t.vote;
    }
}

/// The estimate for one part of a frame.
#[derive(Debug, Clone)]
pub struct PartEstimate {
    /// Best-matching type; None when the part is not a known type (or several parts).
    pub type_name: Option<String>,
    /// 0 when `type_name` is None.
    pub type_id: u16,
    /// Which face lies up; None with `type_name`.
    pub face: Option<Face>,
    /// Rotation carrying the template (of that type and face) onto the part, degrees in [0, 360).
    pub angle_deg: f64,
    /// The template's origin in the frame (the part's centroid for centred templates), pixels.
    pub x: f64,
    /// See `x`.
    pub y: f64,
    /// Part size relative to its template.
    pub scale: f64,
    /// 0..1: the line features' agreement with the template at the pose.
    pub confidence: f64,
    /// The robot may pick it (`decision` accepts it).
    pub accepted: bool,
    /// `decision`'s verdict as the PLC's REASON (kept beside it: every consumer reads it).
    pub reason: Reason,
    /// The verdict and the numbers behind it (rendered by [`PartEstimate::detail`]).
    pub decision: Decision,
    /// Fraction of the outline explained by the template (the worse of both directions).
    pub fit: f64,
    /// Best template (index into [`Estimator::templates`]) and its pose, when one was registered.
    pub matched: Option<(usize, Similarity)>,
    /// The refined outline, frame pixels.
    pub outline: Vec<Pt>,
    /// The orientation axis (longest-supported segment), if any segment was found.
    pub axis: Option<Segment>,
    /// Line segments inside the part.
    pub segments: Vec<Segment>,
    /// The LFI descriptor: (log r, phi) of the segments in the axis-aligned frame.
    pub descriptor: Vec<LineFeature>,
}

impl PartEstimate {
    /// Moves everything the part holds in pixels by `by`: its position, outline, line features
    /// and the matched template's pose (the overlay draws them, a calibration registers the
    /// template again from that pose).
    pub fn shift(&mut self, by: Pt) {
        self.x += by.x;
        self.y += by.y;
        for q in &mut self.outline {
            *q = *q + by;
        }
        for s in self.segments.iter_mut().chain(self.axis.as_mut()) {
            s.a = s.a + by;
            s.b = s.b + by;
        }
        if let Some((_, pose)) = &mut self.matched {
            pose.to = pose.to + by;
        }
    }

    /// The decision and its numbers as text, for logs and the operator's "why".
    pub fn detail(&self) -> String {
        if self.reason == self.decision.verdict.reason() {
            self.decision.to_string()
        } else {
            format!("{} (after the estimate; the estimate: {})", self.reason, self.decision)
        }
    }

    /// Takes a verdict made after the estimate (the PLC handshake's expected-type rule), so that
    /// the part is shown and counted as the PLC got it; the estimate's own decision stays as the
    /// evidence. Only ever a reject: nothing after the estimate may accept a part.
    pub fn overrule(&mut self, accepted: bool, reason: Reason) {
        if self.accepted && !accepted {
            self.accepted = false;
            self.reason = reason;
        }
    }

    /// A part without a type (yet) at `at`, with the decision so far.
    fn unnamed(at: Pt, outline: Vec<Pt>, decision: Decision) -> Self {
        PartEstimate {
            type_name: None,
            type_id: 0,
            face: None,
            angle_deg: 0.0,
            x: at.x,
            y: at.y,
            scale: 1.0,
            confidence: 0.0,
            accepted: decision.verdict.accepts(),
            reason: decision.verdict.reason(),
            decision,
            fit: 0.0,
            matched: None,
            outline,
            axis: None,
            segments: Vec::new(),
            descriptor: Vec::new(),
        }
    }

    /// Names the part as template `tpl` (library entry `entry`) at `pose`, template pixels to
    /// frame pixels: its type, face, angle and position (the template's origin).
    fn name(&mut self, tpl: &Template, entry: usize, pose: Similarity) {
        let origin = pose.apply(tpl.origin);
        self.type_name = Some(tpl.type_name.clone());
        self.type_id = tpl.type_id;
        self.face = Some(tpl.face);
        self.angle_deg = pose.angle_deg();
        self.x = origin.x;
        self.y = origin.y;
        self.scale = pose.scale;
        self.matched = Some((entry, pose));
    }

    /// Takes the decision: REASON and acceptance follow from it, in this one place, and a
    /// verdict that names no type takes the type away.
    fn conclude(&mut self, decision: Decision) {
        self.reason = decision.verdict.reason();
        self.accepted = decision.verdict.accepts();
        if !decision.verdict.names_type() {
            self.type_name = None;
            self.type_id = 0;
            self.face = None;
        }
        self.decision = decision;
    }
}

/// The estimate for one frame.
#[derive(Debug, Clone)]
pub struct FrameEstimate {
    /// One per part region, in detection order.
    pub parts: Vec<PartEstimate>,
    /// Pieces of material in the frame too small or too unlike any part to be one (bolts,
    /// washers, chips): never part results, counted so that a line can blow them off.
    pub debris: usize,
    /// Robust standard deviation of the background's pixel noise, gray levels.
    pub noise_sigma: f64,
    /// Wall time per stage.
    pub timings: Timings,
    /// The decimation factor of the look that stands: the configured one when a first, coarser
    /// look settled the frame, else the finer one the catalogue's smallest part needs (see
    /// [`Estimator::estimate`]).
    pub decimation: usize,
}

/// Why an estimator cannot be built.
#[derive(Debug, thiserror::Error)]
pub enum EstimatorError {
    /// No template to compare with.
    #[error("the knowledge base has no templates; enroll at least one type and face")]
    Empty,
    /// A parameter out of its range.
    #[error("parameter {name} = {value} is out of range ({expected})")]
    Param {
        /// The parameter.
        name: &'static str,
        /// Its value.
        value: String,
        /// What it must be.
        expected: &'static str,
    },
    /// The worker threads could not be started.
    #[error("cannot start {threads} estimator threads: {why}")]
    Threads {
        /// How many were asked for.
        threads: usize,
        /// The system's reason.
        why: String,
    },
}

/// Estimates part poses in frames against a fixed set of templates.
#[derive(Debug, Clone)]
pub struct Estimator {
    lib: Library,
    params: Params,
    min_area: f64,
    min_debris_area: f64,
    min_template_area: f64,
    max_template_area: f64,
    /// The decimation a frame is looked at first when the catalogue's smallest part needs a
    /// finer one (`Params::coarse_factor` as configured; `params` holds the finer): see
    /// [`Estimator::estimate`].
    first_factor: Option<usize>,
    /// Workers for frames of several regions (`Params::threads` > 1).
    pool: Option<Arc<rayon::ThreadPool>>,
}

/// How far below the least fit ([`Params::min_fit`]) the closest template's registration may
/// start before it is given up (see [`register::register_unless`]): outlines of one part come
/// well within it even before the registration has converged.
const GIVE_UP_MARGIN: f64 = 0.15;

/// Decimated pixels of rms radius a part needs: line features and the closing need that much,
/// whatever the camera's resolution. The decimation goes only as far as the catalogue's smallest
/// part keeps it, and a first, coarser look settles only parts that keep it there.
const DECIMATED_RADIUS: f64 = 45.0;

/// What one coarse region holds: its parts, the debris found in it, and the time each stage took.
struct Regional {
    parts: Vec<PartEstimate>,
    debris: usize,
    timings: Timings,
}

/// What the single-part look at a region leaves for the region search.
struct Looked {
    /// Part-to-belt contrast along the region's outline, gray levels.
    contrast: f64,
    /// The part is brighter than the belt.
    brighter: bool,
    /// The frame's pixel noise, gray levels.
    noise: f64,
    /// The region's line segments down to [`Estimator::least_segment`], when they were found.
    segments: Option<Vec<Segment>>,
    /// The region's area, frame pixels, and its signature's correlation distance to the
    /// nearest template, when it was looked at whole.
    area: f64,
    nearest: Option<f64>,
}

/// What the region search saw of a region, for measuring each part it found there.
struct Seen<'a> {
    frame: GrayView<'a>,
    coarse: &'a detect::Coarse,
    /// The region's refined outline, frame pixels, and its index.
    outline: &'a [Pt],
    outline_index: &'a OutlineIndex,
    /// The region's line segments down to [`Estimator::least_segment`].
    segments: &'a [Segment],
    /// The frame's pixel noise and the part-to-belt contrast, gray levels.
    noise: f64,
    contrast: f64,
    /// The part is brighter than the belt.
    brighter: bool,
    /// Frame points where the part's own outline is not seen (against or under another part
    /// found in the region): nothing is judged there.
    excused: &'a (dyn Fn(Pt) -> bool + Sync),
    /// Frame points where the part lies on top of another found in the region (inside it):
    /// its edge there runs over that part's surface ([`differ::compare`]).
    over: &'a (dyn Fn(Pt) -> bool + Sync),
    /// Where the refinement found no edge near the coarse outline and bridged the stretch with
    /// a chord (see [`boundary::refine`]): the chords (longer than the refinement's `search`)
    /// and that search, frame pixels. The part's edge lies farther than the search from them,
    /// as at the back of a notch whose shadow the coarse edges followed.
    bridged: &'a [(Pt, Pt)],
    search: f64,
}

impl Seen<'_> {
    /// Whether the region's outline tells nothing at `q`: against or under another part found
    /// here, or within twice the search of a chord the refinement bridged.
    fn unseen(&self, q: Pt) -> bool {
        (self.excused)(q) || by_chord(self.bridged, self.search, q)
    }
}

/// One template explaining a part found in a region: its registration, the image's support for
/// it and its outline tolerance.
#[derive(Clone, Copy)]
struct Explanation {
    entry: usize,
    reg: register::Registration,
    support: f64,
    tolerance: f64,
}

struct Candidate {
    entry: usize,
    reg: register::Registration,
    corr_rms: f64,
    tolerance: f64,
}

impl Estimator {
    /// An estimator for these templates (every type and face enrolled) with these parameters.
    pub fn new(templates: &[Template], params: Params) -> Result<Self, EstimatorError> {
        if templates.is_empty() {
            return Err(EstimatorError::Empty);
        }
        let check = |ok: bool, name: &'static str, value: String, expected: &'static str| {
            if ok { Ok(()) } else { Err(EstimatorError::Param { name, value, expected }) }
        };
        check((1..=8).contains(&params.coarse_factor), "coarse_factor", params.coarse_factor.to_string(), "1..=8")?;
        check(params.blur_sigma > 0.0 && params.blur_sigma <= 10.0, "blur_sigma", params.blur_sigma.to_string(), "0 < sigma <= 10")?;
        check((0.0..=1.0).contains(&params.accept_threshold), "accept_threshold", params.accept_threshold.to_string(), "0..=1")?;
        check(params.signal_bins >= 64, "signal_bins", params.signal_bins.to_string(), ">= 64")?;
        check(params.candidates >= 1, "candidates", params.candidates.to_string(), ">= 1")?;
        check((1..=64).contains(&params.threads), "threads", params.threads.to_string(), "1..=64")?;
        let smallest = templates.iter().map(|t| t.area).fold(f64::INFINITY, f64::min);
        let largest = templates.iter().map(|t| t.area).fold(0.0, f64::max);
        let min_area = params.min_area.unwrap_or(0.25 * smallest);
        let pool = match params.threads {
            1 => None,
            n => Some(Arc::new(
                rayon::ThreadPoolBuilder::new()
                    .num_threads(n)
                    .thread_name(|i| format!("lfi-vision-{i}"))
                    .build()
                    .map_err(|e| EstimatorError::Threads { threads: n, why: e.to_string() })?,
            )),
        };
        let lib = Library::on(templates, params.signal_bins, pool.as_deref());
        let mut params = params;
        let fine = params.coarse_factor.min(((lib.smallest_radius / DECIMATED_RADIUS) as usize).max(1));
        let first_factor = (fine < params.coarse_factor).then_some(params.coarse_factor);
        params.coarse_factor = fine;
        let min_debris_area = params.debris_fraction * smallest;
        Ok(Self { lib, params, min_area, min_debris_area, min_template_area: smallest, max_template_area: largest, first_factor, pool })
    }

    /// How far (template pixels) a part's outline may lie from template `entry`'s and still be
    /// on it, at frame noise `noise`: outlines of rounded parts shift with the light by a few
    /// pixels, larger parts' more; noise adds jitter. One rule for the single-part path, the
    /// region search and a calibration's re-registration.
    fn tolerance(&self, entry: usize, noise: f64) -> f64 {
        let p = &self.params;
        self.clean_tolerance(noise) + p.fit_tolerance_rel * self.lib.entries[entry].template.rms_radius()
    }

    /// The part of [`Estimator::tolerance`] that does not grow with the part's size: how far
    /// (px) an outline at frame noise `noise` strays from its template's on a clean edge.
    fn clean_tolerance(&self, noise: f64) -> f64 {
        self.params.fit_tolerance + noise / 15.0
    }

    /// The shortest segment any template's part keeps (5 % of the smallest one's diagonal).
    fn least_segment(&self) -> f64 {
        self.params.min_segment_fraction * self.lib.entries.iter().map(|e| e.diag).fold(f64::INFINITY, f64::min)
    }

    /// The limits its decisions are held to (recorded with each decision).
    fn limits(&self) -> decide::Limits {
        let p = &self.params;
        decide::Limits {
            min_fit: p.min_fit,
            max_foreign: p.max_foreign,
            min_support: p.min_support,
            scale_range: p.scale_range,
            ambiguity_margin: p.ambiguity_margin,
            confidence_margin: p.confidence_margin,
            accept_threshold: p.accept_threshold,
            touching_area_ratio: p.touching_area_ratio,
            departure_depth: p.departure_depth,
            departure_width: p.departure_width,
            max_area: p.touching_area_ratio * self.max_template_area * (p.scale_range.1 * p.scale_range.1),
        }
    }

    /// The line features' error weight at this noise and part-to-belt contrast: lambda0 (1 -
    /// alpha noise/contrast), the method's lambda with the noise relative to the contrast.
    fn lambda(&self, noise: f64, contrast: f64) -> f64 {
        let p = &self.params;
        let noise_level = if contrast > 0.0 { (noise / contrast).clamp(0.0, 1.0) } else { 1.0 };
        p.lambda0 * (1.0 - p.alpha * noise_level)
    }

    /// The parameters in force.
    pub fn params(&self) -> &Params {
        &self.params
    }
    /// The templates, in the order [`PartEstimate::matched`] indexes them.
    pub fn templates(&self) -> impl Iterator<Item = &Template> {
        self.lib.entries.iter().map(|e| &e.template)
    }

    /// Registers template `entry` again onto `outline` given in another frame of the same scale
    /// (a calibration's rectified view of the part), from `init`: the pose, template pixels to
    /// that frame. None when `entry` is not a template of this estimator or the outline is too
    /// short to register.
    pub fn reregister(&self, entry: usize, outline: &[Pt], init: Similarity) -> Option<Similarity> {
        let e = self.lib.entries.get(entry)?;
        if outline.len() < 16 {
            return None;
        }
        // A rectified view has no pixel noise of its own.
        let reg = register::register(outline, &e.index, init, self.tolerance(entry, 0.0), 1);
        let p = reg.pose;
        (p.to.x.is_finite() && p.to.y.is_finite() && p.angle_rad.is_finite() && p.scale.is_finite()).then_some(p)
    }

    /// The estimate of a frame, or of its region of interest `[x, y, width, height]` with every
    /// part's pixels moved back into the whole frame's. A region that does not fit the frame
    /// (or leaves less than [`MIN_SIDE`] a side) is an error naming both: a camera whose
    /// resolution was changed under a configured ROI.
    pub fn estimate_in(&self, img: &GrayImage, roi: Option<[usize; 4]>) -> Result<FrameEstimate, FrameError> {
        let Some([x, y, w, h]) = roi else { return self.estimate(img.view()?) };
        let misfit = FrameError::Roi { roi: [x, y, w, h], width: img.width, height: img.height };
        let crop = img.crop(x, y, w, h).filter(|c| c.width >= MIN_SIDE && c.height >= MIN_SIDE).ok_or(misfit)?;
        let mut fe = self.estimate(crop.view()?)?;
        let shift = Pt::new(x as f64, y as f64);
        for p in &mut fe.parts {
            p.shift(shift);
        }
        Ok(fe)
    }

    /// Estimates every part in the frame.
    pub fn estimate(&self, frame: GrayView<'_>) -> Result<FrameEstimate, FrameError> {
        let t0 = Instant::now();
        // Pixel noise from the whole frame: the median of pixel differences is not moved by the
        // few percent of pixels on part edges.
        let noise = boundary::noise_sigma(frame, &[]);
        // Decimation is as coarse as the smallest part in the catalogue allows
        // ([`DECIMATED_RADIUS`]); one small type would make every frame pay
        // for the finer one (detection is half a part's time). So a frame is first looked at
        // as coarsely as configured, and that look stands when each region in it is one part
        // the single-part look accepts as a type large enough for it (an empty belt, or
        // debris only, included). Anything else (a reject, a small type, a region of several
        // parts) is looked at again, the whole frame, at the finer factor, as if the first
        // look had not been: the region search and every reject see what they always saw.
        let effective = |f: usize| detect::effective_factor(f, frame.width(), frame.height());
        if let Some(f) = self.first_factor.filter(|&f| effective(f) > effective(self.params.coarse_factor))
            && let Some(first) = self.estimate_at(frame, noise, f, Some(DECIMATED_RADIUS * effective(f) as f64), t0)?
        {
            return Ok(first);
        }
        Ok(self.estimate_at(frame, noise, self.params.coarse_factor, None, t0)?.expect("every region is kept"))
    }

    /// [`Estimator::estimate`] at decimation `factor`, with the frame's `noise`; times from
    /// `t0`. With `settle` (a first, coarser look), only what the first look may settle: None as
    /// soon as a region is not one part accepted as a type of at least that rms radius.
    fn estimate_at(
        &self,
        frame: GrayView<'_>,
        noise: f64,
        factor: usize,
        settle: Option<f64>,
        t0: Instant,
    ) -> Result<Option<FrameEstimate>, FrameError> {
        let mut tm = Timings::default();
        let t = Instant::now();
        let detect = detect::DetectParams { factor, ..self.params.detect_params(self.min_area, self.min_debris_area) };
        let coarse = detect::detect(frame, &detect)?;
        tm.detect = ms(t);

        // Each region on its own; several at once on the second core (`Params::threads`), one
        // on the calling thread only.
        let region = |blob: &detect::Blob| match settle {
            None => self.estimate_blob(frame, &coarse, blob, noise).map(Some),
            Some(large) => {
                let mut tm = Timings::default();
                let (est, _) = self.estimate_part(frame, &coarse, blob, noise, &mut tm)?;
                let settled = est.accepted && est.matched.is_some_and(|(e, _)| self.lib.entries[e].template.rms_radius() >= large);
                Ok(settled.then_some(Regional { parts: vec![est], debris: 0, timings: tm }))
            }
        };
        let each = workers::each(self.pool.as_deref(), &coarse.blobs, region);
        let mut parts = Vec::with_capacity(coarse.blobs.len());
        let mut debris = coarse.debris;
        for r in each {
            let Some(r) = r? else { return Ok(None) };
            parts.extend(r.parts);
            debris += r.debris;
            tm += r.timings;
        }
        parts.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
        tm.total = ms(t0);
        Ok(Some(FrameEstimate { parts, debris, noise_sigma: noise, timings: tm, decimation: coarse.factor }))
    }

    /// The parts of one coarse region: looked at as one part, and searched for several when
    /// one template cannot explain it; also the debris found in it, and the time each stage took.
    fn estimate_blob(&self, frame: GrayView<'_>, coarse: &detect::Coarse, blob: &detect::Blob, noise: f64) -> Result<Regional, FrameError> {
        let mut tm = Timings::default();
        let (est, looked) = self.estimate_part(frame, coarse, blob, noise, &mut tm)?;
        // A region one template cannot explain may hold several parts, or one part whose
        // silhouette came out wrong: look for each part in it by its own evidence.
        if est.decision.verdict.may_be_several() && self.worth_searching(&looked) {
            let t = Instant::now();
            let found = self.estimate_region(frame, coarse, blob, &est, looked, &mut tm)?;
            tm.clump += ms(t);
            if let Some((parts, debris)) = found {
                let verdicts: Vec<&decide::Verdict> = parts.iter().map(|p| &p.decision.verdict).collect();
                if decide::search_explains(&est.decision.verdict, &verdicts) {
                    return Ok(Regional { parts, debris, timings: tm });
                }
            }
        }
        Ok(Regional { parts: vec![est], debris: 0, timings: tm })
    }

    /// Whether a region the single-part look could not explain may hold parts the region search
    /// would find: not when no template's signature comes near it
    /// ([`Params::far_signature`]) and it is too small to hold two of the smallest parts at the
    /// smallest scale, side by side. Such a region is one part of a type not enrolled; its
    /// single-part verdict stands (the unknown part costs a fifth of the search's time).
    fn worth_searching(&self, looked: &Looked) -> bool {
        let p = &self.params;
        let two_parts = 2.0 * self.min_template_area * p.scale_range.0 * p.scale_range.0;
        let far = looked.nearest.is_some_and(|rms| rms > p.far_signature);
        !far || looked.area >= two_parts
    }

    /// The parts of a region the single-part path rejected as touching or unknown, each found
    /// and verified on its own (see [`clump`]); None when no template explains any of it, so
    /// that the single-part verdict stands. Also returns the debris found in the region.
    fn estimate_region(
        &self,
        frame: GrayView<'_>,
        coarse: &detect::Coarse,
        blob: &detect::Blob,
        whole: &PartEstimate,
        looked: Looked,
        tm: &mut Timings,
    ) -> Result<Option<(Vec<PartEstimate>, usize)>, FrameError> {
        let p = &self.params;
        let (contrast, noise) = (looked.contrast, looked.noise);
        let region = clump::Region { coarse, blob, outline: &whole.outline, noise, contrast, pool: self.pool.as_deref() };
        let ex = clump::explain(&self.lib, &region, |ei| self.tolerance(ei, noise), self.min_debris_area, true);
        tm.vote += ex.vote_ms;
        if ex.parts.is_empty() {
            #[cfg(debug_assertions)]
            self.check_glance(&region, None, &[]);
            return Ok(None);
        }
        // The region's segments down to the smallest part's minimum length; each part keeps
        // those its own size allows (5 % of its diagonal), as a separate part would.
        let segments = match looked.segments {
            Some(s) => s,
            None => lines::part_segments(p.line_detector, &coarse.small, &coarse.edges, coarse.factor, blob, self.least_segment())?,
        };
        let outline_index = OutlineIndex::of_frame(&whole.outline);
        let search = p.refine_params(coarse.factor).search;
        let bridged = bridged(&whole.outline, search);
        let seen = Seen {
            frame,
            coarse,
            outline: &whole.outline,
            outline_index: &outline_index,
            segments: &segments,
            noise,
            contrast,
            brighter: looked.brighter,
            excused: &|_| false,
            over: &|_| false,
            bridged: &bridged,
            search,
        };
        let (out, debris) = self.region_parts(&seen, &ex);
        #[cfg(debug_assertions)]
        self.check_glance(&region, Some(&seen), &out);
        Ok(Some((out, debris)))
    }

    /// Each part the region search found measured on its own, side by side on the pool, and the
    /// material it left: a piece the size of a part is an unexplained part, smaller ones debris.
    fn region_parts(&self, seen: &Seen<'_>, ex: &clump::Explained) -> (Vec<PartEstimate>, usize) {
        let mut out = workers::each(self.pool.as_deref(), &ex.parts, |f| self.region_part(seen, ex, f));
        // A part lying on another is named there as it was itself decided: the search's first
        // explanation of it may have given way to a look-alike (a face down found first as its
        // face up), and the lower part's reason must not name the one set aside.
        for (i, f) in ex.parts.iter().enumerate() {
            let Some(k) = f.under else { continue };
            let (Some(type_name), Some(face)) = (out[k].type_name.clone(), out[k].face) else { continue };
            let by = Named { type_name, face };
            let d = &mut out[i].decision;
            if let Order::Under(n) = &mut d.measured.order {
                *n = by.clone();
            }
            if let decide::Verdict::Covered { by: b } = &mut d.verdict {
                *b = by;
            }
        }
        let mut debris = 0;
        for &(area, c) in &ex.leftover {
            if area < self.min_area {
                debris += 1;
                continue;
            }
            let measured = Measured { unexplained: Some(area), ..Measured::default() };
            out.push(PartEstimate::unnamed(c, Vec::new(), decide::decide(measured, self.limits())));
        }
        (out, debris)
    }

    /// In tests, a catalogue's region search (whose vote glances first) is held against every
    /// template voting in full: the same verdicts, types and faces, and poses within a pixel and
    /// a half and half a degree (a quarter of `eval`'s 2 degrees: an ICP from another start, a
    /// look-alike's pose rather than the vote's, ends up to about a pixel away), in any order.
    /// `seen` is what the region offered its parts (None: the glance found none, so the full
    /// vote must not).
    #[cfg(debug_assertions)]
    fn check_glance(&self, region: &clump::Region<'_>, seen: Option<&Seen<'_>>, glanced: &[PartEstimate]) {
        if self.lib.entries.len() <= clump::GLANCE_FROM {
            return;
        }
        let full = clump::explain(&self.lib, region, |ei| self.tolerance(ei, region.noise), self.min_debris_area, false);
        let full = match (seen, full.parts.is_empty()) {
            (_, true) => Vec::new(),
            (Some(seen), false) => self.region_parts(seen, &full).0,
            (None, false) => panic!("the full vote found {} parts where the glance found none", full.parts.len()),
        };
        let verdict = |e: &PartEstimate| (e.type_id, e.face, e.accepted, e.reason);
        let near = |a: &PartEstimate, b: &PartEstimate| {
            let turn = (a.angle_deg - b.angle_deg).rem_euclid(360.0);
            verdict(a) == verdict(b) && (a.x - b.x).hypot(a.y - b.y) < 1.5 && turn.min(360.0 - turn) < 0.5
        };
        let all: Vec<_> = glanced.iter().map(verdict).collect();
        // In any order: the order parts are found in (and listed) follows the hypotheses'.
        let mut unmatched: Vec<&PartEstimate> = full.iter().collect();
        let matched = glanced.iter().all(|a| match unmatched.iter().position(|b| near(a, b)) {
            Some(k) => {
                unmatched.swap_remove(k);
                true
            }
            None => false,
        });
        assert!(
            glanced.len() == full.len() && matched,
            "the glance decided {all:?} where the full vote decides {:?}",
            full.iter().map(verdict).collect::<Vec<_>>()
        );
    }

    /// One part the region search found: named at its pose, measured, decided.
    fn region_part(&self, seen: &Seen<'_>, ex: &clump::Explained, f: &clump::Found) -> PartEstimate {
        let p = &self.params;
        let limits = self.limits();
        let lambda = self.lambda(seen.noise, seen.contrast);
        // Of the two explanations the search found for this material (another type or face
        // nearly as well supported), the one the part follows where their templates differ.
        // Where another part found here lies against or over it, its own outline is not seen:
        // neither compared nor judged there.
        let me = ex.parts.iter().position(|o| std::ptr::eq(o, f));
        let others: Vec<(OutlineIndex, geometry::Inside, bool)> = ex
            .parts
            .iter()
            .filter(|o| !std::ptr::eq(*o, f))
            .map(|o| {
                let at = o.reg.pose.forward();
                let outline: Vec<Pt> = self.lib.entries[o.entry].template.outline.iter().map(|&q| at.apply(q)).collect();
                (OutlineIndex::of_frame(&outline), geometry::Inside::new(&outline), me.is_some() && o.under == me)
            })
            .collect();
        let reach = 3.0 * self.clean_tolerance(seen.noise);
        let excused = |q: Pt| others.iter().any(|(index, inside, _)| index.any_within(q, reach) || inside.contains(q));
        let over = |q: Pt| others.iter().any(|(_, inside, beneath)| *beneath && inside.contains(q));
        let seen = &Seen { excused: &excused, over: &over, ..*seen };
        // Every other explanation is held against the first, as the separate-part path holds
        // every candidate: one the part follows where they differ is the part; else the rival
        // reported is the first tied one the part does not clearly leave behind, else the first
        // tied, else the best supported.
        let first = Explanation { entry: f.entry, reg: f.reg, support: f.support, tolerance: f.tolerance };
        // A rival supported less than the best by more than the ambiguity margin never ties
        // ([`Rival::ties`]): it is measured only as the best supported, reported when none ties.
        let judged: Vec<(Explanation, Rival)> = f
            .rivals
            .iter()
            .enumerate()
            .filter(|&(k, r)| k == 0 || r.2 >= first.support - limits.ambiguity_margin)
            .map(|(_, &(entry, reg, support))| {
                let s = Explanation { entry, reg, support, tolerance: self.tolerance(entry, seen.noise) };
                let r = self.region_rival(seen, &first, &s, &[], 1.0, lambda);
                (s, r)
            })
            .collect();
        let follows = |r: &Rival| r.local.map(|l| l.follows());
        let tied: Vec<&(Explanation, Rival)> = judged.iter().filter(|(_, r)| r.ties(&limits)).collect();
        // Where the outlines do not tell, what lies inside may tell for the rival (as on the
        // separate-part path, `inside`), when the image explains as much of the rival's outline
        // as a part needs: one that leaves part of it unexplained where the first explains all
        // is told by its outline after all (on the unseen catalogue of seed 97 a link of another
        // size, at 1.11 of its scale, showed its slot's edges along the part's own).
        let inside_tells = |s: &Explanation, r: &Rival| {
            r.features.is_some_and(|x| x.tell_second()) && (s.support >= limits.min_support || first.support < limits.min_support)
        };
        // Where the outlines do not tell for the first either, a rival whose outline the region's
        // follows at the tight tolerance by more than the ambiguity margin beyond the first's is
        // the closer explanation, as the separate-part path names its best by fit: the vote
        // found the first at a pose a little turned (on the unseen catalogue of seed 101, a
        // T019 found as its look-alike T020 turned 8 degrees, rms 2.2 px).
        let closer = |r: &Rival| follows(r) != Some(Follows::Best) && r.fit > r.best + limits.ambiguity_margin;
        let (best, other) = match tied
            .iter()
            .find(|(_, r)| follows(r) == Some(Follows::Rival))
            .or(tied.iter().find(|(s, r)| inside_tells(s, r)))
            .or(tied.iter().find(|(_, r)| closer(r)))
        {
            Some((s, _)) => (*s, Some(first)),
            None => {
                let reported = tied.iter().find(|(_, r)| follows(r) != Some(Follows::Best)).or(tied.first()).map(|(s, _)| *s);
                (first, reported.or(judged.first().map(|(s, _)| *s)))
            }
        };
        let e = &self.lib.entries[best.entry];
        let tpl = &e.template;
        let pose = best.reg.pose;
        let to_frame = pose.forward();
        let placed = tpl.outline.iter().map(|&q| to_frame.apply(q)).collect();
        let mut est = PartEstimate::unnamed(Pt::new(0.0, 0.0), placed, decide::decide(Measured::default(), limits));
        est.name(tpl, best.entry, pose);
        est.fit = best.support;
        let diag = e.diag * pose.scale;
        let segments: Vec<Segment> = seen.segments.iter().filter(|s| s.len() >= p.min_segment_fraction * diag).copied().collect();
        est.confidence = confidence(&tpl.segments, &segments, &pose, diag, lambda);
        let mut m = Measured {
            border: Some(outline_bounds(&est.outline, seen.frame)),
            region: Some(RegionFit {
                best: named(tpl),
                support: best.support,
                coverage: best.reg.coverage,
                rms: best.reg.rms,
                scale: pose.scale,
            }),
            order: match (f.under, f.order_unclear) {
                (Some(k), _) => Order::Under(named(&self.lib.entries[ex.parts[k].entry].template)),
                (None, true) => Order::Unclear,
                (None, false) => Order::Free,
            },
            rival: other.map(|o| self.region_rival(seen, &best, &o, &segments, diag, lambda)),
            lines: Some(decide::Lines { confidence: est.confidence, noise: seen.noise, contrast: seen.contrast, lambda }),
            alone: ex.parts.len() == 1 && ex.leftover.iter().all(|&(area, _)| area < self.min_area),
            ..Measured::default()
        };
        // Where it departs from its template: alone in its region (its outline is the part's
        // own), or told from a sibling (which it must follow everywhere else). Either way as
        // closely as a clean outline at this noise follows its template (see `estimate_part`),
        // not within the region fit's own residual: an unknown fork whose arms are longer than
        // the known one's loosens that fit, and a separation widened with it hides the arms.
        let sibling = m.rival.as_ref().is_some_and(|r| r.ties(&limits) && r.local.map(|l| l.follows()) == Some(Follows::Best));
        // The departure from the best template at the separation `near` gives, points where
        // `excused` holds (given `apart`) not judged, the region's outline beyond the template's
        // judged when `beyond`.
        let departure = |near: f64, excused: &dyn Fn(Pt, f64) -> bool, beyond: bool| {
            let (apart, min_run) = differ::separation(near);
            let placed = differ::Placed { index: &e.index, pose, centroid: tpl.centroid };
            let light = differ::Light::new(seen.frame, seen.brighter, seen.contrast, seen.noise);
            decide::telling(
                differ::departures(seen.outline_index, placed, Some(&light), &|q| excused(q, apart), beyond, apart, min_run),
                &limits,
            )
        };
        let tight = register::tight_tolerance(best.reg.rms, p.fit_tolerance, best.tolerance);
        if m.alone || sibling {
            let near = self.clean_tolerance(seen.noise);
            m.departure = departure(near, &|q, _| (seen.excused)(q), m.alone);
            // In a region with others, where the outline leaves the best template may be a
            // neighbour's doing as well as the part's: the region's outline is then no clean
            // view of the part. The departure counts as hidden, so that only what is seen
            // followed where the siblings differ tells ([`Local::follows`]); else the line
            // features decide, as they did before siblings were compared. Alone, it is the
            // part's own outline, as on the separate-part path.
            if let (true, false, Some(d), Some(local)) = (sibling, m.alone, m.departure, m.rival.as_mut().and_then(|r| r.local.as_mut())) {
                local.hidden_len += d.len;
                m.departure = None;
            }
        } else if best.support < limits.min_support {
            // Beside others and part of its outline unexplained: something lies on or against
            // it, or it is a type not enrolled. Where the template's outline runs over open belt
            // (outside the region, away from every part found here), nothing hides it: the part
            // lacks material the template has, its own difference. Inside the region's
            // silhouette it may be under or against something else, and is not judged; nor is
            // the region's outline beyond the template's (it runs around whatever else lies
            // here).
            let region = geometry::Inside::new(seen.outline);
            let covered = |q: Pt, apart: f64| (seen.excused)(q) || (region.contains(q) && !seen.outline_index.any_within(q, apart));
            m.departure = departure(tight, &covered, false);
        }
        // The footprint is looked at only for a part nothing else rejects.
        if decide::failed(&m, &limits).is_none() {
            m.blocked = Some(blocked_footprint(seen.coarse, tpl, &pose, &est.outline));
        }
        est.conclude(decide::decide(m, limits));
        est
    }

    /// `other`, another type or face the region search found explaining the same material as
    /// `best`, held against it: by the image's support for each; at the tight tolerance, by how
    /// much of each template's outline the region's outline covers; by where the two templates
    /// differ ([`differ::compare`] on the region's outline); with its line features' confidence
    /// at its own pose against `segments` (none given: not needed, 0).
    fn region_rival(
        &self,
        seen: &Seen<'_>,
        best: &Explanation,
        other: &Explanation,
        segments: &[Segment],
        diag: f64,
        lambda: f64,
    ) -> Rival {
        // The outline's noise is no more than the closer of the two fits' residuals: a template
        // placed a little askew on the material (a face down's mirror image turned to fit its
        // round body) leaves a residual that would blur the very stretches where the two differ.
        let tight = register::tight_tolerance(best.reg.rms.min(other.reg.rms), self.params.fit_tolerance, best.tolerance);
        let coverage = |entry: usize, pose| register::measure(seen.outline, &self.lib.entries[entry].index, pose, tight, 1).coverage;
        let placed = |x: &Explanation| {
            let e = &self.lib.entries[x.entry];
            differ::Placed { index: &e.index, pose: x.reg.pose, centroid: e.template.centroid }
        };
        let tpl = &self.lib.entries[other.entry].template;
        let light = differ::Light::new(seen.frame, seen.brighter, seen.contrast, seen.noise);
        // Where the region's outline tells nothing (a neighbour, a bridged chord), the frame's
        // light may.
        let unseen = |q: Pt| seen.unseen(q);
        let mut rival = Rival {
            name: named(tpl),
            fit: coverage(other.entry, other.reg.pose),
            best: coverage(best.entry, best.reg.pose),
            tolerance: tight,
            support: Some((other.support, best.support)),
            confidence: if segments.is_empty() { 0.0 } else { confidence(&tpl.segments, segments, &other.reg.pose, diag, lambda) },
            local: Some(differ::compare(seen.outline_index, placed(best), placed(other), &unseen, seen.over, Some(&light), tight)),
            features: None,
        };
        // Where the outlines do not tell the two apart (two faces of one outline), what the
        // image shows inside the part, away from any neighbour, may.
        if rival.outlines_do_not_tell(&self.limits()) {
            let edge = shape::EdgeTest::new(seen.coarse, seen.noise, seen.contrast);
            let interior = |x: &Explanation| self.lib.entries[x.entry].template.interior.as_slice();
            rival.features =
                Some(shape::own_features(&edge, (interior(best), &best.reg.pose), (interior(other), &other.reg.pose), seen.excused));
        }
        rival
    }

    /// A separate region, looked at as one part: its outline, line features and best template
    /// measured step by step, each step only while the ladder has not rejected it; also what the
    /// region search needs should it take over.
    fn estimate_part(
        &self,
        frame: GrayView<'_>,
        coarse: &detect::Coarse,
        blob: &detect::Blob,
        noise: f64,
        tm: &mut Timings,
    ) -> Result<(PartEstimate, Looked), FrameError> {
        let p = &self.params;
        let limits = self.limits();
        // The outline, refined on the full frame.
        let t = Instant::now();
        let refined = boundary::refine(frame, &blob.outline, noise, &p.refine_params(coarse.factor));
        let (contrast, brighter, outline) = (refined.contrast, refined.brighter, refined.outline);
        let (area, centroid) = area_centroid(&outline);
        let area = area.abs();
        let mut est = PartEstimate::unnamed(centroid, outline.clone(), decide::decide(Measured::default(), limits));
        tm.boundary += ms(t);
        // Whole in view (the coarse region of a whole part may reach the edge through the
        // closing, so the refined outline decides) and the size of one part at most.
        let mut m = Measured { border: Some(outline_bounds(&outline, frame)), area: Some(area), ..Measured::default() };
        if let Some(d) = decide::failed(&m, &limits) {
            est.conclude(d);
            return Ok((est, Looked { contrast, brighter, noise, segments: None, area, nearest: None }));
        }

        // Its line features.
        let t = Instant::now();
        let (lo, hi) = bounds(&outline);
        let diag = (hi - lo).norm();
        let all = self.line_features(coarse, blob, diag, centroid, &mut est)?;
        tm.lines += ms(t);

        // The best template and its pose: by outline fit, and between templates that fit alike
        // (revisions of one part), by where they differ.
        let (aligned, mut cands) = self.candidates(&outline, centroid, noise, tm);
        let looked = Looked { contrast, brighter, noise, segments: Some(all), area, nearest: Some(aligned[0].1.rms) };
        let fitted = |est: &mut PartEstimate, best: &Candidate| {
            est.fit = best.reg.fit();
            est.scale = best.reg.pose.scale;
            est.matched = Some((best.entry, best.reg.pose));
        };
        fitted(&mut est, &cands[0]);
        m.outline = Some(self.outline_fit(&aligned, &cands));
        if let Some(d) = decide::failed(&m, &limits) {
            est.conclude(d);
            return Ok((est, looked));
        }
        let t = Instant::now();
        let lambda = self.lambda(noise, contrast);
        let edge = shape::EdgeTest::new(coarse, noise, contrast);
        // Where the refinement bridged a stretch with a chord, the outline tells nothing there
        // and the frame's light may, as on the region path ([`Seen::unseen`]).
        let search = p.refine_params(coarse.factor).search;
        let chords = bridged(&outline, search);
        let unseen = |q: Pt| by_chord(&chords, search, q);
        let light = differ::Light::new(frame, brighter, contrast, noise);
        let view = Unseen { unseen: &unseen, light: &light };
        m.rival = self.rival(&outline, &mut cands, &est.segments, diag, lambda, &limits, &view);
        // Where the outlines do not tell the two apart, what lies inside may; when it tells for
        // the rival, the rival is the part (registered fully, first in `cands`, ties looked at
        // again from it).
        if let Some(k) = self.inside(&mut m.rival, &cands, &edge, &limits) {
            let e = &self.lib.entries[cands[k].entry];
            cands[k].reg = register::register(&outline, &e.index, cands[k].reg.pose, cands[k].tolerance, 1);
            cands.swap(0, k);
            m.rival = self.rival(&outline, &mut cands, &est.segments, diag, lambda, &limits, &view);
            self.inside(&mut m.rival, &cands, &edge, &limits);
        }
        tm.confidence += ms(t);
        if cands[0].entry != est.matched.map_or(usize::MAX, |(e, _)| e) {
            fitted(&mut est, &cands[0]);
            m.outline = Some(self.outline_fit(&aligned, &cands));
            if let Some(d) = decide::failed(&m, &limits) {
                est.conclude(d);
                return Ok((est, looked));
            }
        }
        let best = &cands[0];
        let tpl = &self.lib.entries[best.entry].template;
        let pose = best.reg.pose;
        // From here on the part has a type, face and pose, accepted or not.
        est.name(tpl, best.entry, pose);

        // It must follow the best everywhere (told from a tied sibling by where the two differ,
        // everywhere else), as closely as an outline of the part at this frame's noise follows
        // its own template (the fit tolerance and the noise's share of the tolerance, not this
        // outline's residual: a loose fit must not widen what counts as following, or a
        // different part that only resembles the best passes).
        // Looked for only where one can be: a run of outline farther than `apart` from the
        // other is farther than the fit's tolerance too, so when the outline the fit left
        // unexplained on either side is shorter than half a run, there is none (most parts:
        // the search would cost a tenth of the estimate).
        let (apart, min_run) = differ::separation(self.clean_tolerance(noise));
        let perimeter = |pts: &[Pt]| pts.iter().zip(pts.iter().cycle().skip(1)).map(|(a, b)| (*b - *a).norm()).sum::<f64>();
        let unexplained = (1.0 - best.reg.coverage) * perimeter(&tpl.outline) * pose.scale + (1.0 - best.reg.inliers) * perimeter(&outline);
        if best.tolerance > apart || unexplained >= 0.5 * min_run {
            let placed = differ::Placed { index: &self.lib.entries[best.entry].index, pose, centroid: tpl.centroid };
            let light = differ::Light::new(frame, brighter, contrast, noise);
            let found = differ::departures(&OutlineIndex::of_frame(&outline), placed, Some(&light), &|_| false, true, apart, min_run);
            m.departure = decide::telling(found, &limits);
        }

        // The line features at the pose.
        let t = Instant::now();
        est.confidence = confidence(&tpl.segments, &est.segments, &pose, diag, lambda);
        m.lines = Some(decide::Lines { confidence: est.confidence, noise, contrast, lambda });
        tm.confidence += ms(t);
        // The footprint is looked at only for a part nothing else rejects.
        if decide::failed(&m, &limits).is_none() {
            m.blocked = Some(blocked_footprint(coarse, tpl, &pose, &outline));
        }
        est.conclude(decide::decide(m, limits));
        Ok((est, looked))
    }

    /// Stage 3 for a separate region: its line segments down to the smallest template's minimum
    /// length at once (should the region hold several parts, each keeps those its own size
    /// allows, and the detector runs once), returned; those the part keeps (5 % of its diagonal
    /// `diag`), its orientation axis and LFI descriptor, into `est`.
    fn line_features(
        &self,
        coarse: &detect::Coarse,
        blob: &detect::Blob,
        diag: f64,
        centroid: Pt,
        est: &mut PartEstimate,
    ) -> Result<Vec<Segment>, FrameError> {
        let p = &self.params;
        let least = self.least_segment().min(p.min_segment_fraction * diag);
        let all = lines::part_segments(p.line_detector, &coarse.small, &coarse.edges, coarse.factor, blob, least)?;
        let segments: Vec<Segment> = all.iter().filter(|s| s.len() >= p.min_segment_fraction * diag).copied().collect();
        let axis = lines::orientation_axis(&segments);
        est.descriptor = lines::descriptor(&segments, centroid, axis.map(|s| s.direction()).unwrap_or(0.0));
        est.axis = axis;
        est.segments = segments;
        Ok(all)
    }

    /// How the outline fits the best candidate, with the runners-up the "why" shows.
    fn outline_fit(&self, aligned: &[(usize, correlate::Alignment)], cands: &[Candidate]) -> OutlineFit {
        let best = &cands[0];
        OutlineFit {
            best: named(&self.lib.entries[best.entry].template),
            fit: best.reg.fit(),
            inliers: best.reg.inliers,
            coverage: best.reg.coverage,
            extra: best.reg.extra,
            missing: best.reg.missing,
            rms: best.reg.rms,
            tolerance: best.tolerance,
            corr_rms: best.corr_rms,
            scale: best.reg.pose.scale,
            nominal: self.lib.entries[aligned[0].0].template.area,
            next: self.runners_up(aligned, cands, best.entry),
        }
    }

    /// Stages 4 and 4b: every template by correlation distance (best first), and the closest
    /// ones registered onto the outline (best fit first).
    fn candidates(
        &self,
        outline: &[Pt],
        centroid: Pt,
        noise: f64,
        tm: &mut Timings,
    ) -> (Vec<(usize, correlate::Alignment)>, Vec<Candidate>) {
        let p = &self.params;
        let t = Instant::now();
        let corr = &self.lib.correlator;
        let signal = signal::log_radius_signal(outline, centroid, corr.bins());
        let spec = corr.spectrum(&signal);
        // The candidates below are the nearest `p.candidates`, and the why names the two after
        // the best: only those need correlating.
        let need = p.candidates.max(3);
        let aligned = self.lib.nearest(&spec, need);
        tm.correlate += ms(t);
        // In tests, every part checks the shortlist against correlating every template.
        #[cfg(debug_assertions)]
        {
            let all: Vec<usize> = self.lib.align_all(&spec).iter().take(need).map(|a| a.0).collect();
            let short: Vec<usize> = aligned.iter().map(|a| a.0).collect();
            assert_eq!(short, all, "the shortlist cut a template nearer than its last");
        }

        let t = Instant::now();
        // The closest template by correlation is registered on every point; runners-up whose
        // correlation distance is not far off (within 3x + 0.02) on a quarter of them, enough to
        // see whether they rival it. The others cannot: their outline differs everywhere.
        let best_rms = aligned[0].1.rms;
        let mut cands: Vec<Candidate> = aligned
            .iter()
            .take(p.candidates)
            .enumerate()
            .filter(|(rank, (_, al))| *rank == 0 || al.rms <= 3.0 * best_rms + 0.02)
            .map(|(rank, &(i, al))| {
                let e = &self.lib.entries[i];
                let init = template::placed(corr, &al, e.template.centroid, centroid);
                let tolerance = self.tolerance(i, noise);
                // The closest is given up early when most of the outline is not near it at all
                // (several parts in one region: the region search takes over), well below the
                // fit that could name a type.
                let reg = if rank == 0 {
                    register::register_unless(outline, &e.index, init, tolerance, p.min_fit - GIVE_UP_MARGIN).unwrap_or_else(|r| r)
                } else {
                    register::register(outline, &e.index, init, tolerance, 4)
                };
                Candidate { entry: i, reg, corr_rms: al.rms, tolerance }
            })
            .collect();
        // Should a runner-up beat the first, register it fully too: its pose is the one reported.
        if let Some(k) = (1..cands.len()).max_by(|&x, &y| cands[x].reg.fit().total_cmp(&cands[y].reg.fit()))
            && cands[k].reg.fit() > cands[0].reg.fit()
        {
            let e = &self.lib.entries[cands[k].entry];
            cands[k].reg = register::register(outline, &e.index, cands[k].reg.pose, cands[k].tolerance, 1);
        }
        cands.sort_by(|a, b| b.reg.fit().total_cmp(&a.reg.fit()).then(a.reg.rms.total_cmp(&b.reg.rms)));
        tm.register += ms(t);
        (aligned, cands)
    }

    /// The two templates after `best` by correlation distance, with their fit where they were
    /// registered: the "why" shows what came next.
    fn runners_up(&self, aligned: &[(usize, correlate::Alignment)], cands: &[Candidate], best: usize) -> Vec<(Named, NextFit)> {
        aligned
            .iter()
            .filter(|(i, _)| *i != best)
            .take(2)
            .map(|(i, al)| {
                let fit = match cands.iter().find(|c| c.entry == *i) {
                    Some(c) => NextFit::Fit(c.reg.fit()),
                    None => NextFit::CorrRms(al.rms),
                };
                (named(&self.lib.entries[*i].template), fit)
            })
            .collect()
    }

    /// The other types and faces (by fit) whose outline ties with the best's at the tight
    /// tolerance ([`Rival::ties`]), each with its candidate's index: measured on the part's
    /// outline evened out against the best ([`register::even_out`]), at four times the scatter
    /// left.
    fn tied(&self, even: &register::Evened, cands: &[Candidate], limits: &decide::Limits) -> Vec<(usize, Rival)> {
        let best = &cands[0];
        let tpl = &self.lib.entries[best.entry].template;
        let others: Vec<usize> = (1..cands.len())
            .filter(|&k| {
                let o = &self.lib.entries[cands[k].entry].template;
                o.type_name != tpl.type_name || o.face != tpl.face
            })
            .collect();
        if others.is_empty() {
            return Vec::new();
        }
        let tight = register::tight_tolerance(even.scatter, self.params.fit_tolerance, best.tolerance);
        let outline = &even.outline;
        let best_tight = register::measure(outline, &self.lib.entries[best.entry].index, best.reg.pose, tight, 1).fit();
        others
            .into_iter()
            .map(|k| {
                let e = &self.lib.entries[cands[k].entry];
                let fit = register::measure(outline, &e.index, cands[k].reg.pose, tight, 4).fit();
                let rival = Rival {
                    name: named(&e.template),
                    fit,
                    best: best_tight,
                    tolerance: tight,
                    support: None,
                    confidence: 0.0,
                    local: None,
                    features: None,
                };
                (k, rival)
            })
            .filter(|(_, r)| r.ties(limits))
            .collect()
    }

    /// What the image shows inside the part of the best's and a tied `rival`'s own features
    /// (`Rival::features`), measured when the outlines do not tell the two apart; the rival's
    /// index in `cands` when they tell for the rival instead of the best.
    fn inside(&self, rival: &mut Option<Rival>, cands: &[Candidate], edge: &shape::EdgeTest<'_>, limits: &decide::Limits) -> Option<usize> {
        let r = rival.as_mut()?;
        if !r.outlines_do_not_tell(limits) {
            return None;
        }
        let k = cands.iter().position(|c| named(&self.lib.entries[c.entry].template) == r.name)?;
        let (best, other) = (&cands[0], &cands[k]);
        let interior = |c: &Candidate| self.lib.entries[c.entry].template.interior.as_slice();
        let f = shape::own_features(edge, (interior(best), &best.reg.pose), (interior(other), &other.reg.pose), &|_| false);
        r.features = Some(f);
        f.tell_second().then_some(k)
    }

    /// Where candidates `best` and `rival` differ on the part (outline `part`), at the tight
    /// tolerance `near` ([`differ::separation`]); where `view` says the outline tells nothing,
    /// by its light.
    fn local(&self, part: &OutlineIndex, best: &Candidate, rival: &Candidate, near: f64, view: &Unseen<'_>) -> Local {
        let placed = |c: &Candidate| {
            let e = &self.lib.entries[c.entry];
            differ::Placed { index: &e.index, pose: c.reg.pose, centroid: e.template.centroid }
        };
        differ::compare(part, placed(best), placed(rival), view.unseen, &|_| false, Some(view.light), near)
    }

    /// The closest rival of the best candidate, with where they differ and its line features'
    /// confidence; None when no other type or face ties with it. Where the part follows a tied
    /// rival and not the best (a revision sibling fitting the outline as well), the rival is the
    /// part: it is registered fully and moved first in `cands`, and the ties are looked at again
    /// from it (at most twice). The rival reported is the first tied one the part does not
    /// clearly leave behind, else the first.
    #[allow(clippy::too_many_arguments)]
    fn rival(
        &self,
        outline: &[Pt],
        cands: &mut [Candidate],
        found: &[Segment],
        diag: f64,
        lambda: f64,
        limits: &decide::Limits,
        view: &Unseen<'_>,
    ) -> Option<Rival> {
        for round in 0..3 {
            let best = &self.lib.entries[cands[0].entry];
            let even = register::even_out(outline, &best.index, cands[0].reg.pose, cands[0].tolerance);
            let tied = self.tied(&even, cands, limits);
            if tied.is_empty() {
                return None;
            }
            let part = &OutlineIndex::of_frame(&even.outline);
            let judged: Vec<(usize, Rival)> = tied
                .into_iter()
                .map(|(k, mut r)| {
                    r.local = Some(self.local(part, &cands[0], &cands[k], r.tolerance, view));
                    (k, r)
                })
                .collect();
            let follows = |r: &Rival| r.local.map(|l| l.follows());
            if round < 2
                && let Some(&(k, _)) = judged.iter().find(|(_, r)| follows(r) == Some(Follows::Rival))
            {
                let e = &self.lib.entries[cands[k].entry];
                cands[k].reg = register::register(outline, &e.index, cands[k].reg.pose, cands[k].tolerance, 1);
                cands.swap(0, k);
                continue;
            }
            let (k, mut rival) =
                judged.iter().find(|(_, r)| follows(r) != Some(Follows::Best)).or(judged.first()).cloned().expect("some tied");
            rival.confidence = confidence(&self.lib.entries[cands[k].entry].template.segments, found, &cands[k].reg.pose, diag, lambda);
            return Some(rival);
        }
        None
    }
}

/// Where a separate part's refined outline tells nothing ([`boundary::refine`]'s chords) and the
/// frame's light that may tell instead, for [`differ::compare`].
struct Unseen<'a> {
    unseen: &'a dyn Fn(Pt) -> bool,
    light: &'a differ::Light<'a>,
}

/// The chords with which the refinement bridged a refined `outline` (consecutive points
/// farther apart than its `search`, frame pixels): no edge was found near the coarse outline
/// there, and the part's edge lies farther than the search from them, as at the back of a
/// notch whose shadow the coarse edges followed.
fn bridged(outline: &[Pt], search: f64) -> Vec<(Pt, Pt)> {
    outline.iter().zip(outline.iter().cycle().skip(1)).filter(|(a, b)| (**b - **a).norm() > search).map(|(a, b)| (*a, *b)).collect()
}

/// Whether `q` lies within twice the `search` of one of the `bridged` chords: what the outline
/// shows there is the chord, not the part's edge.
fn by_chord(bridged: &[(Pt, Pt)], search: f64, q: Pt) -> bool {
    bridged.iter().any(|&(a, b)| geometry::point_segment(q, a, b).0 < 2.0 * search)
}

fn named(t: &Template) -> Named {
    Named { type_name: t.type_name.clone(), face: t.face }
}

/// An outline's bounds and whether they come within 3 px of the frame's edge: the part may be
/// cut off there.
fn outline_bounds(outline: &[Pt], frame: GrayView<'_>) -> Bounds {
    let (lo, hi) = bounds(outline);
    let edge = 3.0;
    let at_border = lo.x < edge || lo.y < edge || hi.x > frame.width() as f64 - 1.0 - edge || hi.y > frame.height() as f64 - 1.0 - edge;
    Bounds { lo, hi, at_border }
}

/// Other material inside the part's keep-out footprint: the number of the decimated frame's edge
/// pixels inside any of the template's keep-out circles (placed by `pose`) that are neither
/// inside the part's own outline (`own`, frame pixels) nor within a few pixels of it, when there
/// are at least three (a speck of noise is not an obstacle); 0 when the footprint is clear or
/// the part has none.
fn blocked_footprint(coarse: &detect::Coarse, tpl: &Template, pose: &Similarity, own: &[Pt]) -> usize {
    use opencv::prelude::*;
    if tpl.keep_out.is_empty() {
        return 0;
    }
    let f = coarse.factor as f64;
    let (w, h) = (coarse.edges.cols() as usize, coarse.edges.rows() as usize);
    let Ok(edges) = coarse.edges.data_bytes() else {
        return 0;
    };
    let poly: Vec<Pt> = own.iter().step_by(4).copied().collect();
    let spacing = poly.windows(2).map(|p| (p[1] - p[0]).norm()).fold(0.0, f64::max);
    let band = 3.0 * f + spacing;
    let mut count = 0;
    for k in &tpl.keep_out {
        let c = pose.apply(k.c);
        let r = k.r * pose.scale;
        let to_small = |v: f64| (v - (f - 1.0) / 2.0) / f;
        let (x0, x1) = (to_small(c.x - r).floor().max(0.0) as usize, (to_small(c.x + r).ceil().max(0.0) as usize).min(w.saturating_sub(1)));
        let (y0, y1) = (to_small(c.y - r).floor().max(0.0) as usize, (to_small(c.y + r).ceil().max(0.0) as usize).min(h.saturating_sub(1)));
        for y in y0..=y1 {
            for x in x0..=x1 {
                if edges[y * w + x] == 0 {
                    continue;
                }
                let q = Pt::new(x as f64 * f + (f - 1.0) / 2.0, y as f64 * f + (f - 1.0) / 2.0);
                if (q - c).norm() > r || geometry::contains(&poly, q) || poly.iter().any(|p| (*p - q).norm() <= band) {
                    continue;
                }
                count += 1;
            }
        }
    }
    if count >= 3 { count } else { 0 }
}

/// conf = (1/N) sum_k gamma_k exp(-lambda err_k) over the template's N line features mapped into
/// the frame, gamma_k proportional to segment length (mean 1). A template without line features
/// cannot vouch for anything and gets 0.
pub fn confidence(expected: &[Segment], found: &[Segment], pose: &Similarity, size: f64, lambda: f64) -> f64 {
    let total: f64 = expected.iter().map(|s| s.len()).sum();
    if expected.is_empty() || total <= 0.0 || size <= 0.0 {
        return 0.0;
    }
    let n = expected.len() as f64;
    let to_frame = pose.forward();
    let sum: f64 = expected
        .iter()
        .map(|s| {
            let mapped = Segment { a: to_frame.apply(s.a), b: to_frame.apply(s.b), width: s.width };
            let gamma = n * s.len() / total;
            gamma * (-lambda * lines::segment_error(&mapped, found, size)).exp()
        })
        .sum();
    (sum / n).clamp(0.0, 1.0)
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// The confidence stage as the estimator runs it: features scattered by noise, with the
    /// tolerance widened for that noise (lambda = lambda0 (1 - alpha noise)): it still falls.
    #[test]
    fn confidence_falls_with_noise() {
        let expected: Vec<Segment> = (0..12)
            .map(|i| {
                let a = i as f64 * 0.5;
                let c = Pt::new(300.0 + 150.0 * a.cos(), 300.0 + 150.0 * a.sin());
                Segment { a: c, b: c + Pt::new(40.0 * (a + 1.0).cos(), 40.0 * (a + 1.0).sin()), width: 2.0 }
            })
            .collect();
        let pose = Similarity { from: Pt::new(0.0, 0.0), to: Pt::new(0.0, 0.0), angle_rad: 0.0, scale: 1.0 };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let mut last = f64::INFINITY;
        for sigma in [0.0f64, 1.0, 3.0, 8.0] {
            let n = Normal::new(0.0, sigma.max(1e-9)).unwrap();
            let mut jitter = |p: Pt| Pt::new(p.x + n.sample(&mut rng), p.y + n.sample(&mut rng));
            let found: Vec<Segment> = expected.iter().map(|s| Segment { a: jitter(s.a), b: jitter(s.b), width: s.width }).collect();
            let noise_level = (sigma / 8.0).min(1.0);
            let c = confidence(&expected, &found, &pose, 400.0, 25.0 * (1.0 - 0.5 * noise_level));
            assert!(c < last, "sigma {sigma}: confidence {c} not below {last}");
            last = c;
        }
        assert!(confidence(&expected, &[], &pose, 400.0, 25.0) < 1e-6);
    }

    #[test]
    fn reasons_are_listed_once_at_their_index() {
        for (i, r) in Reason::ALL.iter().enumerate() {
            assert_eq!(r.index(), i, "{r}");
        }
        assert_eq!(Reason::AtBorder.as_str(), "at the image border");
        assert_eq!("down".parse::<Face>().unwrap(), Face::Down);
        assert!("side".parse::<Face>().is_err());
    }
}
