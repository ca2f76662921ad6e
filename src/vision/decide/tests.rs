use super::*;

fn named(type_name: &str, face: Face) -> Named {
    Named { type_name: type_name.into(), face }
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
        touching_area_ratio: 1.3,
        departure_depth: 2.0,
        departure_width: 3.0,
        max_area: 200_000.0,
    }
}

fn bounds() -> Bounds {
    Bounds { lo: Pt::new(100.0, 120.0), hi: Pt::new(400.0, 300.0), at_border: false }
}

fn lines(confidence: f64) -> Lines {
    Lines { confidence, noise: 2.0, contrast: 100.0, lambda: 24.9 }
}

/// A separate part that passes every test.
fn separate() -> Measured {
    Measured {
        border: Some(bounds()),
        area: Some(50_000.0),
        outline: Some(OutlineFit {
            best: named("bracket", Face::Up),
            fit: 0.97,
            inliers: 0.98,
            coverage: 0.97,
            extra: 0.01,
            missing: 0.02,
            rms: 0.4,
            tolerance: 3.0,
            corr_rms: 0.01,
            scale: 1.0,
            nominal: 50_000.0,
            next: vec![(named("bracket", Face::Down), NextFit::Fit(0.81))],
        }),
        lines: Some(lines(0.8)),
        blocked: Some(0),
        ..Measured::default()
    }
}

/// A part found in a region of several that passes every test.
fn region() -> Measured {
    Measured {
        border: Some(bounds()),
        region: Some(RegionFit { best: named("bracket", Face::Up), support: 0.97, coverage: 0.8, rms: 0.5, scale: 1.0 }),
        lines: Some(lines(0.8)),
        blocked: Some(0),
        ..Measured::default()
    }
}

/// Which variant a verdict is; exhaustive, so that a new verdict must be added to the table.
fn variant(v: &Verdict) -> usize {
    match v {
        Verdict::Accept => 0,
        Verdict::AtBorder { .. } => 1,
        Verdict::TooLarge { .. } => 2,
        Verdict::NoFit { .. } => 3,
        Verdict::Scale { .. } => 4,
        Verdict::Foreign { .. } => 5,
        Verdict::Covered { .. } => 6,
        Verdict::OrderUnclear => 7,
        Verdict::Unseen { .. } => 8,
        Verdict::Rival { .. } => 9,
        Verdict::LowConfidence { .. } => 10,
        Verdict::NoClearance { .. } => 11,
        Verdict::Unexplained { .. } => 12,
        Verdict::Unlike { .. } => 13,
    }
}
const VERDICTS: usize = 14;

/// One failed limit: what it does to a passing record, and the verdict and "why" row it gives.
struct Failure {
    name: &'static str,
    /// Applies to a separate part / a part in a region.
    separate: bool,
    region: bool,
    apply: fn(&mut Measured),
    verdict: fn(&Verdict) -> bool,
    row: &'static str,
}

fn set_scale(m: &mut Measured, s: f64) {
    if let Some(o) = &mut m.outline {
        o.scale = s;
    }
    if let Some(r) = &mut m.region {
        r.scale = s;
    }
}

