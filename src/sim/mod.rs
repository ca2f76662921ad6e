//! The simulated camera: scenes of built-in parts on a conveyor, with ground truth.
//!
//! Scene `i` of a seed is the same whatever the count, so a failing scene can be rendered alone.
//! Conditions cycle through [`CONDITIONS`]; `noise` scenes cycle through sigma 10, 20, 30, 40.

pub mod catalog;
pub mod models;
pub mod optics;
pub mod render;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::truth::{TruthPart, TruthRecord};
use crate::vision::geometry::{contains, point_segment};
use crate::vision::{Face, GrayImage, Pt};
use render::{Lighting, Placement, Prepared};

/// Scene kinds, in the order they cycle.
pub const CONDITIONS: [&str; 9] = ["clean", "noise", "glare", "dim", "multi", "touching", "overlapping", "empty", "unknown"];

/// Simulator settings.
#[derive(Debug, Clone)]
pub struct SimConfig {
    /// Frame width, pixels.
    pub width: usize,
    /// Frame height, pixels.
    pub height: usize,
    /// The same seed renders the same scenes.
    pub seed: u64,
    /// Noise sigma for every scene instead of the condition's own.
    pub noise: Option<f64>,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self { width: 2592, height: 1944, seed: 1, noise: None }
    }
}

/// A rendered scene and its truth (image path relative to the dataset directory).
#[derive(Debug, Clone)]
pub struct Scene {
    /// File name of the image (`scene-0003.png`).
    pub name: String,
    /// The frame.
    pub image: GrayImage,
    /// What it shows.
    pub truth: TruthRecord,
    /// How it was rendered.
    pub extra: SceneExtra,
    /// Where debris (washers, bolts) lies, frame pixels: never a part, not in the truth.
    pub debris: Vec<Pt>,
}

/// Renderer settings recorded beside the truth (ignored by readers that do not know them).
#[derive(Debug, Clone, serde::Serialize)]
pub struct SceneExtra {
    /// Blur of the optics, pixels.
    pub blur_sigma: f64,
    /// Exposure factor on the light (1: nominal).
    pub exposure: f64,
    /// Pixels per millimetre of the belt.
    pub scale_px_per_mm: f64,
    /// Frame width, pixels.
    pub width: usize,
    /// Frame height, pixels.
    pub height: usize,
    /// Pieces of debris in the scene.
    pub debris: usize,
}

/// Why the simulator cannot render.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// The frame asked for is too small.
    #[error("frame size {width} x {height} is too small for the simulator (at least 320 x 240)")]
    TooSmall {
        /// Width asked for.
        width: usize,
        /// Height asked for.
        height: usize,
    },
    /// A noise sigma outside 0..=100.
    #[error("noise sigma {0} is out of range (0..=100)")]
    Noise(f64),
    /// A condition not in [`CONDITIONS`].
    #[error("unknown condition {0:?}; expected one of {CONDITIONS:?}")]
    Condition(String),
    /// OpenCV failed while drawing.
    #[error("rendering failed: {0}")]
    Render(#[from] opencv::Error),
    /// A model's template does not enrol (a defect in the models).
    #[error("simulator template {name} {face} does not enrol: {message}")]
    Template {
        /// The model's type name.
        name: String,
        /// Its face.
        face: Face,
        /// Why it does not enrol.
        message: String,
    },
}

/// Renders scenes and templates of the built-in models.
pub struct Simulator {
    cfg: SimConfig,
    known: Vec<Prepared>,
    /// Never enrolled: the "unknown" scenes' parts (one for the built-in models).
    unknown: Vec<Prepared>,
    debris: Vec<Prepared>,
    px_per_mm: f64,
    optics: Option<optics::Optics>,
}

