//! The PLC handshake of one camera as a plain state machine: register writes and camera events
//! in, register contents and commands out. No sockets, no clock: the caller passes the time.
//!
//! The protocol is the smart-camera one controls engineers know: TRIGGER -> TRIGGER_ACK + BUSY
//! -> results queued -> BUSY clears; RESULT_VALID while the queue holds results; RESULT_ACK =
//! RESULT_SEQ pops the oldest. `register-map.md` documents every register.

use std::collections::VecDeque;
use std::time::Duration;

use crate::registers::{self as map, RobotView, addr, error_code, status, u16_word, u32_from_words, u32_words};
pub use crate::registers::{WordOrder, job_status};
use crate::vision::Reason;

/// One part's result as the PLC sees it, in the robot frame.
#[derive(Debug, Clone, PartialEq)]
pub struct PartResult {
    /// The robot may pick it.
    pub accepted: bool,
    /// Why not, when it may not (REASON).
    pub reason: Reason,
    /// TYPE_ID: the enrolled type's id, 0 unknown.
    pub type_id: u16,
    /// 0 unknown, 1 up, 2 down.
    pub face: u16,
    /// Rotation of the part from its template, degrees in [0, 360).
    pub angle_deg: f64,
    /// Position in the robot frame, millimetres.
    pub x_mm: f64,
    /// Position in the robot frame, millimetres.
    pub y_mm: f64,
    /// 0..1: the line features' agreement.
    pub confidence: f64,
}

/// What became of an acquisition.
#[derive(Debug, Clone, PartialEq)]
pub enum Outcome {
    /// The frame was estimated; parts in the order the estimator found them (empty: no part on
    /// the belt). [`Handshake::complete`] puts them into picking order.
    Parts {
        /// The frame's parts.
        parts: Vec<PartResult>,
        /// Trigger-to-estimate time, for PROCESSING_TIME.
        processing_ms: f64,
    },
    /// No frame, or an unusable one.
    Failed {
        /// Camera or frame: ERROR_CODE follows from it.
        fault: Fault,
    },
}

/// Why an acquisition gave no frame to estimate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fault {
    /// The camera gave no frame (ERROR_CODE 1).
    Camera,
    /// A frame came and could not be used (ERROR_CODE 2).
    Frame,
}

impl Fault {
    /// The ERROR_CODE register's value for it.
    pub fn code(self) -> u16 {
        match self {
            Fault::Camera => error_code::CAMERA,
            Fault::Frame => error_code::FRAME,
        }
    }
}

/// What the appliance must do after an event.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// Take a frame and report it with [`Handshake::complete`] under this acquisition id.
    Acquire {
        /// The acquisition id (ACQ_ID of its results).
        acq_id: u16,
    },
    /// Load job `id` and report with [`Handshake::job_changed`].
    ChangeJob {
        /// The job id the PLC wrote to JOB_REQUEST.
        id: u16,
    },
}

/// How a job change ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JobOutcome {
    /// The job is in force; its expected type (if it has one) goes into EXPECTED_TYPE.
    InForce {
        /// Its EXPECTED_TYPE, if the job sets one.
        expected_type: Option<u16>,
    },
    /// Not configured, or its knowledge base would not load: the job in force stays.
    Failed,
}

/// Order of a frame's parts in the result queue: accepted parts first (after the
/// expected-type rule), each group in this order. Spelt in the configuration `"x-ascending"`,
/// `"x-descending"`, `"y-ascending"`, `"y-descending"`, `"confidence"`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PickingOrder {
    /// Smallest robot-frame x first.
    #[default]
    XAscending,
    /// Largest robot-frame x first.
    XDescending,
    /// Smallest robot-frame y first.
    YAscending,
    /// Largest robot-frame y first.
    YDescending,
    /// Most confident first.
    Confidence,
}

impl PickingOrder {
    /// The order of two parts of the same group (accepted or not).
    pub fn compare(&self, a: &PartResult, b: &PartResult) -> std::cmp::Ordering {
        match self {
            PickingOrder::XAscending => a.x_mm.total_cmp(&b.x_mm),
            PickingOrder::XDescending => b.x_mm.total_cmp(&a.x_mm),
            PickingOrder::YAscending => a.y_mm.total_cmp(&b.y_mm),
            PickingOrder::YDescending => b.y_mm.total_cmp(&a.y_mm),
            PickingOrder::Confidence => b.confidence.total_cmp(&a.confidence),
        }
    }
}