/// Every failure, in the ladder's order.
fn failures() -> Vec<Failure> {
    vec![
        Failure {
            name: "border",
            separate: true,
            region: true,
            apply: |m| m.border.as_mut().unwrap().at_border = true,
            verdict: |v| matches!(v, Verdict::AtBorder { .. }),
            row: "outline clear of the frame's edge",
        },
        Failure {
            name: "size",
            separate: true,
            region: false,
            apply: |m| m.area = Some(300_000.0),
            verdict: |v| matches!(v, Verdict::TooLarge { area } if *area == 300_000.0),
            row: "region area",
        },
        Failure {
            name: "fit",
            separate: true,
            region: false,
            apply: |m| m.outline.as_mut().unwrap().fit = 0.6,
            verdict: |v| matches!(v, Verdict::NoFit { merged: false, .. }),
            row: "outline fit (bracket up)",
        },
        Failure {
            name: "scale",
            separate: true,
            region: true,
            apply: |m| set_scale(m, 1.3),
            verdict: |v| matches!(v, Verdict::Scale { scale, .. } if *scale == 1.3),
            row: "scale",
        },
        Failure {
            name: "foreign",
            separate: true,
            region: false,
            apply: |m| m.outline.as_mut().unwrap().missing = 0.2,
            verdict: |v| matches!(v, Verdict::Foreign { missing, .. } if *missing == 0.2),
            row: "extra outline (other material), missing outline (hidden)",
        },
        Failure {
            name: "covered",
            separate: false,
            region: true,
            apply: |m| m.order = Order::Under(named("flange", Face::Down)),
            verdict: |v| matches!(v, Verdict::Covered { by } if by.type_name == "flange"),
            row: "lies on top",
        },
        Failure {
            name: "support",
            separate: false,
            region: true,
            apply: |m| m.region.as_mut().unwrap().support = 0.8,
            verdict: |v| matches!(v, Verdict::Unseen { support, .. } if *support == 0.8),
            row: "outline explained (bracket up)",
        },
        Failure {
            name: "rival",
            separate: true,
            region: true,
            apply: |m| {
                let support = m.region.as_ref().map(|r| (r.support - 0.02, r.support));
                m.rival = Some(Rival {
                    name: named("bracket", Face::Down),
                    fit: 0.9,
                    best: 0.95,
                    tolerance: 1.6,
                    support,
                    confidence: 0.7,
                    local: None,
                    features: None,
                })
            },
            verdict: |v| matches!(v, Verdict::Rival { rival } if rival.name.face == Face::Down),
            row: "confidence lead over bracket down",
        },
        Failure {
            name: "confidence",
            separate: true,
            region: true,
            apply: |m| m.lines.as_mut().unwrap().confidence = 0.3,
            verdict: |v| matches!(v, Verdict::LowConfidence { confidence, .. } if *confidence == 0.3),
            row: "confidence (line features)",
        },
        Failure {
            name: "clearance",
            separate: true,
            region: true,
            apply: |m| m.blocked = Some(7),
            verdict: |v| matches!(v, Verdict::NoClearance { edge_px: 7 }),
            row: "keep-out footprint clear",
        },
    ]
}

fn failed_rows(d: &Decision) -> Vec<String> {
    d.measures().into_iter().filter(|m| m.pass == Some(false)).map(|m| m.name).collect()
}

/// The ladder, table-driven: every failure alone gives its verdict and its row; for every pair
/// of failures, on either path, the ladder's first is the verdict, and the "why" panel reports
/// it as the one failed row, after nothing but passed (or information) rows.
#[test]
fn the_ladder_reports_its_first_failure() {
    for (path, base) in [("separate", separate()), ("region", region())] {
        let d = decide(base.clone(), limits());
        assert_eq!(d.verdict, Verdict::Accept, "{path}: {d}");
        assert!(d.measures().iter().all(|m| m.pass != Some(false)), "{path}: {:?}", d.measures());
        assert!(failed(&base, &limits()).is_none(), "{path}");
        let fs: Vec<Failure> = failures().into_iter().filter(|f| if path == "separate" { f.separate } else { f.region }).collect();
        for (i, first) in fs.iter().enumerate() {
            let mut m = base.clone();
            (first.apply)(&mut m);
            let d = decide(m.clone(), limits());
            assert!((first.verdict)(&d.verdict), "{path} {}: {:?}", first.name, d.verdict);
            assert_eq!(failed_rows(&d), [first.row], "{path} {}", first.name);
            assert_eq!(failed(&m, &limits()).map(|d| d.verdict), Some(d.verdict.clone()), "{path} {}", first.name);
            let rows = d.measures();
            assert_eq!(
                rows.iter().rposition(|r| r.pass.is_some()),
                rows.iter().position(|r| r.pass == Some(false)),
                "{path} {}",
                first.name
            );
            for second in &fs[i + 1..] {
                for order in [[first, second], [second, first]] {
                    let mut m = base.clone();
                    for f in order {
                        (f.apply)(&mut m);
                    }
                    let d = decide(m, limits());
                    assert!((first.verdict)(&d.verdict), "{path} {} + {}: {:?}", first.name, second.name, d.verdict);
                    assert_eq!(failed_rows(&d), [first.row], "{path} {} + {}", first.name, second.name);
                }
            }
        }
    }
}

