//! Built-in part models, in millimetres (x right, y down as seen from above, face up).
//!
//! Each is irregular (no outline symmetry, so angle and face are always defined) and has
//! different features on its two faces, as cast and forged parts do. The face-down view of a
//! model is its mirror image about the x axis with the bottom features showing.

/// A 2-D primitive, as one or more closed polygons filled even-odd.
#[derive(Debug, Clone)]
pub enum Shape {
    /// A disc.
    Circle {
        /// Centre, mm.
        c: (f64, f64),
        /// Radius, mm.
        r: f64,
    },
    /// Filled ring between two radii.
    Ring {
        /// Centre, mm.
        c: (f64, f64),
        /// Inner radius, mm.
        r_in: f64,
        /// Outer radius, mm.
        r_out: f64,
    },
    /// A stadium: the set of points within `r` of the segment a-b.
    Capsule {
        /// One end, mm.
        a: (f64, f64),
        /// The other end, mm.
        b: (f64, f64),
        /// Half the width, mm.
        r: f64,
    },
    /// A polygon, mm (either winding).
    Poly(Vec<(f64, f64)>),
    /// Part of a ring between two angles (degrees, counter-clockwise as displayed).
    Sector {
        /// Centre, mm.
        c: (f64, f64),
        /// Inner radius, mm.
        r_in: f64,
        /// Outer radius, mm.
        r_out: f64,
        /// Start angle.
        from_deg: f64,
        /// End angle.
        to_deg: f64,
    },
}

/// How a face feature looks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Look {
    /// A boss or rib standing proud: brighter, with a shadow line at its foot.
    Raised,
    /// A pocket or groove: darker, with a dark edge.
    Recessed,
    /// A blind hole: nearly black.
    Blind,
}

/// A feature on one face of a model.
#[derive(Debug, Clone)]
pub struct Feature {
    /// Where it is.
    pub shape: Shape,
    /// How it shows.
    pub look: Look,
}

/// A part type the simulator renders: its material, through-holes and the features of each face.
#[derive(Debug, Clone)]
pub struct Model {
    /// The type name it is enrolled under.
    pub name: String,
    /// Union of these is the part's material ...
    pub material: Vec<Shape>,
    /// ... minus these through-holes.
    pub holes: Vec<Shape>,
    /// Features seen face up.
    pub top: Vec<Feature>,
    /// Features seen face down.
    pub bottom: Vec<Feature>,
    /// Width (mm) of the margin over which a forged part's rounded edge darkens towards its
    /// silhouette; 0 for a flat plate with a sharp edge.
    pub rounded: f64,
}

const STEP_DEG: f64 = 2.0;

fn arc(c: (f64, f64), r: f64, from: f64, to: f64) -> Vec<(f64, f64)> {
    let n = (((to - from).abs() / STEP_DEG).ceil() as usize).max(2);
    (0..=n)
        .map(|i| {
            let a = (from + (to - from) * i as f64 / n as f64).to_radians();
            (c.0 + r * a.cos(), c.1 - r * a.sin())
        })
        .collect()
}

impl Shape {
    /// Closed polygons (mm), filled even-odd.
    pub fn contours(&self) -> Vec<Vec<(f64, f64)>> {
        match *self {
            Shape::Circle { c, r } => {
                let mut v = arc(c, r, 0.0, 360.0);
                v.pop();
                vec![v]
            }
            Shape::Ring { c, r_in, r_out } => {
                let mut a = arc(c, r_out, 0.0, 360.0);
                a.pop();
                let mut b = arc(c, r_in, 0.0, 360.0);
                b.pop();
                vec![a, b]
            }
            Shape::Capsule { a, b, r } => {
                let d = (b.1 - a.1, b.0 - a.0);
                // Direction of a->b as displayed (y down).
                let th = (-(d.0)).atan2(d.1).to_degrees();
                let mut v = arc(b, r, th - 90.0, th + 90.0);
                v.extend(arc(a, r, th + 90.0, th + 270.0));
                vec![v]
            }
            Shape::Poly(ref p) => vec![p.clone()],
            Shape::Sector { c, r_in, r_out, from_deg, to_deg } => {
                let mut v = arc(c, r_out, from_deg, to_deg);
                let mut inner = arc(c, r_in, from_deg, to_deg);
                inner.reverse();
                v.extend(inner);
                vec![v]
            }
        }
    }
}

pub(crate) fn circle(x: f64, y: f64, r: f64) -> Shape {
    Shape::Circle { c: (x, y), r }
}
pub(crate) fn ring(x: f64, y: f64, r_in: f64, r_out: f64) -> Shape {
    Shape::Ring { c: (x, y), r_in, r_out }
}
pub(crate) fn capsule(a: (f64, f64), b: (f64, f64), r: f64) -> Shape {
    Shape::Capsule { a, b, r }
}
pub(crate) fn feat(shape: Shape, look: Look) -> Feature {
    Feature { shape, look }
}

/// A cast bracket: irregular plate, a boss ring at one end, a lug at the other.
pub fn bracket() -> Model {
    Model {
        name: "bracket".into(),
        material: vec![
            Shape::Poly(vec![
                (-44.0, -19.0),
                (-8.0, -27.0),
                (28.0, -24.0),
                (49.0, -9.0),
                (50.0, 13.0),
                (21.0, 23.0),
                (-28.0, 21.0),
                (-49.0, 6.0),
            ]),
            circle(-50.0, 18.0, 11.0),
            circle(40.0, 0.0, 20.0),
        ],
        holes: vec![circle(-50.0, 18.0, 5.0), circle(40.0, 0.0, 8.5), circle(-9.0, 8.0, 3.5)],
        top: vec![
            feat(ring(40.0, 0.0, 8.5, 17.0), Look::Raised),
            feat(capsule((-42.0, 13.0), (24.0, 3.0), 3.2), Look::Raised),
            feat(ring(-9.0, 8.0, 3.5, 7.5), Look::Raised),
        ],
        bottom: vec![
            feat(Shape::Poly(vec![(-30.0, -18.0), (2.0, -20.0), (3.0, -5.0), (-29.0, -3.0)]), Look::Recessed),
            feat(circle(15.0, -15.0, 2.6), Look::Blind),
            feat(circle(-38.0, 0.0, 2.6), Look::Blind),
            feat(circle(12.0, 14.0, 2.6), Look::Blind),
        ],
        rounded: 0.0,
    }
}