/// A result of an acquisition, as queued for the PLC (`seq` 0: the queue was full, dropped).
#[derive(Debug, Clone, PartialEq)]
pub struct Queued {
    /// RESULT_SEQ: 1..=65535, wrapping past 0.
    pub seq: u16,
    /// ACQ_ID of the frame it came from.
    pub acq_id: u16,
    /// The part.
    pub part: PartResult,
    /// 1-based index in picking order; 0 (with `count` 0) for a no-part or frame-error result.
    pub index: u16,
    /// PART_COUNT: parts of the frame.
    pub count: u16,
    /// PROCESSING_TIME of the frame, ms.
    pub processing_ms: f64,
    /// USER_DATA as latched when the frame was taken.
    pub user_data: u32,
    /// Position of the part in the [`Outcome::Parts`] it came from (None: no-part or frame
    /// error), so that a shell can pair the final result with its estimate.
    pub detection: Option<usize>,
}

impl Queued {
    /// A part on the belt, as opposed to a no-part or frame-error result.
    pub fn is_part(&self) -> bool {
        self.index > 0
    }
}

/// Counters the operator sees beside the registers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Counters {
    /// Acquisitions started (ACQ_COUNT).
    pub acquisitions: u64,
    /// Results queued.
    pub results: u64,
    /// Results dropped on a full queue (OVERRUN_COUNT).
    pub dropped: u64,
    /// TRIGGER edges while not READY (MISSED_TRIGGERS).
    pub missed_triggers: u64,
    /// RESULT_ACK writes that matched no waiting result (RESULT_ACK_IGNORED).
    pub ignored_acks: u64,
}

/// Settings of one camera's handshake.
#[derive(Debug, Clone)]
pub struct Settings {
    /// Results queued at most; beyond, the newest are dropped.
    pub queue_depth: usize,
    /// ONLINE at start-up.
    pub online: bool,
    /// Word order of floats and 32-bit values.
    pub word_order: WordOrder,
    /// TYPES_ENROLLED at start-up.
    pub types_enrolled: u16,
    /// The order a frame's results are queued in.
    pub picking_order: PickingOrder,
    /// BOOT_ID: drawn by the appliance at start (non-zero), the same for every camera.
    pub boot_id: u16,
    /// The job in force at start-up (JOB_ID).
    pub job_id: u16,
}

/// One camera's registers and result queue.
#[derive(Debug, Clone)]
pub struct Handshake {
    settings: Settings,
    trigger: bool,
    result_ack: u16,
    online: bool,
    expected_type: u16,
    /// USER_DATA (5-6) as the PLC wrote them.
    user_data: [u16; 2],
    trigger_ack: bool,
    /// The acquisition running: its id, start, and the USER_DATA latched for it.
    busy: Option<(u16, Duration, u32)>,
    error: bool,
    error_code: u16,
    overrun: bool,
    camera_ok: bool,
    /// CAMERA_OK was reported true at least once.
    camera_seen: bool,
    heartbeat: u16,
    acq_count: u16,
    overrun_count: u16,
    missed: u16,
    ack_ignored: u16,
    last_cycle: u16,
    /// Debris pieces in the last estimated frame.
    debris: u16,
    next_seq: u16,
    /// JOB_REQUEST as last written (0 before any), the job in force, JOB_STATUS, and how many
    /// requested changes have not been reported yet.
    job_request: u16,
    job_id: u16,
    job_status: u16,
    jobs_pending: u16,
    queue: VecDeque<Queued>,
    robot: RobotView,
    counters: Counters,
}

impl Handshake {
    /// A handshake at power-up: nothing queued, no acquisition running.
    pub fn new(settings: Settings) -> Self {
        let job_id = settings.job_id;
        Self {
            online: settings.online,
            settings,
            trigger: false,
            result_ack: 0,
            expected_type: 0,
            user_data: [0, 0],
            trigger_ack: false,
            busy: None,
            error: false,
            error_code: error_code::NONE,
            overrun: false,
            camera_ok: true,
            camera_seen: false,
            heartbeat: 0,
            acq_count: 0,
            overrun_count: 0,
            missed: 0,
            ack_ignored: 0,
            last_cycle: 0,
            debris: 0,
            next_seq: 1,
            job_request: 0,
            job_id,
            job_status: job_status::IDLE,
            jobs_pending: 0,
            queue: VecDeque::new(),
            robot: RobotView::default(),
            counters: Counters::default(),
        }
    }

