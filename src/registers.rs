//! The PLC register map: one table, from which the handshake, the Modbus service, the tests and
//! `register-map.md` are derived. It is pure data near the bottom of the house: everything that
//! speaks to the PLC stands on it, and it imports nothing of theirs, only the estimator's words
//! (`Face`, `Reason`), to which it gives their numbers on the wire. Addresses are 0-based
//! protocol addresses (PLC tools show 400001 + address).

use crate::vision::{Face, Reason};

/// Who may write a register.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// Written by the PLC (FC6/FC16), read back as written.
    ReadWrite,
    /// Written by the appliance only; a PLC write is exception 0x02.
    ReadOnly,
}

/// How a register's 16 bits are to be read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// Unsigned 16 bits.
    U16,
    /// Signed 16 bits (two's complement).
    I16,
    /// Bit flags, named in `doc`.
    Bits,
    /// One half of an IEEE-754 float32 (word order per camera).
    F32,
    /// An unsigned 32-bit value in two words (word order per camera, as floats).
    U32,
}

impl Kind {
    /// Registers one value takes.
    pub const fn words(self) -> u16 {
        match self {
            Kind::F32 | Kind::U32 => 2,
            _ => 1,
        }
    }
}

/// One register (or the first word of a float).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Register {
    /// 0-based protocol address (PLC tools show 400001 + address).
    pub addr: u16,
    /// The name the PLC programmer and the document use.
    pub name: &'static str,
    /// Who writes it.
    pub access: Access,
    /// How its bits are read.
    pub kind: Kind,
    /// Scaling and unit, as a PLC programmer needs it.
    pub unit: &'static str,
    /// Values a PLC may write (None: any).
    pub allowed: Option<&'static [u16]>,
    /// The range a PLC may write, inclusive (None: any).
    pub range: Option<(u16, u16)>,
    /// What it means, for `register-map.md`.
    pub doc: &'static str,
    /// A code register's values and what each means (empty for others): the document lists
    /// them and the operator view shows the word beside the number, from this one list.
    pub codes: &'static [(u16, &'static str)],
}

/// Highest address of the map plus one; any address at or beyond is exception 0x02.
pub const SIZE: u16 = 300;
/// Value of MAP_VERSION: bumped when a PLC program written for the old map would break.
pub const MAP_VERSION: u16 = 4;

/// Register addresses by name. What each one means is its row of [`MAP`] (and
/// `register-map.md`, generated from it): a second description here would be a second truth
/// to drift, so these names carry none.
#[allow(missing_docs)]
pub mod addr {
    pub const TRIGGER: u16 = 0;
    pub const RESULT_ACK: u16 = 1;
    pub const CLEAR_ERROR: u16 = 2;
    pub const ONLINE: u16 = 3;
    pub const EXPECTED_TYPE: u16 = 4;
    pub const USER_DATA: u16 = 5;
    pub const JOB_REQUEST: u16 = 7;
    pub const STATUS: u16 = 100;
    pub const HEARTBEAT: u16 = 101;
    pub const ERROR_CODE: u16 = 102;
    pub const ACQ_COUNT: u16 = 103;
    pub const RESULTS_PENDING: u16 = 104;
    pub const OVERRUN_COUNT: u16 = 105;
    pub const MISSED_TRIGGERS: u16 = 106;
    pub const MAP_VERSION: u16 = 107;
    pub const LAST_CYCLE_TIME: u16 = 108;
    pub const TYPES_ENROLLED: u16 = 109;
    pub const ROBOT_STATUS: u16 = 110;
    pub const ROBOT_QUEUE: u16 = 111;
    pub const ROBOT_DELIVERED: u16 = 112;
    pub const ROBOT_ACK_TIMEOUTS: u16 = 113;
    pub const ROBOT_WRONG_ACKS: u16 = 114;
    pub const ROBOT_RECONNECTS: u16 = 115;
    pub const ROBOT_DROPPED: u16 = 116;
    pub const ROBOT_DATA_SEQ: u16 = 117;
    pub const ROBOT_ACK_SEQ: u16 = 118;
    pub const DEBRIS_COUNT: u16 = 119;
    pub const RESULT_ACK_IGNORED: u16 = 120;
    pub const JOB_ID: u16 = 121;
    pub const JOB_STATUS: u16 = 122;
    pub const BOOT_ID: u16 = 123;
    pub const RESULT_SEQ: u16 = 200;
    pub const ACQ_ID: u16 = 201;
    pub const DECISION: u16 = 202;
    pub const REASON: u16 = 203;
    pub const TYPE_ID: u16 = 204;
    pub const FACE: u16 = 205;
    pub const ANGLE: u16 = 206;
    pub const X: u16 = 207;
    pub const Y: u16 = 208;
    pub const CONFIDENCE: u16 = 209;
    pub const PART_INDEX: u16 = 210;
    pub const PART_COUNT: u16 = 211;
    pub const ANGLE_F32: u16 = 212;
    pub const X_F32: u16 = 214;
    pub const Y_F32: u16 = 216;
    pub const PROCESSING_TIME: u16 = 218;
    pub const RESULT_USER_DATA: u16 = 219;
    /// Last address of the result block.
    pub const RESULT_END: u16 = 220;
}

