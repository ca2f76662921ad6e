//! The `lfi-bridge` command line: thin parsing and one function per mode.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};

use lfi_bridge::eval::{self, Observation};
use lfi_bridge::imageio;
use lfi_bridge::kb::KnowledgeBase;
use lfi_bridge::sim::{SimConfig, Simulator};
use lfi_bridge::truth::{EstimatePart, EstimateRecord, parse_truth};
use lfi_bridge::vision::{Estimator, Face, Params, Pt, Template};

#[derive(Parser)]
#[command(name = "lfi-bridge", version, about = "Part type, face and pose from a conveyor camera (LFI method)")]
struct Cli {
    /// OpenCV worker threads (1 keeps timings comparable with the benchmark; 0 = OpenCV's default).
    #[arg(long, global = true, default_value_t = 1)]
    cv_threads: i32,
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Add one template (one clean image of one face of one part type) to a knowledge base, or
    /// with `--dir` every `TYPE_FACE.png` of a folder in one go.
    Enroll {
        #[arg(long)]
        kb: PathBuf,
        /// A catalogue folder: every `TYPE_up` / `TYPE_down` image in it (`T012_up.png`, ...) is
        /// enrolled and the knowledge base written once, or not at all when any image fails. New
        /// types take their ids from `DIR/ids.toml` (`T012 = 12` per type) or, without it, the
        /// next free ids in type-name order; a type already enrolled keeps its id. Sub-folders
        /// (such as `unknown/`) are not enrolled.
        #[arg(long, conflicts_with_all = ["type_name", "id", "face", "origin", "keep_out", "image"])]
        dir: Option<PathBuf>,
        /// Type name (as reported and as written in ground truth).
        #[arg(long = "type", required_unless_present = "dir")]
        type_name: Option<String>,
        /// Numeric type id served to the PLC (1..=65535).
        #[arg(long, required_unless_present = "dir")]
        id: Option<u16>,
        #[arg(long, value_parser = parse_face, required_unless_present = "dir")]
        face: Option<Face>,
        /// Template point reported as the part's position, "X,Y" in template pixels (default: the image centre).
        #[arg(long, value_parser = parse_point)]
        origin: Option<Pt>,
        /// A circle of the gripper's keep-out footprint, "X,Y,R" in template pixels (repeat for
        /// more): other material inside it rejects the part as "no clearance".
        #[arg(long = "keep-out", value_parser = parse_circle)]
        keep_out: Vec<lfi_bridge::vision::KeepOut>,
        #[arg(required_unless_present = "dir")]
        image: Option<PathBuf>,
    },
    /// Render scenes of built-in parts with ground truth (images/, templates/, truth.jsonl).
    Simulate {
        #[arg(long)]
        out: PathBuf,
        #[arg(long, default_value_t = 18)]
        count: u64,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Gaussian noise sigma (gray levels) for every scene instead of each condition's own.
        #[arg(long)]
        noise: Option<f64>,
        #[arg(long, default_value_t = 2592)]
        width: usize,
        #[arg(long, default_value_t = 1944)]
        height: usize,
        /// Render through the built-in cell's camera (tilt, barrel distortion, robot frame):
        /// truth gains x_mm, y_mm and robot_angle_deg, and plates/ holds a calibration plate of
        /// each kind with its touched-up points (plates/plates.json).
        #[arg(long)]
        cell: bool,
        /// Instead of the three built-in parts, a generated catalogue of N types (T001...; from
        /// the seed) with revision families and never-enrolled types (U01..., templates under
        /// templates/unknown/), described in catalog.json.
        #[arg(long, value_name = "N", conflicts_with = "cell", value_parser = clap::value_parser!(u16).range(1..=999))]
        catalog: Option<u16>,
    },
    /// Calibrate a camera from images of a grid plate lying on the belt: lens and plane, written
    /// to a calibration file for `[camera.calibration] file`.
    Calibrate {
        #[arg(long, value_parser = parse_grid)]
        grid: lfi_bridge::plate::Grid,
        /// Points per row: dots, or a chessboard's inner corners.
        #[arg(long)]
        cols: usize,
        /// Rows of points.
        #[arg(long)]
        rows: usize,
        /// Distance between neighbouring points, mm (asymmetric circles: OpenCV's square size,
        /// half the distance between dots in a row).
        #[arg(long)]
        pitch_mm: f64,
        /// The calibration file to write.
        #[arg(long)]
        out: PathBuf,
        /// Print one JSON object instead of text.
        #[arg(long)]
        json: bool,
        #[arg(required = true)]
        images: Vec<PathBuf>,
    },
    /// Print the robot millimetres of image points through a camera's calibration (its start
    /// job's), one "X_MM Y_MM" line per point, without starting any camera.
    Map {
        #[arg(long)]
        config: PathBuf,
        /// The camera (its unit id); may be left out when there is one camera.
        #[arg(long)]
        camera: Option<u8>,
        /// Image points "X,Y" in pixels.
        #[arg(required = true, allow_hyphen_values = true)]
        points: Vec<String>,
    },
    /// Estimate parts in images.
    Estimate {
        #[arg(long)]
        kb: PathBuf,
        /// One JSON object per image per line.
        #[arg(long)]
        json: bool,
        /// Also write an annotated copy of each image into this folder.
        #[arg(long)]
        overlay_dir: Option<PathBuf>,
        /// Estimate each image this many times and report the median time per stage.
        #[arg(long, default_value_t = 1)]
        repeat: usize,
        #[arg(required = true)]
        images: Vec<PathBuf>,
    },
    /// Run the appliance: cameras, estimation and the Modbus/TCP server (the main job).
    Run {
        #[arg(long)]
        config: PathBuf,
    },
    /// Print the PLC register map as Markdown (the source of register-map.md).
    RegisterMap,
    /// Score the estimator against ground truth (truth.jsonl beside images/).
    Eval {
        #[arg(long)]
        kb: PathBuf,
        #[arg(long)]
        truth: PathBuf,
        /// A catalogue's `catalog.json` (types, revision families): adds how each family member
        /// was taken for a sibling. Default: `catalog.json` beside the truth file, when there.
        #[arg(long)]
        catalog: Option<PathBuf>,
        #[arg(long)]
        json: bool,
    },
}

