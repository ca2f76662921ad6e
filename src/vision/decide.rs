//! The accept/reject ladder, written once: what the estimator measured about a part in, the
//! decision out.
//!
//! The estimator's two paths (a separate part; each part the region search found) only measure:
//! they fill one [`Measured`] record per part and hand it here. [`decide`] tests it against the
//! limits in one order, the same for either path; a test whose measure the path does not take
//! (a region's support on a separate part, the outline's extra material on a part in a region)
//! is skipped. [`failed`] walks the same ladder over what is measured so far, so that a path can
//! stop measuring once a part is rejected. The log's text, the operator's "why" panel
//! ([`Decision::measures`]) and the PLC's REASON all read the one [`Decision`] it returns.

use std::fmt;

use super::geometry::Pt;
use super::part::{Face, Reason};

/// A template named by type and face, as the text shows it ("bracket up").
#[derive(Debug, Clone, PartialEq)]
pub struct Named {
    /// The part type's name, as enrolled.
    pub type_name: String,
    /// Which face of it lies up.
    pub face: Face,
}

impl fmt::Display for Named {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} {}", self.type_name, self.face)
    }
}

/// What the estimator concluded about a part.
#[derive(Debug, Clone, PartialEq)]
pub enum Verdict {
    /// Every measure passed: the robot may pick it.
    Accept,
    /// The outline comes within 3 px of the frame's edge (bounds of the outline).
    AtBorder {
        /// Top-left of the outline's bounds, frame pixels.
        lo: Pt,
        /// Bottom-right of the outline's bounds, frame pixels.
        hi: Pt,
    },
    /// The region is larger than any enrolled part could be.
    TooLarge {
        /// The region's area, px^2.
        area: f64,
    },
    /// No template's outline fits at least `need`; `merged` when the region is also larger
    /// than the closest template and shows most of its outline (that part and more: several
    /// parts), which makes it touching rather than unknown.
    NoFit {
        /// The least fit that names a type.
        need: f64,
        /// The region is also larger than the closest template and shows most of its outline:
        /// several parts, not an unknown one.
        merged: bool,
    },
    /// The best fit is at a scale outside the accepted range.
    Scale {
        /// The best fit's scale (part size over template size).
        scale: f64,
        /// The accepted scales, inclusive.
        range: (f64, f64),
    },
    /// The outline runs onto something else (`extra`) or is partly hidden (`missing`).
    Foreign {
        /// Fraction of the part's outline far from the template's.
        extra: f64,
        /// Length fraction of the template's outline not seen.
        missing: f64,
        /// The most either may be.
        limit: f64,
    },
    /// Another part found in the same region lies on this one.
    Covered {
        /// The part that lies on it.
        by: Named,
    },
    /// It overlaps another part and the image does not tell which lies on top.
    OrderUnclear,
    /// Part of its outline is not seen: `support` of it is explained, `need` required.
    Unseen {
        /// Explained length fraction of its outline.
        support: f64,
        /// The least accepted.
        need: f64,
    },
    /// Another type or face explains the outline nearly as well and its line features are not
    /// clearly worse.
    Rival {
        /// Who rivals it, and by how much.
        rival: Rival,
    },
    /// A type not enrolled, like an enrolled one except in one place: another type or face fits
    /// as well and where the two differ the part follows neither; or it was told from such a
    /// sibling and departs from the best elsewhere; or, alone in its region, the best explains
    /// too little of it.
    Unlike {
        /// The best template.
        like: Named,
        /// The sibling it ties with, and where they differ.
        rival: Option<Rival>,
        /// Where it departs most from the best, when measured.
        departure: Option<Departure>,
    },
    /// The line features agree less than the acceptance threshold.
    LowConfidence {
        /// The line features' agreement.
        confidence: f64,
        /// The least accepted (`accept_threshold`).
        threshold: f64,
    },
    /// Edge pixels of other material inside the gripper's keep-out footprint.
    NoClearance {
        /// Edge pixels found inside the footprint.
        edge_px: usize,
    },
    /// Part-sized material beside the parts found in a region that no template explains.
    Unexplained {
        /// Its area, px^2.
        area: f64,
    },
}

impl Verdict {
    /// The REASON the verdict gives the PLC.
    pub fn reason(&self) -> Reason {
        match self {
            Verdict::Accept => Reason::Ok,
            Verdict::AtBorder { .. } => Reason::AtBorder,
            Verdict::TooLarge { .. } | Verdict::Foreign { .. } | Verdict::OrderUnclear | Verdict::Unseen { .. } => Reason::Touching,
            Verdict::Unexplained { .. } => Reason::Touching,
            Verdict::NoFit { merged, .. } => {
                if *merged {
                    Reason::Touching
                } else {
                    Reason::UnknownType
                }
            }
            Verdict::Scale { .. } | Verdict::Unlike { .. } => Reason::UnknownType,
            Verdict::Covered { .. } => Reason::Covered,
            Verdict::Rival { .. } => Reason::Ambiguous,
            Verdict::LowConfidence { .. } => Reason::LowConfidence,
            Verdict::NoClearance { .. } => Reason::NoClearance,
        }
    }

    /// Whether a region rejected with this verdict may hold several parts (or one whose
    /// silhouette came out wrong), so that the region search should look at it: not when one
    /// template explains all of it but one stretch (a type not enrolled).
    pub fn may_be_several(&self) -> bool {
        matches!(
            self,
            Verdict::AtBorder { .. } | Verdict::TooLarge { .. } | Verdict::NoFit { .. } | Verdict::Scale { .. } | Verdict::Foreign { .. }
        )
    }

