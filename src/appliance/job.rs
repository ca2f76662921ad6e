//! A camera's job: loaded whole (knowledge base, the estimator on it, calibration), or not at
//! all, and then put in force by the camera's worker, its only writer.

use super::error::StartError;
use super::source::SimSource;
use crate::calibration::Calibration;
use crate::config::{JobConfig, KbSource, SourceConfig};
use crate::kb::KnowledgeBase;
use crate::sim::Simulator;
use crate::vision::{Estimator, EstimatorError, Params};

/// A job ready to run, or running: everything a frame's estimate and its results need, made
/// together and replaced together (a job change, an enrolment), so that no frame sees half of
/// one job and half of another. Readers hold an `Arc` of it; only the worker swaps it.
pub struct InForce {
    /// The job's id (JOB_ID).
    pub id: u16,
    /// The job's name.
    pub name: String,
    /// Where its templates live (a file is rewritten on enrolment).
    pub kb: KbSource,
    /// The part of the frame it estimates, if not all.
    pub roi: Option<[usize; 4]>,
    /// The type the PLC expects under it, if any.
    pub expected_type: Option<u16>,
    /// Pixels to robot millimetres (the operator view shows it and draws its grid).
    pub calibration: Calibration,
    /// Its templates and where each came from.
    pub templates: KnowledgeBase,
    /// The estimator on them.
    pub estimator: Estimator,
}

impl InForce {
    /// TYPES_ENROLLED: the types its templates name (saturates).
    pub fn types_enrolled(&self) -> u16 {
        self.templates.type_count().min(u16::MAX as usize) as u16
    }

    /// The same job with other templates (an enrolment), its estimator built on them.
    pub fn with_templates(&self, templates: KnowledgeBase) -> Result<InForce, EstimatorError> {
        let estimator = Estimator::new(&templates.templates(), self.estimator.params().clone())?;
        Ok(InForce {
            id: self.id,
            name: self.name.clone(),
            kb: self.kb.clone(),
            roi: self.roi,
            expected_type: self.expected_type,
            calibration: self.calibration.clone(),
            templates,
            estimator,
        })
    }
}

/// A job loaded, and where its templates came from (for the log).
pub struct Loaded {
    /// The job, ready to be put in force.
    pub job: InForce,
    /// Where the templates came from, for the log.
    pub kb_desc: String,
}

/// Loads a job of camera `camera` (the start-up job, or one the PLC asks for): nothing of the
/// camera changes until all of it is there.
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
        Estimator::new(&kb.templates(), params).map_err(|source| StartError::Estimator { camera: camera.to_string(), source })?;
    let calibration =
        Calibration::from_config(&job.calibration).map_err(|source| StartError::Calibration { camera: camera.to_string(), source })?;
    let job = InForce {
        id: job.id,
        name: job.name.clone(),
        kb: job.kb.clone(),
        roi: job.roi,
        expected_type: job.expected_type,
        calibration,
        templates: kb,
        estimator,
    };
    Ok(Loaded { job, kb_desc })
}

/// The jobs a camera may switch between, and what loading one needs.
pub struct Jobs {
    /// The camera's name (errors name it).
    pub camera: String,
    /// Its `[[camera.job]]` tables.
    pub configured: Vec<JobConfig>,
    /// Its source (a simulated camera's templates make a `kb_from_simulator` job).
    pub source: SourceConfig,
    /// The parameters every job starts from.
    pub base: Params,
}

impl Jobs {
    /// Loads job `id`, or says why not: not configured (naming the jobs that are), or the load's
    /// whole error chain.
    pub fn load(&self, id: u16) -> Result<Loaded, String> {
        let Some(job) = self.configured.iter().find(|j| j.id == id) else {
            let ids: Vec<String> = self.configured.iter().map(|j| j.id.to_string()).collect();
            return Err(format!("job {id} is not configured (jobs: {})", ids.join(", ")));
        };
        load_job(&self.camera, job, &self.source, &self.base)
            .map_err(|e| format!("job {id} ({}): {}", job.name, crate::logging::error_chain(&e)))
    }
}
