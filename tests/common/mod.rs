//! Helpers shared by the integration tests.

#![allow(dead_code)]

pub mod appliance;
pub mod fanuc;
pub mod http;
pub mod webdriver;

use lfi_bridge::eval::Observation;
use lfi_bridge::sim::{SimConfig, Simulator};
use lfi_bridge::truth::EstimatePart;
use lfi_bridge::vision::{Estimator, Params, Template};

/// The simulator's templates enrolled as types 1, 2, 3 (the unknown model is left out).
pub fn enrolled(sim: &Simulator) -> Vec<Template> {
    sim.enrolled(&Params::default()).expect("templates render and enrol")
}

pub fn simulator(seed: u64, noise: Option<f64>) -> Simulator {
    Simulator::new(SimConfig { width: 2592, height: 1944, seed, noise }).expect("simulator")
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
