//! Handing accepted parts to a FANUC robot controller over Modbus/TCP.
//!
//! The controller is the Modbus server: the appliance writes its input words (group inputs on
//! the robot side) and reads its output words. [`Link`] is the protocol as a plain state machine
//! (connection events, polled outputs and the time in; writes out), tested without sockets;
//! [`link`] drives it with a tokio-modbus client.

pub mod link;

use std::collections::VecDeque;
use std::time::Duration;

use crate::handshake::{PartResult, Queued, WordOrder};
use crate::registers::{RobotView, angle_word, confidence_word, mm_word, robot_bits, u32_words};

/// Robot input words (offsets from `input_words_at`), written by the appliance.
pub mod input {
    /// Sequence number of the part in words 1..=9 (written last, so the robot never reads half a part).
    pub const DATA_SEQ: u16 = 0;
    /// The part's TYPE_ID.
    pub const TYPE_ID: u16 = 1;
    /// FACE: 1 up, 2 down.
    pub const FACE: u16 = 2;
    /// Angle, 0.01 degree.
    pub const ANGLE: u16 = 3;
    /// x, 0.1 mm (signed).
    pub const X: u16 = 4;
    /// y, 0.1 mm (signed).
    pub const Y: u16 = 5;
    /// Confidence, 0.1 %.
    pub const CONFIDENCE: u16 = 6;
    /// +1 every poll: the robot can tell the link is alive.
    pub const HEARTBEAT: u16 = 7;
    /// USER_DATA of the part's frame (two words, the camera's word order).
    pub const USER_DATA: u16 = 8;
    /// Input words used.
    pub const COUNT: u16 = 10;
}

/// Robot output words (offsets from `output_words_at`), read by the appliance.
pub mod output {
    /// Bit 0 READY, bit 1 FAULT.
    pub const STATUS: u16 = 0;
    /// The DATA_SEQ the robot has taken.
    pub const ACK_SEQ: u16 = 1;
    /// Output words read.
    pub const COUNT: u16 = 2;
    /// STATUS bit 0: ready for a part.
    pub const READY: u16 = 1 << 0;
    /// STATUS bit 1: fault.
    pub const FAULT: u16 = 1 << 1;
}

/// The robot words as Markdown (appended to `register-map.md`).
pub fn markdown() -> String {
    let mut s = String::new();
    s.push_str("\n# Robot link (FANUC controller as Modbus/TCP server)\n\n");
    s.push_str("Per camera, `[camera.robot]` makes the appliance a Modbus/TCP client of the robot controller. It writes the controller's *input words* (group inputs on the robot, rack 96) at `input_words_at` and reads its *output words* at `output_words_at` (FC3, or FC4 with `output_function = 4`). Offsets below are from those bases. Signed values are two's complement; the controller's group inputs are unsigned, so a TP program recovers them with `R = GI - (GI DIV 32768) * 65536` (see `docs/fanuc/LFI_PICK.LS`).\n\n");
    s.push_str("| Offset | Input word (written by the appliance) | Type | Unit |\n|---:|---|---|---|\n");
    for (o, name, ty, unit) in [
        (input::DATA_SEQ, "DATA_SEQ: 1..65535, wraps to 1; written last, alone", "uint16", "seq"),
        (input::TYPE_ID, "TYPE_ID (0 for a rejected part, sent only with `send = \"all\"`: never pick it)", "uint16", "type id"),
        (input::FACE, "FACE: 1 up, 2 down", "uint16", "code"),
        (input::ANGLE, "ANGLE, robot frame", "int16", "0.01 deg"),
        (input::X, "X, robot frame", "int16", "0.1 mm"),
        (input::Y, "Y, robot frame", "int16", "0.1 mm"),
        (input::CONFIDENCE, "CONFIDENCE (0 for a rejected part)", "uint16", "0.001"),
        (input::HEARTBEAT, "HEARTBEAT: +1 per second while connected", "uint16", "count"),
        (
            input::USER_DATA,
            "USER_DATA (words 8-9): the PLC's USER_DATA latched with the part's frame (e.g. the conveyor encoder count, for line tracking); high word first unless the camera's `float_word_order = \"low-first\"`",
            "uint32",
            "any",
        ),
    ] {
        s.push_str(&format!("| {o} | {name} | {ty} | {unit} |\n"));
    }
    s.push_str("\n| Offset | Output word (read by the appliance) | Meaning |\n|---:|---|---|\n");
    s.push_str("| 0 | STATUS | b0 ready for a part, b1 fault |\n| 1 | ACK_SEQ | the DATA_SEQ the robot program has taken |\n");
    s.push_str("\nHandover: words 1..9 are written in one FC16 request, then DATA_SEQ alone in a second request, so the robot never acts on half-written data. The next part is written only after ACK_SEQ equals the last DATA_SEQ and STATUS b0 is set. After any (re)connection the appliance reads ACK_SEQ before writing anything: a part acknowledged meanwhile counts as delivered, one that was not is written again with the same DATA_SEQ, so nothing is lost or handed over twice. On a fresh start DATA_SEQ continues from the robot's ACK_SEQ. The robot link's queue is separate from the PLC's (RESULT_ACK does not consume robot parts, nor the robot PLC results); its state is in registers 110..118 above.\n");
    s
}