fn parse_grid(s: &str) -> Result<lfi_bridge::plate::Grid, String> {
    s.parse()
}

fn parse_face(s: &str) -> Result<Face, String> {
    s.parse()
}

fn parse_circle(s: &str) -> Result<lfi_bridge::vision::KeepOut, String> {
    let v: Vec<f64> = s.split(',').map(|p| p.trim().parse::<f64>()).collect::<Result<_, _>>().map_err(|e| format!("{s:?}: {e}"))?;
    match v[..] {
        [x, y, r] if x.is_finite() && y.is_finite() && r.is_finite() && r > 0.0 => Ok(lfi_bridge::vision::KeepOut { c: Pt::new(x, y), r }),
        _ => Err(format!("{s:?}: expected X,Y,R in template pixels with R > 0")),
    }
}

fn parse_point(s: &str) -> Result<Pt, String> {
    let (x, y) = s.split_once(',').ok_or_else(|| format!("expected X,Y, got {s:?}"))?;
    let x: f64 = x.trim().parse().map_err(|e| format!("bad X in {s:?}: {e}"))?;
    let y: f64 = y.trim().parse().map_err(|e| format!("bad Y in {s:?}: {e}"))?;
    if !x.is_finite() || !y.is_finite() {
        return Err(format!("origin {s:?} is not finite"));
    }
    Ok(Pt::new(x, y))
}