    /// Whether the robot may pick the part.
    pub fn accepts(&self) -> bool {
        matches!(self, Verdict::Accept)
    }

    /// Whether the part keeps the type its best fit named: not when no template fits, or only
    /// at a size no part of that type has.
    pub fn names_type(&self) -> bool {
        !matches!(self, Verdict::NoFit { .. } | Verdict::Scale { .. } | Verdict::Unlike { .. } | Verdict::Unexplained { .. })
    }
}

impl fmt::Display for Verdict {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Verdict::Accept => f.write_str("accepted"),
            Verdict::AtBorder { lo, hi } => {
                write!(f, "its outline reaches the frame border (x {:.1}..{:.1}, y {:.1}..{:.1})", lo.x, hi.x, lo.y, hi.y)
            }
            Verdict::TooLarge { area } => write!(f, "region of {area:.0} px^2 is larger than any enrolled part could be"),
            Verdict::NoFit { need, .. } => write!(f, "no template fits (need {need:.2})"),
            Verdict::Scale { scale, range } => write!(f, "scale {scale:.3} outside {:.2}..{:.2}", range.0, range.1),
            Verdict::Foreign { extra, missing, limit } => write!(
                f,
                "the outline {} (extra {extra:.3}, missing {missing:.3}, limit {limit:.3})",
                if extra > limit { "runs onto something else" } else { "is partly hidden" }
            ),
            Verdict::Covered { by } => write!(f, "{by} lies on it"),
            Verdict::OrderUnclear => f.write_str("it overlaps another part and the image does not tell which lies on top"),
            Verdict::Unseen { support, need } => {
                write!(
                    f,
                    "part of its outline is not seen (explained {support:.3}, need {need:.2}): something unknown lies on or against it"
                )
            }
            Verdict::Rival { rival } => {
                let shown = |x: &OwnFeatures| {
                    format!(
                        "the best's own shown {:.0} % of {}, the rival's {:.0} % of {}",
                        100.0 * x.a_shown,
                        x.a_count,
                        100.0 * x.b_shown,
                        x.b_count
                    )
                };
                write!(f, "{} fits almost as well ({:.3}) and ", rival.name, rival.fit)?;
                match rival.features {
                    Some(x) if x.against() => write!(f, "the features inside show its own ({})", shown(&x))?,
                    Some(x) => write!(f, "its line features are not clearly worse, nor do the features inside tell ({})", shown(&x))?,
                    None => f.write_str("its line features are not clearly worse")?,
                }
                match rival.local {
                    Some(l) if l.best_len == 0.0 && l.rival_len == 0.0 && l.hidden_len == 0.0 => {
                        write!(f, "; their outlines are nowhere {:.1} px apart", l.apart)
                    }
                    Some(l) => write!(
                        f,
                        "; where they differ by {:.1} px or more, the part follows {:.0} % of the best's {:.0} px and {:.0} % of the rival's {:.0} px",
                        l.apart,
                        100.0 * l.best_follows,
                        l.best_len,
                        100.0 * l.rival_follows,
                        l.rival_len
                    )
                    .and_then(|()| match l.hidden_len > 0.0 {
                        true => write!(f, " ({:.0} px more are hidden: against a neighbour, or where no edge was found)", l.hidden_len),
                        false => Ok(()),
                    }),
                    None => Ok(()),
                }
            }
            Verdict::Unlike { like, rival: Some(rival), departure: None } => write!(
                f,
                "like {like} and {} except where they differ (at {:.0} deg of {like}): the part follows neither, a type not enrolled",
                rival.name,
                rival.local.map(|l| l.at_deg).unwrap_or(0.0)
            ),
            Verdict::Unlike { like, rival, departure } => {
                write!(f, "like {like}")?;
                if let Some(r) = rival {
                    write!(f, " (not {})", r.name)?;
                }
                match departure {
                    Some(d) => write!(
                        f,
                        " except {:.0} px of outline {:.0} px deep at {:.0} deg, where {}",
                        d.len,
                        d.depth,
                        d.at_deg,
                        if d.part_lacks { "the part lacks the template's outline" } else { "the part has outline the template lacks" }
                    )?,
                    None => write!(f, " except where its outline is not explained")?,
                }
                f.write_str(": a type not enrolled")
            }
            Verdict::LowConfidence { confidence, threshold } => write!(f, "confidence {confidence:.3} below {threshold:.2}"),
            Verdict::NoClearance { edge_px } => {
                write!(f, "{edge_px} edge pixels of other material inside the gripper's keep-out footprint")
            }
            Verdict::Unexplained { area } => {
                write!(f, "{area:.0} px^2 of material beside the parts found here that no enrolled part explains")
            }
        }
    }
}

/// The closest other type or face, measured against the best at a tight tolerance.
///
/// The tight tolerance comes from the best fit's own residual (see
/// [`super::register::tight_tolerance`]): noise widens the tolerance for naming a type, but must
/// not blur a small face difference (an eyelet on one side) into a tie.
#[derive(Debug, Clone, PartialEq)]
pub struct Rival {
    /// The rival template.
    pub name: Named,
    /// Its fit at the tight tolerance, measured as its path measures fits: on a separate part
    /// the worse of inliers and coverage; in a region, whose outline also runs around other
    /// parts, the coverage of the template's outline.
    pub fit: f64,
    /// The best template's at the same tolerance.
    pub best: f64,
    /// The tight tolerance both were measured at, px.
    pub tolerance: f64,
    /// In a region: its support and the best's (the image's evidence for each, at the generous
    /// tolerance), which must tie too.
    pub support: Option<(f64, f64)>,
    /// Its line features' confidence at its pose.
    pub confidence: f64,
    /// Where it and the best differ and what the part does there, when measured.
    pub local: Option<Local>,
    /// What the image shows of the best's own interior features and of its own (holes,
    /// pockets, bosses one has where the other has none), each at its pose; measured where the
    /// outlines do not tell (a part whose two faces have one outline: only what lies inside
    /// tells them). `a` is the best, `b` the rival.
    pub features: Option<OwnFeatures>,
}

