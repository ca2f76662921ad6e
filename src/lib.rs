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
pub mod modbus;
pub mod overlay;
pub mod robot;
pub mod sim;
pub mod truth;
pub mod vision;
