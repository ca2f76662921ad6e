//! A generated catalogue of castings and forgings: plates, levers, housings and forks of 50-150
//! mm with holes, bosses and ribs, different on their two faces, no two outlines alike and none
//! symmetric; some of them families of design revisions, where a sibling differs from its parent
//! by one local change of outline of 3.5-6.5 mm (a boss added, a notch cut) and nothing else; and
//! types never to be enrolled, some of them the next revision of an enrolled family.
//!
//! Everything follows from the seed: the same seed gives the same catalogue.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::models::{Look, Model, Shape, capsule, circle, feat, ring};
use super::render::Polygons;
use crate::truth::{CatalogChange, CatalogType};

/// A catalogue: the models to enrol (T001, T002, ...), the never-enrolled ones (U01, ...), and
/// each type's description for `catalog.json`, enrolled types first.
#[derive(Debug, Clone)]
pub struct Catalogue {
    /// Enrolled types, in id order.
    pub known: Vec<Model>,
    /// Never enrolled.
    pub unknown: Vec<Model>,
    /// Every type's family, parent and change.
    pub types: Vec<CatalogType>,
}

/// How deep a revision's change of outline is, mm.
pub const CHANGE_MM: std::ops::Range<f64> = 3.5..6.5;

fn polar(r: f64, deg: f64) -> (f64, f64) {
    let a = deg.to_radians();
    (r * a.cos(), -r * a.sin())
}

/// An irregular plate with a boss at one corner and a lug.
fn plate(rng: &mut ChaCha8Rng, name: String) -> Model {
    let n = rng.random_range(6..=8);
    let half = rng.random_range(28.0..55.0);
    let mut corners = Vec::with_capacity(n);
    for i in 0..n {
        let deg = 360.0 * i as f64 / n as f64 + rng.random_range(-12.0..12.0);
        let stretch = 1.0 + 0.45 * (deg.to_radians()).cos().abs();
        corners.push(polar(half * stretch * rng.random_range(0.7..1.0), deg));
    }
    let boss = corners[rng.random_range(0..n)];
    let lug_at = corners[(n / 2 + rng.random_range(0..2)) % n];
    let lug_end = (lug_at.0 * 1.18, lug_at.1 * 1.18);
    let (b, l) = (rng.random_range(9.0..13.0), rng.random_range(5.0..7.0));
    let hole = (rng.random_range(-0.3..0.3) * half, rng.random_range(-0.2..0.2) * half);
    Model {
        name,
        material: vec![Shape::Poly(corners), circle(boss.0, boss.1, b), capsule(lug_at, lug_end, l)],
        holes: vec![
            circle(boss.0, boss.1, 0.45 * b),
            circle(lug_end.0, lug_end.1, 0.45 * l),
            circle(hole.0, hole.1, rng.random_range(3.0..6.0)),
        ],
        top: vec![
            feat(ring(boss.0, boss.1, 0.45 * b, 0.85 * b), Look::Raised),
            feat(capsule((hole.0, hole.1), (0.5 * (boss.0 + hole.0), 0.5 * (boss.1 + hole.1)), 2.8), Look::Raised),
        ],
        bottom: vec![
            feat(circle(0.4 * lug_at.0, 0.4 * lug_at.1, 4.0), Look::Recessed),
            feat(circle(-0.4 * boss.0, 0.3 * boss.1, 2.6), Look::Blind),
        ],
        rounded: 0.0,
    }
}

/// A forged lever: a big eye and a small one joined by an arm, a bump on one side.
fn lever(rng: &mut ChaCha8Rng, name: String) -> Model {
    let len = rng.random_range(55.0..120.0);
    let (r1, r2) = (rng.random_range(12.0..20.0), rng.random_range(7.0..11.0));
    let (a, b) = ((-len / 2.0, 0.0), (len / 2.0, rng.random_range(-12.0..12.0)));
    let w = rng.random_range(4.5..7.0);
    let t = rng.random_range(0.25..0.55);
    let bump = (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1) - rng.random_range(5.0..9.0));
    Model {
        name,
        material: vec![circle(a.0, a.1, r1), circle(b.0, b.1, r2), capsule(a, b, w), capsule((bump.0, bump.1 + 6.0), bump, 4.5)],
        holes: vec![circle(a.0, a.1, 0.5 * r1), circle(b.0, b.1, 0.5 * r2)],
        top: vec![
            feat(capsule((a.0 + r1, a.1), (b.0 - r2, b.1), 2.0), Look::Raised),
            feat(ring(a.0, a.1, 0.5 * r1, 0.8 * r1), Look::Raised),
        ],
        bottom: vec![feat(capsule((a.0 + r1 + 3.0, a.1), (a.0 + r1 + 18.0, a.1 + 0.3 * (b.1 - a.1)), 2.5), Look::Recessed)],
        rounded: rng.random_range(2.0..4.0),
    }
}