/// Every verdict is reached by some record, and a part in a region and a separate part with the
/// same measures get the same decision.
#[test]
fn every_verdict_is_reached_and_both_paths_agree() {
    let mut reached = [false; VERDICTS];
    for (path, base) in [("separate", separate()), ("region", region())] {
        reached[variant(&decide(base.clone(), limits()).verdict)] = true;
        for f in failures().iter().filter(|f| if path == "separate" { f.separate } else { f.region }) {
            let mut m = base.clone();
            (f.apply)(&mut m);
            reached[variant(&decide(m, limits()).verdict)] = true;
        }
    }
    let mut unclear = region();
    unclear.order = Order::Unclear;
    reached[variant(&decide(unclear, limits()).verdict)] = true;
    for (path, base) in [("separate", separate()), ("region", region())] {
        let mut m = base;
        m.rival = Some(Rival {
            name: named("bracket", Face::Down),
            fit: 0.94,
            best: 0.95,
            tolerance: 1.6,
            support: m.region.as_ref().map(|r| (r.support, r.support)),
            confidence: 0.2,
            local: Some(local(0.1, 0.05)),
            features: None,
        });
        let d = decide(m, limits());
        assert!(matches!(&d.verdict, Verdict::Unlike { like, .. } if like.type_name == "bracket"), "{path}: {}", d.verdict);
        assert_eq!(d.verdict.reason(), Reason::UnknownType);
        assert_eq!(failed_rows(&d), ["where bracket up and bracket down differ, the part follows"], "{path}");
        reached[variant(&d.verdict)] = true;
    }
    let leftover = Measured { unexplained: Some(9000.0), ..Measured::default() };
    let d = decide(leftover, limits());
    assert_eq!(d.verdict, Verdict::Unexplained { area: 9000.0 });
    assert_eq!(failed_rows(&d), ["material explained"]);
    reached[variant(&d.verdict)] = true;
    assert!(
        reached.iter().all(|&r| r),
        "verdicts never reached: {:?}",
        reached.iter().enumerate().filter(|(_, r)| !**r).collect::<Vec<_>>()
    );

    for f in failures().iter().filter(|f| f.separate && f.region) {
        let (mut a, mut b) = (separate(), region());
        (f.apply)(&mut a);
        (f.apply)(&mut b);
        let (a, b) = (decide(a, limits()), decide(b, limits()));
        assert_eq!(variant(&a.verdict), variant(&b.verdict), "{}", f.name);
        assert_eq!(a.verdict.reason(), b.verdict.reason(), "{}", f.name);
        assert_eq!(failed_rows(&a), failed_rows(&b), "{}", f.name);
    }
}

fn local(best_follows: f64, rival_follows: f64) -> Local {
    Local { best_len: 120.0, best_follows, rival_len: 60.0, rival_follows, hidden_len: 0.0, apart: 6.0, at_deg: 212.0 }
}

/// bracket down, tying with the best (fit 0.95 both) where the two differ as `local` says.
fn tied_rival(confidence: f64, local: Option<Local>) -> Rival {
    Rival { name: named("bracket", Face::Down), fit: 0.95, best: 0.95, tolerance: 1.6, support: None, confidence, local, features: None }
}

