//! The estimator's decision on one part, typed: the verdict and the evidence behind it.
//!
//! The estimator decides; this module holds what it decided and renders it, once, for the log
//! and the operator's "why" (`detail`). Tests assert on the fields, not on the text.

use std::fmt;

use super::geometry::Pt;
use super::{Face, Reason};

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
    /// than the closest template (several parts), which makes it touching rather than unknown.
    NoFit {
        /// The least fit that names a type.
        need: f64,
        /// The region is also larger than the closest template: several parts, not an unknown one.
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
            Verdict::Scale { .. } => Reason::UnknownType,
            Verdict::Covered { .. } => Reason::Covered,
            Verdict::Rival { .. } => Reason::Ambiguous,
            Verdict::LowConfidence { .. } => Reason::LowConfidence,
            Verdict::NoClearance { .. } => Reason::NoClearance,
        }
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
                write!(f, "{} fits almost as well ({:.3}) and its line features are not clearly worse", rival.name, rival.fit)
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

/// The closest other type or face.
#[derive(Debug, Clone, PartialEq)]
pub struct Rival {
    /// The rival template.
    pub name: Named,
    /// Its fit (support, in a region) at the tight tolerance.
    pub fit: f64,
    /// The best template's at the same tolerance, and that tolerance (px).
    pub best: f64,
    /// The tight tolerance both were measured at, px.
    pub tolerance: f64,
    /// Its line features' confidence at its pose.
    pub confidence: f64,
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
    /// Length fraction of the template's outline the image explains, and the least accepted.
    pub support: f64,
    /// The least support accepted.
    pub need: f64,
    /// Fraction of it on the region's outline, and the registration's RMS (px).
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

/// The limits a decision was held to: the estimator's parameters when it decided.
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

/// Everything measured about a part, as far as the estimator got.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Evidence {
    /// The separate-part path's outline fit.
    pub outline: Option<OutlineFit>,
    /// The several-parts path's fit.
    pub region: Option<RegionFit>,
    /// The line features' agreement, once a type and pose were found.
    pub lines: Option<Lines>,
    /// The closest other type or face, when one came near.
    pub rival: Option<Rival>,
    /// The limits in force, once a template was compared at all.
    pub limits: Option<Limits>,
}

/// The verdict on a part and the evidence behind it.
#[derive(Debug, Clone, PartialEq)]
pub struct Decision {
    /// What was concluded.
    pub verdict: Verdict,
    /// What it was concluded from.
    pub evidence: Evidence,
}

impl Decision {
    /// A decision from its parts.
    pub fn new(verdict: Verdict, evidence: Evidence) -> Self {
        Self { verdict, evidence }
    }

