//! Why the appliance cannot start.

use std::net::SocketAddr;

/// Why the appliance cannot start; each names the camera or address at fault.
#[derive(Debug, thiserror::Error)]
pub enum StartError {
    /// Its knowledge base cannot be loaded.
    #[error("camera {camera}: knowledge base")]
    Kb {
        /// The camera (`camera[0] (line 1)`).
        camera: String,
        /// What is wrong with the file.
        source: crate::kb::KbError,
    },
    /// Its templates do not make an estimator.
    #[error("camera {camera}: cannot build the estimator")]
    Estimator {
        /// The camera.
        camera: String,
        /// Why not.
        source: crate::vision::EstimatorError,
    },
    /// The simulated camera cannot render its scenes.
    #[error("camera {camera}: simulated camera: {message}")]
    Sim {
        /// The camera.
        camera: String,
        /// The simulator's complaint.
        message: String,
    },
    /// Its calibration does not fit.
    #[error("camera {camera}: calibration")]
    Calibration {
        /// The camera.
        camera: String,
        /// Why not.
        source: crate::calibration::CalibrationError,
    },
    /// Its image archive's folder cannot be made or read.
    #[error("camera {camera}: image archive {dir}")]
    Archive {
        /// The camera.
        camera: String,
        /// The archive folder.
        dir: std::path::PathBuf,
        /// Why the system refused it.
        source: std::io::Error,
    },
    /// The OPC UA server cannot be set up (its PKI folder, its information model).
    #[error("OPC UA: {message}")]
    Opcua {
        /// What went wrong, naming the file or node.
        message: String,
    },
    /// The PLC's port is taken or not ours.
    #[error("cannot listen for Modbus on {addr}")]
    Bind {
        /// The configured address.
        addr: SocketAddr,
        /// Why the system refused it.
        source: std::io::Error,
    },
}
