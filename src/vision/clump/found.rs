//! What a region offers, and what is found in it: the words every step of `explain` shares.

use super::super::detect::{Blob, Coarse};
use super::super::geometry::Pt;
use super::super::register::Registration;
use super::super::shape::EdgeTest;

/// What the region offers as evidence.
pub struct Region<'a> {
    /// The frame's coarse stage (decimated, blurred frame for the edge tests).
    pub coarse: &'a Coarse,
    /// The region.
    pub blob: &'a Blob,
    /// The region's refined outline, frame pixels.
    pub outline: &'a [Pt],
    /// Frame noise, gray levels.
    pub noise: f64,
    /// Part-to-belt contrast along the region's outline, gray levels.
    pub contrast: f64,
    /// Workers the vote and the looks at hypotheses may share (None: the calling thread only).
    pub pool: Option<&'a rayon::ThreadPool>,
}

/// A part found in a region.
#[derive(Debug, Clone)]
pub struct Found {
    /// Index of the template in the library.
    pub entry: usize,
    /// The registration at its pose.
    pub reg: Registration,
    /// The outline tolerance used, template pixels.
    pub tolerance: f64,
    /// Length fraction of the template's outline explained by the image at the pose.
    pub support: f64,
    /// Index (into [`Explained::parts`]) of a part found lying on this one.
    pub under: Option<usize>,
    /// Overlaps another part found here, and the image cannot tell which lies on top.
    pub order_unclear: bool,
    /// The other types and faces explaining the same material: (entry, its registration,
    /// support), best supported first, one per template. All of them, not the runner-up alone:
    /// a type whose outline is part of this one's (two lugs of a three-lug flange) may be
    /// supported a little better by a region that hides the third, while the type that has the
    /// third comes after a face of the first.
    pub rivals: Vec<(usize, Registration, f64)>,
    /// Verification points.
    pub(super) points: Vec<Probe>,
}

/// Everything found in a region.
#[derive(Debug, Clone, Default)]
pub struct Explained {
    /// The parts found, best supported first.
    pub parts: Vec<Found>,
    /// Material of the region that no found part explains: (area in frame pixels, centroid).
    pub leftover: Vec<(f64, Pt)>,
    /// Wall time of the vote, milliseconds (the rest of the region's time is verification).
    pub vote_ms: f64,
}

/// Least support for a hypothesis to stand for a physical part at all.
pub const MIN_SUPPORT: f64 = 0.7;

/// One verification point of a template's outline at a hypothesised pose.
#[derive(Debug, Clone, Copy)]
pub(super) struct Probe {
    /// Frame position.
    pub(super) at: Pt,
    /// The outline's outward unit normal there.
    pub(super) normal: Pt,
    /// Explained: on the region's outline, or a clear edge across the outline there.
    pub(super) seen: bool,
    /// Gray-level step across the outline there, inside minus outside (see
    /// [`EdgeTest::across`]); measured where the region's outline does not explain the point,
    /// otherwise NaN until [`Probe::across`] measures it (only where another part lies).
    pub(super) across: f64,
}

impl Probe {
    /// The step across the outline here, measured once.
    pub(super) fn across(&mut self, edge: &EdgeTest<'_>) -> f64 {
        if self.across.is_nan() {
            self.across = edge.across(self.at, self.normal);
        }
        self.across
    }
}