/// Logging for one-shot commands writes every line; `run` passes a throttle (from inside its
/// runtime, whose task writes the summaries of held-back lines).
fn init_logging(default_level: &str, throttle: Option<lfi_bridge::logging::Throttle>) {
    use std::io::IsTerminal;
    // Colour codes only for a terminal: a file or the journal gets plain text.
    let ansi = std::io::stderr().is_terminal();
    let _ = tracing::subscriber::set_global_default(lfi_bridge::logging::subscriber(default_level, ansi, std::io::stderr, throttle));
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    if cli.cv_threads > 0 {
        let _ = opencv::core::set_num_threads(cli.cv_threads);
    }
    if !matches!(cli.cmd, Cmd::Run { .. }) {
        init_logging("info", None);
    }
    let result = match cli.cmd {
        Cmd::Run { config } => run(&config),
        Cmd::RegisterMap => {
            print!("{}{}", lfi_bridge::registers::markdown(), lfi_bridge::robot::markdown());
            Ok(ExitCode::SUCCESS)
        }
        Cmd::Enroll { kb, dir, type_name, id, face, origin, keep_out, image } => match (dir, type_name, id, face, image) {
            (Some(dir), ..) => enroll_folder(&kb, &dir),
            (None, Some(type_name), Some(id), Some(face), Some(image)) => enroll(&kb, &type_name, id, face, origin, keep_out, &image),
            // clap requires all four without --dir.
            _ => Err(anyhow::anyhow!("enroll needs --dir DIR, or --type, --id, --face and an IMAGE")),
        },
        Cmd::Simulate { out, count, seed, noise, width, height, cell, catalog } => {
            simulate(&out, count, SimConfig { width, height, seed, noise }, cell, catalog)
        }
        Cmd::Calibrate { grid, cols, rows, pitch_mm, out, json, images } => {
            calibrate(lfi_bridge::plate::GridSpec { grid, cols, rows, pitch_mm }, &out, json, &images)
        }
        Cmd::Map { config, camera, points } => map(&config, camera, &points),
        Cmd::Estimate { kb, json, overlay_dir, repeat, images } => estimate(&kb, json, overlay_dir.as_deref(), repeat.max(1), &images),
        Cmd::Eval { kb, truth, catalog, json } => evaluate(&kb, &truth, catalog.as_deref(), json),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(2)
        }
    }
}

fn run(config: &Path) -> Result<ExitCode> {
    let cfg = match lfi_bridge::config::Config::load(config) {
        Ok(c) => c,
        Err(e) => {
            init_logging("info", None);
            return Err(e.into());
        }
    };
    let rt = tokio::runtime::Builder::new_multi_thread().enable_all().build().context("cannot start the async runtime")?;
    {
        let _inside = rt.enter();
        init_logging(&cfg.log_level, Some(lfi_bridge::logging::Throttle::default()));
    }
    tracing::info!("lfi-bridge {} starting with {}", env!("CARGO_PKG_VERSION"), config.display());
    rt.block_on(async {
        let running = lfi_bridge::start(&cfg).await?;
        tracing::info!("ready: PLC registers on {} (see register-map.md); stop with Ctrl-C or SIGTERM", running.modbus_addr);
        wait_for_signal().await;
        tracing::info!("stopping");
        running.stop().await;
        Ok::<_, anyhow::Error>(())
    })?;
    Ok(ExitCode::SUCCESS)
}

async fn wait_for_signal() {
    #[cfg(unix)]
    {
        let mut term = match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(s) => s,
            Err(_) => {
                let _ = tokio::signal::ctrl_c().await;
                return;
            }
        };
        tokio::select! {
            _ = tokio::signal::ctrl_c() => {}
            _ = term.recv() => {}
        }
    }
    #[cfg(not(unix))]
    {
        let _ = tokio::signal::ctrl_c().await;
    }
}

fn enroll(
    kb_path: &Path,
    type_name: &str,
    id: u16,
    face: Face,
    origin: Option<Pt>,
    keep_out: Vec<lfi_bridge::vision::KeepOut>,
    image: &Path,
) -> Result<ExitCode> {
    let mut kb = KnowledgeBase::load_or_new(kb_path)?;
    let mut t = learn(image, type_name, id, face, origin, &Params::default())?;
    t.keep_out = keep_out;
    let summary = format!(
        "{} {} (id {}): {} outline points, {} line features, area {:.0} px^2, outline centroid ({:.2}, {:.2}), origin ({:.2}, {:.2})",
        t.type_name,
        t.face,
        t.type_id,
        t.outline.len(),
        t.segments.len(),
        t.area,
        t.centroid.x,
        t.centroid.y,
        t.origin.x,
        t.origin.y
    );
    let new = (t.type_name.clone(), t.face);
    let replaced = kb.enroll(t, image.display().to_string())?;
    kb.save(kb_path)?;
    println!("{} {summary} in {}", if replaced { "replaced" } else { "enrolled" }, kb_path.display());
    report_alike(&kb, Some((&new.0, new.1)));
    Ok(ExitCode::SUCCESS)
}

