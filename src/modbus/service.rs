//! Modbus requests against one camera's registers: validation in the order of the Modbus
//! specification (function, quantity, address, value), then the handshake. Pure: no I/O.

use std::time::Duration;

use tokio_modbus::{ExceptionCode, Request, Response};

use super::map::{self, SIZE};
use crate::handshake::{Command, Handshake};

/// Largest read (FC3) and write (FC16) quantities of the Modbus specification.
pub const MAX_READ: u16 = 125;
pub const MAX_WRITE: u16 = 123;

/// Handles one request. `may_write` is false for a client outside the configured allow-list.
pub fn handle(hs: &mut Handshake, req: &Request<'_>, may_write: bool, now: Duration) -> Result<(Response, Vec<Command>), ExceptionCode> {
    match req {
        Request::ReadHoldingRegisters(start, qty) => {
            let (start, qty) = (*start, *qty);
            if qty == 0 || qty > MAX_READ {
                return Err(ExceptionCode::IllegalDataValue);
            }
            if start as u32 + qty as u32 > SIZE as u32 {
                return Err(ExceptionCode::IllegalDataAddress);
            }
            Ok((Response::ReadHoldingRegisters(hs.read(start, qty)), Vec::new()))
        }
        Request::WriteSingleRegister(a, v) => {
            if !may_write {
                return Err(ExceptionCode::IllegalFunction);
            }
            check_writes(*a, &[*v])?;
            let cmds = hs.write(*a, *v, now).into_iter().collect();
            Ok((Response::WriteSingleRegister(*a, *v), cmds))
        }
        Request::WriteMultipleRegisters(start, values) => {
            if !may_write {
                return Err(ExceptionCode::IllegalFunction);
            }
            if values.is_empty() || values.len() > MAX_WRITE as usize {
                return Err(ExceptionCode::IllegalDataValue);
            }
            check_writes(*start, values)?;
            let mut cmds = Vec::new();
            for (i, v) in values.iter().enumerate() {
                cmds.extend(hs.write(start + i as u16, *v, now));
            }
            Ok((Response::WriteMultipleRegisters(*start, values.len() as u16), cmds))
        }
        _ => Err(ExceptionCode::IllegalFunction),
    }
}

/// Address then value checks for writes of `values` from `start`.
fn check_writes(start: u16, values: &[u16]) -> Result<(), ExceptionCode> {
    if start as u32 + values.len() as u32 > SIZE as u32 {
        return Err(ExceptionCode::IllegalDataAddress);
    }
    for i in 0..values.len() as u16 {
        if !map::writable(start + i) {
            return Err(ExceptionCode::IllegalDataAddress);
        }
    }
    for (i, v) in values.iter().enumerate() {
        let r = map::lookup(start + i as u16).expect("writable implies defined");
        if r.allowed.is_some_and(|ok| !ok.contains(v)) {
            return Err(ExceptionCode::IllegalDataValue);
        }
    }
    Ok(())
}
