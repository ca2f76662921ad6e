//! Handing parts to a (simulated) FANUC controller: the robot program sees every accepted part
//! exactly once, in order, whatever the controller does.

mod common;

use std::sync::{Arc, Mutex};
use std::time::Duration;

use common::appliance::{cycle, plc, read, start};
use common::fanuc::{Fanuc, Picked, Program, tp_program};
use lfi_bridge::config::{RobotConfig, RobotSend};
use lfi_bridge::handshake::{PartResult, RobotView};
use lfi_bridge::modbus::map::robot_status;
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

struct Rig {
    fanuc: Fanuc,
    tx: tokio::sync::mpsc::UnboundedSender<(u16, PartResult)>,
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
        r.tx.send((i as u16, part(i))).unwrap();
    }
    r.until("all delivered", Duration::from_secs(60), |v| v.delivered == 500 && v.queue == 0).await;
    let v = r.view();
    assert_eq!((v.wrong_acks, v.ack_timeouts, v.dropped), (0, 0, 0));
    assert!(v.bits & robot_status::CONNECTED != 0);
    let (picked, fanuc) = r.finish().await;
    check_in_order(&picked, 500);
    // Words 1..7 always went in one request before DATA_SEQ alone.
    let writes = fanuc.state.lock().unwrap().writes.clone();
    let data: Vec<_> = writes.iter().filter(|(a, _)| *a == IN || *a == IN + 1).collect();
    for pair in data.chunks(2) {
        assert_eq!((pair[0].0, pair[0].1.len()), (IN + 1, 7));
        assert_eq!((pair[1].0, pair[1].1.len()), (IN, 1));
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_robot_restart_mid_stream_loses_and_repeats_nothing() {
    let mut r = rig(Duration::from_millis(3), Duration::from_secs(5), Duration::from_secs(5)).await;
    for i in 0..120 {
        r.tx.send((0, part(i))).unwrap();
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

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nothing_is_written_while_the_robot_is_not_ready() {
    let r = rig(Duration::from_millis(1), Duration::from_secs(5), Duration::from_secs(5)).await;
    tokio::time::sleep(Duration::from_millis(50)).await;
    r.fanuc.set_output(OUT as usize, 0);
    for i in 0..3 {
        r.tx.send((0, part(i))).unwrap();
    }
    tokio::time::sleep(Duration::from_millis(300)).await;
    assert_eq!(r.fanuc.inputs()[IN as usize], 0, "no DATA_SEQ while not ready");
    assert_eq!(r.view().queue, 3);
    assert!(r.view().bits & robot_status::ROBOT_READY == 0);
    r.fanuc.set_output(OUT as usize, 1);
    r.until("delivered once ready", Duration::from_secs(10), |v| v.delivered == 3).await;
    let (picked, _) = r.finish().await;
    check_in_order(&picked, 3);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_ack_timeout_is_flagged_and_the_part_kept() {
    // The robot picks for 600 ms; the appliance allows 200 ms.
    let r = rig(Duration::from_millis(600), Duration::from_millis(200), Duration::from_secs(5)).await;
    r.tx.send((0, part(0))).unwrap();
    r.tx.send((0, part(1))).unwrap();
    r.until("timeout flagged", Duration::from_secs(5), |v| v.bits & robot_status::ACK_TIMEOUT != 0).await;
    let v = r.view();
    assert_eq!(v.ack_timeouts, 1);
    assert_eq!(v.delivered, 0);
    assert_eq!(r.fanuc.inputs()[IN as usize], v.data_seq, "no different part was sent");
    r.until("both delivered", Duration::from_secs(10), |v| v.delivered == 2).await;
    assert_eq!(r.view().bits & robot_status::ACK_TIMEOUT, 0, "cleared by the acknowledgement");
    let (picked, _) = r.finish().await;
    check_in_order(&picked, 2);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_wrong_ack_is_ignored_and_counted() {
    let r = rig(Duration::from_millis(1), Duration::from_secs(5), Duration::from_secs(5)).await;
    r.stop_robot.cancel();
    let _ = tokio::time::timeout(Duration::from_secs(2), async {
        while !r.robot.is_finished() {
            tokio::time::sleep(Duration::from_millis(5)).await
        }
    })
    .await;
    r.fanuc.set_output(OUT as usize, 1);
    r.tx.send((0, part(0))).unwrap();
    r.tx.send((0, part(1))).unwrap();
    r.until("first part written", Duration::from_secs(5), |v| v.data_seq != 0).await;
    let seq = r.view().data_seq;
    r.fanuc.set_output(OUT as usize + 1, seq.wrapping_add(1000));
    r.until("wrong ack counted", Duration::from_secs(5), |v| v.wrong_acks == 1).await;
    assert_eq!(r.view().delivered, 0);
    assert_eq!(r.fanuc.inputs()[IN as usize], seq, "still the first part");
    r.fanuc.set_output(OUT as usize + 1, seq);
    r.until("first delivered", Duration::from_secs(5), |v| v.delivered == 1).await;
    r.until("second written", Duration::from_secs(5), |v| v.data_seq == seq.wrapping_add(1)).await;
    r.stop_link.cancel();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fifth_connection_and_the_idle_timeout_do_not_lose_parts() {
    // Idle timeout shorter than... nothing: the link polls every 5 ms; extra clients come and go.
    let r = rig(Duration::from_millis(2), Duration::from_secs(5), Duration::from_millis(250)).await;
    for i in 0..60 {
        r.tx.send((0, part(i))).unwrap();
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
    let fanuc = Fanuc::start(Duration::from_secs(10)).await;
    let stop_robot = CancellationToken::new();
    let robot = tokio::spawn(tp_program(
        fanuc.state.clone(),
        Program { input_at: IN as usize, output_at: OUT as usize, pick: Duration::from_millis(40) },
        stop_robot.clone(),
    ));
    let cfg = common::appliance::config(
        "",
        &format!(
            "[camera.robot]\naddress = \"{}\"\ninput_words_at = {IN}\noutput_words_at = {OUT}\npoll_ms = 5\nack_timeout_s = 5",
            fanuc.addr
        ),
    );
    let running = start(&cfg).await;
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
    stop_robot.cancel();
    let picked = robot.await.unwrap();
    let robot_saw: Vec<(u16, i16, i16)> = picked.iter().map(|p| (p.type_id, p.x as i16, p.y as i16)).collect();
    assert_eq!(robot_saw, accepted_by_plc, "same parts, same order");
    fanuc.stop();
}