/// Templates alike overall (with `only`: those alike to that type and face): where a frame can
/// tell them apart, and a warning naming both where nothing can.
fn report_alike(kb: &KnowledgeBase, only: Option<(&str, Face)>) {
    for a in kb.alike(&Params::default(), only) {
        println!("{}", a.describe(None));
        if !a.told_apart {
            tracing::warn!(first = %a.first, second = %a.second, largest_px = a.largest_px, "no stretch of outline tells these templates apart");
        }
    }
}

/// A template from an image file, the image's conversions and any material left out of the
/// template logged (the one way both enrolment commands read a template).
fn learn(image: &Path, type_name: &str, id: u16, face: Face, origin: Option<Pt>, params: &Params) -> Result<Template> {
    let (img, notes) = imageio::read_gray(image).with_context(|| format!("cannot read {}", image.display()))?;
    for n in notes {
        tracing::warn!(image = %image.display(), "{n}");
    }
    let (t, left_out) =
        Template::learn(img.view()?, type_name, id, face, origin, params).with_context(|| format!("cannot enroll {}", image.display()))?;
    if let Some(l) = left_out {
        tracing::warn!(image = %image.display(), "{l}");
    }
    Ok(t)
}

/// A folder of `TYPE_FACE` templates: every image compiled (on every core), then enrolled and
/// the knowledge base written once; any image that fails fails the command and writes nothing,
/// naming every such image, so that a catalogue is never half enrolled.
fn enroll_folder(kb_path: &Path, dir: &Path) -> Result<ExitCode> {
    let t0 = std::time::Instant::now();
    let mut kb = KnowledgeBase::load_or_new(kb_path)?;
    let (plan, ignored) = lfi_bridge::kb::plan_folder(dir, &kb)?;
    for path in &ignored {
        let why = if path.is_dir() { "a sub-folder" } else { "not an image named TYPE_up or TYPE_down" };
        tracing::warn!(file = %path.display(), "not enrolled: {why}");
    }
    let params = Params::default();
    // Templates compile independently: one chunk of the list per core.
    let workers = std::thread::available_parallelism().map_or(1, |n| n.get()).min(plan.len());
    let compiled: Vec<Result<Template>> = std::thread::scope(|s| {
        let chunks: Vec<_> = plan
            .chunks(plan.len().div_ceil(workers))
            .map(|files| s.spawn(|| files.iter().map(|f| learn(&f.path, &f.type_name, f.id, f.face, None, &params)).collect::<Vec<_>>()))
            .collect();
        chunks.into_iter().flat_map(|h| h.join().expect("a template worker panicked")).collect()
    });
    let mut failed = Vec::new();
    let mut templates = Vec::with_capacity(plan.len());
    for (f, r) in plan.iter().zip(compiled) {
        match r {
            Ok(t) => templates.push((f, t)),
            Err(e) => failed.push(format!("{e:#}")),
        }
    }
    if !failed.is_empty() {
        anyhow::bail!(
            "{} of {} templates in {} failed; {} not written:\n  {}",
            failed.len(),
            plan.len(),
            dir.display(),
            kb_path.display(),
            failed.join("\n  ")
        );
    }
    let mut replaced = 0;
    for (f, t) in templates {
        println!("{} {} (id {}) from {}", t.type_name, t.face, t.type_id, f.path.display());
        replaced += usize::from(
            kb.enroll(t, f.path.display().to_string())
                .with_context(|| format!("{}; {} not written", f.path.display(), kb_path.display()))?,
        );
    }
    kb.save(kb_path)?;
    report_alike(&kb, None);
    println!(
        "enrolled {} templates ({} replaced), {} types in {}, in {:.1} s",
        plan.len(),
        replaced,
        kb.type_count(),
        kb_path.display(),
        t0.elapsed().as_secs_f64()
    );
    Ok(ExitCode::SUCCESS)
}

fn bar(len: u64, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(len);
    pb.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} {elapsed_precise} eta {eta}")
            .expect("static template")
            .progress_chars("=> "),
    );
    pb.set_message(what.to_string());
    pb
}