    /// READY = ONLINE and not BUSY and CAMERA_OK and not ERROR and no job change running (a
    /// full queue does not clear it): exactly when a TRIGGER edge starts an acquisition, so a
    /// PLC that waits for READY never triggers into an error it has not cleared or a knowledge
    /// base being swapped, and a free-running camera takes a frame only then (its files wait in
    /// the inbox meanwhile rather than be consumed unseen).
    pub fn ready(&self) -> bool {
        self.online && self.busy.is_none() && self.camera_ok && !self.error && self.jobs_pending == 0
    }

    /// The job in force (JOB_ID).
    pub fn job_id(&self) -> u16 {
        self.job_id
    }

    /// Reports a job change asked for by [`Command::ChangeJob`]: JOB_STATUS becomes done or
    /// failed once no other change is waiting; a job in force sets EXPECTED_TYPE if it has one.
    pub fn job_changed(&mut self, id: u16, outcome: JobOutcome) {
        self.jobs_pending = self.jobs_pending.saturating_sub(1);
        let status = match outcome {
            JobOutcome::InForce { expected_type } => {
                self.job_id = id;
                if let Some(t) = expected_type {
                    self.expected_type = t;
                }
                job_status::DONE
            }
            JobOutcome::Failed => job_status::FAILED,
        };
        self.job_status = if self.jobs_pending > 0 { job_status::CHANGING } else { status };
    }

    /// STATUS as the PLC reads it.
    pub fn status(&self) -> u16 {
        let mut s = 0;
        let mut set = |bit: u16, on: bool| {
            if on {
                s |= bit;
            }
        };
        set(status::READY, self.ready());
        set(status::TRIGGER_ACK, self.trigger_ack);
        set(status::BUSY, self.busy.is_some());
        set(status::RESULT_VALID, !self.queue.is_empty());
        set(status::RESULT_OVERRUN, self.overrun);
        set(status::ERROR, self.error);
        set(status::ONLINE, self.online);
        set(status::CAMERA_OK, self.camera_ok);
        s
    }

    /// The results waiting for RESULT_ACK, oldest first.
    pub fn queue(&self) -> &VecDeque<Queued> {
        &self.queue
    }
    /// The counters so far.
    pub fn counters(&self) -> Counters {
        self.counters
    }
    /// EXPECTED_TYPE as last written (0: any type).
    pub fn expected_type(&self) -> u16 {
        self.expected_type
    }
    /// An acquisition runs (BUSY).
    pub fn busy(&self) -> bool {
        self.busy.is_some()
    }
    /// Job `id` is in force and no change is waiting.
    pub fn job_settled(&self, id: u16) -> bool {
        self.job_id == id && self.jobs_pending == 0
    }
    /// The ACQ_ID of the acquisition running, if one is.
    pub fn running(&self) -> Option<u16> {
        self.busy.map(|(id, _, _)| id)
    }