/// A forged flange: a hub with a big bore, an offset lug and two ears.
pub fn flange() -> Model {
    Model {
        name: "flange".into(),
        material: vec![
            circle(0.0, 0.0, 40.0),
            capsule((0.0, 0.0), (50.0, -22.0), 11.0),
            circle(50.0, -22.0, 13.0),
            capsule((-26.0, 33.0), (-34.0, 40.0), 6.5),
            capsule((36.0, 28.0), (43.0, 33.0), 6.0),
        ],
        holes: vec![circle(0.0, 0.0, 17.0), circle(50.0, -22.0, 5.5), circle(-34.0, 40.0, 2.8), circle(43.0, 33.0, 2.6)],
        top: vec![
            feat(ring(0.0, 0.0, 17.0, 27.0), Look::Raised),
            feat(ring(0.0, 0.0, 30.0, 37.0), Look::Recessed),
            feat(capsule((22.0, -10.0), (40.0, -18.0), 3.0), Look::Raised),
        ],
        bottom: vec![
            feat(circle(28.0, 8.0, 3.0), Look::Blind),
            feat(circle(-18.0, 23.0, 3.0), Look::Blind),
            feat(circle(-10.0, -28.0, 3.0), Look::Blind),
            feat(capsule((-36.0, -6.0), (-24.0, -6.0), 2.5), Look::Recessed),
        ],
        rounded: 1.5,
    }
}

/// A clevis hook: an open ring on a neck with an eye, an eyelet on one side only.
pub fn clevis() -> Model {
    let arc_c = (18.0, 0.0);
    let end = |deg: f64| {
        let a = f64::to_radians(deg);
        (arc_c.0 + 28.0 * a.cos(), arc_c.1 - 28.0 * a.sin())
    };
    Model {
        name: "clevis".into(),
        material: vec![
            Shape::Sector { c: arc_c, r_in: 23.5, r_out: 32.5, from_deg: 42.0, to_deg: 318.0 },
            Shape::Circle { c: end(42.0), r: 6.5 },
            Shape::Circle { c: end(318.0), r: 7.5 },
            capsule((-12.0, 0.0), (-40.0, 0.0), 8.5),
            circle(-46.0, 0.0, 12.5),
            circle(-30.0, 11.5, 5.5),
        ],
        holes: vec![circle(-46.0, 0.0, 6.5), circle(-30.0, 11.5, 2.2)],
        top: vec![
            feat(Shape::Sector { c: arc_c, r_in: 26.5, r_out: 29.0, from_deg: 60.0, to_deg: 300.0 }, Look::Raised),
            feat(capsule((-16.0, 0.0), (-34.0, 0.0), 5.0), Look::Raised),
        ],
        bottom: vec![
            feat(capsule((-15.0, 0.0), (-33.0, 0.0), 2.6), Look::Recessed),
            feat(Shape::Sector { c: arc_c, r_in: 27.0, r_out: 28.5, from_deg: 70.0, to_deg: 200.0 }, Look::Recessed),
            feat(circle(-46.0, -10.0, 1.8), Look::Blind),
        ],
        rounded: 3.0,
    }
}

/// An L-shaped lever: the simulator's "unknown" part, never enrolled.
pub fn lever() -> Model {
    Model {
        name: "lever".into(),
        material: vec![Shape::Poly(vec![(-52.0, -26.0), (44.0, -26.0), (46.0, -9.0), (-18.0, -9.0), (-20.0, 31.0), (-52.0, 31.0)])],
        holes: vec![capsule((-4.0, -18.0), (24.0, -18.0), 3.2), circle(-41.0, 21.0, 4.0), circle(37.0, -18.0, 3.0)],
        top: vec![feat(capsule((-30.0, 14.0), (-12.0, -16.0), 2.5), Look::Raised)],
        bottom: vec![feat(circle(-38.0, -15.0, 2.0), Look::Blind)],
        rounded: 0.0,
    }
}

/// The models the simulator enrolls, in type-id order (ids 1, 2, 3).
pub fn known() -> Vec<Model> {
    vec![bracket(), flange(), clevis()]
}

/// Debris that lies about on a real belt: a washer and a bolt (far smaller than any part).
pub fn debris() -> Vec<Model> {
    vec![
        Model { name: "washer".into(), material: vec![ring(0.0, 0.0, 2.2, 4.6)], holes: vec![], top: vec![], bottom: vec![], rounded: 0.0 },
        Model {
            name: "bolt".into(),
            material: vec![Shape::Poly(vec![
                (-9.0, -1.6),
                (5.0, -1.6),
                (5.0, -3.6),
                (9.0, -3.6),
                (9.0, 3.6),
                (5.0, 3.6),
                (5.0, 1.6),
                (-9.0, 1.6),
            ])],
            holes: vec![],
            top: vec![],
            bottom: vec![],
            rounded: 0.0,
        },
    ]
}

/// The model that appears in "unknown" scenes and is never enrolled.
pub fn unknown() -> Model {
    lever()
}
