//! Modbus/TCP towards the PLC: the register map, the request service, the framing and the server.

pub mod frame;
pub mod map;
pub mod server;
pub mod service;
