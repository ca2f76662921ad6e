//! The shortlist (issue 37): a part is correlated only with the templates whose key could place
//! them among its nearest, and that never cuts one that would have been there. In tests every
//! estimate checks its shortlist against correlating every template (`Estimator::candidates`,
//! debug assertions); this file runs it over the simulator's 40-type catalogue in every
//! condition and at every noise level, and checks the library's own templates turned and
//! mirrored.

mod common;

use lfi_bridge::sim::catalog;
use lfi_bridge::sim::{SimConfig, Simulator};
use lfi_bridge::vision::template::Library;
use lfi_bridge::vision::{Estimator, Params};

#[test]
fn the_shortlist_never_cuts_a_near_template_in_any_condition_or_noise() {
    let _shared = common::MACHINE.blocking_read();
    let cat = catalog::generate(40, 3);
    let sim = Simulator::with_catalogue(SimConfig { width: 1296, height: 972, seed: 11, noise: None }, &cat).expect("simulator");
    let templates = sim.enrolled(&Params::default()).expect("templates");
    let est = Estimator::new(&templates, Params::default()).expect("estimator");
    let mut parts = 0;
    // Noise scenes cycle through sigma 10, 20, 30, 40: eight of them see each twice.
    let mut scenes: Vec<(u64, &str)> = (1..=8).map(|i| (i, "noise")).collect();
    for cond in ["clean", "glare", "dim", "multi", "touching", "overlapping", "unknown"] {
        scenes.extend((1..=3).map(|i| (i, cond)));
    }
    for (i, cond) in scenes {
        let scene = sim.scene_with(i, cond).expect("scene renders");
        // Panics (the debug assertion) if the shortlist differs from correlating everything.
        let fe = est.estimate(scene.image.view().unwrap()).expect("estimate runs");
        parts += fe.parts.len();
    }
    assert!(parts >= 40, "only {parts} parts estimated");
}

#[test]
fn the_library_finds_its_own_templates_turned_and_mirrored() {
    let cat = catalog::generate(40, 3);
    let sim = Simulator::with_catalogue(SimConfig { width: 1296, height: 972, seed: 11, noise: None }, &cat).expect("simulator");
    let templates = sim.enrolled(&Params::default()).expect("templates");
    let lib = Library::new(&templates, 1024);
    let c = &lib.correlator;
    for (i, t) in templates.iter().enumerate() {
        let signal = lfi_bridge::vision::signal::log_radius_signal(&t.outline, t.centroid, c.bins());
        for turn in [0, 100, 517] {
            let turned: Vec<f64> = (0..signal.len()).map(|k| signal[(k + turn) % signal.len()]).collect();
            let mirrored: Vec<f64> = (0..signal.len()).map(|k| turned[(signal.len() - k) % signal.len()]).collect();
            for (s, own) in [(turned, true), (mirrored, false)] {
                let spec = c.spectrum(&s);
                let near = lib.nearest(&spec, 3);
                let all: Vec<usize> = lib.align_all(&spec).iter().take(3).map(|a| a.0).collect();
                assert_eq!(near.iter().map(|a| a.0).collect::<Vec<_>>(), all, "template {i} turned {turn}");
                if own {
                    assert!(near[0].1.rms < 1e-6, "template {i} turned is nearest to itself: {near:?}");
                }
            }
        }
    }
}

/// The region search's glance (more than 24 templates: each votes from a quarter of the region,
/// the best 24 vote in full) decides as every template voting in full: `Estimator::check_glance`
/// asserts it in debug builds by searching the region again without the glance (the same
/// verdicts, types, faces and reasons, poses within 1.5 px and 0.5 degrees). Touching and
/// overlapping pairs of the 40-type catalogue (80 templates), with and without debris, at noise
/// 0, 20 and 40.
#[test]
fn the_region_glance_decides_as_the_full_vote_at_every_noise() {
    let _shared = common::MACHINE.blocking_read();
    let cat = catalog::generate(40, 3);
    let clean = SimConfig { width: 1296, height: 972, seed: 11, noise: None };
    let templates = Simulator::with_catalogue(clean.clone(), &cat).expect("simulator").enrolled(&Params::default()).expect("templates");
    let est = Estimator::new(&templates, Params::default()).expect("estimator");
    let mut searched = 0;
    for noise in [None, Some(20.0), Some(40.0)] {
        let sim = Simulator::with_catalogue(SimConfig { noise, ..clean.clone() }, &cat).expect("simulator");
        for cond in ["touching", "overlapping"] {
            for i in 1..=4 {
                let scene = sim.scene_with(i, cond).expect("scene renders");
                // Panics (the debug assertion) if the glance changed what the region search finds.
                let fe = est.estimate(scene.image.view().unwrap()).expect("estimate runs");
                searched += (fe.timings.vote > 0.0) as usize;
            }
        }
    }
    assert!(searched >= 18, "the region search voted in only {searched} of 24 frames");
}
