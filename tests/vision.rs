//! The estimator's contract, stage by stage, on rendered parts.

mod common;

use lfi_bridge::sim::render::{self, Lighting, Placement, Prepared};
use lfi_bridge::sim::{SimConfig, Simulator, models};
use lfi_bridge::vision::geometry::angle_diff_deg;
use lfi_bridge::vision::{Estimator, Face, GrayImage, Params, Reason, Template};
use rand::SeedableRng;

fn small_sim() -> Simulator {
    Simulator::new(SimConfig { width: 1296, height: 972, seed: 5, noise: None }).unwrap()
}

fn light(noise: f64) -> Lighting {
    Lighting { exposure: 0.92, gradient: 0.05, gradient_dir_deg: 30.0, glare: None, blur_sigma: 0.4, noise_sigma: noise, belt_gray: 55.0 }
}

fn frame_with(model: &Prepared, face: Face, angle: f64, noise: f64, seed: u64) -> GrayImage {
    let pl = Placement { face, angle_deg: angle, x: 640.3, y: 481.7, px_per_mm: 3.25, gray: 170.0 };
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    render::render(1296, 972, &[(model, pl)], &light(noise), &mut rng).unwrap()
}

#[test]
fn rotating_a_part_by_t_rotates_the_estimate_by_t() {
    let sim = small_sim();
    let est = Estimator::new(&common::enrolled(&sim), Params::default()).unwrap();
    let bracket = Prepared::new(models::bracket());
    for (i, angle) in [0.0, 33.3, 147.9, 200.05, 271.1, 359.6].into_iter().enumerate() {
        let img = frame_with(&bracket, Face::Up, angle, 2.0, i as u64);
        let fe = est.estimate(img.view().unwrap()).unwrap();
        assert_eq!(fe.parts.len(), 1);
        let p = &fe.parts[0];
        assert!(p.accepted, "angle {angle}: {} {}", p.reason, p.detail());
        assert_eq!(p.type_name.as_deref(), Some("bracket"));
        assert_eq!(p.face, Some(Face::Up));
        let err = angle_diff_deg(p.angle_deg, angle);
        assert!(err.abs() < 0.1, "angle {angle}: estimated {} (error {err})", p.angle_deg);
        // The drop shadow falls the same way whatever the angle, biasing the outline by a few
        // tenths of a pixel on one side: a position error that turns with the part.
        assert!((p.x - 640.3).hypot(p.y - 481.7) < 0.75, "angle {angle}: position ({}, {})", p.x, p.y);
    }
}

#[test]
fn a_mirrored_template_is_recognised_as_the_other_face() {
    let sim = small_sim();
    let templates = common::enrolled(&sim);
    let est = Estimator::new(&templates, Params::default()).unwrap();
    let (_, _, up) = sim.templates().unwrap().into_iter().find(|(n, f, _)| n == "flange" && *f == Face::Up).unwrap();
    // Turning a part over about the x axis mirrors it top to bottom: the face-down view at 0;
    // mirroring left to right is the same view turned by 180 degrees.
    for (flip_rows, expect) in [(true, 0.0), (false, 180.0)] {
        let mut m = up.clone();
        for y in 0..up.height {
            for x in 0..up.width {
                let (sx, sy) = if flip_rows { (x, up.height - 1 - y) } else { (up.width - 1 - x, y) };
                m.data[y * up.width + x] = up.data[sy * up.width + sx];
            }
        }
        let fe = est.estimate(m.view().unwrap()).unwrap();
        let p = &fe.parts[0];
        assert_eq!(p.type_name.as_deref(), Some("flange"), "{}", p.detail());
        assert_eq!(p.face, Some(Face::Down), "{}", p.detail());
        assert!(angle_diff_deg(p.angle_deg, expect).abs() < 0.2, "angle {} expected {expect}", p.angle_deg);
    }
}

#[test]
fn an_unknown_part_is_rejected_not_named_after_the_nearest_type() {
    let sim = small_sim();
    let est = Estimator::new(&common::enrolled(&sim), Params::default()).unwrap();
    let lever = Prepared::new(models::lever());
    for (i, face) in [Face::Up, Face::Down].into_iter().enumerate() {
        let fe = est.estimate(frame_with(&lever, face, 41.0 + 90.0 * i as f64, 2.0, 9).view().unwrap()).unwrap();
        assert_eq!(fe.parts.len(), 1);
        assert!(!fe.parts[0].accepted);
        assert_eq!(fe.parts[0].reason, Reason::UnknownType, "{}", fe.parts[0].detail());
        assert_eq!(fe.parts[0].type_name, None);
    }
}