/// STATUS (100) bits.
pub mod status {
    /// A TRIGGER edge now starts an acquisition (ONLINE, CAMERA_OK, not BUSY, no ERROR, no job change).
    pub const READY: u16 = 1 << 0;
    /// The TRIGGER edge was taken; cleared when TRIGGER returns to 0.
    pub const TRIGGER_ACK: u16 = 1 << 1;
    /// An acquisition runs.
    pub const BUSY: u16 = 1 << 2;
    /// A result waits in the result block.
    pub const RESULT_VALID: u16 = 1 << 3;
    /// Results were dropped on a full queue since the last CLEAR_ERROR.
    pub const RESULT_OVERRUN: u16 = 1 << 4;
    /// A camera or frame fault; ERROR_CODE says which.
    pub const ERROR: u16 = 1 << 5;
    /// The camera takes triggers (the PLC's ONLINE).
    pub const ONLINE: u16 = 1 << 6;
    /// The camera delivers frames.
    pub const CAMERA_OK: u16 = 1 << 7;
    /// Bit names, bit 0 first, for the page and the document.
    pub const NAMES: [&str; 8] = ["READY", "TRIGGER_ACK", "BUSY", "RESULT_VALID", "RESULT_OVERRUN", "ERROR", "ONLINE", "CAMERA_OK"];
}

/// ROBOT_STATUS (110) bits.
pub mod robot_status {
    /// A robot link is configured for this camera.
    pub const CONFIGURED: u16 = 1 << 0;
    /// Its Modbus/TCP connection is up.
    pub const CONNECTED: u16 = 1 << 1;
    /// A part was written and its ack is awaited.
    pub const WAITING_ACK: u16 = 1 << 2;
    /// The last part's ack did not come in time (it is sent again).
    pub const ACK_TIMEOUT: u16 = 1 << 3;
    /// The robot program says it is ready for parts.
    pub const ROBOT_READY: u16 = 1 << 4;
    /// The robot program reports a fault.
    pub const ROBOT_FAULT: u16 = 1 << 5;
    /// Bit names, bit 0 first, for the page and the document.
    pub const NAMES: [&str; 6] = ["CONFIGURED", "CONNECTED", "WAITING_ACK", "ACK_TIMEOUT", "ROBOT_READY", "ROBOT_FAULT"];
}

/// JOB_STATUS (122) values.
pub mod job_status {
    /// No job change since start-up.
    pub const IDLE: u16 = 0;
    /// A job is being loaded (READY is 0).
    pub const CHANGING: u16 = 1;
    /// The last change put the job asked for in force.
    pub const DONE: u16 = 2;
    /// The last change failed; the job before it stays in force.
    pub const FAILED: u16 = 3;
}

/// ERROR_CODE (102) values.
pub mod error_code {
    /// No fault.
    pub const NONE: u16 = 0;
    /// The camera delivered no frame (source failed, timed out, or is gone).
    pub const CAMERA: u16 = 1;
    /// The frame could not be estimated (unreadable, wrong size or format).
    pub const FRAME: u16 = 2;
    /// The knowledge base could not be used.
    pub const KNOWLEDGE_BASE: u16 = 3;
}

use Access::*;
use Kind::*;

const BOOL: &[u16] = &[0, 1];