impl Simulator {
    /// A simulator of `cfg`'s frame size and seed.
    pub fn new(cfg: SimConfig) -> Result<Self, SimError> {
        if cfg.width < 320 || cfg.height < 240 {
            return Err(SimError::TooSmall { width: cfg.width, height: cfg.height });
        }
        if let Some(n) = cfg.noise
            && !(0.0..=100.0).contains(&n)
        {
            return Err(SimError::Noise(n));
        }
        // 6.5 px/mm on a 5-MP frame; smaller frames see the same field of view.
        let px_per_mm = 6.5 * cfg.width.min(cfg.height * 4 / 3) as f64 / 2592.0;
        Ok(Self {
            known: models::known().into_iter().map(Prepared::new).collect(),
            unknown: vec![Prepared::new(models::unknown())],
            debris: models::debris().into_iter().map(Prepared::new).collect(),
            px_per_mm,
            optics: None,
            cfg,
        })
    }

    /// The same simulator seen through the built-in cell's camera ([`optics::Optics::cell`]):
    /// frames tilted and distorted, truth positions in frame pixels and robot millimetres.
    pub fn through_cell_camera(self) -> Self {
        let o = optics::Optics::cell(self.cfg.width, self.cfg.height, self.px_per_mm);
        self.with_optics(o)
    }

    /// The same simulator seen through a camera model of one's own.
    pub fn with_optics(mut self, optics: optics::Optics) -> Self {
        self.optics = Some(optics);
        self
    }

    /// The camera model frames are rendered through, if any.
    pub fn optics(&self) -> Option<&optics::Optics> {
        self.optics.as_ref()
    }

    /// Flat render pixels per belt millimetre.
    pub fn px_per_mm(&self) -> f64 {
        self.px_per_mm
    }

    /// The calibration plate that covers most of the field, as the cell's camera sees it (the
    /// flat render when there is no camera model), and the plate; see [`Simulator::plate_image`].
    pub fn plate(&self, grid: crate::plate::Grid, blur: f64) -> Result<(GrayImage, optics::Plate), SimError> {
        let (w, h) = (self.cfg.width as f64 / self.px_per_mm, self.cfg.height as f64 / self.px_per_mm);
        let plate = optics::Plate::covering(grid, w, h);
        Ok((self.plate_image(&plate, blur)?, plate))
    }

    /// A plate lying on the belt as the camera sees it: blurred by `blur` px, with sensor noise
    /// of sigma 2 gray levels.
    pub fn plate_image(&self, plate: &optics::Plate, blur: f64) -> Result<GrayImage, SimError> {
        let flat = plate.render(self.cfg.width, self.cfg.height, self.px_per_mm, blur)?;
        let mut image = match &self.optics {
            Some(o) => o.image(&flat)?,
            None => flat,
        };
        let mut rng = ChaCha8Rng::seed_from_u64(self.cfg.seed ^ 0x0A7E);
        let noise = rand_distr::Normal::new(0.0, 2.0).expect("a positive sigma");
        for v in image.data.iter_mut() {
            *v = (*v as f64 + rand_distr::Distribution::sample(&noise, &mut rng)).round().clamp(0.0, 255.0) as u8;
        }
        Ok(image)
    }

    /// Where a point of the belt (millimetres) shows in the frame, pixels.
    pub fn belt_to_frame(&self, belt_mm: nalgebra::Vector2<f64>) -> Pt {
        let flat = Pt::new(belt_mm.x * self.px_per_mm, belt_mm.y * self.px_per_mm);
        self.optics.as_ref().map_or(flat, |o| o.to_frame(flat))
    }

    /// Grid point `index` of `plate` as a robot touches it up: `[x_px, y_px, x_mm, y_mm]`, its
    /// true pixel and robot millimetres (None without the cell's camera or past the grid).
    pub fn touch_up(&self, plate: &optics::Plate, index: usize) -> Option<[f64; 4]> {
        let px = self.belt_to_frame(plate.to_belt(*plate.points().get(index)?));
        let mm = self.frame_to_robot(px)?;
        Some([px.x, px.y, mm.x, mm.y])
    }

    /// The robot millimetres a frame pixel truly shows (None without the cell's camera).
    pub fn frame_to_robot(&self, px: Pt) -> Option<nalgebra::Vector2<f64>> {
        let o = self.optics.as_ref()?;
        o.to_flat(px).map(|f| o.to_robot(f))
    }