/// A part of a type not enrolled, alone, is judged by the single-part look only: no template's
/// signature comes near it and it is too small to hold two parts, so the region search does not
/// run (it never found anything in such a region, at four times the cost of the rest). Two of
/// them touching are large enough for two parts: searched, and still nothing accepted.
#[test]
fn an_unknown_part_alone_is_not_searched_for_several_parts_two_touching_are() {
    let sim = small_sim();
    let est = Estimator::new(&common::enrolled(&sim), Params::default()).unwrap();
    let lever = Prepared::new(models::lever());
    let at = |x: f64| Placement { face: Face::Up, angle_deg: 0.0, x, y: 481.7, px_per_mm: 3.25, gray: 170.0 };
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let alone = render::render(1296, 972, &[(&lever, at(640.3))], &light(2.0), &mut rng).unwrap();
    let fe = est.estimate(alone.view().unwrap()).unwrap();
    assert_eq!(fe.parts.len(), 1);
    assert_eq!(fe.parts[0].reason, Reason::UnknownType, "{}", fe.parts[0].detail());
    assert_eq!(fe.timings.clump, 0.0, "the region search ran on one unknown part");
    // The lever is 98 mm long (318 px): side by side, their ends touch.
    let pair = render::render(1296, 972, &[(&lever, at(440.0)), (&lever, at(756.0))], &light(2.0), &mut rng).unwrap();
    let fe = est.estimate(pair.view().unwrap()).unwrap();
    assert!(
        fe.timings.clump > 0.0,
        "two unknown parts touching were not searched: {:?}",
        fe.parts.iter().map(|p| p.detail()).collect::<Vec<_>>()
    );
    assert!(fe.parts.iter().all(|p| !p.accepted), "{:?}", fe.parts.iter().map(|p| p.detail()).collect::<Vec<_>>());
}

#[test]
fn a_frame_without_parts_yields_no_estimates() {
    let sim = small_sim();
    let est = Estimator::new(&common::enrolled(&sim), Params::default()).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let belt = render::render(1296, 972, &[], &light(8.0), &mut rng).unwrap();
    assert!(est.estimate(belt.view().unwrap()).unwrap().parts.is_empty());
    let black = GrayImage::new(640, 480, 0);
    assert!(est.estimate(black.view().unwrap()).unwrap().parts.is_empty());
    let white = GrayImage::new(640, 480, 255);
    assert!(est.estimate(white.view().unwrap()).unwrap().parts.is_empty());
}

#[test]
fn a_part_cut_by_the_frame_edge_is_rejected_at_the_border() {
    let sim = small_sim();
    let est = Estimator::new(&common::enrolled(&sim), Params::default()).unwrap();
    let bracket = Prepared::new(models::bracket());
    let pl = Placement { face: Face::Up, angle_deg: 10.0, x: 60.0, y: 400.0, px_per_mm: 3.25, gray: 170.0 };
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let img = render::render(1296, 972, &[(&bracket, pl)], &light(2.0), &mut rng).unwrap();
    let fe = est.estimate(img.view().unwrap()).unwrap();
    assert_eq!(fe.parts.len(), 1);
    assert_eq!(fe.parts[0].reason, Reason::AtBorder);
    assert!(!fe.parts[0].accepted);
}

#[test]
fn templates_need_a_whole_part() {
    let empty = GrayImage::new(300, 300, 60);
    assert!(Template::from_image(empty.view().unwrap(), "x", 1, Face::Up, None, &Params::default()).is_err());
    let sim = small_sim();
    let (_, _, img) = sim.templates().unwrap().remove(0);
    assert!(Template::from_image(img.view().unwrap(), "x", 0, Face::Up, None, &Params::default()).is_err(), "id 0 is reserved");
    assert!(Template::from_image(img.view().unwrap(), " ", 1, Face::Up, None, &Params::default()).is_err(), "empty name");
}