    /// Every measure the decision used, each with its limit and whether it passed, in the order
    /// the estimator applies them; the verdict's own finding where no measure shows it.
    pub fn measures(&self) -> Vec<Measure> {
        let e = &self.evidence;
        let mut m = Vec::new();
        let f3 = |v: f64| format!("{v:.3}");
        match &self.verdict {
            Verdict::AtBorder { lo, hi } => m.push(Measure::new(
                "outline clear of the frame's edge",
                format!("x {:.0}..{:.0}, y {:.0}..{:.0} px", lo.x, hi.x, lo.y, hi.y),
                "3 px from every edge".into(),
                Some(false),
            )),
            Verdict::TooLarge { area } => {
                m.push(Measure::new("region area", format!("{area:.0} px^2"), "at most an enrolled part's".into(), Some(false)))
            }
            _ => {}
        }
        if let (Some(o), Some(l)) = (&e.outline, &e.limits) {
            m.push(Measure::new(format!("outline fit ({})", o.best), f3(o.fit), format!(">= {:.2}", l.min_fit), Some(o.fit >= l.min_fit)));
            m.push(Measure::new(
                "scale",
                f3(o.scale),
                format!("{:.2}..{:.2}", l.scale_range.0, l.scale_range.1),
                Some(in_range(o.scale, l)),
            ));
            m.push(Measure::new(
                "extra outline (other material)",
                f3(o.extra),
                format!("<= {:.3}", l.max_foreign),
                Some(o.extra <= l.max_foreign),
            ));
            m.push(Measure::new(
                "missing outline (hidden)",
                f3(o.missing),
                format!("<= {:.3}", l.max_foreign),
                Some(o.missing <= l.max_foreign),
            ));
            m.push(Measure::new("outline rms", format!("{:.2} px", o.rms), format!("tolerance {:.2} px", o.tolerance), None));
        }
        if let (Some(r), Some(l)) = (&e.region, &e.limits) {
            m.push(Measure::new(
                format!("outline explained ({})", r.best),
                f3(r.support),
                format!(">= {:.2}", r.need),
                Some(r.support >= r.need),
            ));
            m.push(Measure::new(
                "scale",
                f3(r.scale),
                format!("{:.2}..{:.2}", l.scale_range.0, l.scale_range.1),
                Some(in_range(r.scale, l)),
            ));
            m.push(Measure::new("on the region's outline", f3(r.coverage), "the rest from edges in the image".into(), None));
        }
        match &self.verdict {
            Verdict::Covered { by } => {
                m.push(Measure::new("lies on top", format!("no: {by} lies on it"), "nothing on it".into(), Some(false)))
            }
            Verdict::OrderUnclear => {
                m.push(Measure::new("lies on top", "the image does not tell".into(), "nothing on it".into(), Some(false)))
            }
            Verdict::Unexplained { area } => m.push(Measure::new(
                "material explained",
                format!("{area:.0} px^2 left over"),
                "every part-sized piece by a part".into(),
                Some(false),
            )),
            _ => {}
        }
        if let (Some(r), Some(lines), Some(l)) = (&e.rival, &e.lines, &e.limits) {
            m.push(Measure::new(
                format!("rival {}: fit", r.name),
                format!("{:.3} vs {:.3} at {:.2} px", r.fit, r.best, r.tolerance),
                format!("within {:.2}: line features decide", l.ambiguity_margin),
                None,
            ));
            let lead = lines.confidence - r.confidence;
            m.push(Measure::new(
                format!("confidence lead over {}", r.name),
                f3(lead),
                format!(">= {:.2}", l.confidence_margin),
                Some(lead >= l.confidence_margin),
            ));
        }
        if let (Some(lines), Some(l)) = (&e.lines, &e.limits) {
            m.push(Measure::new(
                "confidence (line features)",
                f3(lines.confidence),
                format!(">= {:.2}", l.accept_threshold),
                Some(lines.confidence >= l.accept_threshold),
            ));
        }
        if let Verdict::NoClearance { edge_px } = &self.verdict {
            m.push(Measure::new(
                "keep-out footprint clear",
                format!("{edge_px} edge px of other material"),
                "fewer than 3".into(),
                Some(false),
            ));
        }
        m
    }

    /// The runner-up: the next template on the separate-part path, or the rival in a region.
    pub fn runner_up(&self) -> Option<String> {
        let e = &self.evidence;
        if let Some((n, fit)) = e.outline.as_ref().and_then(|o| o.next.first()) {
            return Some(match fit {
                NextFit::Fit(v) => format!("{n}: fit {v:.3}"),
                NextFit::CorrRms(v) => format!("{n}: correlation distance {v:.4} (not registered)"),
            });
        }
        e.rival.as_ref().map(|r| format!("{}: fit {:.3}, confidence {:.3}", r.name, r.fit, r.confidence))
    }
}

fn in_range(scale: f64, l: &Limits) -> bool {
    scale >= l.scale_range.0 && scale <= l.scale_range.1
}