    /// A simulator whose parts are a generated catalogue's (`catalog::generate`): scenes of every
    /// condition draw from its enrolled types, and "unknown" scenes from its never-enrolled ones.
    pub fn with_catalogue(cfg: SimConfig, catalogue: &catalog::Catalogue) -> Result<Self, SimError> {
        let mut sim = Self::new(cfg)?;
        sim.known = catalogue.known.iter().cloned().map(Prepared::new).collect();
        sim.unknown = catalogue.unknown.iter().cloned().map(Prepared::new).collect();
        Ok(sim)
    }

    /// Names of the enrollable types, in id order (1, 2, 3...).
    pub fn type_names(&self) -> Vec<&str> {
        self.known.iter().map(|p| p.model.name.as_str()).collect()
    }

    /// The names of the models that are never enrolled (the "unknown" scenes' parts).
    pub fn unknown_type_names(&self) -> Vec<&str> {
        self.unknown.iter().map(|p| p.model.name.as_str()).collect()
    }

    /// The templates enrolled as a user would: types 1, 2, 3 in [`Simulator::type_names`]
    /// order, both faces, the unknown model never.
    pub fn enrolled(&self, params: &crate::vision::Params) -> Result<Vec<crate::vision::Template>, SimError> {
        let names = self.type_names();
        let mut out = Vec::new();
        for (name, face, img) in self.templates()? {
            let id = names.iter().position(|n| *n == name).map_or(0, |i| i as u16 + 1);
            let t = img
                .view()
                .map_err(|e| e.to_string())
                .and_then(|v| crate::vision::Template::from_image(v, &name, id, face, None, params).map_err(|e| e.to_string()))
                .map_err(|message| SimError::Template { name: name.clone(), face, message })?;
            out.push(t);
        }
        Ok(out)
    }

    /// One clean template per known type and face: the part at angle 0, its material centroid at
    /// the image centre.
    pub fn templates(&self) -> Result<Vec<(String, Face, GrayImage)>, SimError> {
        self.templates_of(&self.known, 0)
    }

    /// The never-enrolled types' templates, as [`Simulator::templates`] makes them (for
    /// inspection: a user does not enrol them).
    pub fn unknown_templates(&self) -> Result<Vec<(String, Face, GrayImage)>, SimError> {
        self.templates_of(&self.unknown, self.known.len())
    }

    /// Templates of `models`, their noise seeded from their index counted from `first`.
    fn templates_of(&self, models: &[Prepared], first: usize) -> Result<Vec<(String, Face, GrayImage)>, SimError> {
        let mut out = Vec::new();
        for (ti, prep) in models.iter().enumerate().map(|(i, p)| (first + i, p)) {
            for (fi, face) in [Face::Up, Face::Down].into_iter().enumerate() {
                let r = prep.radius * self.px_per_mm;
                let half = (r + (0.12 * r).max(30.0)).ceil() as usize;
                let size = 2 * half + 1;
                let pl = Placement { face, angle_deg: 0.0, x: half as f64, y: half as f64, px_per_mm: self.px_per_mm, gray: 175.0 };
                let light = Lighting {
                    exposure: 0.92,
                    gradient: 0.0,
                    gradient_dir_deg: 0.0,
                    glare: None,
                    blur_sigma: 0.0,
                    noise_sigma: 1.0,
                    belt_gray: 55.0,
                };
                let mut rng = ChaCha8Rng::seed_from_u64(self.cfg.seed ^ (0x7e3a_0000 + (ti * 2 + fi) as u64));
                let img = render::render(size, size, &[(prep, pl)], &light, &mut rng)?;
                out.push((prep.model.name.to_string(), face, img));
            }
        }
        Ok(out)
    }

    /// Scene `index` with its cycling condition.
    pub fn scene(&self, index: u64) -> Result<Scene, SimError> {
        self.scene_with(index, CONDITIONS[(index % CONDITIONS.len() as u64) as usize])
    }