/// Where two templates differ decides between them when the part follows one; the line features
/// decide only when it does not tell; neither followed is a type not enrolled.
#[test]
fn where_templates_differ_decides_a_tie() {
    let tie = |local: Option<Local>, confidence: f64| {
        let mut m = separate();
        m.rival = Some(tied_rival(confidence, local));
        decide(m, limits()).verdict
    };
    // The part follows the best where they differ: accepted even though the lines tie.
    assert_eq!(tie(Some(local(0.95, 0.0)), 0.8), Verdict::Accept);
    // It does not tell: the line features decide, as without the measure.
    assert!(matches!(tie(Some(local(0.6, 0.5)), 0.8), Verdict::Rival { .. }));
    assert_eq!(tie(Some(local(0.6, 0.5)), 0.2), Verdict::Accept);
    assert!(matches!(tie(None, 0.8), Verdict::Rival { .. }));
    // Neither: unknown type, whatever the line features.
    assert!(matches!(tie(Some(local(0.1, 0.1)), 0.0), Verdict::Unlike { .. }));
    // The part follows the rival (the estimator should have named it): never accepted as the best.
    assert!(matches!(tie(Some(local(0.1, 0.9)), 0.8), Verdict::Rival { .. }));
    assert!(matches!(tie(Some(local(0.1, 0.9)), 0.2), Verdict::Rival { .. }));
    // Told from the sibling, it must follow the best everywhere else: a departure as deep as a
    // revision's change makes it a type not enrolled, one within the outline's noise does not;
    // the departure is the failing row.
    let departing = |depth: f64| {
        let mut m = separate();
        m.rival = Some(tied_rival(0.8, Some(local(0.95, 0.0))));
        m.departure = Some(Departure {
            len: 90.0,
            width: 40.0,
            depth,
            apart: 6.0,
            reach: 24.0,
            at_deg: 40.0,
            part_lacks: false,
            less_material: false,
        });
        decide(m, limits())
    };
    assert_eq!(departing(10.0).verdict, Verdict::Accept);
    let d = departing(24.0);
    assert!(matches!(&d.verdict, Verdict::Unlike { departure: Some(x), .. } if x.depth == 24.0), "{}", d.verdict);
    assert_eq!(d.verdict.reason(), Reason::UnknownType);
    assert_eq!(failed_rows(&d), ["follows the best everywhere else"]);
    assert!(d.to_string().starts_with("like bracket up (not bracket down) except 90 px of outline 24 px deep at 40 deg"), "{d}");
    // Without any sibling enrolled, the same: a notch or lug deep and wide is a type not
    // enrolled (nothing tied: no "not ..."), a slit as deep but narrow is not.
    let alone = |depth: f64, width: f64| {
        let mut m = separate();
        m.departure =
            Some(Departure { len: 90.0, width, depth, apart: 6.0, reach: 24.0, at_deg: 250.0, part_lacks: false, less_material: true });
        decide(m, limits())
    };
    assert_eq!(alone(24.0, 10.0).verdict, Verdict::Accept);
    assert_eq!(alone(10.0, 40.0).verdict, Verdict::Accept);
    let d = alone(24.0, 40.0);
    assert!(matches!(&d.verdict, Verdict::Unlike { rival: None, departure: Some(_), .. }), "{}", d.verdict);
    assert_eq!(failed_rows(&d), ["follows the best everywhere else"]);
    assert!(d.to_string().starts_with("like bracket up except 90 px of outline 24 px deep at 250 deg"), "{d}");
    // Which template it follows: most of one's stretches and little of the other's; one side
    // without stretches counts as not followed by the other.
    for (l, f) in [
        (local(0.95, 0.05), Follows::Best),
        (local(0.05, 0.95), Follows::Rival),
        (local(0.1, 0.2), Follows::Neither),
        (local(0.5, 0.5), Follows::Unclear),
        (local(0.4, 0.1), Follows::Neither),
        (local(0.5, 0.1), Follows::Unclear),
        (Local { rival_len: 0.0, rival_follows: 0.0, ..local(0.9, 0.0) }, Follows::Best),
        (Local { rival_len: 0.0, rival_follows: 0.0, ..local(0.1, 0.0) }, Follows::Rival),
        (Local { best_len: 0.0, rival_len: 0.0, ..local(0.0, 0.0) }, Follows::Unclear),
        // With a stretch hidden, only what is seen followed tells.
        (Local { hidden_len: 30.0, ..local(0.95, 0.05) }, Follows::Best),
        (Local { hidden_len: 30.0, ..local(0.05, 0.95) }, Follows::Rival),
        (Local { hidden_len: 30.0, ..local(0.1, 0.2) }, Follows::Unclear),
        (Local { hidden_len: 30.0, rival_len: 0.0, rival_follows: 0.0, ..local(0.1, 0.0) }, Follows::Unclear),
        (Local { hidden_len: 30.0, best_len: 0.0, rival_len: 0.0, ..local(0.0, 0.0) }, Follows::Unclear),
    ] {
        assert_eq!(l.follows(), f, "{l:?}");
    }
}