const fn reg(addr: u16, name: &'static str, access: Access, kind: Kind, unit: &'static str, doc: &'static str) -> Register {
    Register { addr, name, access, kind, unit, allowed: None, range: None, doc, codes: &[] }
}
/// A read-only code register: its values are `codes`, `doc` says the rest.
const fn coded(addr: u16, name: &'static str, codes: &'static [(u16, &'static str)], doc: &'static str) -> Register {
    Register { addr, name, access: ReadOnly, kind: U16, unit: "code", allowed: None, range: None, doc, codes }
}
const fn flag(addr: u16, name: &'static str, doc: &'static str) -> Register {
    Register { addr, name, access: ReadWrite, kind: U16, unit: "0/1", allowed: Some(BOOL), range: None, doc, codes: &[] }
}

/// REASON's value for a reason: the one place its number is written. A PLC program keys on
/// these numbers: a reason keeps its number for ever, and a new one takes the next.
pub const fn reason_code(r: Reason) -> u16 {
    match r {
        Reason::Ok => 0,
        Reason::NoPart => 1,
        Reason::UnknownType => 2,
        Reason::LowConfidence => 3,
        Reason::Ambiguous => 4,
        Reason::Touching => 5,
        Reason::WrongType => 6,
        Reason::FrameError => 7,
        Reason::AtBorder => 8,
        Reason::Covered => 9,
        Reason::NoClearance => 10,
    }
}

/// FACE's value: 1 up, 2 down, 0 when no face was found.
pub const fn face_code(f: Option<Face>) -> u16 {
    match f {
        None => 0,
        Some(Face::Up) => 1,
        Some(Face::Down) => 2,
    }
}

/// REASON's codes and words, in code order (the words are the estimator's, as the page shows them).
const REASON_CODES: [(u16, &str); Reason::ALL.len()] = {
    let mut out = [(0, ""); Reason::ALL.len()];
    let mut i = 0;
    while i < Reason::ALL.len() {
        let r = Reason::ALL[i];
        out[reason_code(r) as usize] = (reason_code(r), r.as_str());
        i += 1;
    }
    out
};

/// FACE's codes and words.
const FACE_CODES: [(u16, &str); 3] =
    [(face_code(None), "unknown"), (face_code(Some(Face::Up)), Face::Up.as_str()), (face_code(Some(Face::Down)), Face::Down.as_str())];

/// Every defined register, in address order. Addresses not listed below SIZE are reserved:
/// they read as 0 and refuse writes.
pub const MAP: &[Register] = &[
    flag(addr::TRIGGER, "TRIGGER", "0->1 edge starts one acquisition; hold 1 until TRIGGER_ACK, then write 0."),
    reg(
        addr::RESULT_ACK,
        "RESULT_ACK",
        ReadWrite,
        U16,
        "seq",
        "Write the RESULT_SEQ being consumed: the result is removed and the next shown. Other values are ignored and counted (RESULT_ACK_IGNORED).",
    ),
    flag(addr::CLEAR_ERROR, "CLEAR_ERROR", "Write 1: clears ERROR, ERROR_CODE and RESULT_OVERRUN. Reads 0."),
    flag(addr::ONLINE, "ONLINE", "1 online, 0 offline (triggers are missed). Start-up value from the configuration."),
    reg(
        addr::EXPECTED_TYPE,
        "EXPECTED_TYPE",
        ReadWrite,
        U16,
        "type id",
        "0 accepts any type; otherwise accepted parts of other types are rejected with REASON 6 (wrong type).",
    ),
    reg(
        addr::USER_DATA,
        "USER_DATA",
        ReadWrite,
        U32,
        "any",
        "The PLC's value for the next frame (e.g. its conveyor encoder count), latched at the TRIGGER edge (free-run: when the frame is taken) and returned with that frame's results in 219-220 and robot words 8-9. In one FC16 with TRIGGER, the new value is latched (every write of a request lands before the TRIGGER edge is taken).",
    ),
    Register {
        addr: addr::JOB_REQUEST,
        name: "JOB_REQUEST",
        access: ReadWrite,
        kind: U16,
        unit: "job id",
        allowed: None,
        range: Some((1, 999)),
        doc: "Write a job id (1..999; other values are exception 0x03) to switch the camera to that job: its knowledge base is (re)loaded, so writing the id in force again reloads it. JOB_STATUS tells the outcome. Reads back the last request (0 before any).",
        codes: &[],
    },
    reg(
        addr::STATUS,
        "STATUS",
        ReadOnly,
        Bits,
        "bits",
        "b0 READY (ONLINE and not BUSY and CAMERA_OK and not ERROR and no job change running: a TRIGGER edge now starts an acquisition), b1 TRIGGER_ACK, b2 BUSY, b3 RESULT_VALID, b4 RESULT_OVERRUN, b5 ERROR, b6 ONLINE, b7 CAMERA_OK.",
    ),
    reg(addr::HEARTBEAT, "HEARTBEAT", ReadOnly, U16, "count", "+1 every second (wraps)."),
    coded(addr::ERROR_CODE, "ERROR_CODE", &[(0, "none"), (1, "camera (no frame)"), (2, "frame (unusable)"), (3, "knowledge base")], ""),
    reg(
        addr::ACQ_COUNT,
        "ACQ_COUNT",
        ReadOnly,
        U16,
        "count",
        "Accepted triggers (wraps); a result's ACQ_ID is the ACQ_COUNT of its frame.",
    ),
    reg(addr::RESULTS_PENDING, "RESULTS_PENDING", ReadOnly, U16, "count", "Results queued, including the one shown."),
    reg(addr::OVERRUN_COUNT, "OVERRUN_COUNT", ReadOnly, U16, "count", "Results dropped because the queue was full (wraps)."),
    reg(
        addr::MISSED_TRIGGERS,
        "MISSED_TRIGGERS",
        ReadOnly,
        U16,
        "count",
        "Trigger edges while BUSY, offline or in ERROR: nothing started (wraps).",
    ),
    reg(addr::MAP_VERSION, "MAP_VERSION", ReadOnly, U16, "version", "4 (see \"Changes\" below)."),
    reg(
        addr::LAST_CYCLE_TIME,
        "LAST_CYCLE_TIME",
        ReadOnly,
        U16,
        "0.1 ms",
        "Trigger to results queued, last acquisition (saturates at 65535).",
    ),
    reg(addr::TYPES_ENROLLED, "TYPES_ENROLLED", ReadOnly, U16, "count", "Part types in the knowledge base."),
    reg(
        addr::ROBOT_STATUS,
        "ROBOT_STATUS",
        ReadOnly,
        Bits,
        "bits",
        "Robot link: b0 CONFIGURED, b1 CONNECTED, b2 WAITING_ACK, b3 ACK_TIMEOUT, b4 ROBOT_READY, b5 ROBOT_FAULT (b4 and b5 as last read from the robot, 0 while not connected).",
    ),
    reg(addr::ROBOT_QUEUE, "ROBOT_QUEUE", ReadOnly, U16, "count", "Parts waiting for the robot, including the one being handed over."),
    reg(addr::ROBOT_DELIVERED, "ROBOT_DELIVERED", ReadOnly, U16, "count", "Parts the robot acknowledged (wraps)."),
    reg(
        addr::ROBOT_ACK_TIMEOUTS,
        "ROBOT_ACK_TIMEOUTS",
        ReadOnly,
        U16,
        "count",
        "Times the robot did not acknowledge within ack_timeout_s (wraps).",
    ),
    reg(addr::ROBOT_WRONG_ACKS, "ROBOT_WRONG_ACKS", ReadOnly, U16, "count", "ACK_SEQ values that matched no part sent (ignored; wraps)."),
    reg(
        addr::ROBOT_RECONNECTS,
        "ROBOT_RECONNECTS",
        ReadOnly,
        U16,
        "count",
        "Connections to the robot controller made after the first (wraps).",
    ),
    reg(addr::ROBOT_DROPPED, "ROBOT_DROPPED", ReadOnly, U16, "count", "Parts not queued for the robot because its queue was full (wraps)."),
    reg(addr::ROBOT_DATA_SEQ, "ROBOT_DATA_SEQ", ReadOnly, U16, "seq", "Last DATA_SEQ written to the robot (0 none yet)."),
    reg(addr::ROBOT_ACK_SEQ, "ROBOT_ACK_SEQ", ReadOnly, U16, "seq", "Last ACK_SEQ read from the robot."),
    reg(
        addr::DEBRIS_COUNT,
        "DEBRIS_COUNT",
        ReadOnly,
        U16,
        "count",
        "Pieces of debris (bolts, washers, chips: material too small to be a part) in the last estimated frame; never part results.",
    ),
    reg(addr::RESULT_ACK_IGNORED, "RESULT_ACK_IGNORED", ReadOnly, U16, "count", "RESULT_ACK writes that named no pending result (wraps)."),
    reg(addr::JOB_ID, "JOB_ID", ReadOnly, U16, "job id", "The job in force (a camera without configured jobs: 1)."),
    coded(
        addr::JOB_STATUS,
        "JOB_STATUS",
        &[(0, "idle"), (1, "changing"), (2, "done"), (3, "failed")],
        "Idle: no request yet. While changing, READY is 0, triggers count as missed and queued results stay readable. Failed: the id is not configured or its knowledge base does not load; the job in force stays, and the reason is logged and shown on the operator view. Done and failed hold until the next request. A job with an expected_type writes it into EXPECTED_TYPE when it comes into force; the PLC may overwrite it afterwards.",
    ),
    reg(
        addr::BOOT_ID,
        "BOOT_ID",
        ReadOnly,
        U16,
        "id",
        "Random, non-zero, drawn at every start of the appliance. When it changes, the appliance restarted: queued results are gone and RESULT_SEQ, ACQ_COUNT and HEARTBEAT start again (see \"After a restart\").",
    ),
    reg(
        addr::RESULT_SEQ,
        "RESULT_SEQ",
        ReadOnly,
        U16,
        "seq",
        "Oldest unacknowledged result: 1..65535, wraps to 1; 0 when the queue is empty.",
    ),
    reg(addr::ACQ_ID, "ACQ_ID", ReadOnly, U16, "count", "ACQ_COUNT of the frame this result belongs to."),
    coded(
        addr::DECISION,
        "DECISION",
        &[(0, "none"), (1, "accept"), (2, "reject")],
        "0 when the queue is empty: the whole result block reads 0.",
    ),
    coded(addr::REASON, "REASON", &REASON_CODES, ""),
    reg(addr::TYPE_ID, "TYPE_ID", ReadOnly, U16, "type id", "0 when no type."),
    coded(addr::FACE, "FACE", &FACE_CODES, ""),
    reg(addr::ANGLE, "ANGLE", ReadOnly, I16, "0.01 deg", "-18000..17999, robot frame."),
    reg(addr::X, "X", ReadOnly, I16, "0.1 mm", "Robot frame (saturates at -32768/32767; the float copy is exact)."),
    reg(addr::Y, "Y", ReadOnly, I16, "0.1 mm", "Robot frame (saturates at -32768/32767; the float copy is exact)."),
    reg(addr::CONFIDENCE, "CONFIDENCE", ReadOnly, U16, "0.001", "0..1000."),
    reg(addr::PART_INDEX, "PART_INDEX", ReadOnly, U16, "index", "1..PART_COUNT in picking order; 0 for a no-part result."),
    reg(addr::PART_COUNT, "PART_COUNT", ReadOnly, U16, "count", "Parts in this frame (0 for a no-part result)."),
    reg(addr::ANGLE_F32, "ANGLE_F32", ReadOnly, F32, "deg", "ANGLE as float32, words 212-213."),
    reg(addr::X_F32, "X_F32", ReadOnly, F32, "mm", "X as float32, words 214-215."),
    reg(addr::Y_F32, "Y_F32", ReadOnly, F32, "mm", "Y as float32, words 216-217."),
    reg(addr::PROCESSING_TIME, "PROCESSING_TIME", ReadOnly, U16, "0.1 ms", "Estimate time of this result's frame (saturates)."),
    reg(
        addr::RESULT_USER_DATA,
        "RESULT_USER_DATA",
        ReadOnly,
        U32,
        "any",
        "USER_DATA as latched for this result's frame (every result of the frame, no-part and frame-error results too).",
    ),
];

/// The word a code register's value stands for (None: not a code register, or not a code).
pub fn code_word(r: &Register, value: u16) -> Option<&'static str> {
    r.codes.iter().find(|(v, _)| *v == value).map(|(_, w)| *w)
}

/// A register's description in the document: its codes, then what `doc` says.
fn description(r: &Register) -> String {
    let codes: Vec<String> = r.codes.iter().map(|(v, w)| format!("{v} {w}")).collect();
    match (codes.is_empty(), r.doc.is_empty()) {
        (true, _) => r.doc.to_string(),
        (false, true) => format!("{}.", codes.join(", ")),
        (false, false) => format!("{}. {}", codes.join(", "), r.doc),
    }
}

/// The register defined at `addr` (the second word of a two-word value returns the same entry).
pub fn lookup(addr: u16) -> Option<&'static Register> {
    MAP.iter().find(|r| addr >= r.addr && addr < r.addr + r.kind.words())
}