    /// Scene `index` of a given condition.
    pub fn scene_with(&self, index: u64, condition: &str) -> Result<Scene, SimError> {
        if !CONDITIONS.contains(&condition) {
            return Err(SimError::Condition(condition.into()));
        }
        let mut rng = ChaCha8Rng::seed_from_u64(self.cfg.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ index);
        let scale = self.px_per_mm * rng.random_range(0.975..1.025);
        let mut light = lighting(&mut rng);
        let parts = self.arrange(&mut rng, index, condition, scale, &mut light);
        if let Some(n) = self.cfg.noise {
            light.noise_sigma = n;
        }
        let scene_parts = self.with_debris(index, condition, scale, &parts);
        let mut debris: Vec<Pt> = scene_parts[parts.len()..].iter().map(|(_, pl)| Pt::new(pl.x, pl.y)).collect();
        let mut image = render::render(self.cfg.width, self.cfg.height, &scene_parts, &light, &mut rng)?;
        if let Some(o) = &self.optics {
            image = o.image(&image)?;
            debris.iter_mut().for_each(|d| *d = o.to_frame(*d));
        }
        let name = format!("s{index:05}_{condition}");
        let visible = render::visible_fractions(self.cfg.width, self.cfg.height, &parts)?;
        let truth = TruthRecord {
            image: format!("images/{name}.png"),
            condition: condition.to_string(),
            noise_sigma: r3(light.noise_sigma),
            parts: parts.iter().zip(&visible).map(|((p, pl), v)| self.truth_of(p, pl, *v)).collect(),
        };
        let extra = SceneExtra {
            blur_sigma: r3(light.blur_sigma),
            exposure: r4(light.exposure),
            scale_px_per_mm: r4(scale),
            width: self.cfg.width,
            height: self.cfg.height,
            debris: debris.len(),
        };
        Ok(Scene { name, image, truth, extra, debris })
    }

    /// The parts of scene `index` under `condition` at `scale` (px/mm), drawn from `rng`; a
    /// condition that is about the light (noise, dim, glare) sets it in `light`.
    fn arrange(&self, rng: &mut ChaCha8Rng, index: u64, condition: &str, scale: f64, light: &mut Lighting) -> Vec<(&Prepared, Placement)> {
        let noise_cycle = [10.0, 20.0, 30.0, 40.0];
        let mut parts: Vec<(&Prepared, Placement)> = Vec::new();
        let known = |rng: &mut ChaCha8Rng| &self.known[rng.random_range(0..self.known.len())];
        match condition {
            "clean" | "glare" | "dim" | "noise" => {
                let p = known(rng);
                if let Some(pl) = self.free_spot(rng, p, scale, &parts) {
                    parts.push((p, pl));
                }
                match condition {
                    "noise" => light.noise_sigma = noise_cycle[((index / CONDITIONS.len() as u64) % 4) as usize],
                    "dim" => light.exposure = rng.random_range(0.18..0.35),
                    "glare" => {
                        if let Some((p, pl)) = parts.first() {
                            let r = p.radius * pl.px_per_mm;
                            let c = Pt::new(pl.x + rng.random_range(-0.4..0.4) * r, pl.y + rng.random_range(-0.4..0.4) * r);
                            light.glare = Some((c, rng.random_range(0.3..0.6) * r, rng.random_range(90.0..160.0)));
                        }
                    }
                    _ => {}
                }
            }
            "multi" => {
                let n = rng.random_range(2..=4);
                for _ in 0..n {
                    let p = known(rng);
                    if let Some(pl) = self.free_spot(rng, p, scale, &parts) {
                        parts.push((p, pl));
                    }
                }
            }
            "touching" | "overlapping" => {
                for _ in 0..50 {
                    let a = known(rng);
                    let b = known(rng);
                    let Some(pa) = self.free_spot(rng, a, scale, &[]) else {
                        continue;
                    };
                    if let Some(pb) = self.neighbour(rng, (a, pa), b, scale, condition == "overlapping") {
                        parts = vec![(a, pa), (b, pb)];
                        break;
                    }
                }
            }
            "unknown" => {
                // One draw more only where there is a choice: the built-in scenes stay as they were.
                let u = if self.unknown.len() > 1 { &self.unknown[rng.random_range(0..self.unknown.len())] } else { &self.unknown[0] };
                if let Some(pl) = self.free_spot(rng, u, scale, &parts) {
                    parts.push((u, pl));
                }
                if rng.random_bool(0.5) {
                    let p = known(rng);
                    if let Some(pl) = self.free_spot(rng, p, scale, &parts) {
                        parts.push((p, pl));
                    }
                }
            }
            _ => {}
        }
        parts
    }