/// A part that ties with a rival and follows neither clearly where the two differ is ambiguous;
/// departing from the best besides, deep and wide, it is a type not enrolled. At a loose fit's
/// `apart` (half the reach or more) a lug as deep as the reach counts there, and only there.
#[test]
fn a_tie_the_stretches_do_not_tell_with_a_deep_departure_is_a_type_not_enrolled() {
    let tied = |departure: Option<Departure>| {
        let mut m = separate();
        m.rival = Some(tied_rival(0.8, Some(local(0.0, 0.58))));
        m.departure = departure;
        decide(m, limits())
    };
    let lug = |depth: f64, apart: f64| {
        Some(Departure { len: 229.0, width: 60.0, depth, apart, reach: 24.0, at_deg: 37.0, part_lacks: false, less_material: false })
    };
    assert_eq!(tied(None).verdict.reason(), Reason::Ambiguous);
    // Shallow: the stretches still do not tell.
    assert_eq!(tied(lug(10.0, 6.0)).verdict.reason(), Reason::Ambiguous);
    let d = tied(lug(24.0, 6.0));
    assert!(matches!(&d.verdict, Verdict::Unlike { rival: Some(_), departure: Some(_), .. }), "{}", d.verdict);
    assert_eq!(failed_rows(&d), ["confidence lead over bracket down"]);
    // apart 12.2: 2 x apart is beyond the reach, yet a depth at the reach counts in the tie...
    assert_eq!(tied(lug(24.0, 12.2)).verdict.reason(), Reason::UnknownType);
    // ...and not for a part without one, where a stain against a blurred part reaches as deep.
    let mut m = separate();
    m.departure = lug(24.0, 12.2);
    assert_eq!(decide(m, limits()).verdict, Verdict::Accept);
}

/// A part alone in its region whose outline its best template does not all explain is the part
/// that differs (a type not enrolled, named by where), not one something lies on; with another
/// part found beside it, something does.
#[test]
fn alone_in_its_region_a_part_not_all_explained_is_a_type_not_enrolled() {
    let mut m = region();
    m.region.as_mut().unwrap().support = 0.74;
    let d = decide(m.clone(), limits());
    assert_eq!(d.verdict.reason(), Reason::Touching, "{}", d.verdict);
    m.alone = true;
    m.departure = Some(Departure {
        len: 120.0,
        width: 40.0,
        depth: 24.0,
        apart: 6.0,
        reach: 24.0,
        at_deg: 95.0,
        part_lacks: true,
        less_material: true,
    });
    let d = decide(m, limits());
    assert!(matches!(&d.verdict, Verdict::Unlike { rival: None, departure: Some(_), .. }), "{}", d.verdict);
    assert_eq!(d.verdict.reason(), Reason::UnknownType);
    assert!(!d.verdict.names_type());
    assert_eq!(failed_rows(&d), ["outline explained (bracket up)"]);
    assert_eq!(
        d.to_string().split(';').next().unwrap(),
        "like bracket up except 120 px of outline 24 px deep at 95 deg, where the part lacks the template's outline: a type not enrolled"
    );
    // The region search looks again at what may be several parts, not at a type not enrolled.
    assert!(!d.verdict.may_be_several());
    assert!(Verdict::NoFit { need: 0.75, merged: true }.may_be_several());
}

/// A region much larger than the template it resembles is several parts (touching), not an
/// unknown type; one that shows little of the template's outline, or resembles it only at a
/// scale no part takes, does not resemble it: one part no template explains, a type not
/// enrolled, whatever its size.
#[test]
fn no_fit_on_a_region_twice_the_part_is_touching() {
    let mut m = separate();
    let o = m.outline.as_mut().unwrap();
    (o.fit, o.coverage) = (0.5, 0.9);
    m.area = Some(110_000.0);
    let d = decide(m.clone(), limits());
    assert_eq!(d.verdict, Verdict::NoFit { need: 0.75, merged: true });
    assert_eq!(d.verdict.reason(), Reason::Touching);
    // Resembling the template only stretched beyond the accepted scales: one part.
    let mut stretched = m.clone();
    stretched.outline.as_mut().unwrap().scale = 1.2;
    let d = decide(stretched, limits());
    assert_eq!(d.verdict, Verdict::NoFit { need: 0.75, merged: false });
    assert_eq!(d.verdict.reason(), Reason::UnknownType);
    let o = m.outline.as_mut().unwrap();
    (o.fit, o.coverage) = (0.3, 0.3);
    let d = decide(m, limits());
    assert_eq!(d.verdict, Verdict::NoFit { need: 0.75, merged: false });
    assert_eq!(d.verdict.reason(), Reason::UnknownType);
}