/// Whether `v` is a value a PLC may write to register `r` (its allowed values and range).
pub fn value_allowed(r: &Register, v: u16) -> bool {
    r.allowed.is_none_or(|ok| ok.contains(&v)) && r.range.is_none_or(|(lo, hi)| (lo..=hi).contains(&v))
}

/// Whether a PLC may write `addr`.
pub fn writable(addr: u16) -> bool {
    lookup(addr).is_some_and(|r| r.access == Access::ReadWrite)
}

fn kind_name(k: Kind) -> &'static str {
    match k {
        U16 => "uint16",
        I16 => "int16",
        Bits => "bits",
        F32 => "float32 (2 words)",
        U32 => "uint32 (2 words)",
    }
}

/// The register map as Markdown (the body of `register-map.md`).
pub fn markdown() -> String {
    let mut s = String::new();
    s.push_str("# lfi-bridge register map\n\n");
    s.push_str("Generated from `src/registers.rs` by `lfi-bridge register-map`; a test fails if this file and the table differ (refresh: `LFI_BLESS=1 cargo test --test register_map`).\n\n");
    s.push_str(&format!(
        "Holding registers, function codes 3 (read), 6 and 16 (write). MAP_VERSION = {MAP_VERSION}. \"Address\" is the 0-based protocol address; \"PLC\" the 1-based number PLC tools show (400001 + address). Addresses 0..{} not listed are reserved: they read as 0 and refuse writes (exception 0x02).\n\n",
        SIZE - 1
    ));
    s.push_str("Each camera is its own Modbus unit id (unit 0 and 255 reach the first camera; an unknown unit id gets exception 0x0B). Floats (IEEE-754) and uint32 values take two registers, high word first unless the camera's `float_word_order = \"low-first\"`. A read of 100..220 in one request is one consistent snapshot.\n\n");
    s.push_str("| Address | PLC | Name | Access | Type | Unit | Description |\n|---:|---:|---|---|---|---|---|\n");
    for r in MAP {
        let access = match r.access {
            ReadWrite => "R/W",
            ReadOnly => "R",
        };
        let address = if r.kind.words() == 2 { format!("{}-{}", r.addr, r.addr + 1) } else { r.addr.to_string() };
        let plc = if r.kind.words() == 2 {
            format!("{}-{}", 400_001 + r.addr as u32, 400_002 + r.addr as u32)
        } else {
            (400_001 + r.addr as u32).to_string()
        };
        s.push_str(&format!("| {address} | {plc} | {} | {access} | {} | {} | {} |\n", r.name, kind_name(r.kind), r.unit, description(r)));
    }
    s.push_str("\n## Exceptions\n\nChecked in the order of the Modbus specification: a unit id that is no camera gets 0x0B first; then function, quantity, address, value.\n\n");
    s.push_str("| Code | When |\n|---|---|\n");
    s.push_str(
        "| 0x01 Illegal function | a function other than 3, 6, 16; a write from a client not in `write_allow` (when set; logged) |\n",
    );
    s.push_str("| 0x03 Illegal data value | read quantity 0 or over 125; write quantity 0 or over 123; FC16 byte count not 2 x quantity; a malformed request |\n");
    s.push_str("| 0x02 Illegal data address | any address outside 0..299; a write to a read-only or reserved register |\n");
    s.push_str("| 0x03 Illegal data value | a value other than 0 or 1 written to TRIGGER, CLEAR_ERROR or ONLINE |\n");
    s.push_str("| 0x0B Gateway target failed | a unit id that is no camera |\n");
    s.push_str("\nFraming: a request whose MBAP length field claims more bytes than its function's own layout (FC3 and FC6: 5 PDU bytes; FC16: 6 plus its byte count) is cut where the function ends and answered 0x03, so the request behind it is not swallowed. Only one client should drive a camera's handshake (TRIGGER, RESULT_ACK, CLEAR_ERROR): two writers each consume results the other never sees, so set `write_allow` to the line PLC; a write from a second address is logged. A request must be complete within `frame_timeout_s` (3 s) of its first byte and a connection with no complete request for `idle_timeout_s` is closed; when all `max_connections` slots are taken, the connection silent longest (at least 1 s) is closed for the newcomer.\n");
    s.push_str("\n## After a restart\n\nBOOT_ID (123) is drawn anew at every start. A PLC keeps the last value it read; when it differs (or it was 0: the PLC itself restarted), the appliance restarted: results queued before are gone and will not come, RESULT_SEQ, ACQ_COUNT and HEARTBEAT count from the start again, EXPECTED_TYPE and USER_DATA read 0 and ONLINE reads its configured start value. Then: drop any result the PLC was waiting for (the part it belonged to is to be treated as not inspected: re-trigger or reject it), write EXPECTED_TYPE and ONLINE again, and continue the handshake from READY.\n");
    s.push_str("\n## Changes\n\n");
    s.push_str("MAP_VERSION 4 (from 3): jobs: JOB_REQUEST (7), JOB_ID (121) and JOB_STATUS (122) are new, and READY is also 0 while a job change runs. Every other address and meaning is unchanged: a MAP_VERSION 3 program that never writes JOB_REQUEST sees no difference (JOB_ID reads the start job, JOB_STATUS 0).\n\n");
    s.push_str("MAP_VERSION 3 (from 2): READY is now 0 while ERROR is set (it was 1, and a trigger then was missed: a PLC that waited only for READY triggered into an error); USER_DATA (5-6), BOOT_ID (123) and RESULT_USER_DATA (219-220, the result block now ends at 220) are new; robot input words 8-9 carry USER_DATA. A MAP_VERSION 2 program keeps working: it now waits at READY instead of losing a trigger while ERROR is set, and should clear ERROR (CLEAR_ERROR) when it sees it.\n\n");
    s.push_str("MAP_VERSION 2 (from 1): REASON gains 9 `covered` (another part lies partly on this one: grasping it would drag the one on top) and 10 `no clearance` (the gripper's keep-out footprint around the part holds other material); DEBRIS_COUNT (119) is new. Every other address and meaning is unchanged. A MAP_VERSION 1 program that treats any DECISION 2 as a reject keeps working; one that looks REASON up in a table of nine entries must grow it.\n");
    s
}