/// What the image shows of two templates' own interior features, each at its pose: the
/// features one has and the other lacks there (no feature of the other within two decimated
/// pixels), as the outline's stretches where two templates differ. Two faces of one outline
/// share their through-holes; a pocket or boss on one face only is what tells them apart.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OwnFeatures {
    /// How many of the first template's own features lie in the frame.
    pub a_count: usize,
    /// The share of them the image shows with their polarity.
    pub a_shown: f64,
    /// See `a_count`, for the second template.
    pub b_count: usize,
    /// See `a_shown`, for the second template.
    pub b_shown: f64,
}

impl OwnFeatures {
    /// The same, the second template first.
    pub fn reversed(self) -> Self {
        Self { a_count: self.b_count, a_shown: self.b_shown, b_count: self.a_count, b_shown: self.a_shown }
    }

    /// Whether they tell the first template from the second: one of the two has own features
    /// ([`FEATURES_MIN`]); the image shows most of the first's, if it has any
    /// ([`FEATURES_SHOWN`]), and little of the second's, if it has any ([`FEATURES_RIVAL`]). A
    /// wrong face placed on the right one shows few of its own: its pockets lie where the part
    /// has none.
    pub fn tell(&self) -> bool {
        let (a, b) = (self.a_count >= FEATURES_MIN, self.b_count >= FEATURES_MIN);
        (a || b) && (!a || self.a_shown >= FEATURES_SHOWN) && (!b || self.b_shown <= FEATURES_RIVAL)
    }

    /// Whether they tell for the second template instead: a tied rival they name is the part.
    pub fn tell_second(&self) -> bool {
        !self.tell() && self.reversed().tell()
    }

    /// Whether they speak for the second template: the image shows most of its own features
    /// and not most of the first's. A part whose line features favour the first while what
    /// lies inside shows the second's pockets is no part to accept as the first (on the unseen
    /// catalogue of seed 41, a three-lug flange half under another part, its third lug hidden,
    /// was accepted as a two-lug flange's face by its confidence lead while the other face's
    /// own features showed 92 % and its own 39 %).
    pub fn against(&self) -> bool {
        self.b_count >= FEATURES_MIN && self.b_shown >= FEATURES_SHOWN && (self.a_count < FEATURES_MIN || self.a_shown < FEATURES_SHOWN)
    }
}

/// Least share of the best's own interior features the image must show for them to tell.
pub const FEATURES_SHOWN: f64 = 0.6;
/// Most share of the rival's own interior features the image may show for them to tell.
pub const FEATURES_RIVAL: f64 = 0.3;
/// Fewest own features that count: a few points of a feature placed a little differently by
/// the two poses are not a feature of one's own.
pub const FEATURES_MIN: usize = 12;

impl Rival {
    /// Whether its outline ties with the best's: every fit measured of it within the ambiguity
    /// margin of the best's. The one rival test of both paths.
    pub fn ties(&self, l: &Limits) -> bool {
        let within = |rival: f64, best: f64| rival >= best - l.ambiguity_margin;
        within(self.fit, self.best) && self.support.is_none_or(|(rival, best)| within(rival, best))
    }

    /// Whether it ties and where the two differ the outline does not tell (no stretches, or
    /// unclear ones): then what lies inside is looked at ([`OwnFeatures`]), on either path.
    pub fn outlines_do_not_tell(&self, l: &Limits) -> bool {
        self.ties(l) && matches!(self.local.map(|x| x.follows()), None | Some(Follows::Unclear))
    }

    /// Whether the features inside tell the best from it ([`OwnFeatures::tell`]).
    pub fn features_tell(&self) -> bool {
        self.features.is_some_and(|f| f.tell())
    }

    /// Whether the features inside speak for it rather than the best, short of telling
    /// ([`OwnFeatures::against`]): then no confidence lead decides for the best.
    pub fn features_against(&self) -> bool {
        self.features.is_some_and(|f| f.against())
    }
}

/// Where the best template and a rival differ, placed at their poses on the part, and what the
/// part's outline does there (measured by [`super::differ::compare`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Local {
    /// Length of the best template's outline farther than `apart` from the rival's, px.
    pub best_len: f64,
    /// The fraction of it the part's outline lies on.
    pub best_follows: f64,
    /// Length of the rival's outline farther than `apart` from the best's, px.
    pub rival_len: f64,
    /// The fraction of it the part's outline lies on.
    pub rival_follows: f64,
    /// Length of the stretches where they differ that are hidden in part (a neighbouring part
    /// against them, or the region's outline bridging where no edge was found), px.
    pub hidden_len: f64,
    /// How far the outlines must be to count as apart, px.
    pub apart: f64,
    /// Where the longest stretch lies, degrees around its template's centroid (in the
    /// template's own frame, so the same for every pose).
    pub at_deg: f64,
}