/// Beside another part, a part not all explained is one something lies on or against, unless
/// it lacks material the template has, deep and wide, where nothing hides it: then it is the
/// part that differs. A shallow departure says nothing.
#[test]
fn beside_others_a_part_lacking_the_templates_material_on_open_belt_is_a_type_not_enrolled() {
    let mut m = region();
    m.region.as_mut().unwrap().support = 0.73;
    let notch =
        Departure { len: 184.0, width: 40.0, depth: 24.0, apart: 6.0, reach: 24.0, at_deg: 270.0, part_lacks: true, less_material: true };
    m.departure = Some(Departure { depth: 7.0, ..notch });
    let d = decide(m.clone(), limits());
    assert!(matches!(d.verdict, Verdict::Unseen { .. }), "{}", d.verdict);
    m.departure = Some(notch);
    let d = decide(m, limits());
    assert!(matches!(&d.verdict, Verdict::Unlike { rival: None, departure: Some(_), .. }), "{}", d.verdict);
    assert_eq!(d.verdict.reason(), Reason::UnknownType);
}

/// A record that stops short of a type or of the line features is never accepted.
#[test]
fn an_incomplete_record_is_never_accepted() {
    let mut no_lines = separate();
    no_lines.lines = None;
    let mut no_fit = region();
    no_fit.region = None;
    for m in [Measured::default(), no_lines, no_fit, Measured { border: Some(bounds()), ..Measured::default() }] {
        let d = decide(m.clone(), limits());
        assert_eq!(d.verdict, Verdict::NoFit { need: 0.75, merged: false }, "{m:?}");
        assert!(!d.verdict.accepts());
    }
}

/// The one rival test: a rival ties when every fit measured of it comes within the margin of
/// the best's; one that does not tie decides nothing, whatever its line features.
#[test]
fn a_rival_rejects_only_when_it_ties_and_its_lines_are_not_clearly_worse() {
    let rival = |fit: f64, support: Option<(f64, f64)>, confidence: f64| Rival {
        name: named("flange", Face::Up),
        fit,
        best: 0.95,
        tolerance: 1.6,
        support,
        confidence,
        local: None,
        features: None,
    };
    let l = limits();
    assert!(rival(0.86, None, 0.0).ties(&l));
    assert!(!rival(0.84, None, 0.0).ties(&l));
    assert!(rival(0.9, Some((0.9, 0.97)), 0.0).ties(&l));
    assert!(!rival(0.9, Some((0.8, 0.97)), 0.0).ties(&l), "the support must tie too");
    for (path, base) in [("separate", separate()), ("region", region())] {
        for (r, verdict) in [
            (rival(0.9, base.region.as_ref().map(|_| (0.95, 0.97)), 0.7), 9),
            (rival(0.9, base.region.as_ref().map(|_| (0.95, 0.97)), 0.6), 0),
            (rival(0.8, base.region.as_ref().map(|_| (0.95, 0.97)), 0.8), 0),
        ] {
            let mut m = base.clone();
            m.rival = Some(r.clone());
            let d = decide(m, l);
            assert_eq!(variant(&d.verdict), verdict, "{path}: {r:?} -> {}", d.verdict);
        }
    }
}

/// The why panel's measures: each test made with its limit and whether it passed, the failing
/// one the verdict's, nothing the ladder did not reach; the runner-up named.
#[test]
fn measures_say_which_limit_a_part_failed() {
    let mut m = separate();
    m.lines = Some(lines(0.42));
    m.blocked = None;
    let d = decide(m, limits());
    assert_eq!(d.verdict, Verdict::LowConfidence { confidence: 0.42, threshold: 0.5 });
    let rows = d.measures();
    let names: Vec<&str> = rows.iter().filter(|m| m.pass.is_some()).map(|m| m.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "outline clear of the frame's edge",
            "region area",
            "outline fit (bracket up)",
            "scale",
            "extra outline (other material), missing outline (hidden)",
            "confidence (line features)"
        ]
    );
    let conf = rows.iter().find(|m| m.name == "confidence (line features)").unwrap();
    assert_eq!((conf.value.as_str(), conf.limit.as_str(), conf.pass), ("0.420", ">= 0.50", Some(false)));
    assert_eq!(d.runner_up().as_deref(), Some("bracket down: fit 0.810"));
    // A covered part in a region: the order is the failing measure, its support never tested.
    let mut m = region();
    m.order = Order::Under(named("flange", Face::Down));
    m.region.as_mut().unwrap().support = 0.8;
    let d = decide(m, limits());
    assert_eq!(failed_rows(&d), ["lies on top"]);
    assert!(!d.measures().iter().any(|r| r.name.starts_with("outline explained")));
}

