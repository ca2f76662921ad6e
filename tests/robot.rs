//! Handing parts to a (simulated) FANUC controller: the robot program sees every accepted part
//! exactly once, in order, whatever the controller does.

mod common;

use std::sync::{Arc, Mutex};
use std::time::Duration;

use common::appliance::{cycle, plc, read, start};
use common::fanuc::{Cell, Fanuc, Picked, Program, tp_program};
use lfi_bridge::config::{RobotConfig, RobotSend};
use lfi_bridge::handshake::{PartResult, Queued, WordOrder};
use lfi_bridge::registers::RobotView;
use lfi_bridge::registers::robot_status;
use lfi_bridge::robot::{Action, Link};
use lfi_bridge::vision::Reason;
use tokio_util::sync::CancellationToken;

const IN: u16 = 10;
const OUT: u16 = 30;

fn robot_config(fanuc: &Fanuc, ack_timeout: Duration) -> RobotConfig {
    RobotConfig {
        address: fanuc.addr.to_string(),
        unit_id: 1,
        input_words_at: IN,
        output_words_at: OUT,
        output_function: 3,
        poll: Duration::from_millis(5),
        ack_timeout,
        send: RobotSend::Accepted,
        queue_depth: 1000,
        word_order: WordOrder::HighFirst,
    }
}

fn part(i: usize) -> PartResult {
    PartResult {
        accepted: true,
        reason: Reason::Ok,
        type_id: 1 + (i % 3) as u16,
        face: 1 + (i % 2) as u16,
        angle_deg: -179.5 + i as f64 * 0.7,
        x_mm: i as f64 - 250.0,
        y_mm: -(i as f64) / 10.0,
        confidence: 0.9,
    }
}

/// Part `i` as the handshake hands it on: its frame's USER_DATA is 70000 + i (over 16 bits).
fn queued(i: usize) -> Queued {
    Queued {
        seq: 0,
        acq_id: i as u16,
        part: part(i),
        index: 1,
        count: 1,
        processing_ms: 1.0,
        user_data: 70_000 + i as u32,
        detection: Some(0),
    }
}

struct Rig {
    fanuc: Fanuc,
    tx: tokio::sync::mpsc::UnboundedSender<Queued>,
    view: Arc<Mutex<RobotView>>,
    stop_link: CancellationToken,
    stop_robot: CancellationToken,
    link: tokio::task::JoinHandle<()>,
    robot: tokio::task::JoinHandle<Vec<Picked>>,
}

async fn rig(pick: Duration, ack_timeout: Duration, idle: Duration) -> Rig {
    let fanuc = Fanuc::start(idle).await;
    let (tx, rx) = tokio::sync::mpsc::unbounded_channel();
    let view = Arc::new(Mutex::new(RobotView::default()));
    let stop_link = CancellationToken::new();
    let link =
        tokio::spawn(lfi_bridge::robot::link::run("test".into(), robot_config(&fanuc, ack_timeout), rx, view.clone(), stop_link.clone()));
    let stop_robot = CancellationToken::new();
    let robot =
        tokio::spawn(tp_program(fanuc.state.clone(), Program { input_at: IN as usize, output_at: OUT as usize, pick }, stop_robot.clone()));
    Rig { fanuc, tx, view, stop_link, stop_robot, link, robot }
}