/// The longest stretch where a part departs from its best template (see
/// [`super::differ::departure`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Departure {
    /// Its length along the outline, px.
    pub len: f64,
    /// How wide it is: the area between the two outlines over its depth, px.
    pub width: f64,
    /// How far the outlines are apart there at most, px, up to `reach`.
    pub depth: f64,
    /// The farthest the other outline is looked for, px: a depth of `reach` is at least that.
    pub reach: f64,
    /// The separation that counts as apart, px.
    pub apart: f64,
    /// Where it lies, degrees around the template's centroid in the template's own frame.
    pub at_deg: f64,
    /// The template has outline there the part lacks (rather than the part outline the
    /// template lacks).
    pub part_lacks: bool,
    /// The part has less material there than the template (a notch, a lug cut short), rather
    /// than more (a lug, or something lying against it).
    pub less_material: bool,
}

impl Departure {
    /// Whether it makes the part a type not enrolled: deep and wide (a notch or lug of a few
    /// millimetres), not the outline's noise or a slit.
    pub fn counts(&self, l: &Limits) -> bool {
        self.depth >= l.departure_depth * self.apart && self.width >= l.departure_width * self.apart
    }

    /// Whether it makes a part that ties with a rival, and does not follow it where the two
    /// differ, a type not enrolled: it counts, or it is as deep as the other outline is looked
    /// for and wide (where `apart` is half the reach or more, a loose fit's or a noisy frame's,
    /// a lug could not count otherwise). Not for a part without a tie: there a stain or a
    /// neighbour's edge against a blurred part reaches that deep, and the part is its best.
    pub fn counts_in_a_tie(&self, l: &Limits) -> bool {
        self.counts(l) || (self.depth >= self.reach && self.width >= l.departure_width * self.apart)
    }
}

/// Of the places where a part departs from its template ([`super::differ::departures`]), the one
/// its decision reads: the longest that makes it a type not enrolled ([`Departure::counts`]),
/// else the longest. A placement a little off runs shallow beside the part's outline for long
/// stretches; a lug beside them is shorter and is what tells.
pub fn telling(found: Vec<Departure>, l: &Limits) -> Option<Departure> {
    found.into_iter().max_by(|a, b| a.counts(l).cmp(&b.counts(l)).then(a.len.total_cmp(&b.len)))
}

/// Which template the part follows where two differ.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Follows {
    /// The best's stretches, not the rival's.
    Best,
    /// The rival's, not the best's.
    Rival,
    /// Neither's: the part is like both except there, a type not enrolled.
    Neither,
    /// The stretches do not tell (none, or the part's outline lies on some of both).
    Unclear,
}

impl Local {
    /// Which template the part follows: most (at least 70 %) of one's stretches and little (at
    /// most 30 %) of the other's. Where only one template has stretches (a lug too narrow for
    /// the other's outline to run apart from it), not following it is following the other. A
    /// part on less than half of each one's stretches follows neither: it is like both except
    /// there (the ends of a stretch, where the templates only begin to part, lie near both).
    ///
    /// A stretch a neighbour hides in part may be the one that tells, so with one hidden only
    /// what is seen to be followed counts: the part lies on most of one template's stretches in
    /// view and little of the other's. Not lying on a stretch says nothing then (the template
    /// the part is may differ just where it is hidden), nor does following neither.
    pub fn follows(&self) -> Follows {
        const MOST: f64 = 0.7;
        const LITTLE: f64 = 0.3;
        const HALF: f64 = 0.5;
        let (b, r) = (self.best_len > 0.0, self.rival_len > 0.0);
        if self.hidden_len > 0.0 {
            let seen =
                |on: bool, follows: f64, other: bool, other_follows: f64| on && follows >= MOST && (!other || other_follows <= LITTLE);
            return if seen(b, self.best_follows, r, self.rival_follows) {
                Follows::Best
            } else if seen(r, self.rival_follows, b, self.best_follows) {
                Follows::Rival
            } else {
                Follows::Unclear
            };
        }
        if !b && !r {
            return Follows::Unclear;
        }
        let best = if b { self.best_follows } else { 1.0 - self.rival_follows };
        let rival = if r { self.rival_follows } else { 1.0 - self.best_follows };
        if best >= MOST && rival <= LITTLE {
            Follows::Best
        } else if rival >= MOST && best <= LITTLE {
            Follows::Rival
        } else if b && r && best < HALF && rival < HALF {
            Follows::Neither
        } else {
            Follows::Unclear
        }
    }
}

/// How the part's outline fits its best template on the separate-part path.
#[derive(Debug, Clone, PartialEq)]
pub struct OutlineFit {
    /// The best template.
    pub best: Named,
    /// The worse of `inliers` and `coverage`: the number the decision compares.
    pub fit: f64,
    /// Fraction of the part's outline within the tolerance of the template's.
    pub inliers: f64,
    /// Length fraction of the template's outline with part outline within the tolerance.
    pub coverage: f64,
    /// Fraction of the part's outline far from the template's (other material).
    pub extra: f64,
    /// Length fraction of the template's outline with nothing near it (hidden).
    pub missing: f64,
    /// RMS distance of the inliers, px.
    pub rms: f64,
    /// The outline tolerance at this frame's noise, px.
    pub tolerance: f64,
    /// Correlation distance of the log-polar signals, before registration.
    pub corr_rms: f64,
    /// Part size over template size.
    pub scale: f64,
    /// Area of the template closest by correlation, px^2: a region much larger than the part it
    /// resembles holds several.
    pub nominal: f64,
    /// The next templates: registered (fit) or by correlation distance only.
    pub next: Vec<(Named, NextFit)>,
}