#[test]
fn each_verdict_gives_its_reason() {
    let rival = Rival {
        name: named("bracket", Face::Up),
        fit: 0.9,
        best: 0.91,
        tolerance: 3.0,
        support: None,
        confidence: 0.7,
        local: None,
        features: None,
    };
    for (v, r) in [
        (Verdict::Accept, Reason::Ok),
        (Verdict::AtBorder { lo: Pt::new(0.0, 0.0), hi: Pt::new(9.0, 9.0) }, Reason::AtBorder),
        (Verdict::TooLarge { area: 1.0 }, Reason::Touching),
        (Verdict::NoFit { need: 0.75, merged: false }, Reason::UnknownType),
        (Verdict::NoFit { need: 0.75, merged: true }, Reason::Touching),
        (Verdict::Scale { scale: 1.3, range: (0.9, 1.1) }, Reason::UnknownType),
        (Verdict::Foreign { extra: 0.1, missing: 0.0, limit: 0.06 }, Reason::Touching),
        (Verdict::Covered { by: named("bracket", Face::Up) }, Reason::Covered),
        (Verdict::OrderUnclear, Reason::Touching),
        (Verdict::Unseen { support: 0.8, need: 0.93 }, Reason::Touching),
        (Verdict::Rival { rival }, Reason::Ambiguous),
        (Verdict::LowConfidence { confidence: 0.3, threshold: 0.5 }, Reason::LowConfidence),
        (Verdict::NoClearance { edge_px: 4 }, Reason::NoClearance),
        (Verdict::Unexplained { area: 5000.0 }, Reason::Touching),
    ] {
        assert_eq!(v.reason(), r, "{v:?}");
        assert_eq!(v.accepts(), r == Reason::Ok, "{v:?}");
    }
}

#[test]
fn the_text_names_the_verdict_first_then_the_evidence() {
    let mut m = region();
    m.region = Some(RegionFit { best: named("flange", Face::Down), support: 0.97, coverage: 0.7, rms: 1.2, scale: 1.0 });
    m.order = Order::Under(named("bracket", Face::Up));
    m.lines = None;
    let d = decide(m, limits());
    assert_eq!(
        d.to_string(),
        "bracket up lies on it; found in a region of several parts: flange down outline explained 0.970 (need 0.93), on the region's outline 0.700, rms 1.20 px, scale 1.000"
    );
    let far = Verdict::Foreign { extra: 0.2, missing: 0.0, limit: 0.06 };
    assert!(far.to_string().starts_with("the outline runs onto something else"), "{far}");
}

/// The other face of one outline, tied with the best (its outline fits as well and differs from
/// it nowhere), with line-feature `confidence` and what the features inside show.
fn one_outline_tie(confidence: f64, features: Option<OwnFeatures>) -> Rival {
    Rival {
        name: named("bracket", Face::Down),
        fit: 1.0,
        best: 1.0,
        tolerance: 2.0,
        support: None,
        confidence,
        local: Some(Local { best_len: 0.0, rival_len: 0.0, ..local(0.0, 0.0) }),
        features,
    }
}

/// The features inside tell the best from a tied rival when one has own features: most of the
/// best's shown, little of the rival's.
#[test]
fn own_features_inside_tell_faces_of_one_outline() {
    let tells = |a_count: usize, a_shown: f64, b_count: usize, b_shown: f64| {
        one_outline_tie(0.7, Some(OwnFeatures { a_count, a_shown, b_count, b_shown })).features_tell()
    };
    assert!(tells(52, 1.0, 0, 0.0));
    assert!(tells(0, 0.0, 52, 0.0));
    assert!(tells(40, 0.8, 30, 0.2));
    assert!(!tells(0, 0.0, 0, 0.0), "neither has own features");
    assert!(!tells(0, 0.0, 52, 1.0), "the rival's pocket shows");
    assert!(!tells(52, 0.4, 0, 0.0), "the best's pocket hardly shows");
    assert!(!tells(40, 0.9, 30, 0.5), "both show");
    assert!(tells(40, 0.9, 5, 1.0), "a few points of the rival's are not a feature");
    // In the ladder: the same tie, ambiguous without the features, accepted with them.
    let mut m = separate();
    let confidence = m.lines.as_ref().unwrap().confidence;
    let (without, with) = (
        one_outline_tie(confidence, None),
        one_outline_tie(confidence, Some(OwnFeatures { a_count: 52, a_shown: 1.0, b_count: 0, b_shown: 0.0 })),
    );
    m.rival = Some(without);
    assert_eq!(decide(m.clone(), limits()).verdict.reason(), Reason::Ambiguous);
    m.rival = Some(with);
    assert_eq!(decide(m, limits()).verdict, Verdict::Accept);
}