/// A template image whose part lies near the image's edge with a stain of the belt between:
/// the part is enrolled with its whole outline and the stain is reported as left out; a part
/// that the image's edge really cuts is refused.
#[test]
fn a_stain_at_the_templates_border_is_left_out_and_a_cut_part_refused() {
    use lfi_bridge::vision::TemplateError;
    let sim = small_sim();
    let params = Params::default();
    for (name, face, img) in sim.templates().unwrap() {
        let whole = Template::from_image(img.view().unwrap(), &name, 1, face, None, &params).unwrap();
        // The part's rightmost point, and the image cut 16 px to its right.
        let right = whole.outline.iter().copied().max_by(|a, b| a.x.total_cmp(&b.x)).unwrap();
        let w = right.x.ceil() as usize + 16;
        let mut near = img.crop(0, 0, w, img.height).unwrap();
        // A dark stain on the belt, touching the image's edge, 8 px from the part: within the
        // reach of the scenes' closing.
        let (cx, cy) = (w as f64 - 1.0, right.y);
        for y in 0..near.height {
            for x in 0..w {
                if (x as f64 - cx).hypot(y as f64 - cy) <= 7.0 {
                    near.data[y * w + x] = 12;
                }
            }
        }
        let view = near.view().unwrap();
        let (t, left_out) = Template::learn(view, &name, 1, face, None, &params).unwrap_or_else(|e| panic!("{name} {face}: {e}"));
        assert!(left_out.is_some(), "{name} {face}: the stain joined the part at the scenes' closing (else this tests nothing)");
        assert!((t.area / whole.area - 1.0).abs() < 0.01, "{name} {face}: area {:.0} against {:.0} without the stain", t.area, whole.area);
        // Point by point: the refinement near the stain sees its edge 8 px away.
        let mut off: Vec<f64> =
            t.outline.iter().map(|p| whole.outline.iter().map(|q| (*p - *q).norm()).fold(f64::INFINITY, f64::min)).collect();
        off.sort_by(f64::total_cmp);
        let (p95, max) = (off[off.len() * 95 / 100], off[off.len() - 1]);
        eprintln!("{name} {face}: outline off the stainless template's by p95 {p95:.2} px, max {max:.2} px");
        assert!(
            p95 < 0.5 && max < 2.0,
            "{name} {face}: the outline strays from the stainless template's: p95 {p95:.2} px, max {max:.2} px"
        );

        // The image's edge through the part, a quarter of its length from its right end: refused.
        // (The cut outline is an open chain that encloses nothing, so the largest region found
        // may be something inside the part, e.g. the bracket's inset plate, that does not touch
        // the border: before, that was enrolled as the part.)
        let left = whole.outline.iter().map(|p| p.x).fold(f64::INFINITY, f64::min);
        let cut = img.crop(0, 0, (right.x - 0.25 * (right.x - left)) as usize, img.height).unwrap();
        let refused = Template::learn(cut.view().unwrap(), &name, 1, face, None, &params);
        assert!(matches!(refused, Err(TemplateError::AtBorder)), "{name} {face}: {:?}", refused.map(|(_, l)| l));
    }
}

/// A camera whose resolution changed under a configured ROI: the error names both.
#[test]
fn a_roi_past_the_frame_names_the_roi_and_the_frame() {
    let sim = Simulator::new(SimConfig::default()).unwrap();
    let estimator = Estimator::new(&sim.enrolled(&Params::default()).unwrap(), Params::default()).unwrap();
    let img = GrayImage::new(640, 480, 30);
    assert!(estimator.estimate_in(&img, Some([0, 0, 640, 480])).is_ok());
    for roi in [[600, 0, 100, 100], [0, 470, 64, 64], [usize::MAX, 0, 64, 64]] {
        let e = estimator.estimate_in(&img, Some(roi)).unwrap_err();
        assert_eq!(e, lfi_bridge::vision::FrameError::Roi { roi, width: 640, height: 480 });
        let text = e.to_string();
        assert!(text.contains("region of interest") && text.contains("640 x 480"), "{text}");
    }
}

/// A ROI's parts are reported in the whole frame's pixels, pose and lines too.
#[test]
fn a_part_found_in_a_roi_is_reported_in_frame_pixels_with_its_pose_and_lines() {
    let sim = Simulator::new(SimConfig { width: 1296, height: 972, seed: 5, noise: None }).unwrap();
    let estimator = Estimator::new(&sim.enrolled(&Params::default()).unwrap(), Params::default()).unwrap();
    let scene = sim.scene_with(0, "clean").unwrap();
    let whole = estimator.estimate_in(&scene.image, None).unwrap();
    let roi = [40, 30, 1296 - 40, 972 - 30];
    let cut = estimator.estimate_in(&scene.image, Some(roi)).unwrap();
    let (a, b) = (&whole.parts[0], &cut.parts[0]);
    assert!((a.x - b.x).abs() < 0.05 && (a.y - b.y).abs() < 0.05, "{} {} vs {} {}", a.x, a.y, b.x, b.y);
    let origin = |p: &lfi_bridge::vision::PartEstimate| {
        let (i, pose) = p.matched.unwrap();
        pose.apply(estimator.templates().nth(i).unwrap().origin)
    };
    assert!((origin(a) - origin(b)).norm() < 0.05, "the matched pose moved with the ROI");
    let (sa, sb) = (a.axis.unwrap(), b.axis.unwrap());
    assert!((sa.a - sb.a).norm() < 0.5, "{sa:?} vs {sb:?}");
}

