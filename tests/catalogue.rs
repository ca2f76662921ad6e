//! The simulator's generated catalogue: reproducible from its seed, and every revision differs
//! from its parent along one stretch of outline only, 3-7 mm deep.

use lfi_bridge::sim::catalog::{self, Catalogue};
use lfi_bridge::sim::models::{Model, Shape};
use lfi_bridge::sim::{SimConfig, Simulator};
use opencv::core::{self, Mat, Point, Scalar, Vector};
use opencv::imgproc;

/// Pixels per millimetre of the silhouettes compared.
const PX: f64 = 10.0;

/// The model's silhouette (material less holes) in model coordinates, 10 px/mm, in a box of
/// +-150 mm: its outer outline, in pixels.
fn outline(m: &Model) -> Vector<Point> {
    let side = (300.0 * PX) as i32;
    let fill = |shapes: &[Shape]| -> Mat {
        let mut all = Mat::new_rows_cols_with_default(side, side, core::CV_8UC1, Scalar::all(0.0)).unwrap();
        for s in shapes {
            let mut one = Mat::new_rows_cols_with_default(side, side, core::CV_8UC1, Scalar::all(0.0)).unwrap();
            let polys: Vector<Vector<Point>> = s
                .contours()
                .iter()
                .map(|c| c.iter().map(|&(x, y)| Point::new(((x + 150.0) * PX).round() as i32, ((y + 150.0) * PX).round() as i32)).collect())
                .collect();
            imgproc::fill_poly(&mut one, &polys, Scalar::all(255.0), imgproc::LINE_8, 0, Point::new(0, 0)).unwrap();
            let mut or = Mat::default();
            core::bitwise_or(&all, &one, &mut or, &core::no_array()).unwrap();
            all = or;
        }
        all
    };
    let (material, holes) = (fill(&m.material), fill(&m.holes));
    let mut solid = Mat::default();
    let mut not_holes = Mat::default();
    core::bitwise_not(&holes, &mut not_holes, &core::no_array()).unwrap();
    core::bitwise_and(&material, &not_holes, &mut solid, &core::no_array()).unwrap();
    let mut contours: Vector<Vector<Point>> = Vector::new();
    imgproc::find_contours(&solid, &mut contours, imgproc::RETR_EXTERNAL, imgproc::CHAIN_APPROX_NONE, Point::new(0, 0)).unwrap();
    contours.iter().max_by(|a, b| imgproc::contour_area(a, false).unwrap().total_cmp(&imgproc::contour_area(b, false).unwrap())).unwrap()
}

/// How far each point of `a` lies from the outline `b`, mm.
fn distances(a: &Vector<Point>, b: &Vector<Point>) -> Vec<f64> {
    a.iter().map(|p| imgproc::point_polygon_test(b, core::Point2f::new(p.x as f32, p.y as f32), true).unwrap().abs() / PX).collect()
}

/// The runs (cyclic) of points farther than `limit`: how many, and the largest distance.
fn stretches(d: &[f64], limit: f64) -> (usize, f64) {
    let n = d.len();
    let far = |i: usize| d[i % n] > limit;
    let runs = (0..n).filter(|&i| far(i) && !far(i + n - 1)).count();
    let runs = if runs == 0 && far(0) { 1 } else { runs };
    (runs, d.iter().copied().fold(0.0, f64::max))
}

fn model<'a>(c: &'a Catalogue, name: &str) -> &'a Model {
    c.known.iter().chain(&c.unknown).find(|m| m.name == name).unwrap()
}

#[test]
fn a_catalogue_is_the_same_for_a_seed_and_its_scenes_too() {
    let (a, b) = (catalog::generate(40, 3), catalog::generate(40, 3));
    assert_eq!(format!("{:?}", a.known), format!("{:?}", b.known));
    assert_eq!(format!("{:?}", a.unknown), format!("{:?}", b.unknown));
    assert_eq!(a.types, b.types);
    assert_ne!(format!("{:?}", catalog::generate(40, 4).known), format!("{:?}", a.known), "another seed, another catalogue");
    let names: Vec<&str> = a.known.iter().map(|m| m.name.as_str()).collect();
    assert_eq!((names.len(), names[0], names[39]), (40, "T001", "T040"));
    assert!(a.types.iter().filter(|t| t.parent.is_some() && t.known).count() >= 3, "revision families: {:?}", a.types);
    assert!(a.types.iter().any(|t| !t.known && t.parent.is_some()), "an unseen next revision");
    assert!(a.types.iter().any(|t| !t.known && t.parent.is_none()), "an unknown new design");
    let cfg = SimConfig { width: 1296, height: 972, seed: 3, noise: None };
    let (sa, sb) = (Simulator::with_catalogue(cfg.clone(), &a).unwrap(), Simulator::with_catalogue(cfg, &b).unwrap());
    for i in [4, 8] {
        let (x, y) = (sa.scene(i).unwrap(), sb.scene(i).unwrap());
        assert_eq!(x.image, y.image, "scene {i}");
        assert_eq!(x.truth, y.truth, "scene {i}");
    }
}

#[test]
fn every_revision_differs_from_its_parent_along_one_stretch_three_to_seven_mm_deep() {
    for seed in [3, 11] {
        let c = catalog::generate(40, seed);
        let mut checked = 0;
        for t in c.types.iter().filter(|t| t.parent.is_some()) {
            let parent = t.parent.as_deref().unwrap();
            let (child, parent_outline) = (outline(model(&c, &t.name)), outline(model(&c, parent)));
            // Each way: the points more than 0.5 mm off the other's outline form one stretch.
            let (runs_c, depth_c) = stretches(&distances(&child, &parent_outline), 0.5);
            let (runs_p, depth_p) = stretches(&distances(&parent_outline, &child), 0.5);
            let depth = depth_c.max(depth_p);
            eprintln!(
                "seed {seed}: {} from {parent}: {} ({runs_c} + {runs_p} stretches, {depth:.2} mm)",
                t.name,
                t.change.as_ref().unwrap().what
            );
            assert!(
                runs_c <= 1 && runs_p <= 1 && runs_c + runs_p >= 1,
                "seed {seed}: {} differs from {parent} in {runs_c} + {runs_p} stretches",
                t.name
            );
            assert!((3.0..=7.0).contains(&depth), "seed {seed}: {} differs from {parent} by {depth:.2} mm", t.name);
            checked += 1;
        }
        assert!(checked >= 4, "seed {seed}: only {checked} revisions");
    }
}