    /// The value of one register (reserved addresses read 0).
    pub fn word(&self, a: u16) -> u16 {
        let head = self.queue.front();
        let float = |v: f32, second: bool| self.split(v.to_bits(), second);
        // Either word of a two-word value that starts at `at`.
        let two = |a: u16, at: u16| a == at || a == at + 1;
        match a {
            addr::TRIGGER => self.trigger as u16,
            addr::RESULT_ACK => self.result_ack,
            addr::CLEAR_ERROR => 0,
            addr::ONLINE => self.online as u16,
            addr::EXPECTED_TYPE => self.expected_type,
            a if two(a, addr::USER_DATA) => self.user_data[(a - addr::USER_DATA) as usize],
            addr::BOOT_ID => self.settings.boot_id,
            addr::JOB_REQUEST => self.job_request,
            addr::JOB_ID => self.job_id,
            addr::JOB_STATUS => self.job_status,
            addr::STATUS => self.status(),
            addr::HEARTBEAT => self.heartbeat,
            addr::ERROR_CODE => self.error_code,
            addr::ACQ_COUNT => self.acq_count,
            addr::RESULTS_PENDING => self.queue.len().min(65535) as u16,
            addr::OVERRUN_COUNT => self.overrun_count,
            addr::MISSED_TRIGGERS => self.missed,
            addr::MAP_VERSION => map::MAP_VERSION,
            addr::LAST_CYCLE_TIME => self.last_cycle,
            addr::TYPES_ENROLLED => self.settings.types_enrolled,
            addr::ROBOT_STATUS => self.robot.bits,
            addr::ROBOT_QUEUE => self.robot.queue,
            addr::ROBOT_DELIVERED => self.robot.delivered,
            addr::ROBOT_ACK_TIMEOUTS => self.robot.ack_timeouts,
            addr::ROBOT_WRONG_ACKS => self.robot.wrong_acks,
            addr::ROBOT_RECONNECTS => self.robot.reconnects,
            addr::ROBOT_DROPPED => self.robot.dropped,
            addr::ROBOT_DATA_SEQ => self.robot.data_seq,
            addr::ROBOT_ACK_SEQ => self.robot.ack_seq,
            addr::DEBRIS_COUNT => self.debris,
            addr::RESULT_ACK_IGNORED => self.ack_ignored,
            addr::RESULT_SEQ..=addr::RESULT_END => {
                let Some(q) = head else { return 0 };
                let p = &q.part;
                match a {
                    addr::RESULT_SEQ => q.seq,
                    addr::ACQ_ID => q.acq_id,
                    addr::DECISION => {
                        if p.accepted {
                            1
                        } else {
                            2
                        }
                    }
                    addr::REASON => map::reason_code(p.reason),
                    addr::TYPE_ID => p.type_id,
                    addr::FACE => p.face,
                    addr::ANGLE => map::angle_word(p.angle_deg),
                    addr::X => map::mm_word(p.x_mm),
                    addr::Y => map::mm_word(p.y_mm),
                    addr::CONFIDENCE => map::confidence_word(p.confidence),
                    addr::PART_INDEX => q.index,
                    addr::PART_COUNT => q.count,
                    a if two(a, addr::ANGLE_F32) => float(map::angle_f32(p.angle_deg), a > addr::ANGLE_F32),
                    a if two(a, addr::X_F32) => float(p.x_mm as f32, a > addr::X_F32),
                    a if two(a, addr::Y_F32) => float(p.y_mm as f32, a > addr::Y_F32),
                    addr::PROCESSING_TIME => map::tenth_ms_word(q.processing_ms),
                    a if two(a, addr::RESULT_USER_DATA) => self.split(q.user_data, a > addr::RESULT_USER_DATA),
                    _ => 0,
                }
            }
            _ => 0,
        }
    }

    /// One word of a two-word value (a float's bits, a uint32) in the camera's word order.
    fn split(&self, v: u32, second: bool) -> u16 {
        u32_words(v, self.settings.word_order)[second as usize]
    }

    /// USER_DATA as a number, from its two words in the camera's word order.
    pub fn user_data(&self) -> u32 {
        u32_from_words(self.user_data, self.settings.word_order)
    }

    /// Registers `start..start+count` in one consistent snapshot.
    pub fn read(&self, start: u16, count: u16) -> Vec<u16> {
        (start..start.saturating_add(count)).map(|a| self.word(a)).collect()
    }

    /// A PLC write of one register. The caller has checked that the address is writable and the
    /// value allowed (see [`crate::modbus::service`]).
    pub fn write(&mut self, a: u16, v: u16, now: Duration) -> Option<Command> {
        self.write_block(a, &[v], now)
    }

    /// A PLC write of consecutive registers (one FC16): every other register takes its value
    /// first and the TRIGGER edge is taken last, so USER_DATA, EXPECTED_TYPE or CLEAR_ERROR
    /// written in the same request as TRIGGER already hold for that acquisition.
    ///
    /// A JOB_REQUEST starts a job change ([`Command::ChangeJob`]); a TRIGGER edge in the same
    /// request then counts as missed (READY is 0 while the change runs), so one request yields
    /// at most one command.
    pub fn write_block(&mut self, start: u16, values: &[u16], now: Duration) -> Option<Command> {
        let mut trigger = None;
        let mut job = None;
        for (a, v) in (start..).zip(values) {
            match a {
                addr::TRIGGER => trigger = Some(*v),
                addr::JOB_REQUEST => {
                    self.job_request = *v;
                    self.jobs_pending = self.jobs_pending.saturating_add(1);
                    self.job_status = job_status::CHANGING;
                    job = Some(Command::ChangeJob { id: *v });
                }
                _ => self.write_one(a, *v),
            }
        }
        let acquire = trigger.and_then(|v| self.write_trigger(v, now));
        job.or(acquire)
    }

    fn write_trigger(&mut self, v: u16, now: Duration) -> Option<Command> {
        let edge = v == 1 && !self.trigger;
        self.trigger = v == 1;
        if v == 0 {
            self.trigger_ack = false;
        }
        if !edge {
            return None;
        }
        if !self.ready() {
            self.missed = self.missed.wrapping_add(1);
            self.counters.missed_triggers += 1;
            return None;
        }
        self.trigger_ack = true;
        Some(self.begin(now))
    }