/// The robot link's state as shown in registers 110..118.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RobotView {
    /// ROBOT_STATUS bits (see [`robot_status`]).
    pub bits: u16,
    /// ROBOT_QUEUE: parts waiting for the robot.
    pub queue: u16,
    /// ROBOT_DELIVERED: parts the robot acknowledged.
    pub delivered: u16,
    /// ROBOT_ACK_TIMEOUTS.
    pub ack_timeouts: u16,
    /// ROBOT_WRONG_ACKS: acks of a sequence number not sent.
    pub wrong_acks: u16,
    /// ROBOT_RECONNECTS.
    pub reconnects: u16,
    /// ROBOT_DROPPED: parts dropped on a full robot queue.
    pub dropped: u16,
    /// ROBOT_DATA_SEQ: sequence number of the last part written.
    pub data_seq: u16,
    /// ROBOT_ACK_SEQ: the last ack read back.
    pub ack_seq: u16,
}

/// Robot-link bits for [`RobotView::bits`].
pub fn robot_bits(configured: bool, connected: bool, waiting: bool, timed_out: bool, ready: bool, fault: bool) -> u16 {
    let mut b = 0;
    for (on, bit) in [
        (configured, robot_status::CONFIGURED),
        (connected, robot_status::CONNECTED),
        (waiting, robot_status::WAITING_ACK),
        (timed_out, robot_status::ACK_TIMEOUT),
        (ready, robot_status::ROBOT_READY),
        (fault, robot_status::ROBOT_FAULT),
    ] {
        if on {
            b |= bit;
        }
    }
    b
}