/// One part alone, one story: a region the single-part look found a part of a type not enrolled
/// keeps that verdict when the search found one part not seen whole and nothing else but
/// unexplained material; any other outcome of the search replaces it.
#[test]
fn a_search_that_explains_nothing_leaves_the_single_part_story() {
    let unknown = Verdict::NoFit { need: 0.75, merged: false };
    let merged = Verdict::NoFit { need: 0.75, merged: true };
    let unseen = Verdict::Unseen { support: 0.9, need: 0.93 };
    let rest = Verdict::Unexplained { area: 14000.0 };
    assert!(!search_explains(&unknown, &[&unseen, &rest]));
    assert!(!search_explains(&unknown, &[&rest, &unseen, &rest]));
    // The single-part look saw several parts: the search's story stands.
    assert!(search_explains(&merged, &[&unseen, &rest]));
    // A part seen whole, or two parts, or one part and nothing beside it: the search explained.
    assert!(search_explains(&unknown, &[&Verdict::Accept, &rest]));
    assert!(search_explains(&unknown, &[&unseen, &unseen, &rest]));
    assert!(search_explains(&unknown, &[&unseen]));
}

/// Features inside that show the rival's own and not the best's speak against the best: its
/// confidence lead no longer decides the tie (the rest of the ladder is as before).
#[test]
fn features_inside_against_the_best_outweigh_its_confidence_lead() {
    let against = |a_count, a_shown, b_count, b_shown| OwnFeatures { a_count, a_shown, b_count, b_shown }.against();
    assert!(against(54, 0.39, 26, 0.92), "the other face's pockets show, the best's hardly");
    assert!(against(0, 0.0, 26, 0.92), "only the rival has own features, and they show");
    assert!(!against(54, 0.8, 26, 0.92), "both show: neither tells, no word against");
    assert!(!against(54, 0.39, 5, 1.0), "a few points of the rival's are not a feature");
    assert!(!against(54, 0.39, 26, 0.5), "the rival's hardly show either");
    let mut m = separate();
    let lead = m.lines.as_ref().unwrap().confidence - limits().confidence_margin - 0.01;
    m.rival = Some(one_outline_tie(lead, Some(OwnFeatures { a_count: 54, a_shown: 0.7, b_count: 26, b_shown: 0.5 })));
    assert_eq!(decide(m.clone(), limits()).verdict, Verdict::Accept, "the lead decides where the features say nothing");
    m.rival = Some(one_outline_tie(lead, Some(OwnFeatures { a_count: 54, a_shown: 0.39, b_count: 26, b_shown: 0.92 })));
    let d = decide(m, limits());
    assert_eq!(d.verdict.reason(), Reason::Ambiguous);
    assert!(d.verdict.to_string().contains("the features inside show its own"), "{}", d.verdict);
}

/// Of several places where a part departs, the decision reads one that makes it a type not
/// enrolled, however much longer a shallow run beside it (a placement a little off along a
/// long arm) is; with none that counts, the longest.
#[test]
fn the_departure_that_counts_is_the_one_told() {
    let d = |len: f64, depth: f64, width: f64| Departure {
        len,
        width,
        depth,
        apart: 6.0,
        reach: 24.0,
        at_deg: len,
        part_lacks: false,
        less_material: false,
    };
    let (shallow, lug, narrow) = (d(300.0, 9.0, 200.0), d(90.0, 20.0, 60.0), d(120.0, 20.0, 8.0));
    assert_eq!(telling(vec![shallow, lug, narrow], &limits()), Some(lug));
    assert!(lug.counts(&limits()) && !shallow.counts(&limits()) && !narrow.counts(&limits()));
    assert_eq!(telling(vec![narrow, shallow], &limits()), Some(shallow));
    assert_eq!(telling(Vec::new(), &limits()), None);
}
