//! Enrolling a template from a part of a camera's current frame: cut it out, build the
//! template, save the knowledge base (when it is a file), and make the job with it. The camera's
//! worker asks for it and puts the new job in force (it alone changes the job in force); the
//! operator view only carries the request in and the answer out.

use std::path::PathBuf;
use std::sync::Arc;

use super::job::InForce;
use crate::config::KbSource;
use crate::vision::{Face, FrameEstimate, GrayImage, Pt, Template};

/// What to enrol: part `part` of the camera's current frame as `type_name` (id `id`), `face`.
#[derive(Debug, Clone)]
pub struct EnrolRequest {
    /// The part's PART_INDEX in the current frame (1.. in picking order, as the PLC and the
    /// operator view number it).
    pub part: usize,
    /// The type's name (letters, digits, `-`, `_`).
    pub type_name: String,
    /// Its TYPE_ID (1..=65535; the same type keeps its id).
    pub id: u16,
    /// Which face lies up in the frame.
    pub face: Face,
    /// Who asked (kept as the template's source, e.g. "operator view (10.0.0.7:51234)").
    pub by: String,
    /// The ACQ_ID of the frame the part was chosen on, if the request names it: a newer frame
    /// in the meantime refuses the request instead of enrolling another part.
    pub acq_id: Option<u16>,
}

/// An enrolment done.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Enrolled {
    /// An earlier template of the same type and face was replaced.
    pub replaced: bool,
    /// Where it was kept ("saved to ...", or in memory only).
    pub saved: String,
    /// The frame it came from.
    pub from: String,
}