impl Rig {
    fn view(&self) -> RobotView {
        *self.view.lock().unwrap()
    }
    async fn until(&self, what: &str, limit: Duration, pred: impl Fn(&RobotView) -> bool) {
        let end = tokio::time::Instant::now() + limit;
        while !pred(&self.view()) {
            assert!(tokio::time::Instant::now() < end, "{what}: robot link state {:?}", self.view());
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    }
    async fn finish(self) -> (Vec<Picked>, Fanuc) {
        self.stop_link.cancel();
        let _ = self.link.await;
        self.stop_robot.cancel();
        (self.robot.await.unwrap(), self.fanuc)
    }
}

fn check_in_order(picked: &[Picked], n: usize) {
    assert_eq!(picked.len(), n, "parts picked");
    for (i, p) in picked.iter().enumerate() {
        let want = part(i);
        assert_eq!(p.x, (want.x_mm * 10.0).round() as i32, "part {i} out of order or lost");
        assert_eq!(p.y, (want.y_mm * 10.0).round() as i32);
        assert_eq!((p.type_id, p.face, p.confidence), (want.type_id, want.face, 900));
        assert_eq!(p.user_data, queued(i).user_data, "part {i}: USER_DATA in words 8-9");
        let a = ((want.angle_deg + 180.0).rem_euclid(360.0) - 180.0) * 100.0;
        assert!((p.angle as f64 - a).abs() <= 0.5001, "part {i}: angle {} vs {a}", p.angle);
    }
    for w in picked.windows(2) {
        assert_ne!(w[0].seq, w[1].seq, "DATA_SEQ repeats");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn five_hundred_parts_arrive_in_order_none_lost_or_duplicated() {
    let r = rig(Duration::from_millis(1), Duration::from_secs(5), Duration::from_secs(5)).await;
    for i in 0..500 {
        r.tx.send(queued(i)).unwrap();
    }
    r.until("all delivered", Duration::from_secs(60), |v| v.delivered == 500 && v.queue == 0).await;
    let v = r.view();
    assert_eq!((v.wrong_acks, v.ack_timeouts, v.dropped), (0, 0, 0));
    assert!(v.bits & robot_status::CONNECTED != 0);
    let (picked, fanuc) = r.finish().await;
    check_in_order(&picked, 500);
    // Words 1..9 always went in one request before DATA_SEQ alone.
    let writes = fanuc.state.lock().unwrap().writes.clone();
    let data: Vec<_> = writes.iter().filter(|(a, _)| *a == IN || *a == IN + 1).collect();
    for pair in data.chunks(2) {
        assert_eq!((pair[0].0, pair[0].1.len()), (IN + 1, 9));
        assert_eq!((pair[1].0, pair[1].1.len()), (IN, 1));
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_robot_restart_mid_stream_loses_and_repeats_nothing() {
    let mut r = rig(Duration::from_millis(3), Duration::from_secs(5), Duration::from_secs(5)).await;
    for i in 0..120 {
        r.tx.send(queued(i)).unwrap();
    }
    r.until("some delivered", Duration::from_secs(20), |v| v.delivered >= 40).await;
    r.fanuc.restart(Duration::from_millis(300)).await;
    // The restarted controller's program comes back and reports ready again.
    r.fanuc.set_output(OUT as usize, 1);
    r.until("all delivered after the restart", Duration::from_secs(30), |v| v.delivered == 120 && v.queue == 0).await;
    assert!(r.view().reconnects >= 1);
    let (picked, _) = r.finish().await;
    check_in_order(&picked, 120);
}

// The protocol itself, as scripts on a virtual clock: no sockets, no sleeping.

const READY: u16 = lfi_bridge::robot::output::READY;

fn ms(v: u64) -> Duration {
    Duration::from_millis(v)
}

/// The part writes among `actions`: (DATA_SEQ, words 1..=9).
fn sends(actions: &[Action]) -> Vec<(u16, [u16; 9])> {
    actions.iter().filter_map(|a| if let Action::Send { seq, words } = a { Some((*seq, *words)) } else { None }).collect()
}

#[test]
fn nothing_is_written_while_the_robot_is_not_ready() {
    let mut link = Link::new(10, Duration::from_secs(5), WordOrder::HighFirst);
    link.on_connected(ms(0));
    for i in 0..3 {
        assert!(link.enqueue(queued(i)));
    }
    for t in 0..60 {
        assert_eq!(link.on_outputs(0, 0, ms(5 * t)), None, "no DATA_SEQ while not ready");
    }
    assert_eq!(link.view().queue, 3);
    assert!(link.view().bits & robot_status::ROBOT_READY == 0);
    // A fault with ready set holds the parts back too.
    assert_eq!(link.on_outputs(READY | lfi_bridge::robot::output::FAULT, 0, ms(300)), None);
    let Some(Action::Send { seq, words }) = link.on_outputs(READY, 0, ms(305)) else { panic!("ready: the first part goes") };
    assert_eq!((seq, words[0], words[1]), (1, part(0).type_id, part(0).face));
    assert!(link.view().bits & robot_status::ROBOT_READY != 0);
}

#[test]
fn an_ack_timeout_is_flagged_once_and_the_part_kept() {
    let mut link = Link::new(10, ms(200), WordOrder::HighFirst);
    link.on_connected(ms(0));
    link.enqueue(queued(0));
    link.enqueue(queued(1));
    let first = link.on_outputs(READY, 0, ms(0)).expect("the first part is written");
    let Action::Send { seq, .. } = first else { panic!("{first:?}") };
    // The deadline is the first moment that needs the time (after the heartbeat due at once).
    assert_eq!(link.handle_timeout(ms(0)), vec![Action::Heartbeat { value: 1 }]);
    assert_eq!(link.poll_timeout(), Some(ms(200)));
    assert!(link.handle_timeout(ms(200)).is_empty(), "not overdue at the deadline itself");
    assert_eq!(link.on_outputs(READY, 0, ms(150)), None, "nothing else while one is in flight");
    let late = link.handle_timeout(ms(201));
    assert_eq!(late, vec![Action::ReportAckTimeout { seq, waited: ms(201) }]);
    let v = link.view();
    assert!(v.bits & robot_status::ACK_TIMEOUT != 0);
    assert_eq!((v.ack_timeouts, v.delivered, v.data_seq), (1, 0, seq));
    // Flagged once: later looks neither count nor report it again, nor send another part.
    assert!(link.handle_timeout(ms(400)).iter().all(|a| !matches!(a, Action::ReportAckTimeout { .. })));
    assert_eq!(link.on_outputs(READY, 0, ms(500)), None);
    assert_eq!(link.view().ack_timeouts, 1);
    // The acknowledgement clears the flag and lets the next part go.
    let next = link.on_outputs(READY, seq, ms(600));
    assert_eq!(sends(&next.into_iter().collect::<Vec<_>>()).len(), 1);
    let v = link.view();
    assert_eq!((v.delivered, v.bits & robot_status::ACK_TIMEOUT, v.data_seq), (1, 0, seq + 1));
}

#[test]
fn a_wrong_ack_is_ignored_and_counted() {
    let mut link = Link::new(10, Duration::from_secs(5), WordOrder::HighFirst);
    link.on_connected(ms(0));
    link.enqueue(queued(0));
    link.enqueue(queued(1));
    let Some(Action::Send { seq, .. }) = link.on_outputs(READY, 0, ms(0)) else { panic!("first part") };
    assert_eq!(link.on_outputs(READY, seq.wrapping_add(1000), ms(5)), None, "a wrong ack consumes nothing");
    assert_eq!(link.on_outputs(READY, seq.wrapping_add(1000), ms(10)), None);
    let v = link.view();
    assert_eq!((v.wrong_acks, v.delivered, v.data_seq), (1, 0, seq), "counted once, still the first part");
    let Some(Action::Send { seq: second, .. }) = link.on_outputs(READY, seq, ms(15)) else { panic!("the right ack lets the second go") };
    assert_eq!((second, link.view().delivered), (seq + 1, 1));
}

#[test]
fn after_a_restart_a_part_acknowledged_meanwhile_counts_and_one_not_is_written_again() {
    let mut link = Link::new(10, Duration::from_secs(5), WordOrder::HighFirst);
    link.on_connected(ms(0));
    for i in 0..3 {
        link.enqueue(queued(i));
    }
    let Some(Action::Send { seq: s1, .. }) = link.on_outputs(READY, 0, ms(0)) else { panic!() };
    // The robot took it, and the connection dropped before we read its ACK_SEQ.
    link.on_disconnected();
    assert!(link.view().bits & robot_status::CONNECTED == 0);
    assert!(link.view().bits & robot_status::ROBOT_READY == 0, "ROBOT_READY is not known while disconnected");
    link.on_connected(ms(1000));
    let a = link.on_outputs(READY, s1, ms(1000));
    let Some(Action::Send { seq: s2, words }) = a else { panic!("{a:?}") };
    assert_eq!((s2, link.view().delivered, link.view().reconnects), (s1 + 1, 1, 1), "acknowledged meanwhile: delivered, the next goes");
    assert_eq!(words[0], part(1).type_id);
    // This time it was not acknowledged: written again with the same DATA_SEQ, once.
    link.on_disconnected();
    link.on_connected(ms(2000));
    assert_eq!(sends(&link.on_outputs(READY, s1, ms(2000)).into_iter().collect::<Vec<_>>()), vec![(s2, words)]);
    assert_eq!(link.on_outputs(READY, s1, ms(2005)), None, "not a third time");
    assert_eq!(link.view().delivered, 1);
}

#[test]
fn the_heartbeat_advances_once_a_second_while_connected() {
    let mut link = Link::new(10, Duration::from_secs(5), WordOrder::HighFirst);
    assert_eq!(link.poll_timeout(), None, "nothing to do before a connection");
    link.on_connected(ms(0));
    let mut beats = Vec::new();
    let mut t = ms(0);
    // Step the clock to each moment the link asks for, for 3.5 s.
    while let Some(next) = link.poll_timeout()
        && next <= ms(3500)
    {
        t = next.max(t);
        for a in link.handle_timeout(t) {
            if let Action::Heartbeat { value } = a {
                beats.push((t, value));
            }
        }
    }
    assert_eq!(beats, vec![(ms(0), 1), (ms(1000), 2), (ms(2000), 3), (ms(3000), 4)]);
    // A stall of 5 s gives one beat, not five.
    let stalled: Vec<_> = link.handle_timeout(ms(9000)).into_iter().filter(|a| matches!(a, Action::Heartbeat { .. })).collect();
    assert_eq!(stalled, vec![Action::Heartbeat { value: 5 }]);
    assert_eq!(link.poll_timeout(), Some(ms(10000)));
    link.on_disconnected();
    assert_eq!(link.poll_timeout(), None, "no heartbeat while disconnected");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fifth_connection_and_the_idle_timeout_do_not_lose_parts() {
    // Idle timeout shorter than... nothing: the link polls every 5 ms; extra clients come and go.
    let r = rig(Duration::from_millis(2), Duration::from_secs(5), Duration::from_millis(250)).await;
    for i in 0..60 {
        r.tx.send(queued(i)).unwrap();
    }
    let mut others = Vec::new();
    for _ in 0..5 {
        others.push(tokio::net::TcpStream::connect(r.fanuc.addr).await.unwrap());
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    r.until("delivered despite the alarm", Duration::from_secs(30), |v| v.delivered == 60).await;
    assert!(r.fanuc.state.lock().unwrap().alarms >= 1, "the fifth connection closed the oldest");
    drop(others);
    let (picked, _) = r.finish().await;
    check_in_order(&picked, 60);
}

/// The whole appliance: a simulated camera, the PLC triggering and acknowledging quickly, and a
/// slow robot; both see the same accepted parts, each at its own pace.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_plc_and_the_robot_consume_the_same_frames_at_different_speeds() {
    let cell = Cell::start(Duration::from_millis(40)).await;
    let running = start(&common::appliance::config("", &cell.robot_toml)).await;
    let mut ctx = plc(running.modbus_addr, 1).await;
    let mut accepted_by_plc: Vec<(u16, i16, i16)> = Vec::new();
    for _ in 0..27 {
        for b in cycle(&mut ctx).await {
            if b[102] == 1 {
                accepted_by_plc.push((b[104], b[107] as i16, b[108] as i16));
            }
        }
    }
    assert!(accepted_by_plc.len() >= 10, "only {} accepted parts", accepted_by_plc.len());
    // The PLC is done long before the robot; the robot's queue shows in registers 110..118.
    let end = tokio::time::Instant::now() + Duration::from_secs(60);
    loop {
        let r = read(&mut ctx, 110, 9).await;
        if r[2] as usize == accepted_by_plc.len() && r[1] == 0 {
            assert!(r[0] & robot_status::CONNECTED != 0);
            break;
        }
        assert!(tokio::time::Instant::now() < end, "robot registers {r:?}, PLC accepted {}", accepted_by_plc.len());
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    running.stop().await;
    let picked = cell.picked().await;
    let robot_saw: Vec<(u16, i16, i16)> = picked.iter().map(|p| (p.type_id, p.x as i16, p.y as i16)).collect();
    assert_eq!(robot_saw, accepted_by_plc, "same parts, same order");
}