    fn write_one(&mut self, a: u16, v: u16) {
        match a {
            addr::RESULT_ACK => {
                self.result_ack = v;
                match self.queue.front() {
                    Some(q) if q.seq == v => {
                        self.queue.pop_front();
                    }
                    _ => {
                        self.ack_ignored = self.ack_ignored.wrapping_add(1);
                        self.counters.ignored_acks += 1;
                    }
                }
            }
            addr::CLEAR_ERROR if v == 1 => {
                self.error = false;
                self.error_code = error_code::NONE;
                self.overrun = false;
            }
            addr::ONLINE => self.online = v == 1,
            addr::EXPECTED_TYPE => self.expected_type = v,
            5 | 6 => self.user_data[(a - addr::USER_DATA) as usize] = v,
            _ => {}
        }
    }

    fn begin(&mut self, now: Duration) -> Command {
        self.acq_count = self.acq_count.wrapping_add(1);
        self.counters.acquisitions += 1;
        self.busy = Some((self.acq_count, now, self.user_data()));
        Command::Acquire { acq_id: self.acq_count }
    }

    /// Free-running cameras start an acquisition for each frame the source yields, when READY
    /// and not in ERROR; otherwise the frame is skipped (None).
    pub fn free_run(&mut self, now: Duration) -> Option<Command> {
        if self.ready() { Some(self.begin(now)) } else { None }
    }

    /// Reports the debris counted in the frame being completed (DEBRIS_COUNT); call before
    /// [`Handshake::complete`] so that a PLC reading after BUSY clears sees both together.
    pub fn set_debris(&mut self, count: usize) {
        self.debris = count.min(65535) as u16;
    }

    /// Reports an acquisition: decides its final results and queues them (before BUSY clears,
    /// so a PLC that waits for BUSY = 0 after TRIGGER_ACK sees them). Reports for other
    /// acquisitions are ignored.
    ///
    /// Returns the frame's final results as the PLC gets them (after the expected-type rule, in
    /// picking order, a no-part or frame-error result included), whether the queue had room for
    /// them or not: the one truth every other consumer (robot, page, counters, log) takes. Empty
    /// when `acq_id` is not the acquisition running.
    pub fn complete(&mut self, acq_id: u16, outcome: Outcome, now: Duration) -> Vec<Queued> {
        let Some((busy_id, started, user_data)) = self.busy else { return Vec::new() };
        if busy_id != acq_id {
            return Vec::new();
        }
        let mut results: Vec<Queued> = Vec::new();
        match outcome {
            Outcome::Parts { parts, processing_ms } if parts.is_empty() => {
                results.push(Queued {
                    seq: 0,
                    acq_id,
                    part: no_part(Reason::NoPart),
                    index: 0,
                    count: 0,
                    processing_ms,
                    user_data,
                    detection: None,
                });
            }
            Outcome::Parts { parts, processing_ms } => {
                let count = parts.len().min(65535) as u16;
                let mut parts: Vec<(usize, PartResult)> = parts.into_iter().enumerate().collect();
                for (_, p) in &mut parts {
                    if self.expected_type != 0 && p.accepted && p.type_id != self.expected_type {
                        p.accepted = false;
                        p.reason = Reason::WrongType;
                    }
                }
                let order = self.settings.picking_order;
                parts.sort_by(|(_, a), (_, b)| b.accepted.cmp(&a.accepted).then_with(|| order.compare(a, b)));
                for (i, (detection, p)) in parts.into_iter().enumerate() {
                    let index = (i + 1).min(65535) as u16;
                    results.push(Queued { seq: 0, acq_id, part: p, index, count, processing_ms, user_data, detection: Some(detection) });
                }
            }
            Outcome::Failed { fault } => {
                self.error = true;
                self.error_code = fault.code();
                results.push(Queued {
                    seq: 0,
                    acq_id,
                    part: no_part(Reason::FrameError),
                    index: 0,
                    count: 0,
                    processing_ms: 0.0,
                    user_data,
                    detection: None,
                });
            }
        }
        for r in results.iter_mut() {
            if self.queue.len() >= self.settings.queue_depth {
                self.overrun = true;
                self.overrun_count = self.overrun_count.wrapping_add(1);
                self.counters.dropped += 1;
                continue;
            }
            r.seq = self.next_seq;
            self.next_seq = if self.next_seq == u16::MAX { 1 } else { self.next_seq + 1 };
            self.counters.results += 1;
            self.queue.push_back(r.clone());
        }
        self.last_cycle = u16_word(now.saturating_sub(started).as_secs_f64() * 1e4);
        self.busy = None;
        results
    }

