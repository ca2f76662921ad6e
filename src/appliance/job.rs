//! Loading a job: its knowledge base, the estimator on it and its calibration, all or nothing.

use super::error::StartError;
use super::source::SimSource;
use crate::calibration::Calibration;
use crate::config::{JobConfig, KbSource, SourceConfig};
use crate::kb::KnowledgeBase;
use crate::sim::Simulator;
use crate::vision::{Estimator, Params};

/// A job made ready to run: its templates, the estimator built on them with the job's accept
/// threshold, and its calibration. Nothing of the camera changes until all of it is there.
pub struct Loaded {
    /// The job's templates.
    pub kb: KnowledgeBase,
    /// Where the templates came from, for the log.
    pub kb_desc: String,
    /// The estimator on them.
    pub estimator: Estimator,
    /// The parameters it was built with.
    pub params: Params,
    /// Pixels to robot millimetres.
    pub calibration: Calibration,
}

/// Loads a job of camera `camera` (the start-up job, or one the PLC asks for).
pub fn load_job(camera: &str, job: &JobConfig, source: &SourceConfig, base: &Params) -> Result<Loaded, StartError> {
    let params = Params { accept_threshold: job.accept_threshold, ..base.clone() };
    let (kb, kb_desc) = match &job.kb {
        KbSource::File(p) => {
            let kb = KnowledgeBase::load(p).map_err(|source| StartError::Kb { camera: camera.to_string(), source })?;
            let desc = format!("{} ({} templates, {} types)", p.display(), kb.entries.len(), kb.type_count());
            (kb, desc)
        }
        KbSource::Simulator => {
            let SourceConfig::Sim { seed, width, height, noise, .. } = *source else {
                unreachable!("the configuration only allows kb_from_simulator with a sim source")
            };
            let sim_err = |e: &dyn std::fmt::Display| StartError::Sim { camera: camera.to_string(), message: e.to_string() };
            let sim = Simulator::new(SimSource::config(seed, width, height, noise)).map_err(|e| sim_err(&e))?;
            let names = sim.type_names();
            let mut out = KnowledgeBase::default();
            for t in sim.enrolled(&params).map_err(|e| sim_err(&e))? {
                let source = format!("simulator template {}_{}", t.type_name, t.face);
                out.entries.push(crate::kb::Entry { template: t, source });
            }
            let desc = names.iter().enumerate().map(|(i, n)| format!("{n} = {}", i + 1)).collect::<Vec<_>>().join(", ");
            (out, format!("enrolled from the simulated camera's templates ({desc})"))
        }
    };
    let estimator =
        Estimator::new(&kb.templates(), params.clone()).map_err(|source| StartError::Estimator { camera: camera.to_string(), source })?;
    let calibration =
        Calibration::from_config(&job.calibration).map_err(|source| StartError::Calibration { camera: camera.to_string(), source })?;
    Ok(Loaded { kb, kb_desc, estimator, params, calibration })
}
