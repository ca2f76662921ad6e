//! Modbus/TCP towards the PLC: the request service, the framing and the server (the register
//! map they serve is [`crate::registers`]).

pub mod frame;
pub mod server;
pub mod service;
