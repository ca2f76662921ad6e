//! Modbus/TCP framing (the MBAP header) for the server side.
//!
//! tokio-modbus 0.17 keeps its server codec private and answers an FC16 whose byte count is not
//! twice its quantity by closing the connection, where the specification wants exception 0x03;
//! its `serve` loop also ends, dropping every session, on the first failed `accept`. The appliance
//! therefore frames requests itself, checks the request shape, and hands the PDU to
//! tokio-modbus's public request decoder.

use tokio_modbus::{ExceptionCode, Request, Response};

/// MBAP header length (transaction, protocol, length, unit).
pub const HEADER: usize = 7;
/// Largest length field accepted. The specification's largest PDU (253 bytes) plus the unit id
/// makes 254; somewhat longer frames are still framed so that, say, an FC16 of 124 registers
/// gets its exception 0x03 instead of a closed connection.
pub const MAX_LENGTH: usize = 512;

/// One framed request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Adu {
    /// The MBAP transaction id, echoed in the response.
    pub transaction: u16,
    /// The unit id (the camera).
    pub unit: u8,
    /// Function code and data.
    pub pdu: Vec<u8>,
    /// The length field claimed more bytes than the function's own layout holds: the frame was
    /// cut where the function says it ends (so the next request is not swallowed as its tail),
    /// and is answered with exception 0x03.
    pub overlong: bool,
}

/// Where a request PDU ends by its own layout, for the functions the appliance serves (FC3 and
/// FC6 are five bytes; FC16 six plus its byte count), once enough of it is there to tell.
fn own_length(pdu: &[u8]) -> Option<usize> {
    match *pdu.first()? {
        0x03 | 0x06 => Some(5),
        0x10 => pdu.get(5).map(|count| 6 + *count as usize),
        _ => None,
    }
}

/// Why the byte stream cannot be framed (the connection must be closed: its boundaries are lost).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// A protocol id other than 0 (not Modbus).
    #[error("protocol id {0} is not Modbus (0)")]
    Protocol(u16),
    /// A length field outside 2..=254.
    #[error("length field {0} is outside 2..=512")]
    Length(u16),
}

/// Takes one complete request off the front of `buf`, if there is one.
pub fn decode(buf: &mut Vec<u8>) -> Result<Option<Adu>, FrameError> {
    if buf.len() < HEADER {
        return Ok(None);
    }
    let protocol = u16::from_be_bytes([buf[2], buf[3]]);
    if protocol != 0 {
        return Err(FrameError::Protocol(protocol));
    }
    let len = u16::from_be_bytes([buf[4], buf[5]]);
    if !(2..=MAX_LENGTH as u16).contains(&len) {
        return Err(FrameError::Length(len));
    }
    let declared = len as usize - 1;
    let (transaction, unit) = (u16::from_be_bytes([buf[0], buf[1]]), buf[6]);
    if let Some(own) = own_length(&buf[HEADER..])
        && own < declared
        && buf.len() >= HEADER + own
    {
        let adu = Adu { transaction, unit, pdu: buf[HEADER..HEADER + own].to_vec(), overlong: true };
        buf.drain(..HEADER + own);
        return Ok(Some(adu));
    }
    let total = HEADER + declared;
    if buf.len() < total {
        return Ok(None);
    }
    let adu = Adu { transaction, unit, pdu: buf[HEADER..total].to_vec(), overlong: false };
    buf.drain(..total);
    Ok(Some(adu))
}

/// Parses a request PDU. Functions other than 3, 6 and 16 are 0x01 whatever their body; a
/// malformed body of those three is 0x03 (so is an FC16 byte count that is not 2 x quantity).
pub fn parse_request(pdu: &[u8]) -> Result<Request<'static>, ExceptionCode> {
    let Some(&fc) = pdu.first() else { return Err(ExceptionCode::IllegalFunction) };
    let ok = match fc {
        0x03 | 0x06 => pdu.len() == 5,
        0x10 => {
            pdu.len() >= 6 && {
                let qty = u16::from_be_bytes([pdu[3], pdu[4]]) as usize;
                let count = pdu[5] as usize;
                // Quantity limits are the service's (it checks them before addresses); here the
                // frame must merely be consistent, which also keeps 2 x quantity from overflowing.
                count == 2 * qty && pdu.len() == 6 + count
            }
        }
        _ => return Err(ExceptionCode::IllegalFunction),
    };
    if !ok {
        return Err(ExceptionCode::IllegalDataValue);
    }
    Request::try_from(tokio_modbus::bytes::Bytes::copy_from_slice(pdu)).map_err(|_| ExceptionCode::IllegalDataValue)
}

