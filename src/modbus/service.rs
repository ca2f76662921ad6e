//! Modbus requests against one camera's registers: validation in the order of the Modbus
//! specification (function, quantity, address, value), then the handshake. Pure: no I/O.

use std::time::Duration;

use tokio_modbus::{ExceptionCode, Request, Response};

use crate::handshake::{Command, Handshake};
use crate::registers::{self as map, SIZE};

/// Largest read (FC3) and write (FC16) quantities of the Modbus specification.
pub const MAX_READ: u16 = 125;
/// Most registers one write may carry (FC16's limit in the specification).
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
            let cmds = hs.write_block(*start, values, now).into_iter().collect();
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
        if !map::value_allowed(r, *v) {
            return Err(ExceptionCode::IllegalDataValue);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::handshake::{PickingOrder, Settings, WordOrder};
    use crate::modbus::frame;

    /// One request PDU (hex) through the framing's parser, the service and the encoder, against
    /// a fresh handshake; `expect` is the response PDU (hex), as a PLC receives it.
    fn check(request: &str, may_write: bool, expect: &str) {
        let hex = |s: &str| -> Vec<u8> { s.split_whitespace().map(|b| u8::from_str_radix(b, 16).expect("hex byte")).collect() };
        let pdu = hex(request);
        let mut hs = Handshake::new(Settings {
            queue_depth: 4,
            online: true,
            word_order: WordOrder::HighFirst,
            types_enrolled: 3,
            picking_order: PickingOrder::XAscending,
            boot_id: 77,
            job_id: 1,
        });
        let result = frame::parse_request(&pdu).and_then(|req| handle(&mut hs, &req, may_write, Duration::ZERO).map(|(r, _)| r));
        let adu = frame::encode(1, 1, pdu.first().copied().unwrap_or(0), &result);
        let got: Vec<String> = adu[frame::HEADER..].iter().map(|b| format!("{b:02x}")).collect();
        assert_eq!(got.join(" "), expect, "request {request}");
    }

    #[test]
    fn requests_and_their_answers() {
        // FC3: MAP_VERSION (107) reads 4, TYPES_ENROLLED (109) 3, BOOT_ID (123) 77.
        check("03 00 6b 00 01", true, "03 02 00 04");
        check("03 00 7b 00 01", true, "03 02 00 4d");
        check("03 00 6d 00 01", true, "03 02 00 03");
        // Quantity before address: 0 or 126 registers is 0x03, past the map 0x02.
        check("03 00 00 00 00", true, "83 03");
        check("03 00 00 00 7e", true, "83 03");
        check("03 01 2c 00 01", true, "83 02");
        check("03 00 af 00 7e", true, "83 03");
        check("03 00 b0 00 7d", true, "83 02");
        // FC6: ONLINE (3) takes 0/1; 2 is 0x03; a read-only register is 0x02.
        check("06 00 03 00 01", true, "06 00 03 00 01");
        check("06 00 03 00 02", true, "86 03");
        check("06 00 64 00 01", true, "86 02");
        // A client outside the write allow-list may only read.
        check("06 00 03 00 01", false, "86 01");
        check("10 00 03 00 01 02 00 01", false, "90 01");
        // FC16: ONLINE and EXPECTED_TYPE together; a byte count that is not twice the quantity
        // is 0x03; USER_DATA (5-6) takes any value; six registers from 3 reach reserved 8 (0x02).
        check("10 00 03 00 02 04 00 01 00 02", true, "10 00 03 00 02");
        check("10 00 03 00 02 03 00 01 00", true, "90 03");
        check("10 00 05 00 02 04 ff ff ff ff", true, "10 00 05 00 02");
        check("10 00 03 00 06 0c 00 01 00 02 00 00 00 00 00 01 00 00", true, "90 02");
        // JOB_REQUEST (7) takes 1..999: 0 and 1000 are 0x03; JOB_ID (121) is read-only.
        check("06 00 07 00 02", true, "06 00 07 00 02");
        check("06 00 07 00 00", true, "86 03");
        check("06 00 07 03 e8", true, "86 03");
        check("06 00 79 00 01", true, "86 02");
        // Functions the appliance does not serve.
        check("04 00 00 00 01", true, "84 01");
        check("17 00 64 00 01 00 00 00 01 02 00 00", true, "97 01");
        check("", true, "80 01");
    }
}