fn simulate(out: &Path, count: u64, cfg: SimConfig, cell: bool, catalog: Option<u16>) -> Result<ExitCode> {
    let seed = cfg.seed;
    let catalogue = catalog.map(|n| lfi_bridge::sim::catalog::generate(n as usize, seed));
    let sim = match &catalogue {
        Some(c) => Simulator::with_catalogue(cfg, c)?,
        None if cell => Simulator::new(cfg)?.through_cell_camera(),
        None => Simulator::new(cfg)?,
    };
    if cell {
        write_plates(&sim, &out.join("plates"))?;
    }
    let images = out.join("images");
    let templates = out.join("templates");
    for d in [&images, &templates] {
        std::fs::create_dir_all(d).with_context(|| format!("cannot create {}", d.display()))?;
    }
    for (name, face, img) in sim.templates()? {
        imageio::write_png(&templates.join(format!("{name}_{face}.png")), &img)?;
    }
    if let Some(c) = &catalogue {
        let unknown = templates.join("unknown");
        std::fs::create_dir_all(&unknown).with_context(|| format!("cannot create {}", unknown.display()))?;
        for (name, face, img) in sim.unknown_templates()? {
            imageio::write_png(&unknown.join(format!("{name}_{face}.png")), &img)?;
        }
        let path = out.join("catalog.json");
        let text = serde_json::to_string_pretty(&lfi_bridge::truth::Catalog { types: c.types.clone() })?;
        imageio::write_atomic(&path, text.as_bytes()).with_context(|| format!("cannot write {}", path.display()))?;
    }
    let pb = bar(count, "rendering");
    let mut lines = String::new();
    for i in 0..count {
        let scene = sim.scene(i)?;
        imageio::write_png(&out.join(&scene.truth.image), &scene.image)?;
        let mut v = serde_json::to_value(&scene.truth)?;
        if let (Some(obj), serde_json::Value::Object(extra)) = (v.as_object_mut(), serde_json::to_value(&scene.extra)?) {
            obj.extend(extra);
        }
        lines.push_str(&serde_json::to_string(&v)?);
        lines.push('\n');
        pb.inc(1);
    }
    pb.finish_and_clear();
    let truth = out.join("truth.jsonl");
    imageio::write_atomic(&truth, lines.as_bytes()).with_context(|| format!("cannot write {}", truth.display()))?;
    println!("wrote {count} scenes, {} templates and {}", sim.type_names().len() * 2, truth.display());
    println!(
        "types (enroll with ids in this order): {}; never enrolled: {}",
        sim.type_names().join(", "),
        sim.unknown_type_names().join(", ")
    );
    Ok(ExitCode::SUCCESS)
}

/// A plate of each kind as the cell's camera sees it, and `plates.json`: per plate its grid and
/// four grid points near the field's corners as a robot would touch them up (true pixels and
/// robot millimetres).
fn write_plates(sim: &Simulator, dir: &Path) -> Result<()> {
    use lfi_bridge::plate::Grid;
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let mut index = Vec::new();
    for grid in [Grid::Circles, Grid::AsymmetricCircles, Grid::Chessboard] {
        let (img, plate) = sim.plate(grid, 0.6)?;
        let name = format!("{}.png", grid.as_str());
        imageio::write_png(&dir.join(&name), &img)?;
        let (c, r) = (plate.cols, plate.rows);
        let touch = plate
            .corner_marks()
            .iter()
            .map(|&i| sim.touch_up(&plate, i).map(|t| t.map(|v| (v * 1000.0).round() / 1000.0)))
            .collect::<Option<Vec<[f64; 4]>>>()
            .context("plates need the cell's camera")?;
        index.push(serde_json::json!({
            "image": name, "grid": grid.as_str(), "cols": c, "rows": r, "pitch_mm": plate.pitch_mm, "touch_ups": touch,
        }));
    }
    let path = dir.join("plates.json");
    imageio::write_atomic(&path, serde_json::to_string_pretty(&index)?.as_bytes())
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(())
}