/// Encodes a response ADU.
pub fn encode(transaction: u16, unit: u8, fc: u8, result: &Result<Response, ExceptionCode>) -> Vec<u8> {
    let mut pdu = Vec::with_capacity(8);
    match result {
        Ok(Response::ReadHoldingRegisters(words)) => {
            pdu.push(0x03);
            pdu.push((words.len() * 2) as u8);
            for w in words {
                pdu.extend_from_slice(&w.to_be_bytes());
            }
        }
        Ok(Response::WriteSingleRegister(a, v)) => {
            pdu.push(0x06);
            pdu.extend_from_slice(&a.to_be_bytes());
            pdu.extend_from_slice(&v.to_be_bytes());
        }
        Ok(Response::WriteMultipleRegisters(a, q)) => {
            pdu.push(0x10);
            pdu.extend_from_slice(&a.to_be_bytes());
            pdu.extend_from_slice(&q.to_be_bytes());
        }
        Ok(_) => {
            // The service produces no other response; answer as a device failure rather than panic.
            pdu.push(fc | 0x80);
            pdu.push(u8::from(ExceptionCode::ServerDeviceFailure));
        }
        Err(e) => {
            pdu.push(fc | 0x80);
            pdu.push(u8::from(*e));
        }
    }
    let mut out = Vec::with_capacity(HEADER + pdu.len());
    out.extend_from_slice(&transaction.to_be_bytes());
    out.extend_from_slice(&0u16.to_be_bytes());
    out.extend_from_slice(&((pdu.len() + 1) as u16).to_be_bytes());
    out.push(unit);
    out.extend_from_slice(&pdu);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_split_and_joined_requests() {
        let one = [0x00, 0x01, 0, 0, 0, 6, 1, 0x03, 0, 100, 0, 2];
        let mut buf = one[..5].to_vec();
        assert_eq!(decode(&mut buf), Ok(None));
        buf.extend_from_slice(&one[5..]);
        buf.extend_from_slice(&one);
        let a = decode(&mut buf).unwrap().unwrap();
        assert_eq!((a.transaction, a.unit, a.pdu.as_slice()), (1, 1, &[0x03, 0, 100, 0, 2][..]));
        assert!(decode(&mut buf).unwrap().is_some());
        assert!(buf.is_empty());
        assert_eq!(decode(&mut vec![0, 1, 0, 5, 0, 6, 1, 3, 0, 0, 0, 1]), Err(FrameError::Protocol(5)));
        assert_eq!(decode(&mut vec![0, 1, 0, 0, 0xff, 0xff, 1]), Err(FrameError::Length(0xffff)));
    }

    /// A length field longer than the request: the frame ends where its function says, and the
    /// next request right behind it is framed on its own, not swallowed.
    #[test]
    fn an_overlong_length_field_does_not_swallow_the_next_request() {
        let long = [0, 1, 0, 0, 0, 40, 1, 0x03, 0, 100, 0, 2];
        let next = [0, 2, 0, 0, 0, 6, 1, 0x03, 0, 107, 0, 1];
        let mut buf = [&long[..], &next[..]].concat();
        let a = decode(&mut buf).unwrap().unwrap();
        assert_eq!((a.transaction, a.overlong, a.pdu.len()), (1, true, 5));
        let b = decode(&mut buf).unwrap().unwrap();
        assert_eq!((b.transaction, b.overlong, b.pdu.as_slice()), (2, false, &[0x03, 0, 107, 0, 1][..]));
        // FC16: its byte count says where it ends.
        let mut buf = vec![0, 3, 0, 0, 0, 30, 1, 0x10, 0, 3, 0, 1, 2, 0, 1];
        let c = decode(&mut buf).unwrap().unwrap();
        assert_eq!((c.overlong, c.pdu.len(), buf.len()), (true, 8, 0));
    }

    #[test]
    fn request_shapes_map_to_exceptions() {
        assert_eq!(parse_request(&[0x03, 0, 100, 0, 10]), Ok(Request::ReadHoldingRegisters(100, 10)));
        assert_eq!(parse_request(&[0x04, 0, 0, 0, 1]), Err(ExceptionCode::IllegalFunction));
        assert_eq!(parse_request(&[0x2b, 0x0e]), Err(ExceptionCode::IllegalFunction));
        assert_eq!(parse_request(&[]), Err(ExceptionCode::IllegalFunction));
        assert_eq!(parse_request(&[0x03, 0, 100]), Err(ExceptionCode::IllegalDataValue));
        // FC16 byte count not 2 x quantity, and a quantity whose double overflows 16 bits.
        assert_eq!(parse_request(&[0x10, 0, 0, 0, 2, 3, 0, 1, 0]), Err(ExceptionCode::IllegalDataValue));
        assert_eq!(parse_request(&[0x10, 0, 0, 0x80, 0x00, 0]), Err(ExceptionCode::IllegalDataValue));
        assert!(parse_request(&[0x10, 0, 0, 0, 1, 2, 0, 1]).is_ok());
    }

    /// tokio-modbus's own decoder, handed the overflowing FC16 directly, must not panic in this
    /// (debug) profile: Cargo.toml turns its overflow checks off.
    #[test]
    fn tokio_modbus_decoder_survives_a_quantity_of_0x8000() {
        let pdu = tokio_modbus::bytes::Bytes::from_static(&[0x10, 0, 0, 0x80, 0x00, 0]);
        assert!(Request::try_from(pdu).is_err());
    }

    #[test]
    fn encodes_responses_and_exceptions() {
        let r = encode(7, 1, 3, &Ok(Response::ReadHoldingRegisters(vec![0x0102, 0x0304])));
        assert_eq!(r, vec![0, 7, 0, 0, 0, 7, 1, 3, 4, 1, 2, 3, 4]);
        let e = encode(7, 2, 0x10, &Err(ExceptionCode::IllegalDataAddress));
        assert_eq!(e, vec![0, 7, 0, 0, 0, 3, 2, 0x90, 0x02]);
    }
}
