//! Helpers shared by the integration tests.

#![allow(dead_code)]

pub mod appliance;
pub mod fanuc;
pub mod http;
pub mod load;
pub mod opcua;
pub mod webdriver;

use lfi_bridge::eval::Observation;
use lfi_bridge::sim::{SimConfig, Simulator};
use lfi_bridge::truth::EstimatePart;
use lfi_bridge::vision::{Estimator, Params, Template};

/// The machine, as the tests of one binary share it (they run two at a time). A test that
/// measures time against the machine's own pace takes it exclusively (`MACHINE.write()`), and a
/// test that loads the machine (a CPU-bound loop, hundreds of sockets, a child process) takes it
/// shared (`MACHINE.read()`, or `blocking_read()` outside a runtime): a measurement then never
/// runs beside another test's load, while the loads still overlap one another. Light tests with
/// deadlines of seconds need not take it.
pub static MACHINE: tokio::sync::RwLock<()> = tokio::sync::RwLock::const_new(());

/// The simulator's templates enrolled as types 1, 2, 3 (the unknown model is left out).
pub fn enrolled(sim: &Simulator) -> Vec<Template> {
    sim.enrolled(&Params::default()).expect("templates render and enrol")
}

pub fn simulator(seed: u64, noise: Option<f64>) -> Simulator {
    Simulator::new(SimConfig { width: 2592, height: 1944, seed, noise }).expect("simulator")
}

/// A shared sample set's folder (`../shared/NAME`, beside the checkout as in CI) and its
/// templates A, B, C enrolled as ids 1, 2, 3, both faces, as a new user would.
pub fn shared_set(name: &str) -> (std::path::PathBuf, Vec<Template>) {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared").join(name);
    let truth = dir.join("truth.jsonl");
    assert!(truth.exists(), "{} not found: the shared samples must lie beside the checkout (as in CI)", truth.display());
    let mut templates = Vec::new();
    for (i, name) in ["A", "B", "C"].iter().enumerate() {
        for face in [lfi_bridge::vision::Face::Up, lfi_bridge::vision::Face::Down] {
            let (img, _) = lfi_bridge::imageio::read_gray(&dir.join(format!("templates/{name}_{face}.png"))).unwrap();
            templates.push(Template::from_image(img.view().unwrap(), name, i as u16 + 1, face, None, &Params::default()).unwrap());
        }
    }
    (dir, templates)
}

/// Renders and estimates scenes `indices` of the given conditions.
pub fn observe(sim: &Simulator, est: &Estimator, scenes: &[(u64, &str)]) -> Vec<Observation> {
    scenes
        .iter()
        .map(|&(i, cond)| {
            let scene = sim.scene_with(i, cond).expect("scene renders");
            let fe = est.estimate(scene.image.view().unwrap()).expect("estimate runs");
            Observation {
                truth: scene.truth,
                parts: fe.parts.iter().map(EstimatePart::from_estimate).collect(),
                elapsed_ms: fe.timings.total,
            }
        })
        .collect()
}