fn calibrate(spec: lfi_bridge::plate::GridSpec, out: &Path, json: bool, images: &[PathBuf]) -> Result<ExitCode> {
    use lfi_bridge::calibration::{PlateFile, PlateFitRecord, PlateGrid};
    use lfi_bridge::lens::View;
    let mut views = Vec::new();
    let mut used = Vec::new();
    let mut refused: Vec<(String, String)> = Vec::new();
    let mut size: Option<(usize, usize, PathBuf)> = None;
    for path in images {
        let (img, _) = match imageio::read_gray(path) {
            Ok(i) => i,
            Err(e) => {
                refused.push((path.display().to_string(), e.to_string()));
                continue;
            }
        };
        if let Some((w, h, first)) = &size
            && (img.width, img.height) != (*w, *h)
        {
            refused
                .push((path.display().to_string(), format!("{} x {} pixels, but {} is {w} x {h}", img.width, img.height, first.display())));
            continue;
        }
        match lfi_bridge::plate::find_grid(&img, &spec) {
            Ok(pixels) => {
                tracing::info!("{}: {} grid points found", path.display(), pixels.len());
                size.get_or_insert((img.width, img.height, path.clone()));
                views.push(View { pixels, plate: spec.plate_points() });
                used.push(path.display().to_string());
            }
            Err(e) => refused.push((path.display().to_string(), e.to_string())),
        }
    }
    for (p, why) in &refused {
        tracing::warn!("{p}: grid not used: {why}");
    }
    let Some((width, height, _)) = size else {
        let why: Vec<String> = refused.iter().map(|(p, w)| format!("{p}: {w}")).collect();
        bail!("no image showed the {} x {} {} grid:\n  {}", spec.cols, spec.rows, spec.grid.as_str(), why.join("\n  "));
    };
    let fit = lfi_bridge::lens::fit_plate(&views, width, height).context("the lens fit")?;
    let record = PlateFitRecord {
        images: images.iter().map(|p| p.display().to_string()).collect(),
        images_used: views.len(),
        points: fit.points,
        rms_px: fit.rms_px,
        residual_mm_median: fit.residual_mm_median,
        residual_mm_max: fit.residual_mm_max,
    };
    let grid = PlateGrid { kind: spec.grid.as_str().into(), cols: spec.cols, rows: spec.rows, pitch_mm: spec.pitch_mm };
    let file = PlateFile::new(&fit.camera, width, height, grid, record);
    imageio::write_atomic(out, file.to_toml()?.as_bytes()).with_context(|| format!("cannot write {}", out.display()))?;
    let lens = &fit.camera.lens;
    if json {
        let v = serde_json::json!({
            "out": out.display().to_string(),
            "rms_px": fit.rms_px,
            "residual_mm_max": fit.residual_mm_max,
            "residual_mm_median": fit.residual_mm_median,
            "images_used": views.len(),
            "points": fit.points,
            "k1": lens.k1, "k2": lens.k2, "p1": lens.p1, "p2": lens.p2,
            "centre_px": lens.centre_px,
            "corner_shift_px": lens.corner_shift_px(width, height),
            "refused": refused.iter().map(|(p, w)| serde_json::json!({"image": p, "why": w})).collect::<Vec<_>>(),
        });
        println!("{v}");
    } else {
        println!("wrote {}: {} of {} images used, {} grid points", out.display(), views.len(), images.len(), fit.points);
        println!(
            "reprojection RMS {:.4} px; plate residual median {:.4} mm, max {:.4} mm",
            fit.rms_px, fit.residual_mm_median, fit.residual_mm_max
        );
        println!(
            "lens: k1 {:.5}, k2 {:.5}, p1 {:.6}, p2 {:.6}, centre ({:.1}, {:.1}) px: the frame's corners move {:.1} px",
            lens.k1,
            lens.k2,
            lens.p1,
            lens.p2,
            lens.centre_px[0],
            lens.centre_px[1],
            lens.corner_shift_px(width, height)
        );
        for (p, why) in &refused {
            println!("not used: {p}: {why}");
        }
    }
    Ok(ExitCode::SUCCESS)
}

fn map(config: &Path, unit: Option<u8>, points: &[String]) -> Result<ExitCode> {
    let cfg = lfi_bridge::config::Config::load(config)?;
    let ids: Vec<u8> = cfg.cameras.iter().map(|c| c.unit_id).collect();
    let cam = match unit {
        Some(u) => cfg
            .cameras
            .iter()
            .find(|c| c.unit_id == u)
            .with_context(|| format!("{}: no camera with unit id {u} (cameras: {ids:?})", config.display()))?,
        None if cfg.cameras.len() == 1 => &cfg.cameras[0],
        None => bail!("{}: {} cameras (unit ids {ids:?}): say which with --camera", config.display(), cfg.cameras.len()),
    };
    let job = cam.job(cam.start_job).with_context(|| format!("camera {}: start job {} is not configured", cam.unit_id, cam.start_job))?;
    let cal = lfi_bridge::calibration::Calibration::from_config(&job.calibration)
        .with_context(|| format!("camera {}: calibration", cam.unit_id))?;
    tracing::info!("camera {} job {}: {}", cam.unit_id, job.id, cal.describe());
    let mut out = String::new();
    for p in points {
        let q = parse_point(p).map_err(|e| anyhow::anyhow!("point {e}"))?;
        let (x, y) = cal.to_robot(q.x, q.y).with_context(|| format!("point {p:?} is outside the calibrated field"))?;
        out.push_str(&format!("{x:.3} {y:.3}\n"));
    }
    print!("{out}");
    Ok(ExitCode::SUCCESS)
}

