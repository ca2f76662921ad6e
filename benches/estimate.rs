//! Estimate time on a 2592 x 1944 frame held in memory, one OpenCV thread.
//!
//! `cargo bench --bench estimate` prints a per-stage table (medians over 60 runs) and then
//! criterion's measurement of the whole estimate for a one-part and a multi-part frame; then the
//! same scenes of the three built-in types estimated with 3, 10, 40 and 100 types enrolled (the
//! extra ones from the simulator's generated catalogue, `simulate --catalog`): a table of medians
//! over 30 runs, and criterion's `catalogue` group.

use criterion::{Criterion, criterion_group, criterion_main};
use lfi_bridge::sim::{SimConfig, Simulator};
use lfi_bridge::vision::{Estimator, GrayImage, Params, Template, Timings};

fn setup() -> (Estimator, Frames) {
    let sim = Simulator::new(SimConfig { width: 2592, height: 1944, seed: 7, noise: None }).expect("simulator");
    let templates = sim.enrolled(&Params::default()).expect("templates enrol");
    let est = Estimator::new(&templates, Params::default()).expect("estimator");
    let frames = vec![
        ("one part, clean", sim.scene_with(0, "clean").unwrap().image),
        (
            "one part, noise 30",
            Simulator::new(SimConfig { width: 2592, height: 1944, seed: 7, noise: Some(30.0) })
                .unwrap()
                .scene_with(0, "clean")
                .unwrap()
                .image,
        ),
        ("multi-part", sim.scene_with(3, "multi").unwrap().image),
        ("four separate parts", (0..).map(|i| sim.scene_with(i, "multi").unwrap()).find(|s| s.truth.parts.len() == 4).unwrap().image),
        ("touching pair", sim.scene_with(0, "touching").unwrap().image),
        ("overlapping pair", sim.scene_with(0, "overlapping").unwrap().image),
        ("empty belt", sim.scene_with(0, "empty").unwrap().image),
        ("unknown part", sim.scene_with(0, "unknown").unwrap().image),
    ];
    (est, frames)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn stage_table(est: &Estimator, frames: &[(&str, GrayImage)]) {
    println!("\nper-stage medians over 60 runs (ms), 2592 x 1944, one OpenCV thread");
    println!(
        "{:<20} {:>5} {:>7} {:>8} {:>6} {:>9} {:>8} {:>10} {:>7} {:>6} {:>7}",
        "frame", "parts", "detect", "boundary", "lines", "correlate", "register", "confidence", "several", "(vote)", "total"
    );
    for (name, img) in frames {
        let runs: Vec<(usize, Timings)> = (0..60)
            .map(|_| {
                let fe = est.estimate(img.view().unwrap()).unwrap();
                (fe.parts.len(), fe.timings)
            })
            .collect();
        let m = |f: fn(&Timings) -> f64| median(runs.iter().map(|r| f(&r.1)).collect());
        println!(
            "{:<20} {:>5} {:>7.2} {:>8.2} {:>6.2} {:>9.2} {:>8.2} {:>10.2} {:>7.2} {:>6.2} {:>7.2}",
            name,
            runs[0].0,
            m(|t| t.detect),
            m(|t| t.boundary),
            m(|t| t.lines),
            m(|t| t.correlate),
            m(|t| t.register),
            m(|t| t.confidence),
            m(|t| t.clump),
            m(|t| t.vote),
            m(|t| t.total)
        );
    }
    println!();
}

/// Named frames to time.
type Frames = Vec<(&'static str, GrayImage)>;

/// Catalogue sizes of the catalogue group.
const SIZES: [usize; 4] = [3, 10, 40, 100];

/// Estimators of the three built-in types plus the first `n - 3` types of a generated catalogue
/// (ids 4, 5, ...), for each of [`SIZES`], and the frames they are timed on.
fn catalogue_setup() -> (Vec<(usize, Estimator)>, Frames) {
    let cfg = SimConfig { width: 2592, height: 1944, seed: 7, noise: None };
    let sim = Simulator::new(cfg.clone()).expect("simulator");
    // One thread, as the figures are: the ratios compare work, not the pool's luck.
    let params = Params { threads: 1, ..Params::default() };
    let mut templates = sim.enrolled(&params).expect("templates enrol");
    let extra = lfi_bridge::sim::catalog::generate(SIZES[SIZES.len() - 1] - 3, 7);
    let types = Simulator::with_catalogue(cfg, &extra).expect("catalogue").templates().expect("catalogue templates");
    for (k, (name, face, img)) in types.iter().enumerate() {
        let t = Template::from_image(img.view().unwrap(), name, 4 + (k / 2) as u16, *face, None, &params).expect("catalogue template");
        templates.push(t);
    }
    let estimators = SIZES.iter().map(|&n| (n, Estimator::new(&templates[..2 * n], params.clone()).expect("estimator"))).collect();
    let frames = vec![
        ("one part", sim.scene_with(0, "clean").unwrap().image),
        ("four separate parts", (0..).map(|i| sim.scene_with(i, "multi").unwrap()).find(|s| s.truth.parts.len() == 4).unwrap().image),
        ("touching pair", sim.scene_with(0, "touching").unwrap().image),
    ];
    (estimators, frames)
}

fn catalogue_table(estimators: &[(usize, Estimator)], frames: &[(&str, GrayImage)]) {
    println!("\nwhole estimate, medians over 30 runs (ms), by types enrolled; the same frames of the three built-in types");
    print!("{:<20}", "frame");
    for (n, _) in estimators {
        print!(" {:>9}", format!("{n} types"));
    }
    println!(" {:>9}", "100 / 3");
    for (name, img) in frames {
        print!("{name:<20}");
        let mut first = f64::NAN;
        let mut last = f64::NAN;
        for (_, est) in estimators {
            let m = median((0..30).map(|_| est.estimate(img.view().unwrap()).unwrap().timings.total).collect());
            if first.is_nan() {
                first = m;
            }
            last = m;
            print!(" {m:>9.2}");
        }
        println!(" {:>8.2}x", last / first);
    }
    println!();
}

fn bench(c: &mut Criterion) {
    opencv::core::set_num_threads(1).expect("OpenCV threads");
    let (est, frames) = setup();
    if std::env::args().any(|a| a == "--bench") {
        stage_table(&est, &frames);
    }
    let mut g = c.benchmark_group("estimate 2592x1944");
    g.sample_size(60);
    for (name, img) in &frames {
        g.bench_function(*name, |b| b.iter(|| est.estimate(std::hint::black_box(img.view().unwrap())).unwrap()));
    }
    // Both ways: frames of several separate regions use the second core by default.
    let one = Estimator::new(&est.templates().cloned().collect::<Vec<_>>(), Params { threads: 1, ..Params::default() }).expect("estimator");
    for (name, img) in frames.iter().filter(|(n, _)| n.contains("multi") || n.contains("four")) {
        g.bench_function(format!("{name}, one thread"), |b| b.iter(|| one.estimate(std::hint::black_box(img.view().unwrap())).unwrap()));
    }
    g.finish();

    // Rendering and enrolling 200 templates takes a while: only in a real bench run, not in
    // `cargo test --all-targets`'s pass over the benches.
    if !std::env::args().any(|a| a == "--bench") {
        return;
    }
    let (estimators, frames) = catalogue_setup();
    catalogue_table(&estimators, &frames);
    for (n, est) in [&estimators[0], &estimators[estimators.len() - 1]] {
        println!("{n} types:");
        stage_table(est, &frames);
    }
    let mut g = c.benchmark_group("catalogue");
    g.sample_size(20);
    for (name, img) in &frames {
        for (n, est) in &estimators {
            g.bench_function(format!("{name}, {n} types"), |b| b.iter(|| est.estimate(std::hint::black_box(img.view().unwrap())).unwrap()));
        }
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