/// A runner-up's measure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum NextFit {
    /// Registered: its fit.
    Fit(f64),
    /// Not registered (its outline differs everywhere): its correlation distance.
    CorrRms(f64),
}

/// How a part found in a region of several fits (see [`super::clump`]).
#[derive(Debug, Clone, PartialEq)]
pub struct RegionFit {
    /// The best template.
    pub best: Named,
    /// Length fraction of the template's outline the image explains.
    pub support: f64,
    /// Fraction of it on the region's outline (the rest from edges in the image).
    pub coverage: f64,
    /// RMS distance of the registration, px.
    pub rms: f64,
    /// Part size over template size.
    pub scale: f64,
}

/// The line features' agreement and what it was computed with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lines {
    /// The confidence, (1/N) sum gamma_k exp(-lambda err_k).
    pub confidence: f64,
    /// Background noise sigma, gray levels.
    pub noise: f64,
    /// Part-to-belt contrast along the outline, gray levels.
    pub contrast: f64,
    /// The error weight, lambda0 (1 - alpha noise/contrast).
    pub lambda: f64,
}

/// The outline's bounds in the frame and whether they come near its edge.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bounds {
    /// Top-left, frame pixels.
    pub lo: Pt,
    /// Bottom-right, frame pixels.
    pub hi: Pt,
    /// Within 3 px of the frame's edge: the part may be cut off there.
    pub at_border: bool,
}

/// How a part found in a region lies among the others found there.
#[derive(Debug, Clone, PartialEq, Default)]
pub enum Order {
    /// Nothing found lies on it (or it is the only part).
    #[default]
    Free,
    /// This part lies on it.
    Under(Named),
    /// It overlaps another and the image does not tell which lies on top.
    Unclear,
}

/// Everything the estimator measured about one part, as far as it got. A measure a path does not
/// take, or had no need to take (the part was already rejected), is `None` and not tested.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Measured {
    /// The outline's bounds.
    pub border: Option<Bounds>,
    /// The region's area, px^2 (a separate part: the region is the part).
    pub area: Option<f64>,
    /// Part-sized material, px^2, beside the parts found in a region, that no template explains.
    pub unexplained: Option<f64>,
    /// A separate part: how its outline fits the best template.
    pub outline: Option<OutlineFit>,
    /// A part found in a region: how the image supports the best template.
    pub region: Option<RegionFit>,
    /// A part found in a region: whether another lies on it.
    pub order: Order,
    /// A part found in a region: the only one found there, and no part-sized material beside it.
    pub alone: bool,
    /// The closest other type or face, when one was measured.
    pub rival: Option<Rival>,
    /// The line features' agreement at the best pose.
    pub lines: Option<Lines>,
    /// Where the part departs most from the best template, measured when it was told from a
    /// tied sibling by where the two differ, or when the best explains too little of a part in
    /// a region (beside others, only where nothing could hide the part's outline).
    pub departure: Option<Departure>,
    /// Edge pixels of other material inside the gripper's keep-out footprint (three or more:
    /// a speck of noise is not an obstacle); `Some(0)` when the footprint is clear or the part
    /// has none.
    pub blocked: Option<usize>,
}

/// The limits a decision is held to: the estimator's parameters when it decided.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    /// Least outline fit that names a type.
    pub min_fit: f64,
    /// Most outline that may be foreign (extra) or unseen (missing).
    pub max_foreign: f64,
    /// Least support of a part found in a region of several.
    pub min_support: f64,
    /// Accepted scales.
    pub scale_range: (f64, f64),
    /// A rival within this of the best fit is compared by its line features ...
    pub ambiguity_margin: f64,
    /// ... which must be worse by at least this.
    pub confidence_margin: f64,
    /// Least confidence accepted.
    pub accept_threshold: f64,
    /// A region larger than this times the template it resembles holds several parts.
    pub touching_area_ratio: f64,
    /// A departure from the best template at least this many times as deep as the separation
    /// that counts as apart makes a part told from a sibling a type not enrolled.
    pub departure_depth: f64,
    /// ... and at least this many times as wide (a slit the outline ran into is not a notch).
    pub departure_width: f64,
    /// The largest region one part can make (the largest template at the largest scale, times
    /// `touching_area_ratio`), px^2.
    pub max_area: f64,
}

/// The ladder's tests, in the order [`ladder`] makes them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Test {
    Border,
    Size,
    Material,
    Fit,
    Scale,
    Foreign,
    Order,
    Support,
    Rival,
    Departure,
    Confidence,
    Clearance,
}