/// Order of the two words of a float32 or uint32 (per camera: `float_word_order`, spelt
/// `"high-first"` or `"low-first"`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum WordOrder {
    /// The high word at the lower address (big-endian, Modicon's usual).
    #[default]
    HighFirst,
    /// The low word at the lower address (word-swapped).
    LowFirst,
}

/// A 32-bit value (a float's bits, a uint32) as two register words in `order`.
pub fn u32_words(v: u32, order: WordOrder) -> [u16; 2] {
    let (hi, lo) = ((v >> 16) as u16, v as u16);
    match order {
        WordOrder::HighFirst => [hi, lo],
        WordOrder::LowFirst => [lo, hi],
    }
}

/// The 32-bit value two register words in `order` hold (the inverse of [`u32_words`]).
pub fn u32_from_words(w: [u16; 2], order: WordOrder) -> u32 {
    let [first, second] = w.map(u32::from);
    match order {
        WordOrder::HighFirst => (first << 16) | second,
        WordOrder::LowFirst => (second << 16) | first,
    }
}

/// A value as an unsigned register word, rounded and saturated at 0..65535.
pub fn u16_word(v: f64) -> u16 {
    v.round().clamp(0.0, 65535.0) as u16
}

/// A value as a signed (two's complement) register word, rounded and saturated at
/// -32768..32767.
pub fn i16_word(v: f64) -> u16 {
    (v.round().clamp(-32768.0, 32767.0) as i16) as u16
}