    /// The scene's parts and, in scenes of several parts, up to two pieces of debris clear of
    /// them, from a generator of their own (so that the parts and light stay those of earlier
    /// versions).
    fn with_debris<'a>(
        &'a self,
        index: u64,
        condition: &str,
        scale: f64,
        parts: &[(&'a Prepared, Placement)],
    ) -> Vec<(&'a Prepared, Placement)> {
        let mut debris_rng = ChaCha8Rng::seed_from_u64(self.cfg.seed.wrapping_mul(0xD1B5_4A32_D192_ED03) ^ index);
        let mut scene_parts = parts.to_vec();
        if matches!(condition, "multi" | "touching" | "overlapping") {
            for _ in 0..debris_rng.random_range(0..=2) {
                let d = &self.debris[debris_rng.random_range(0..self.debris.len())];
                if let Some(pl) = self.free_spot(&mut debris_rng, d, scale, &scene_parts) {
                    scene_parts.push((d, pl));
                }
            }
        }
        scene_parts
    }

    /// A part's ground truth as placed (`visible`: the fraction of it no other part hides); through
    /// the cell's camera, in the frame's pixels and the robot's millimetres.
    fn truth_of(&self, p: &Prepared, pl: &Placement, visible: f64) -> TruthPart {
        let mut t = TruthPart {
            type_name: p.model.name.to_string(),
            face: pl.face.as_str().to_string(),
            angle_deg: r4(pl.angle_deg),
            x_px: r3(pl.x),
            y_px: r3(pl.y),
            visible_fraction: r4(visible),
            x_mm: None,
            y_mm: None,
            robot_angle_deg: None,
        };
        if let Some(o) = &self.optics {
            let flat = Pt::new(pl.x, pl.y);
            let (f, m) = (o.to_frame(flat), o.to_robot(flat));
            let (frame_deg, robot_deg) = o.angles(flat, pl.angle_deg);
            (t.x_px, t.y_px, t.angle_deg) = (r3(f.x), r3(f.y), r4(frame_deg));
            (t.x_mm, t.y_mm, t.robot_angle_deg) = (Some(r4(m.x)), Some(r4(m.y)), Some(r4(robot_deg)));
        }
        t
    }

    fn random_pose(&self, rng: &mut ChaCha8Rng, p: &Prepared, scale: f64) -> Option<Placement> {
        let r = p.radius * scale + 12.0;
        let (w, h) = (self.cfg.width as f64, self.cfg.height as f64);
        if 2.0 * r >= w || 2.0 * r >= h {
            return None;
        }
        Some(Placement {
            face: if rng.random_bool(0.5) { Face::Up } else { Face::Down },
            angle_deg: rng.random_range(0.0..360.0),
            x: rng.random_range(r..w - r),
            y: rng.random_range(r..h - r),
            px_per_mm: scale,
            gray: rng.random_range(150.0..195.0),
        })
    }

    /// A pose at least 40 px clear of every part already placed.
    fn free_spot(&self, rng: &mut ChaCha8Rng, p: &Prepared, scale: f64, placed: &[(&Prepared, Placement)]) -> Option<Placement> {
        for _ in 0..300 {
            let pl = self.random_pose(rng, p, scale)?;
            let polys = p.material_polys(&pl);
            if placed.iter().all(|(q, ql)| separation(&polys, &q.material_polys(ql)) > 40.0) {
                return Some(pl);
            }
        }
        None
    }

    /// A pose of `b` touching `a` (or overlapping it by about a quarter), inside the frame.
    fn neighbour(&self, rng: &mut ChaCha8Rng, a: (&Prepared, Placement), b: &Prepared, scale: f64, overlap: bool) -> Option<Placement> {
        let pa = a.0.material_polys(&a.1);
        let mut pl = self.random_pose(rng, b, scale)?;
        let dir = rng.random_range(0.0..std::f64::consts::TAU);
        let at = |d: f64, pl: &mut Placement| {
            pl.x = a.1.x + d * dir.cos();
            pl.y = a.1.y + d * dir.sin();
        };
        // Bisection on the centre distance for zero separation.
        let (mut lo, mut hi) = (0.0, (a.0.radius + b.radius) * scale + 10.0);
        for _ in 0..30 {
            let mid = 0.5 * (lo + hi);
            at(mid, &mut pl);
            if separation(&pa, &b.material_polys(&pl)) > 0.5 { hi = mid } else { lo = mid }
        }
        let d = if overlap { 0.8 * lo } else { lo };
        at(d, &mut pl);
        let r = b.radius * scale + 12.0;
        let inside = pl.x > r && pl.y > r && pl.x < self.cfg.width as f64 - r && pl.y < self.cfg.height as f64 - r;
        inside.then_some(pl)
    }
}

/// Smallest distance between two parts' material polygons; negative when they overlap.
fn separation(a: &[Vec<Pt>], b: &[Vec<Pt>]) -> f64 {
    let inside = |p: Pt, polys: &[Vec<Pt>]| polys.iter().any(|poly| contains(poly, p));
    if a.iter().flatten().any(|&p| inside(p, b)) || b.iter().flatten().any(|&p| inside(p, a)) {
        return -1.0;
    }
    let mut best = f64::INFINITY;
    for pa in a {
        for &p in pa {
            for pb in b {
                for i in 0..pb.len() {
                    best = best.min(point_segment(p, pb[i], pb[(i + 1) % pb.len()]).0);
                }
            }
        }
    }
    best
}

/// A scene's light, drawn from `rng`.
fn lighting(rng: &mut ChaCha8Rng) -> Lighting {
    Lighting {
        exposure: rng.random_range(0.85..1.0),
        gradient: rng.random_range(0.0..0.12),
        gradient_dir_deg: rng.random_range(0.0..360.0),
        glare: None,
        blur_sigma: if rng.random_bool(0.5) { rng.random_range(0.0..1.1) } else { 0.0 },
        noise_sigma: rng.random_range(0.5..4.0),
        belt_gray: rng.random_range(48.0..62.0),
    }
}

/// Rounded to 4 decimals, as the truth records keep it.
fn r4(v: f64) -> f64 {
    (v * 10000.0).round() / 10000.0
}

/// Rounded to 3 decimals.
fn r3(v: f64) -> f64 {
    (v * 1000.0).round() / 1000.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn material_centroid_of_a_disc_with_an_offset_hole() {
        use models::{Model, Shape};
        let m = Model {
            name: "t".into(),
            material: vec![Shape::Circle { c: (0.0, 0.0), r: 10.0 }],
            holes: vec![Shape::Circle { c: (5.0, 0.0), r: 2.0 }],
            top: vec![],
            bottom: vec![],
            rounded: 0.0,
        };
        let p = Prepared::new(m);
        // Moment balance: -(pi 4)(5) / (pi 100 - pi 4) = -0.2083 mm.
        assert!((p.centroid.0 + 0.20833).abs() < 0.01, "{:?}", p.centroid);
        assert!(p.centroid.1.abs() < 0.01);
    }

    #[test]
    fn scenes_are_reproducible_and_name_their_condition() {
        let sim = Simulator::new(SimConfig { width: 640, height: 480, seed: 7, noise: None }).unwrap();
        let a = sim.scene(4).unwrap();
        let b = sim.scene(4).unwrap();
        assert_eq!(a.image, b.image);
        assert_eq!(a.truth.condition, "multi");
        assert!(a.name.ends_with("multi"));
        assert!(sim.scene_with(0, "fog").is_err());
        assert!(Simulator::new(SimConfig { width: 100, height: 100, seed: 1, noise: None }).is_err());
    }
}