/// A housing: a round body with a bore and two or three ears at uneven angles.
fn housing(rng: &mut ChaCha8Rng, name: String) -> Model {
    let r = rng.random_range(22.0..40.0);
    let mut material = vec![circle(0.0, 0.0, r)];
    let mut holes = vec![circle(0.0, 0.0, rng.random_range(0.3..0.5) * r)];
    let mut deg = rng.random_range(0.0..360.0);
    let ears = rng.random_range(2..=3);
    for k in 0..ears {
        let reach = r + rng.random_range(9.0..18.0) + 3.0 * k as f64;
        let e = polar(reach, deg);
        let er = rng.random_range(6.0..9.0);
        material.push(capsule((0.0, 0.0), e, er));
        holes.push(circle(e.0, e.1, 0.4 * er));
        deg += rng.random_range(80.0..150.0);
    }
    let rib = polar(0.75 * r, deg + 40.0);
    Model {
        name,
        material,
        holes,
        top: vec![feat(ring(0.0, 0.0, 0.5 * r, 0.7 * r), Look::Raised), feat(capsule((0.0, 0.0), rib, 2.5), Look::Raised)],
        bottom: vec![feat(ring(0.0, 0.0, 0.55 * r, 0.85 * r), Look::Recessed), feat(circle(rib.0, rib.1, 2.4), Look::Blind)],
        rounded: rng.random_range(1.0..3.0),
    }
}

/// A fork: a hub with a bore and two prongs of unequal length.
fn fork(rng: &mut ChaCha8Rng, name: String) -> Model {
    let hub = rng.random_range(11.0..16.0);
    let len = rng.random_range(45.0..95.0);
    let gap = rng.random_range(9.0..15.0);
    let w = rng.random_range(5.0..7.5);
    let (l1, l2) = (len, len * rng.random_range(0.7..0.9));
    let base = (hub * 0.8, 0.0);
    Model {
        name,
        material: vec![
            circle(0.0, 0.0, hub),
            capsule(base, (base.0 + 8.0, -gap), w),
            capsule(base, (base.0 + 8.0, gap), w),
            capsule((base.0 + 8.0, -gap), (l1, -gap - 2.0), w),
            capsule((base.0 + 8.0, gap), (l2, gap + 1.0), w),
        ],
        holes: vec![circle(0.0, 0.0, 0.5 * hub), circle(l1 - 3.0, -gap - 2.0, 0.45 * w)],
        top: vec![
            feat(ring(0.0, 0.0, 0.5 * hub, 0.85 * hub), Look::Raised),
            feat(capsule((base.0 + 12.0, -gap), (l1 - 10.0, -gap - 2.0), 1.8), Look::Raised),
        ],
        bottom: vec![
            feat(capsule((base.0 + 12.0, gap), (l2 - 8.0, gap + 1.0), 2.0), Look::Recessed),
            feat(circle(-0.4 * hub, 0.5 * hub, 2.0), Look::Blind),
        ],
        rounded: rng.random_range(2.0..3.5),
    }
}

/// How far from `c` along direction `deg` the outline lies (the farthest material point), mm.
fn envelope(m: &Polygons, c: (f64, f64), deg: f64) -> f64 {
    let (ux, uy) = polar(1.0, deg);
    let mut r = m.reach(c) + 1.0;
    while r > 0.0 && !m.contains(c.0 + r * ux, c.1 + r * uy) {
        r -= 0.05;
    }
    r
}