/// A position in millimetres to X or Y: 0.1 mm, saturated.
pub fn mm_word(mm: f64) -> u16 {
    i16_word(mm * 10.0)
}

/// A confidence (0..1) to CONFIDENCE: 0.001, 0..1000.
pub fn confidence_word(c: f64) -> u16 {
    u16_word(c.clamp(0.0, 1.0) * 1000.0)
}

/// Milliseconds to PROCESSING_TIME: 0.1 ms, saturated.
pub fn tenth_ms_word(ms: f64) -> u16 {
    u16_word(ms * 10.0)
}

/// Angle in degrees to the ANGLE register: 0.01 deg, -18000..17999.
pub fn angle_word(deg: f64) -> u16 {
    let mut a = signed_deg(deg);
    if (a * 100.0).round() >= 18000.0 {
        a -= 360.0;
    }
    i16_word(a * 100.0)
}

/// Angle in degrees as ANGLE_F32 holds it: -180 <= a < 180, single precision.
pub fn angle_f32(deg: f64) -> f32 {
    signed_deg(deg) as f32
}

/// An angle in degrees as -180 <= a < 180.
fn signed_deg(deg: f64) -> f64 {
    (deg + 180.0).rem_euclid(360.0) - 180.0
}

/// The millimetres an X or Y word holds (what a PLC reads from [`mm_word`]).
pub fn mm_of_word(w: u16) -> f64 {
    w as i16 as f64 / 10.0
}