/// The ladder: each test whose measure is there, in one order; `seen` is told of each test made
/// and whether it passed. Returns the first failure's verdict.
fn ladder(m: &Measured, l: &Limits, mut seen: impl FnMut(Test, bool)) -> Option<Verdict> {
    let mut test = |t: Test, pass: bool| {
        seen(t, pass);
        !pass
    };
    if let Some(b) = m.border
        && test(Test::Border, !b.at_border)
    {
        return Some(Verdict::AtBorder { lo: b.lo, hi: b.hi });
    }
    if let Some(area) = m.area
        && test(Test::Size, area <= l.max_area)
    {
        return Some(Verdict::TooLarge { area });
    }
    if let Some(area) = m.unexplained
        && test(Test::Material, false)
    {
        return Some(Verdict::Unexplained { area });
    }
    if let Some(o) = &m.outline
        && test(Test::Fit, o.fit >= l.min_fit)
    {
        // Several parts: the region is much larger than the part it resembles, and does
        // resemble it (most of the template's outline lies on the region's, at a scale a part
        // of its type takes: one part of a pile is fitted at its own size). A region that
        // shows little of any template, or resembles one only stretched beyond the sizes parts
        // take, is one part no template explains, whatever its size (up to the largest a part
        // can be, above): a type not enrolled, not a pile (on the unseen catalogue of seed 23,
        // a large unknown part alone showed 0.57-0.59 of a smaller template's outline fitted
        // at 1.19-1.21 of its scale).
        let sized = o.scale >= l.scale_range.0 && o.scale <= l.scale_range.1;
        let merged = m.area.is_some_and(|a| a > l.touching_area_ratio * o.nominal) && o.coverage >= 0.5 && sized;
        return Some(Verdict::NoFit { need: l.min_fit, merged });
    }
    if let Some(scale) = m.outline.as_ref().map(|o| o.scale).or(m.region.as_ref().map(|r| r.scale))
        && test(Test::Scale, scale >= l.scale_range.0 && scale <= l.scale_range.1)
    {
        return Some(Verdict::Scale { scale, range: l.scale_range });
    }
    if let Some(o) = &m.outline
        && test(Test::Foreign, o.extra <= l.max_foreign && o.missing <= l.max_foreign)
    {
        return Some(Verdict::Foreign { extra: o.extra, missing: o.missing, limit: l.max_foreign });
    }
    if m.region.is_some() && test(Test::Order, m.order == Order::Free) {
        return Some(match &m.order {
            Order::Under(by) => Verdict::Covered { by: by.clone() },
            _ => Verdict::OrderUnclear,
        });
    }
    // Part of its outline unexplained: something lies on or against it, unless it is alone in
    // its region, or it lacks material the template has where nothing could hide it (deep and
    // wide, on open belt): then it is the part that differs.
    if let Some(r) = &m.region
        && test(Test::Support, r.support >= l.min_support)
    {
        return Some(if m.alone || m.departure.is_some_and(|d| d.counts(l)) {
            Verdict::Unlike { like: r.best.clone(), rival: None, departure: m.departure }
        } else {
            Verdict::Unseen { support: r.support, need: l.min_support }
        });
    }
    // A rival that ties is told apart where the two differ when the part follows the best
    // there; a part that follows neither is a type not enrolled, one that follows the rival is
    // not the best; where they do not tell, the line features must. Where they do not tell
    // and the part departs from the best deep and wide besides (its own outline: alone), it is
    // not the best, and not clearly the rival either: a type not enrolled, as the departure
    // test below would say.
    if let (Some(r), Some(lines)) = (&m.rival, &m.lines) {
        let follows = r.local.map(|x| x.follows());
        let pass = !r.ties(l)
            || follows == Some(Follows::Best)
            || (matches!(follows, None | Some(Follows::Unclear))
                && ((lines.confidence - r.confidence >= l.confidence_margin && !r.features_against()) || r.features_tell()));
        if test(Test::Rival, pass) {
            let departs = m.departure.filter(|d| d.counts_in_a_tie(l));
            return Some(match (follows, best_named(m)) {
                (Some(Follows::Neither), Some(like)) => Verdict::Unlike { like, rival: Some(r.clone()), departure: None },
                (Some(Follows::Unclear), Some(like)) if departs.is_some() => {
                    Verdict::Unlike { like, rival: Some(r.clone()), departure: departs }
                }
                _ => Verdict::Rival { rival: r.clone() },
            });
        }
    }
    // It must follow the best everywhere (told from a sibling by where they differ, everywhere
    // else): a notch or lug the template lacks, deep and wide, is a type not enrolled.
    if let (Some(d), Some(like)) = (m.departure, best_named(m))
        && test(Test::Departure, !d.counts(l))
    {
        let rival = m.rival.as_ref().filter(|r| r.ties(l)).cloned();
        return Some(Verdict::Unlike { like, rival, departure: Some(d) });
    }
    if let Some(lines) = &m.lines
        && test(Test::Confidence, lines.confidence >= l.accept_threshold)
    {
        return Some(Verdict::LowConfidence { confidence: lines.confidence, threshold: l.accept_threshold });
    }
    if let Some(n) = m.blocked
        && test(Test::Clearance, n == 0)
    {
        return Some(Verdict::NoClearance { edge_px: n });
    }
    None
}

/// The best template, as the part's fit names it.
fn best_named(m: &Measured) -> Option<Named> {
    m.outline.as_ref().map(|o| o.best.clone()).or(m.region.as_ref().map(|r| r.best.clone()))
}

/// The decision on a part: the first test of the ladder it fails, else acceptance, which needs a
/// fit that names a type and the line features' confidence. A record missing either (a path
/// that stopped short) is never accepted: no template is said to fit.
pub fn decide(m: Measured, l: Limits) -> Decision {
    let verdict = ladder(&m, &l, |_, _| {}).unwrap_or_else(|| {
        if (m.outline.is_some() || m.region.is_some()) && m.lines.is_some() {
            Verdict::Accept
        } else {
            Verdict::NoFit { need: l.min_fit, merged: false }
        }
    });
    Decision { verdict, measured: m, limits: l }
}