/// A frame comes out the same on one thread as on two (regions side by side; in a region of
/// several parts, the vote, the looks at its hypotheses and the parts' measures): the same
/// parts in the same order, each decided alike at the same pose, and the same debris.
#[test]
fn several_regions_on_two_threads_are_estimated_as_on_one() {
    let sim = small_sim();
    let templates = common::enrolled(&sim);
    let one = Estimator::new(&templates, Params { threads: 1, ..Params::default() }).unwrap();
    let two = Estimator::new(&templates, Params { threads: 2, ..Params::default() }).unwrap();
    let mut regions = 0;
    for (i, condition) in
        [(0, "multi"), (1, "multi"), (2, "multi"), (0, "touching"), (1, "touching"), (0, "overlapping"), (1, "overlapping"), (0, "unknown")]
    {
        let scene = sim.scene_with(i, condition).unwrap();
        let (a, b) = (one.estimate(scene.image.view().unwrap()).unwrap(), two.estimate(scene.image.view().unwrap()).unwrap());
        let story = |fe: &lfi_bridge::vision::FrameEstimate| {
            fe.parts.iter().map(|p| format!("{} {:.6} {:.6} {:.6}", p.detail(), p.angle_deg, p.x, p.y)).collect::<Vec<_>>()
        };
        assert_eq!(story(&a), story(&b), "{condition} {i}");
        assert_eq!(a.debris, b.debris, "{condition} {i}");
        regions += a.parts.len();
    }
    assert!(regions >= 8, "the scenes hold several parts each: {regions}");
}

/// A plate whose two faces have one outline (a disc with lugs at 0, 90 and 180 degrees,
/// symmetric under the flip) and a bore; face up has a deep pocket beside the bore (shaded dark), face down none.
/// Drawn at `angle_deg` about (cx, cy) in a `w` x `h` frame, 2 x 2 supersampled, with a little
/// deterministic noise.
fn two_faced_plate(w: usize, h: usize, cx: f64, cy: f64, angle_deg: f64, pocket: bool) -> GrayImage {
    let (s, c) = angle_deg.to_radians().sin_cos();
    let gray = |x: f64, y: f64| -> f64 {
        let (dx, dy) = (x - cx, y - cy);
        let (u, v) = (c * dx + s * dy, -s * dx + c * dy);
        let r = u.hypot(v);
        let lug = (v.abs() <= 30.0 && (140.0..=220.0).contains(&u.abs())) || (u.abs() <= 30.0 && (140.0..=210.0).contains(&v));
        if r <= 35.0 || (r > 150.0 && !lug) {
            55.0
        } else if pocket && u.hypot(v + 75.0) <= 28.0 {
            75.0
        } else {
            170.0
        }
    };
    let mut img = GrayImage::new(w, h, 55);
    let mut seed = 0x9E37_79B9_u32;
    for y in 0..h {
        for x in 0..w {
            let mut sum = 0.0;
            for (a, b) in [(-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)] {
                sum += gray(x as f64 + a, y as f64 + b);
            }
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let noise = ((seed >> 24) as f64 / 255.0 - 0.5) * 6.0;
            img.data[y * w + x] = (sum / 4.0 + noise).round().clamp(0.0, 255.0) as u8;
        }
    }
    img
}

/// Two faces with one outline are told apart by what lies inside: the face whose own features
/// (a pocket) the image shows, or whose rival's own features it does not.
#[test]
fn two_faces_of_one_outline_are_told_apart_by_the_features_inside() {
    let learn = |face: Face, pocket: bool| {
        let img = two_faced_plate(560, 560, 279.5, 279.5, 0.0, pocket);
        Template::from_image(img.view().unwrap(), "plate", 1, face, None, &Params::default()).unwrap()
    };
    let est = Estimator::new(&[learn(Face::Up, true), learn(Face::Down, false)], Params::default()).unwrap();
    for (pocket, face) in [(true, Face::Up), (false, Face::Down)] {
        for angle in [30.0, 212.5] {
            let img = two_faced_plate(900, 800, 450.3, 390.7, angle, pocket);
            let fe = est.estimate(img.view().unwrap()).unwrap();
            assert_eq!(fe.parts.len(), 1);
            let p = &fe.parts[0];
            assert!(p.accepted, "{face:?} at {angle}: {} {}", p.reason, p.detail());
            assert_eq!(p.face, Some(face), "at {angle}: {}", p.detail());
            // The drawing turns the plate by -angle in the estimator's sense.
            assert!(angle_diff_deg(p.angle_deg, -angle).abs() < 0.2, "at {angle}: {}", p.angle_deg);
        }
    }
}