/// The confidence a CONFIDENCE word holds (what a PLC reads from [`confidence_word`]).
pub fn confidence_of_word(w: u16) -> f64 {
    w as f64 / 1000.0
}

/// The milliseconds a PROCESSING_TIME word holds.
pub fn ms_of_word(w: u16) -> f64 {
    w as f64 / 10.0
}

/// The face a FACE word names (None for 0 or a value that is no face).
pub fn face_of_code(w: u16) -> Option<Face> {
    [Face::Up, Face::Down].into_iter().find(|f| face_code(Some(*f)) == w)
}

/// A register's value as people read it, in its unit: scaled values, signed words, floats,
/// bits as a binary string. `words` are the register's words (the second only read for a
/// two-word value); `order` is the camera's word order for those.
pub fn value_text(r: &Register, words: [u16; 2], order: WordOrder) -> String {
    let w = words[0];
    let joined = u32_from_words(words, order);
    match (r.kind, r.unit) {
        (Kind::I16, "0.01 deg") => format!("{:.2} deg", angle_of_word(w)),
        (Kind::I16, "0.1 mm") => format!("{:.1} mm", mm_of_word(w)),
        (Kind::I16, _) => (w as i16).to_string(),
        (Kind::U16, "0.1 ms") => format!("{:.1} ms", ms_of_word(w)),
        (Kind::U16, "0.001") => format!("{:.3}", confidence_of_word(w)),
        (Kind::Bits, _) => format!("{w:08b}"),
        (Kind::F32, unit) => format!("{:.3} {unit}", f32::from_bits(joined)),
        (Kind::U32, _) => joined.to_string(),
        _ => w.to_string(),
    }
}

/// The degrees an ANGLE word holds (what a PLC reads from [`angle_word`]).
pub fn angle_of_word(w: u16) -> f64 {
    w as i16 as f64 / 100.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn angle_words_wrap_into_the_signed_range() {
        assert_eq!(angle_word(0.0), 0);
        assert_eq!(angle_word(90.0) as i16, 9000);
        assert_eq!(angle_word(270.0) as i16, -9000);
        assert_eq!(angle_word(180.0) as i16, -18000);
        assert_eq!(angle_word(179.996) as i16, -18000);
        assert_eq!(angle_word(179.99) as i16, 17999);
        assert_eq!(angle_word(-0.004) as i16, 0);
    }

    #[test]
    fn the_table_is_ordered_unique_and_inside_the_map() {
        for w in MAP.windows(2) {
            let end = w[0].addr + w[0].kind.words();
            assert!(end <= w[1].addr, "{} overlaps {}", w[0].name, w[1].name);
        }
        assert!(MAP.iter().all(|r| r.addr < SIZE));
        assert!(writable(addr::TRIGGER) && !writable(addr::STATUS) && !writable(8) && !writable(213));
        assert!(writable(addr::JOB_REQUEST) && !writable(addr::JOB_ID) && !writable(addr::JOB_STATUS));
        assert!(writable(5) && writable(6), "both words of USER_DATA");
        assert_eq!(lookup(213).unwrap().name, "ANGLE_F32");
        assert_eq!(lookup(220).unwrap().name, "RESULT_USER_DATA");
    }

    #[test]
    fn two_word_values_round_trip_in_either_order() {
        for order in [WordOrder::HighFirst, WordOrder::LowFirst] {
            for v in [0, 1, 0x1234_5678, u32::MAX] {
                assert_eq!(u32_from_words(u32_words(v, order), order), v, "{order:?}");
            }
        }
        assert_eq!(u32_words(0x1234_5678, WordOrder::HighFirst), [0x1234, 0x5678]);
        assert_eq!(u32_words(0x1234_5678, WordOrder::LowFirst), [0x5678, 0x1234]);
    }
}