    /// The camera's state (CAMERA_OK), as the shell sees it now; READY follows it. A camera
    /// that was seen working and is lost (cable pulled, power cycle) is a camera fault: ERROR
    /// with ERROR_CODE 1 without waiting for a trigger, cleared by CLEAR_ERROR as any fault.
    /// One never seen working (not found at start-up) only keeps CAMERA_OK at 0.
    pub fn set_camera_ok(&mut self, ok: bool) {
        if self.camera_ok && !ok && self.camera_seen && !self.error {
            self.error = true;
            self.error_code = error_code::CAMERA;
        }
        self.camera_seen |= ok;
        self.camera_ok = ok;
    }
    /// CAMERA_OK.
    pub fn camera_ok(&self) -> bool {
        self.camera_ok
    }

    /// Advances the heartbeat: one count per whole second since the appliance started.
    pub fn tick(&mut self, since_start: Duration) {
        self.heartbeat = (since_start.as_secs() % 65536) as u16;
    }

    /// The robot link's state, for registers 110..118.
    pub fn set_robot(&mut self, view: RobotView) {
        self.robot = view;
    }
    /// The robot link's state as last set.
    pub fn robot(&self) -> RobotView {
        self.robot
    }

    /// The settings it was made with.
    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// After an enrollment changed the knowledge base.
    pub fn set_types_enrolled(&mut self, n: u16) {
        self.settings.types_enrolled = n;
    }

    /// The camera's state as a vision system (OPC 40100's state machines), decided here from
    /// the same flags STATUS shows, so that OPC UA and the PLC never tell two stories. A
    /// camera never seen working is still starting; ERROR outranks offline (the fault is what
    /// needs a hand); inside Operational, `free_run` is continuous execution.
    pub fn vision_state(&self, free_run: bool) -> VisionState {
        if !self.camera_seen {
            VisionState::Preoperational
        } else if self.error {
            VisionState::Error
        } else if !self.online {
            VisionState::Halted
        } else if self.jobs_pending > 0 || !self.camera_ok {
            // Online without a fault but not taking frames: a job being changed, the camera
            // lost (not yet a fault).
            VisionState::Operational(AutoMode::Initialized)
        } else if free_run {
            VisionState::Operational(AutoMode::ContinuousExecution)
        } else if self.busy.is_some() {
            VisionState::Operational(AutoMode::SingleExecution)
        } else {
            VisionState::Operational(AutoMode::Ready)
        }
    }
}

/// The top state of a vision system (OPC 40100-1's VisionStateMachineType).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VisionState {
    /// Starting, or no camera seen yet.
    Preoperational,
    /// Offline (ONLINE = 0): triggers are not taken.
    Halted,
    /// ERROR is set until CLEAR_ERROR.
    Error,
    /// Taking triggers, in the automatic mode's state.
    Operational(AutoMode),
}

/// The automatic mode's state inside Operational (VisionAutomaticModeStateMachineType).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AutoMode {
    /// Online but not ready (a job change running, the camera lost without a fault yet).
    Initialized,
    /// READY: a trigger starts an acquisition.
    Ready,
    /// A triggered frame is being processed (BUSY).
    SingleExecution,
    /// A free-running camera takes every frame.
    ContinuousExecution,
}

impl VisionState {
    /// The state's browse name in the companion specification.
    pub fn name(self) -> &'static str {
        match self {
            VisionState::Preoperational => "Preoperational",
            VisionState::Halted => "Halted",
            VisionState::Error => "Error",
            VisionState::Operational(_) => "Operational",
        }
    }
}

impl AutoMode {
    /// The state's browse name in the companion specification.
    pub fn name(self) -> &'static str {
        match self {
            AutoMode::Initialized => "Initialized",
            AutoMode::Ready => "Ready",
            AutoMode::SingleExecution => "SingleExecution",
            AutoMode::ContinuousExecution => "ContinuousExecution",
        }
    }
}

fn no_part(reason: Reason) -> PartResult {
    PartResult { accepted: false, reason, type_id: 0, face: 0, angle_deg: 0.0, x_mm: 0.0, y_mm: 0.0, confidence: 0.0 }
}