impl fmt::Display for Decision {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let e = &self.evidence;
        write!(f, "{}", self.verdict)?;
        if let Some(o) = &e.outline {
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
        if let Some(r) = &e.region {
            write!(
                f,
                "; found in a region of several parts: {} outline explained {:.3} (need {:.2}), on the region's outline {:.3}, rms {:.2} px, scale {:.3}",
                r.best, r.support, r.need, r.coverage, r.rms, r.scale
            )?;
        }
        if let Some(l) = &e.lines {
            write!(f, "; confidence {:.3} (noise {:.1}, contrast {:.0}, lambda {:.1})", l.confidence, l.noise, l.contrast, l.lambda)?;
        }
        if let Some(r) = &e.rival {
            write!(f, "; rival {} fit {:.3} vs {:.3} at {:.2} px, confidence {:.3}", r.name, r.fit, r.best, r.tolerance, r.confidence)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn named() -> Named {
        Named { type_name: "bracket".into(), face: Face::Up }
    }

    fn limits() -> Limits {
        Limits {
            min_fit: 0.75,
            max_foreign: 0.06,
            min_support: 0.93,
            scale_range: (0.85, 1.18),
            ambiguity_margin: 0.1,
            confidence_margin: 0.15,
            accept_threshold: 0.5,
        }
    }

    /// The why panel's measures: each with its limit and whether it passed, the failing one
    /// the verdict's; the runner-up named.
    #[test]
    fn measures_say_which_limit_a_part_failed() {
        let outline = OutlineFit {
            best: named(),
            fit: 0.97,
            inliers: 0.98,
            coverage: 0.97,
            extra: 0.01,
            missing: 0.02,
            rms: 0.4,
            tolerance: 3.0,
            corr_rms: 0.01,
            scale: 1.0,
            next: vec![(Named { type_name: "bracket".into(), face: Face::Down }, NextFit::Fit(0.81))],
        };
        let lines = Lines { confidence: 0.42, noise: 2.0, contrast: 100.0, lambda: 24.9 };
        let d = Decision::new(
            Verdict::LowConfidence { confidence: 0.42, threshold: 0.5 },
            Evidence { outline: Some(outline), lines: Some(lines), limits: Some(limits()), ..Evidence::default() },
        );
        let m = d.measures();
        let failed: Vec<&str> = m.iter().filter(|m| m.pass == Some(false)).map(|m| m.name.as_str()).collect();
        assert_eq!(failed, ["confidence (line features)"]);
        let conf = m.iter().find(|m| m.name == "confidence (line features)").unwrap();
        assert_eq!((conf.value.as_str(), conf.limit.as_str()), ("0.420", ">= 0.50"));
        assert!(m.iter().any(|m| m.name == "outline fit (bracket up)" && m.pass == Some(true)));
        assert_eq!(d.runner_up().as_deref(), Some("bracket down: fit 0.810"));
        // A covered part in a region: the order is the failing measure.
        let region = RegionFit { best: named(), support: 0.8, need: 0.93, coverage: 0.7, rms: 0.5, scale: 1.0 };
        let covered = Decision::new(
            Verdict::Covered { by: named() },
            Evidence { region: Some(region), limits: Some(limits()), ..Evidence::default() },
        );
        let failed: Vec<String> = covered.measures().into_iter().filter(|m| m.pass == Some(false)).map(|m| m.name).collect();
        assert_eq!(failed, ["outline explained (bracket up)", "lies on top"]);
    }

    #[test]
    fn each_verdict_gives_its_reason() {
        let rival = Rival { name: named(), fit: 0.9, best: 0.91, tolerance: 3.0, confidence: 0.7 };
        for (v, r) in [
            (Verdict::Accept, Reason::Ok),
            (Verdict::AtBorder { lo: Pt::new(0.0, 0.0), hi: Pt::new(9.0, 9.0) }, Reason::AtBorder),
            (Verdict::TooLarge { area: 1.0 }, Reason::Touching),
            (Verdict::NoFit { need: 0.75, merged: false }, Reason::UnknownType),
            (Verdict::NoFit { need: 0.75, merged: true }, Reason::Touching),
            (Verdict::Scale { scale: 1.3, range: (0.9, 1.1) }, Reason::UnknownType),
            (Verdict::Foreign { extra: 0.1, missing: 0.0, limit: 0.06 }, Reason::Touching),
            (Verdict::Covered { by: named() }, Reason::Covered),
            (Verdict::OrderUnclear, Reason::Touching),
            (Verdict::Unseen { support: 0.8, need: 0.93 }, Reason::Touching),
            (Verdict::Rival { rival }, Reason::Ambiguous),
            (Verdict::LowConfidence { confidence: 0.3, threshold: 0.5 }, Reason::LowConfidence),
            (Verdict::NoClearance { edge_px: 4 }, Reason::NoClearance),
            (Verdict::Unexplained { area: 5000.0 }, Reason::Touching),
        ] {
            assert_eq!(v.reason(), r, "{v:?}");
        }
    }

    #[test]
    fn the_text_names_the_verdict_first_then_the_evidence() {
        let d = Decision::new(
            Verdict::Covered { by: named() },
            Evidence {
                region: Some(RegionFit {
                    best: Named { type_name: "flange".into(), face: Face::Down },
                    support: 0.81,
                    need: 0.93,
                    coverage: 0.7,
                    rms: 1.2,
                    scale: 1.0,
                }),
                ..Evidence::default()
            },
        );
        assert_eq!(
            d.to_string(),
            "bracket up lies on it; found in a region of several parts: flange down outline explained 0.810 (need 0.93), on the region's outline 0.700, rms 1.20 px, scale 1.000"
        );
        let far = Verdict::Foreign { extra: 0.2, missing: 0.0, limit: 0.06 };
        assert!(far.to_string().starts_with("the outline runs onto something else"), "{far}");
    }
}