/// Whether the region search's decisions on a region replace the single-part look's (`whole`):
/// not when the search explained none of it, as one part would be: the one part it found not
/// seen whole (part of its outline unexplained) and the rest material no template explains,
/// where the single-part look found a part of a type not enrolled. One part alone on the belt
/// is one story, not a part found in a pile with something unknown beside it (an unknown fork
/// whose longer arm a known fork lacks is not the known fork touching a stranger).
pub fn search_explains(whole: &Verdict, found: &[&Verdict]) -> bool {
    let named: Vec<&&Verdict> = found.iter().filter(|v| !matches!(v, Verdict::Unexplained { .. })).collect();
    let one_unseen = named.len() == 1 && matches!(named[0], Verdict::Unseen { .. }) && found.len() > 1;
    !(one_unseen && whole.reason() == Reason::UnknownType)
}

/// The decision when what is measured so far already fails a test, so that the estimator need
/// not measure the rest; None while every test so far passes.
pub fn failed(m: &Measured, l: &Limits) -> Option<Decision> {
    ladder(m, l, |_, _| {}).map(|verdict| Decision { verdict, measured: m.clone(), limits: *l })
}

/// One measure behind a decision and the limit it was held to, as the operator's "why" panel
/// shows it (the same numbers [`Decision`]'s text writes to the log).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Measure {
    /// What was measured.
    pub name: String,
    /// Its value.
    pub value: String,
    /// What it had to be.
    pub limit: String,
    /// Whether it passed (None: shown for information, decides nothing by itself).
    pub pass: Option<bool>,
}

impl Measure {
    fn new(name: impl Into<String>, value: String, limit: String, pass: Option<bool>) -> Self {
        Self { name: name.into(), value, limit, pass }
    }
}

/// The verdict on a part and what it was concluded from.
#[derive(Debug, Clone, PartialEq)]
pub struct Decision {
    /// What was concluded.
    pub verdict: Verdict,
    /// What it was concluded from.
    pub measured: Measured,
    /// The limits in force.
    pub limits: Limits,
}

impl Decision {
    /// Every test the ladder made, in its order, each with its measure, its limit and whether it
    /// passed (the last one made is the failing one of a reject), with the numbers behind them
    /// shown for information.
    pub fn measures(&self) -> Vec<Measure> {
        let (m, l) = (&self.measured, &self.limits);
        let mut out = Vec::new();
        let f3 = |v: f64| format!("{v:.3}");
        ladder(m, l, |t, pass| {
            let pass = Some(pass);
            match t {
                Test::Border => {
                    let b = m.border.expect("tested");
                    out.push(Measure::new(
                        "outline clear of the frame's edge",
                        format!("x {:.0}..{:.0}, y {:.0}..{:.0} px", b.lo.x, b.hi.x, b.lo.y, b.hi.y),
                        "3 px from every edge".into(),
                        pass,
                    ))
                }
                Test::Size => out.push(Measure::new(
                    "region area",
                    format!("{:.0} px^2", m.area.unwrap_or(0.0)),
                    format!("<= {:.0} px^2 (the largest part, one at a time)", l.max_area),
                    pass,
                )),
                Test::Material => out.push(Measure::new(
                    "material explained",
                    format!("{:.0} px^2 left over", m.unexplained.unwrap_or(0.0)),
                    "every part-sized piece by a part".into(),
                    pass,
                )),
                Test::Fit => {
                    let o = m.outline.as_ref().expect("tested");
                    out.push(Measure::new(format!("outline fit ({})", o.best), f3(o.fit), format!(">= {:.2}", l.min_fit), pass));
                }
                Test::Scale => {
                    let scale = m.outline.as_ref().map(|o| o.scale).or(m.region.as_ref().map(|r| r.scale)).unwrap_or(0.0);
                    out.push(Measure::new("scale", f3(scale), format!("{:.2}..{:.2}", l.scale_range.0, l.scale_range.1), pass))
                }
                Test::Foreign => {
                    let o = m.outline.as_ref().expect("tested");
                    let limit = format!("each <= {:.3}", l.max_foreign);
                    out.push(Measure::new(
                        "extra outline (other material), missing outline (hidden)",
                        format!("{:.3}, {:.3}", o.extra, o.missing),
                        limit,
                        pass,
                    ));
                    out.push(Measure::new("outline rms", format!("{:.2} px", o.rms), format!("tolerance {:.2} px", o.tolerance), None));
                }
                Test::Order => out.push(Measure::new(
                    "lies on top",
                    match &m.order {
                        Order::Free => "nothing found on it".into(),
                        Order::Under(by) => format!("no: {by} lies on it"),
                        Order::Unclear => "the image does not tell".into(),
                    },
                    "nothing on it".into(),
                    pass,
                )),
                Test::Support => {
                    let r = m.region.as_ref().expect("tested");
                    out.push(Measure::new(
                        format!("outline explained ({})", r.best),
                        f3(r.support),
                        format!(">= {:.2}", l.min_support),
                        pass,
                    ));
                    out.push(Measure::new("on the region's outline", f3(r.coverage), "the rest from edges in the image".into(), None));
                }
                Test::Rival => {
                    let r = m.rival.as_ref().expect("tested");
                    let lines = m.lines.as_ref().expect("tested");
                    let support = r.support.map(|(s, b)| format!(", support {s:.3} vs {b:.3}")).unwrap_or_default();
                    let ties = r.ties(l);
                    let follows = r.local.map(|x| x.follows());
                    out.push(Measure::new(
                        format!("rival {}: fit", r.name),
                        format!("{:.3} vs {:.3} at {:.2} px{support}", r.fit, r.best, r.tolerance),
                        format!("within {:.2}: where they differ, then line features, decide", l.ambiguity_margin),
                        if ties { None } else { pass },
                    ));
                    if let (true, Some(x)) = (ties, r.local) {
                        let decides = matches!(x.follows(), Follows::Best | Follows::Neither);
                        out.push(Measure::new(
                            format!(
                                "where {} and {} differ, the part follows",
                                best_named(m).map(|n| n.to_string()).unwrap_or_default(),
                                r.name
                            ),
                            format!(
                                "{:.2} of {:.0} px vs {:.2} of {:.0} px ({:.0} deg)",
                                x.best_follows, x.best_len, x.rival_follows, x.rival_len, x.at_deg
                            ),
                            "most (>= 0.70) of the best's, little (<= 0.30) of the rival's".into(),
                            if decides { pass } else { None },
                        ));
                    }
                    if ties && !matches!(follows, Some(Follows::Best | Follows::Neither)) {
                        out.push(Measure::new(
                            format!("confidence lead over {}", r.name),
                            f3(lines.confidence - r.confidence),
                            format!(">= {:.2}", l.confidence_margin),
                            if r.features.is_some() { None } else { pass },
                        ));
                        if let Some(x) = r.features {
                            out.push(Measure::new(
                                format!("own features inside shown, best vs {}", r.name),
                                format!("{:.2} of {} vs {:.2} of {}", x.a_shown, x.a_count, x.b_shown, x.b_count),
                                format!(
                                    "of >= {FEATURES_MIN}: best's >= {FEATURES_SHOWN:.2}, rival's <= {FEATURES_RIVAL:.2}; or the confidence lead, unless the rival's >= {FEATURES_SHOWN:.2} and the best's not"
                                ),
                                pass,
                            ));
                        }
                    }
                }
                Test::Departure => {
                    let d = m.departure.expect("tested");
                    out.push(Measure::new(
                        "follows the best everywhere else",
                        format!("{:.0} px of outline {:.0} px deep, {:.0} px wide at {:.0} deg", d.len, d.depth, d.width, d.at_deg),
                        format!(
                            "departures < {:.0} px deep or < {:.0} px wide ({} and {} x {:.1} px apart)",
                            l.departure_depth * d.apart,
                            l.departure_width * d.apart,
                            l.departure_depth,
                            l.departure_width,
                            d.apart
                        ),
                        pass,
                    ))
                }
                Test::Confidence => {
                    let c = m.lines.as_ref().expect("tested").confidence;
                    out.push(Measure::new("confidence (line features)", f3(c), format!(">= {:.2}", l.accept_threshold), pass))
                }
                Test::Clearance => out.push(Measure::new(
                    "keep-out footprint clear",
                    format!("{} edge px of other material", m.blocked.unwrap_or(0)),
                    "fewer than 3".into(),
                    pass,
                )),
            }
        });
        out
    }

