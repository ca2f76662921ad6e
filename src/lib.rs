#![warn(missing_docs)]
//! lfi-bridge: part type, face and pose from a conveyor camera, served to a PLC and a robot.
//!
//! The crate is a functional core with an imperative shell. [`vision`] turns a frame into part
//! estimates with the line-feature-invariant (LFI) method and knows nothing of files or networks;
//! [`kb`] stores templates as a TOML knowledge base; [`sim`] renders scenes with ground truth;
//! [`eval`] scores estimates against that truth.

pub mod appliance;
pub mod calibration;
pub mod config;
pub mod eval;
pub mod handshake;
pub mod http;
pub mod imageio;
pub mod kb;
pub mod lens;
pub mod logging;
pub mod modbus;
pub mod opcua;
pub mod overlay;
pub mod plate;
pub mod registers;
pub mod robot;
pub mod sim;
pub mod truth;
pub mod vision;

/// Starts the whole appliance: cameras, the PLC's Modbus server and the robot links
/// ([`appliance::start`]), then the operator view when `[http]` is configured
/// ([`http::attach`]). The one place both are wired: the appliance knows no HTTP.
pub async fn start(cfg: &config::Config) -> Result<appliance::Running, appliance::StartError> {
    let mut running = appliance::start(cfg).await?;
    let opcua_stats = cfg.opcua.as_ref().map(|_| std::sync::Arc::new(opcua::Stats::default()));
    if let Some(h) = &cfg.http {
        http::attach(&mut running, h, opcua_stats.clone()).await?;
    }
    if let (Some(o), Some(stats)) = (&cfg.opcua, opcua_stats) {
        let triggers = cfg.cameras.iter().map(|c| c.trigger).collect();
        let url = opcua::attach(&mut running, o, triggers, stats).await?;
        running.opcua_url = Some(url);
    }
    Ok(running)
}
