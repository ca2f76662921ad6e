//! Estimate time on a 2592 x 1944 frame held in memory, one OpenCV thread.
//!
//! `cargo bench --bench estimate` prints a per-stage table (medians over 60 runs) and then
//! criterion's measurement of the whole estimate for a one-part and a multi-part frame.

use criterion::{Criterion, criterion_group, criterion_main};
use lfi_bridge::sim::{SimConfig, Simulator};
use lfi_bridge::vision::{Estimator, GrayImage, Params, Timings};

fn setup() -> (Estimator, Vec<(&'static str, GrayImage)>) {
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
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