    /// The runner-up: the next template on the separate-part path, or the rival in a region.
    pub fn runner_up(&self) -> Option<String> {
        let m = &self.measured;
        if let Some((n, fit)) = m.outline.as_ref().and_then(|o| o.next.first()) {
            return Some(match fit {
                NextFit::Fit(v) => format!("{n}: fit {v:.3}"),
                NextFit::CorrRms(v) => format!("{n}: correlation distance {v:.4} (not registered)"),
            });
        }
        m.rival.as_ref().map(|r| format!("{}: fit {:.3}, confidence {:.3}", r.name, r.fit, r.confidence))
    }
}

impl fmt::Display for Decision {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let m = &self.measured;
        write!(f, "{}", self.verdict)?;
        if let Some(o) = &m.outline {
            write!(
                f,
                "; best {}: fit {:.3} (inliers {:.3}, coverage {:.3}, extra {:.3}, missing {:.3}, rms {:.2} px, tol {:.2} px), corr rms {:.4}, scale {:.3}",
                o.best, o.fit, o.inliers, o.coverage, o.extra, o.missing, o.rms, o.tolerance, o.corr_rms, o.scale
            )?;
            let next: Vec<String> = o
                .next
                .iter()
                .map(|(n, m)| match m {
                    NextFit::Fit(v) => format!("{n} fit {v:.3}"),
                    NextFit::CorrRms(v) => format!("{n} corr rms {v:.4}"),
                })
                .collect();
            write!(f, "; next: {}", if next.is_empty() { "none".to_string() } else { next.join(", ") })?;
        }
        if let Some(r) = &m.region {
            write!(
                f,
                "; found in a region of several parts: {} outline explained {:.3} (need {:.2}), on the region's outline {:.3}, rms {:.2} px, scale {:.3}",
                r.best, r.support, self.limits.min_support, r.coverage, r.rms, r.scale
            )?;
        }
        if let Some(l) = &m.lines {
            write!(f, "; confidence {:.3} (noise {:.1}, contrast {:.0}, lambda {:.1})", l.confidence, l.noise, l.contrast, l.lambda)?;
        }
        if let Some(r) = &m.rival {
            write!(f, "; rival {} fit {:.3} vs {:.3} at {:.2} px", r.name, r.fit, r.best, r.tolerance)?;
            if let Some((s, b)) = r.support {
                write!(f, ", support {s:.3} vs {b:.3}")?;
            }
            write!(f, ", confidence {:.3}", r.confidence)?;
            if let Some(x) = r.features {
                write!(f, ", own features inside shown {:.2} of {} vs {:.2} of {}", x.a_shown, x.a_count, x.b_shown, x.b_count)?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