/// `parent` with one local change of outline: a boss added or a notch cut where the outline
/// faces straight out from the part's centre (so the change is as deep as asked), and a
/// description of it.
fn revise(rng: &mut ChaCha8Rng, parent: &Model, name: String) -> (Model, CatalogChange) {
    let (_, cx, cy) = super::render::material_moments(parent);
    let polys = Polygons::new(parent);
    let start = rng.random_range(0.0..360.0);
    let (deg, r) = (0..72)
        .map(|k| start + 5.0 * k as f64)
        .map(|deg| (deg, envelope(&polys, (cx, cy), deg)))
        .find(|&(deg, r)| {
            // Solid material behind it (a notch must not break into a bore) and clear belt
            // around it (a boss must not reach another arm).
            let (ux, uy) = polar(1.0, deg);
            let solid = (1..=16).all(|k| polys.contains(cx + (r - 0.5 * k as f64) * ux, cy + (r - 0.5 * k as f64) * uy));
            let clear = [-45.0, 0.0, 45.0].iter().all(|d| {
                let (vx, vy) = polar(1.0, deg + d);
                (2..=9).all(|t| !polys.contains(cx + r * ux + t as f64 * vx, cy + r * uy + t as f64 * vy))
            });
            r > 15.0
                && solid
                && clear
                && [-6.0, -3.0, 3.0, 6.0].iter().all(|d| (envelope(&polys, (cx, cy), deg + d) - r).abs() < 1.2 + 0.1 * d.abs())
        })
        .unwrap_or((start, envelope(&polys, (cx, cy), start)));
    let depth = rng.random_range(CHANGE_MM);
    let (ux, uy) = polar(1.0, deg);
    let at = (cx + r * ux, cy + r * uy);
    let mut child = parent.clone();
    child.name = name;
    // Counter-clockwise as displayed, from the model's +x seen from its centroid.
    let shown = deg.rem_euclid(360.0);
    let (kind, what) = if rng.random_bool(0.5) {
        let b = rng.random_range(4.5..6.5);
        child.material.push(circle(at.0 + (depth - b) * ux, at.1 + (depth - b) * uy, b));
        ("add_boss", format!("a boss standing {depth:.1} mm proud at {shown:.0} deg"))
    } else {
        let b = rng.random_range(3.5..5.0);
        child.holes.push(circle(at.0 + (b - depth) * ux, at.1 + (b - depth) * uy, b));
        ("add_notch", format!("a notch {depth:.1} mm deep at {shown:.0} deg"))
    };
    let r2 = |v: f64| (v * 100.0).round() / 100.0;
    (child, CatalogChange { kind: kind.into(), what, delta_mm: r2(depth) })
}

/// A catalogue of `n` enrolled types from `seed`: about one new design in five starts a revision
/// family of two or three members, and one type in ten more (at least two) is never enrolled,
/// every other one of those the next revision of a family while there are families.
pub fn generate(n: usize, seed: u64) -> Catalogue {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xCA7A_1065);
    let kinds: [fn(&mut ChaCha8Rng, String) -> Model; 4] = [plate, lever, housing, fork];
    let base = |rng: &mut ChaCha8Rng, name: String| kinds[rng.random_range(0..kinds.len())](rng, name);
    let describe = |m: &Model, known: bool, family: Option<(String, u32, Option<String>)>, change: Option<CatalogChange>| CatalogType {
        name: m.name.clone(),
        known,
        family: family.as_ref().map(|f| f.0.clone()),
        revision: family.as_ref().map(|f| f.1),
        parent: family.and_then(|f| f.2),
        change,
    };
    let (mut known, mut types): (Vec<Model>, Vec<CatalogType>) = (Vec::new(), Vec::new());
    // Families' last members, for the unseen next revisions.
    let mut families: Vec<(String, u32, Model)> = Vec::new();
    while known.len() < n {
        let name = |k: usize| format!("T{:03}", k + 1);
        let start_family = n - known.len() >= 2 && rng.random_bool(0.2);
        let parent = base(&mut rng, name(known.len()));
        if !start_family {
            types.push(describe(&parent, true, None, None));
            known.push(parent);
            continue;
        }
        let family = format!("F{:02}", families.len() + 1);
        types.push(describe(&parent, true, Some((family.clone(), 0, None)), None));
        let mut last = parent.clone();
        known.push(parent);
        let members = if n - known.len() >= 2 { rng.random_range(1..=2) } else { 1 };
        for rev in 1..=members {
            let (child, change) = revise(&mut rng, &last, name(known.len()));
            types.push(describe(&child, true, Some((family.clone(), rev, Some(last.name.clone()))), Some(change)));
            last = child.clone();
            known.push(child);
        }
        families.push((family, members, last));
    }
    let mut unknown = Vec::new();
    let count = (n / 10).max(2);
    for k in 0..count {
        let name = format!("U{:02}", k + 1);
        let model = match families.get(k / 2).filter(|_| k % 2 == 0) {
            Some((family, rev, last)) => {
                let (child, change) = revise(&mut rng, last, name);
                types.push(describe(&child, false, Some((family.clone(), rev + 1, Some(last.name.clone()))), Some(change)));
                child
            }
            None => {
                let m = base(&mut rng, name);
                types.push(describe(&m, false, None, None));
                m
            }
        };
        unknown.push(model);
    }
    Catalogue { known, unknown, types }
}