/// Words 1..=6 for a part (TYPE_ID .. CONFIDENCE; the driver appends HEARTBEAT). A rejected
/// part (sent only with `send = "all"`) carries TYPE_ID 0 and CONFIDENCE 0: never a pick
/// instruction.
pub fn part_words(p: &PartResult) -> [u16; 6] {
    let (type_id, conf) = if p.accepted { (p.type_id, confidence_word(p.confidence)) } else { (0, 0) };
    [type_id, p.face, angle_word(p.angle_deg), mm_word(p.x_mm), mm_word(p.y_mm), conf]
}

/// What the driver must do next.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Action {
    /// Write words 1..=9 (the part's six, the heartbeat and USER_DATA, one FC16), then
    /// DATA_SEQ alone (a second request), so the robot never acts on half-written data.
    Send {
        /// DATA_SEQ of the part.
        seq: u16,
        /// Words 1..=9.
        words: [u16; 9],
    },
    /// Write HEARTBEAT alone.
    Heartbeat {
        /// The heartbeat word.
        value: u16,
    },
    /// The robot has not acknowledged DATA_SEQ `seq` within the ack timeout (`waited` so far):
    /// the part stays in flight; say so once.
    ReportAckTimeout {
        /// The DATA_SEQ awaiting its ack.
        seq: u16,
        /// Time since it was written.
        waited: Duration,
    },
}

fn next_seq(s: u16) -> u16 {
    if s == u16::MAX { 1 } else { s + 1 }
}

/// HEARTBEAT advances once per second while connected.
const HEARTBEAT_PERIOD: Duration = Duration::from_secs(1);

/// The robot link's protocol state, sans I/O: connection events, the robot's outputs and the
/// time go in (time only as an argument, so tests run it on a virtual clock); the writes to
/// perform come out. Like a QUIC connection's state machine, it says when it next needs the
/// time ([`Link::poll_timeout`]) and acts on it ([`Link::handle_timeout`]).
#[derive(Debug, Clone)]
pub struct Link {
    /// Final results as the PLC got them (the part and its frame's USER_DATA).
    queue: VecDeque<Queued>,
    depth: usize,
    word_order: WordOrder,
    ack_timeout: Duration,
    connected: bool,
    /// Outputs read since the last (re)connection: nothing is written before.
    synced: bool,
    /// Sequence of the last part written (0: none since start).
    last_seq: u16,
    /// The part written and not yet acknowledged, when it was written, and whether it must be
    /// written again (the connection dropped before we knew it arrived).
    in_flight: Option<(u16, Queued, Duration, bool)>,
    last_ack: Option<u16>,
    robot_ready: bool,
    robot_fault: bool,
    timed_out: bool,
    view: RobotView,
    first_connection: bool,
    heartbeat: u16,
    /// When HEARTBEAT is next due (while connected).
    next_beat: Option<Duration>,
}

impl Link {
    /// A link with room for `depth` parts waiting, acks expected within `ack_timeout`.
    pub fn new(depth: usize, ack_timeout: Duration, word_order: WordOrder) -> Self {
        Self {
            queue: VecDeque::new(),
            depth,
            word_order,
            ack_timeout,
            connected: false,
            synced: false,
            last_seq: 0,
            in_flight: None,
            last_ack: None,
            robot_ready: false,
            robot_fault: false,
            timed_out: false,
            view: RobotView::default(),
            first_connection: true,
            heartbeat: 0,
            next_beat: None,
        }
    }

    /// Queues a part for the robot; false (and counted) when the queue is full.
    pub fn enqueue(&mut self, p: Queued) -> bool {
        if self.queue.len() + self.in_flight.is_some() as usize >= self.depth {
            self.view.dropped = self.view.dropped.wrapping_add(1);
            return false;
        }
        self.queue.push_back(p);
        true
    }

    /// Connected at `now`: the first heartbeat is due at once.
    pub fn on_connected(&mut self, now: Duration) {
        if !self.first_connection {
            self.view.reconnects = self.view.reconnects.wrapping_add(1);
        }
        self.first_connection = false;
        self.connected = true;
        self.synced = false;
        self.next_beat = Some(now);
    }