fn load_estimator(kb_path: &Path) -> Result<(Estimator, Vec<String>)> {
    let kb = KnowledgeBase::load(kb_path)?;
    let names = kb.templates().iter().map(|t| t.type_name.clone()).collect();
    let est = Estimator::new(&kb.templates(), Params::default()).with_context(|| format!("knowledge base {}", kb_path.display()))?;
    Ok((est, names))
}

/// A frame that could not be estimated, in the estimate format: one "frame error" entry.
fn frame_error_part() -> EstimatePart {
    EstimatePart {
        type_name: None,
        type_id: 0,
        face: None,
        angle_deg: 0.0,
        x_px: 0.0,
        y_px: 0.0,
        confidence: 0.0,
        accepted: false,
        reason: lfi_bridge::vision::Reason::FrameError.as_str().into(),
    }
}

fn estimate(kb_path: &Path, json: bool, overlay_dir: Option<&Path>, repeat: usize, images: &[PathBuf]) -> Result<ExitCode> {
    let (est, _) = load_estimator(kb_path)?;
    let mut failed = 0;
    for path in images {
        let shown = path.display().to_string();
        let outcome = imageio::read_gray(path).map_err(anyhow::Error::from).and_then(|(img, notes)| {
            for n in notes {
                tracing::warn!(image = %shown, "{n}");
            }
            let mut runs = Vec::with_capacity(repeat);
            for _ in 0..repeat {
                let t = Instant::now();
                let fe = est.estimate(img.view()?)?;
                runs.push((t.elapsed().as_secs_f64() * 1e3, fe));
            }
            let (ms, mut fe) = median_run(runs);
            if let Some(dir) = overlay_dir {
                let pic = lfi_bridge::overlay::draw(img.view()?, &fe, &est, 0.5)?;
                let name = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "frame".into());
                let bytes = imageio::encode_mat(&pic, ".png").map_err(anyhow::Error::msg)?;
                std::fs::create_dir_all(dir)?;
                imageio::write_atomic(&dir.join(format!("{name}.overlay.png")), &bytes)?;
            }
            fe.timings.total = ms;
            Ok((fe, ms))
        });
        match outcome {
            Ok((fe, ms)) => {
                for p in &fe.parts {
                    tracing::debug!(image = %shown, reason = %p.reason, "{}", p.detail());
                }
                if json {
                    let rec = EstimateRecord {
                        image: shown,
                        elapsed_ms: (ms * 1000.0).round() / 1000.0,
                        parts: fe.parts.iter().map(EstimatePart::from_estimate).collect(),
                    };
                    println!("{}", serde_json::to_string(&rec)?);
                } else {
                    let t = fe.timings;
                    println!(
                        "{shown}: {} part(s), {} debris, {ms:.1} ms (detect {:.1}, boundary {:.1}, lines {:.1}, correlate {:.1}, register {:.1}, confidence {:.1}, several parts {:.1} of which vote {:.1}), noise sigma {:.1}",
                        fe.parts.len(),
                        fe.debris,
                        t.detect,
                        t.boundary,
                        t.lines,
                        t.correlate,
                        t.register,
                        t.confidence,
                        t.clump,
                        t.vote,
                        fe.noise_sigma
                    );
                    for p in &fe.parts {
                        println!(
                            "  {} {} angle {:.2} deg at ({:.1}, {:.1}) conf {:.3} {}{}",
                            p.type_name.as_deref().unwrap_or("-"),
                            p.face.map(|f| f.as_str()).unwrap_or("-"),
                            p.angle_deg,
                            p.x,
                            p.y,
                            p.confidence,
                            if p.accepted { "ACCEPT" } else { "REJECT: " },
                            if p.accepted { "" } else { p.reason.as_str() }
                        );
                        println!("      {}", p.detail());
                    }
                }
            }
            Err(e) => {
                failed += 1;
                eprintln!("error: {shown}: {e:#}");
                if json {
                    let rec = EstimateRecord { image: shown, elapsed_ms: 0.0, parts: vec![frame_error_part()] };
                    println!("{}", serde_json::to_string(&rec)?);
                }
            }
        }
    }
    Ok(if failed > 0 { ExitCode::from(1) } else { ExitCode::SUCCESS })
}