/// Why an enrolment did not happen; nothing changed in any of these cases.
#[derive(Debug, thiserror::Error)]
pub enum EnrolError {
    /// No frame has been taken yet.
    #[error("no frame yet: trigger one first")]
    NoFrame,
    /// The part was chosen on a frame that is no longer the current one.
    #[error("part chosen on frame ACQ_ID {asked}, but the current frame is ACQ_ID {current}: choose again")]
    FrameChanged {
        /// The frame the request names.
        asked: u16,
        /// The current frame.
        current: u16,
    },
    /// The part number is not one of the frame's parts.
    #[error("the current frame has no part {part} (PART_INDEX 1..={count})")]
    NoPart {
        /// The part asked for (as the page numbers them).
        part: usize,
        /// Parts in the frame.
        count: usize,
    },
    /// The part is cut by the frame's edge: its outline is not whole.
    #[error("part {part} is too close to the frame border to cut out a template with a margin")]
    AtBorder {
        /// The part asked for.
        part: usize,
    },
    /// The part does not make a template.
    #[error("part {part} gives no template")]
    Template {
        /// The part asked for.
        part: usize,
        /// Why not.
        source: crate::vision::TemplateError,
    },
    /// The knowledge base refused it (a name or id conflict, or the file).
    #[error(transparent)]
    Kb(#[from] crate::kb::KbError),
    /// The new templates do not make an estimator.
    #[error("the new knowledge base gives no estimator")]
    Estimator(#[from] crate::vision::EstimatorError),
    /// The camera's worker has stopped (the appliance is stopping): nothing was enrolled.
    #[error("the camera's worker has stopped")]
    Stopped,
    /// The image given cannot be used.
    #[error("cannot write the template image {path}: {message}")]
    Image {
        /// The image file.
        path: PathBuf,
        /// Why not.
        message: String,
    },
}

impl EnrolError {
    /// The request itself was wrong (the operator can fix it), rather than the appliance.
    pub fn is_request(&self) -> bool {
        matches!(
            self,
            EnrolError::NoPart { .. }
                | EnrolError::AtBorder { .. }
                | EnrolError::Template { .. }
                | EnrolError::Kb(crate::kb::KbError::TypeName { .. })
        )
    }
    /// The request conflicts with the state (no frame yet, a type's id taken).
    pub fn is_conflict(&self) -> bool {
        matches!(
            self,
            EnrolError::NoFrame
                | EnrolError::FrameChanged { .. }
                | EnrolError::Kb(crate::kb::KbError::IdConflict { .. } | crate::kb::KbError::NameConflict { .. })
        )
    }
}

/// What the camera shows when an enrolment is asked for: the current frame, its estimate (parts
/// in picking order), where it came from, and its ACQ_ID.
pub struct Shown {
    /// The frame.
    pub frame: Option<Arc<GrayImage>>,
    /// Its estimate.
    pub estimate: Option<FrameEstimate>,
    /// Where it came from ("" when unnamed).
    pub label: String,
    /// Its ACQ_ID.
    pub acq_id: u16,
}

/// Enrols part `req.part` of the frame `shown` into `job` (see the module doc): the job with the
/// new template, its estimator built, and what was done. The knowledge base file is written
/// first: if it cannot be, nothing changes.
pub fn enrol(job: &InForce, shown: Shown, req: &EnrolRequest) -> Result<(InForce, Enrolled), EnrolError> {
    // Before anything is cut or written: the name also becomes the template image's file name.
    crate::kb::valid_type_name(&req.type_name)?;
    let Shown { frame, estimate, label, acq_id: current } = shown;
    let (Some(frame), Some(estimate)) = (frame, estimate) else { return Err(EnrolError::NoFrame) };
    if let Some(asked) = req.acq_id
        && asked != current
    {
        return Err(EnrolError::FrameChanged { asked, current });
    }
    let part = estimate.parts.get(req.part.wrapping_sub(1)).ok_or(EnrolError::NoPart { part: req.part, count: estimate.parts.len() })?;
    let crop = crop_part(&frame, &part.outline).ok_or(EnrolError::AtBorder { part: req.part })?;
    let view = crop.view().map_err(|e| EnrolError::Template { part: req.part, source: e.into() })?;
    let (template, left_out) = Template::learn(view, &req.type_name, req.id, req.face, None, job.estimator.params())
        .map_err(|source| EnrolError::Template { part: req.part, source })?;
    if let Some(l) = left_out {
        tracing::warn!(part = req.part, type_name = %req.type_name, "enrolment: {l}");
    }
    let from = if label.is_empty() { "the current frame".to_string() } else { label };
    let mut kb = job.templates.clone();
    let replaced = kb.enroll(template, format!("{}: {from}, part {}", req.by, req.part))?;
    let next = job.with_templates(kb)?;
    let saved = match &job.kb {
        KbSource::File(path) => {
            let png = path.with_file_name(format!("{}_{}.png", req.type_name, req.face));
            crate::imageio::write_png(&png, &crop)
                .map_err(|e| EnrolError::Image { path: png.clone(), message: crate::logging::error_chain(&e) })?;
            next.templates.save(path)?;
            format!("saved to {} (template image {})", path.display(), png.display())
        }
        KbSource::Simulator => "kept in memory only (kb_from_simulator)".to_string(),
    };
    Ok((next, Enrolled { replaced, saved, from }))
}

/// Cuts a part out of the frame: a square centred on its outline's centroid (so the new
/// template's origin, the image centre, is that centroid) with 40 px of belt around it; None
/// when that square does not fit in the frame.
pub fn crop_part(frame: &GrayImage, outline: &[Pt]) -> Option<GrayImage> {
    let (_, c) = crate::vision::geometry::area_centroid(outline);
    let r = outline.iter().map(|p| (*p - c).norm()).fold(0.0, f64::max);
    let half = (r + 40.0).ceil() as i64;
    let (cx, cy) = (c.x.round() as i64, c.y.round() as i64);
    if cx - half < 0 || cy - half < 0 || cx + half >= frame.width as i64 || cy + half >= frame.height as i64 {
        return None;
    }
    let side = (2 * half + 1) as usize;
    frame.crop((cx - half) as usize, (cy - half) as usize, side, side)
}