    /// The connection dropped: whatever was in flight must be confirmed (or re-sent) once the
    /// outputs have been read again.
    pub fn on_disconnected(&mut self) {
        self.connected = false;
        self.synced = false;
        self.next_beat = None;
        if let Some(f) = self.in_flight.as_mut() {
            f.3 = true;
        }
    }

    /// A write of a part failed midway: send it again once connected.
    pub fn on_send_failed(&mut self) {
        if let Some(f) = self.in_flight.as_mut() {
            f.3 = true;
        }
    }

    /// The robot's outputs were read at `now`; returns what to write, if anything.
    pub fn on_outputs(&mut self, status: u16, ack: u16, now: Duration) -> Option<Action> {
        self.robot_ready = status & output::READY != 0;
        self.robot_fault = status & output::FAULT != 0;
        let first_read = !self.synced;
        self.synced = true;
        if self.last_seq == 0 && self.in_flight.is_none() {
            // Continue the robot's numbering: a DATA_SEQ equal to its last ACK_SEQ would look
            // already handled.
            self.last_seq = ack;
        }
        if let Some((seq, _, _, _)) = &self.in_flight {
            if ack == *seq {
                self.in_flight = None;
                self.timed_out = false;
                self.view.delivered = self.view.delivered.wrapping_add(1);
            } else if self.last_ack != Some(ack) && !first_read {
                // ACK_SEQ moved to a value that is not the part in flight: stale or wrong.
                self.view.wrong_acks = self.view.wrong_acks.wrapping_add(1);
            }
        } else if self.last_ack.is_some() && self.last_ack != Some(ack) && ack != self.last_seq {
            self.view.wrong_acks = self.view.wrong_acks.wrapping_add(1);
        }
        self.last_ack = Some(ack);
        self.view.ack_seq = ack;
        if let Some((seq, p, _, resend)) = self.in_flight.clone() {
            if resend {
                if let Some(f) = self.in_flight.as_mut() {
                    f.3 = false;
                }
                return Some(Action::Send { seq, words: self.words(&p) });
            }
            return None;
        }
        if !self.robot_ready || self.robot_fault {
            return None;
        }
        let p = self.queue.pop_front()?;
        let seq = next_seq(self.last_seq);
        self.last_seq = seq;
        self.view.data_seq = seq;
        let words = self.words(&p);
        self.in_flight = Some((seq, p, now, false));
        Some(Action::Send { seq, words })
    }

    fn words(&self, q: &Queued) -> [u16; 9] {
        let w = part_words(&q.part);
        let [u0, u1] = u32_words(q.user_data, self.word_order);
        [w[0], w[1], w[2], w[3], w[4], w[5], self.heartbeat, u0, u1]
    }

    /// The next moment the link needs [`Link::handle_timeout`]: the in-flight part's ack
    /// deadline (until it has passed once) or the next heartbeat, whichever comes first.
    pub fn poll_timeout(&self) -> Option<Duration> {
        let ack = self.in_flight.as_ref().filter(|_| !self.timed_out).map(|f| f.2 + self.ack_timeout);
        match (ack, self.next_beat) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// The time is `now`: flags an overdue acknowledgement (once per part) and advances the
    /// heartbeat when it is due.
    pub fn handle_timeout(&mut self, now: Duration) -> Vec<Action> {
        let mut out = Vec::new();
        if let Some((seq, _, sent, _)) = &self.in_flight
            && !self.timed_out
            && now.saturating_sub(*sent) > self.ack_timeout
        {
            self.timed_out = true;
            self.view.ack_timeouts = self.view.ack_timeouts.wrapping_add(1);
            out.push(Action::ReportAckTimeout { seq: *seq, waited: now.saturating_sub(*sent) });
        }
        if let Some(due) = self.next_beat
            && now >= due
        {
            self.heartbeat = self.heartbeat.wrapping_add(1);
            // Catch up without a burst after a stall: the next beat a period from now.
            self.next_beat = Some(if now - due >= HEARTBEAT_PERIOD { now + HEARTBEAT_PERIOD } else { due + HEARTBEAT_PERIOD });
            out.push(Action::Heartbeat { value: self.heartbeat });
        }
        out
    }

    /// The connection is up, as last reported by the driver.
    pub fn connected(&self) -> bool {
        self.connected
    }
    /// Parts waiting or in flight.
    pub fn pending(&self) -> usize {
        self.queue.len() + self.in_flight.is_some() as usize
    }

    /// The state for registers 110..118.
    pub fn view(&self) -> RobotView {
        let mut v = self.view;
        // What the robot said holds only while connected: after a loss it is not known.
        let (ready, fault) = (self.connected && self.robot_ready, self.connected && self.robot_fault);
        v.bits = robot_bits(true, self.connected, self.in_flight.is_some(), self.timed_out, ready, fault);
        v.queue = self.pending().min(65535) as u16;
        v
    }
}