/// The run with the median total time, its stage timings replaced by the per-stage medians.
fn median_run(mut runs: Vec<(f64, lfi_bridge::vision::FrameEstimate)>) -> (f64, lfi_bridge::vision::FrameEstimate) {
    let med = |f: &dyn Fn(&lfi_bridge::vision::Timings) -> f64, runs: &[(f64, lfi_bridge::vision::FrameEstimate)]| {
        let mut v: Vec<f64> = runs.iter().map(|r| f(&r.1.timings)).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let t = lfi_bridge::vision::Timings {
        detect: med(&|t| t.detect, &runs),
        boundary: med(&|t| t.boundary, &runs),
        lines: med(&|t| t.lines, &runs),
        correlate: med(&|t| t.correlate, &runs),
        register: med(&|t| t.register, &runs),
        confidence: med(&|t| t.confidence, &runs),
        clump: med(&|t| t.clump, &runs),
        vote: med(&|t| t.vote, &runs),
        total: 0.0,
    };
    runs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mid = runs.len() / 2;
    let (ms, mut fe) = runs.swap_remove(mid);
    fe.timings = t;
    (ms, fe)
}

fn evaluate(kb_path: &Path, truth_path: &Path, catalog_path: Option<&Path>, json: bool) -> Result<ExitCode> {
    let (est, enrolled) = load_estimator(kb_path)?;
    let text = std::fs::read_to_string(truth_path).with_context(|| format!("cannot read truth {}", truth_path.display()))?;
    let records = parse_truth(&text, &truth_path.display().to_string()).map_err(anyhow::Error::msg)?;
    if records.is_empty() {
        bail!("truth {} has no records", truth_path.display());
    }
    let base = truth_path.parent().unwrap_or(Path::new("."));
    let beside = base.join("catalog.json");
    let catalog_path = catalog_path.map(Path::to_path_buf).or_else(|| beside.is_file().then_some(beside));
    let catalog = match &catalog_path {
        Some(p) => {
            let text = std::fs::read_to_string(p).with_context(|| format!("cannot read catalogue {}", p.display()))?;
            Some(lfi_bridge::truth::parse_catalog(&text, &p.display().to_string()).map_err(anyhow::Error::msg)?)
        }
        None => None,
    };
    let pb = bar(records.len() as u64, "estimating");
    let mut obs = Vec::with_capacity(records.len());
    let mut errors = Vec::new();
    for rec in records {
        let path = base.join(&rec.image);
        let outcome = imageio::read_gray(&path).map_err(anyhow::Error::from).and_then(|(img, _)| {
            let t = Instant::now();
            let fe = est.estimate(img.view()?)?;
            Ok((fe, t.elapsed().as_secs_f64() * 1e3))
        });
        match outcome {
            Ok((fe, ms)) => {
                obs.push(Observation { truth: rec, parts: fe.parts.iter().map(EstimatePart::from_estimate).collect(), elapsed_ms: ms })
            }
            Err(e) => {
                errors.push(format!("{}: {e:#}", path.display()));
                obs.push(Observation { truth: rec, parts: vec![frame_error_part()], elapsed_ms: 0.0 });
            }
        }
        pb.inc(1);
    }
    pb.finish_and_clear();
    let report = eval::evaluate_catalogue(&obs, &enrolled, catalog.as_ref());
    if json {
        let mut v = serde_json::to_value(&report)?;
        v["frame_errors"] = serde_json::to_value(&errors)?;
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        print!("{}", eval::render_text(&report));
        for e in &errors {
            println!("frame error: {e}");
        }
    }
    Ok(ExitCode::SUCCESS)
}
