//! The PLC handshake, first as a state machine (no sockets, virtual time), then end to end over
//! Modbus/TCP against the real server.

mod common;

use std::time::Duration;

use lfi_bridge::handshake::{Command, Fault, Handshake, JobOutcome, Outcome, PartResult, PickingOrder, Settings, WordOrder, job_status};
use lfi_bridge::registers::{self as map, addr, error_code, status};
use lfi_bridge::vision::Reason;

fn hs(depth: usize) -> Handshake {
    Handshake::new(Settings {
        queue_depth: depth,
        online: true,
        word_order: WordOrder::HighFirst,
        types_enrolled: 3,
        picking_order: PickingOrder::XAscending,
        boot_id: 77,
        job_id: 1,
    })
}

/// A handshake of depth 4 with floats and USER_DATA low word first.
fn low_first() -> Handshake {
    Handshake::new(Settings { word_order: WordOrder::LowFirst, queue_depth: 4, ..hs(4).settings().clone() })
}

fn part(type_id: u16, x: f64) -> PartResult {
    PartResult { accepted: true, reason: Reason::Ok, type_id, face: 1, angle_deg: 12.34, x_mm: x, y_mm: -5.0, confidence: 0.876 }
}

fn ms(v: u64) -> Duration {
    Duration::from_millis(v)
}

fn trigger(h: &mut Handshake, t: u64) -> Option<u16> {
    let c = h.write(addr::TRIGGER, 1, ms(t));
    h.write(addr::TRIGGER, 0, ms(t));
    c.and_then(|c| match c {
        Command::Acquire { acq_id } => Some(acq_id),
        Command::ChangeJob { .. } => None,
    })
}

#[test]
fn a_job_request_changes_the_job_with_ready_down_until_the_camera_reports() {
    let mut h = hs(8);
    assert_eq!((h.word(addr::JOB_REQUEST), h.word(addr::JOB_ID), h.word(addr::JOB_STATUS)), (0, 1, job_status::IDLE));
    assert_eq!(h.write(addr::JOB_REQUEST, 2, ms(0)), Some(Command::ChangeJob { id: 2 }));
    assert_eq!((h.word(addr::JOB_REQUEST), h.word(addr::JOB_STATUS)), (2, job_status::CHANGING));
    assert_eq!(h.word(addr::STATUS) & status::READY, 0, "READY is 0 while the change runs");
    assert_eq!(trigger(&mut h, 1), None, "a trigger meanwhile is missed");
    assert_eq!(h.word(addr::MISSED_TRIGGERS), 1);
    h.job_changed(2, JobOutcome::InForce { expected_type: Some(3) });
    assert_eq!((h.word(addr::JOB_ID), h.word(addr::JOB_STATUS), h.word(addr::EXPECTED_TYPE)), (2, job_status::DONE, 3));
    assert_ne!(h.word(addr::STATUS) & status::READY, 0);
    assert_eq!(trigger(&mut h, 2), Some(1));
    // The PLC may overwrite EXPECTED_TYPE; a job without one leaves it.
    h.complete(1, Outcome::Parts { parts: vec![], processing_ms: 1.0 }, ms(3));
    h.write(addr::EXPECTED_TYPE, 0, ms(4));
    h.write(addr::JOB_REQUEST, 1, ms(5));
    h.job_changed(1, JobOutcome::InForce { expected_type: None });
    assert_eq!((h.word(addr::JOB_ID), h.word(addr::EXPECTED_TYPE)), (1, 0));
}

#[test]
fn a_failed_job_change_leaves_the_job_in_force_and_says_so_until_the_next_request() {
    let mut h = hs(8);
    // Results queued before the change stay readable during it.
    assert_eq!(trigger(&mut h, 0), Some(1));
    h.complete(1, Outcome::Parts { parts: vec![part(2, 10.0)], processing_ms: 1.0 }, ms(1));
    h.write(addr::JOB_REQUEST, 7, ms(2));
    assert_eq!((h.word(addr::RESULT_SEQ), h.word(addr::TYPE_ID)), (1, 2));
    h.job_changed(7, JobOutcome::Failed);
    assert_eq!((h.word(addr::JOB_ID), h.word(addr::JOB_STATUS), h.word(addr::JOB_REQUEST)), (1, job_status::FAILED, 7));
    assert_ne!(h.word(addr::STATUS) & status::READY, 0, "the camera goes on with the job in force");
    // Two requests in a row: CHANGING until both are reported, then the last one's outcome.
    h.write(addr::JOB_REQUEST, 2, ms(3));
    h.write(addr::JOB_REQUEST, 9, ms(3));
    h.job_changed(2, JobOutcome::InForce { expected_type: None });
    assert_eq!((h.word(addr::JOB_ID), h.word(addr::JOB_STATUS)), (2, job_status::CHANGING));
    assert_eq!(h.word(addr::STATUS) & status::READY, 0);
    h.job_changed(9, JobOutcome::Failed);
    assert_eq!((h.word(addr::JOB_ID), h.word(addr::JOB_STATUS)), (2, job_status::FAILED));
    // JOB_REQUEST and TRIGGER in one FC16: the change starts, the trigger is missed.
    let missed = h.word(addr::MISSED_TRIGGERS);
    assert_eq!(h.write_block(addr::TRIGGER, &[1, 0, 0, 1, 0, 0, 0, 3], ms(4)), Some(Command::ChangeJob { id: 3 }));
    assert_eq!(h.word(addr::MISSED_TRIGGERS), missed + 1);
}

#[test]
fn a_trigger_is_acknowledged_and_its_result_shown_until_acknowledged() {
    let mut h = hs(8);
    assert_eq!(
        h.word(addr::STATUS) & (status::READY | status::ONLINE | status::CAMERA_OK),
        status::READY | status::ONLINE | status::CAMERA_OK
    );
    let cmd = h.write(addr::TRIGGER, 1, ms(0));
    assert_eq!(cmd, Some(Command::Acquire { acq_id: 1 }));
    let s = h.word(addr::STATUS);
    assert!(s & status::TRIGGER_ACK != 0 && s & status::BUSY != 0 && s & status::READY == 0);
    assert_eq!(h.word(addr::ACQ_COUNT), 1);
    // Holding TRIGGER at 1 is not a new edge.
    assert_eq!(h.write(addr::TRIGGER, 1, ms(1)), None);
    h.complete(1, Outcome::Parts { parts: vec![part(2, 100.0)], processing_ms: 9.87 }, ms(25));
    let s = h.word(addr::STATUS);
    assert!(s & status::BUSY == 0 && s & status::RESULT_VALID != 0 && s & status::TRIGGER_ACK != 0);
    let block = h.read(200, 19);
    assert_eq!(&block[..6], &[1, 1, 1, 0, 2, 1]);
    assert_eq!(block[6] as i16, 1234);
    assert_eq!((block[7] as i16, block[8] as i16, block[9]), (1000, -50, 876));
    assert_eq!((block[10], block[11]), (1, 1));
    let angle = f32::from_bits(((block[12] as u32) << 16) | block[13] as u32);
    assert!((angle - 12.34).abs() < 1e-4);
    assert_eq!(block[18], 99);
    assert_eq!(h.word(addr::LAST_CYCLE_TIME), 250);
    h.write(addr::TRIGGER, 0, ms(30));
    assert_eq!(h.word(addr::STATUS) & status::TRIGGER_ACK, 0);
    h.write(addr::RESULT_ACK, 1, ms(31));
    assert_eq!(h.word(addr::STATUS) & status::RESULT_VALID, 0);
    assert!(h.read(200, 20).iter().all(|&w| w == 0), "an empty queue reads as zeros");
}

#[test]
fn several_parts_are_queued_in_order_and_a_wrong_ack_is_ignored_and_counted() {
    let mut h = hs(8);
    let id = trigger(&mut h, 0).unwrap();
    h.complete(id, Outcome::Parts { parts: vec![part(1, 10.0), part(2, 20.0), part(3, 30.0)], processing_ms: 5.0 }, ms(10));
    assert_eq!(h.word(addr::RESULTS_PENDING), 3);
    assert_eq!(h.word(addr::RESULT_ACK_IGNORED), 0);
    h.write(addr::RESULT_ACK, 2, ms(11));
    assert_eq!(h.word(addr::RESULT_ACK_IGNORED), 1);
    assert_eq!(h.word(addr::RESULT_SEQ), 1, "a wrong ACK does not pop");
    for (seq, (type_id, index)) in [(1, (1, 1)), (2, (2, 2)), (3, (3, 3))] {
        assert_eq!(h.read(200, 1)[0], seq);
        assert_eq!((h.word(addr::TYPE_ID), h.word(addr::PART_INDEX), h.word(addr::PART_COUNT)), (type_id, index, 3));
        h.write(addr::RESULT_ACK, seq, ms(12));
    }
    assert_eq!(h.word(addr::RESULTS_PENDING), 0);
}

#[test]
fn a_frame_without_parts_queues_one_no_part_result() {
    let mut h = hs(8);
    let id = trigger(&mut h, 0).unwrap();
    h.complete(id, Outcome::Parts { parts: vec![], processing_ms: 3.0 }, ms(5));
    assert_eq!(h.word(addr::DECISION), 2);
    assert_eq!(h.word(addr::REASON), map::reason_code(Reason::NoPart));
    assert_eq!((h.word(addr::PART_INDEX), h.word(addr::PART_COUNT)), (0, 0));
}

#[test]
fn a_trigger_while_busy_offline_or_in_error_is_missed() {
    let mut h = hs(8);
    let id = trigger(&mut h, 0).unwrap();
    assert_eq!(trigger(&mut h, 1), None);
    assert_eq!(h.word(addr::MISSED_TRIGGERS), 1);
    assert_eq!(h.word(addr::ACQ_COUNT), 1);
    h.complete(id, Outcome::Parts { parts: vec![], processing_ms: 1.0 }, ms(5));
    h.write(addr::ONLINE, 0, ms(6));
    assert_eq!(h.word(addr::STATUS) & (status::READY | status::ONLINE), 0);
    assert_eq!(trigger(&mut h, 7), None);
    assert_eq!(h.word(addr::MISSED_TRIGGERS), 2);
    h.write(addr::ONLINE, 1, ms(8));
    let id = trigger(&mut h, 9).unwrap();
    h.complete(id, Outcome::Failed { fault: Fault::Camera }, ms(10));
    assert_eq!(trigger(&mut h, 11), None, "in ERROR");
    assert_eq!(h.word(addr::MISSED_TRIGGERS), 3);
}

#[test]
fn a_camera_lost_between_triggers_is_a_camera_fault_at_once_and_one_never_seen_only_not_ok() {
    // Not found at start-up: CAMERA_OK 0 and READY 0, but no fault to clear.
    let mut h = hs(8);
    h.set_camera_ok(false);
    assert_eq!(h.word(addr::STATUS) & (status::CAMERA_OK | status::READY | status::ERROR), 0);
    // Found, then lost (cable pulled): ERROR with ERROR_CODE 1, no trigger needed.
    h.set_camera_ok(true);
    h.set_camera_ok(true);
    assert_eq!(h.word(addr::STATUS) & (status::CAMERA_OK | status::READY | status::ERROR), status::CAMERA_OK | status::READY);
    h.set_camera_ok(false);
    assert_eq!(h.word(addr::STATUS) & (status::CAMERA_OK | status::READY | status::ERROR), status::ERROR);
    assert_eq!(h.word(addr::ERROR_CODE), error_code::CAMERA);
    // Back again: CAMERA_OK at once, READY only once the PLC has cleared the fault.
    h.set_camera_ok(true);
    assert_eq!(h.word(addr::STATUS) & (status::CAMERA_OK | status::READY | status::ERROR), status::CAMERA_OK | status::ERROR);
    h.write(addr::CLEAR_ERROR, 1, ms(5));
    assert_eq!(h.word(addr::STATUS) & (status::CAMERA_OK | status::READY | status::ERROR), status::CAMERA_OK | status::READY);
}

#[test]
fn a_camera_fault_sets_error_queues_a_frame_error_and_clear_error_clears_it() {
    let mut h = hs(8);
    let id = trigger(&mut h, 0).unwrap();
    h.complete(id, Outcome::Failed { fault: Fault::Frame }, ms(3));
    assert!(h.word(addr::STATUS) & status::ERROR != 0);
    assert_eq!(h.word(addr::ERROR_CODE), error_code::FRAME);
    assert_eq!((h.word(addr::DECISION), h.word(addr::REASON)), (2, map::reason_code(Reason::FrameError)));
    h.write(addr::CLEAR_ERROR, 1, ms(4));
    assert_eq!(h.word(addr::STATUS) & status::ERROR, 0);
    assert_eq!(h.word(addr::ERROR_CODE), 0);
    assert_eq!(h.word(addr::CLEAR_ERROR), 0);
    assert_eq!(h.word(addr::RESULTS_PENDING), 1, "CLEAR_ERROR does not drop results");
}

#[test]
fn a_full_queue_drops_the_newest_and_says_so_until_clear_error() {
    let mut h = hs(2);
    let id = trigger(&mut h, 0).unwrap();
    h.complete(id, Outcome::Parts { parts: vec![part(1, 1.0), part(1, 2.0), part(1, 3.0)], processing_ms: 1.0 }, ms(1));
    assert_eq!(h.word(addr::RESULTS_PENDING), 2);
    assert_eq!(h.word(addr::OVERRUN_COUNT), 1);
    assert!(h.word(addr::STATUS) & status::RESULT_OVERRUN != 0);
    assert!(h.word(addr::STATUS) & status::READY != 0, "a full queue does not clear READY");
    // The kept results are the oldest, and the dropped one consumed no sequence number.
    h.write(addr::RESULT_ACK, 1, ms(2));
    h.write(addr::RESULT_ACK, 2, ms(2));
    let id = trigger(&mut h, 3).unwrap();
    h.complete(id, Outcome::Parts { parts: vec![part(1, 4.0)], processing_ms: 1.0 }, ms(4));
    assert_eq!(h.word(addr::RESULT_SEQ), 3);
    assert!(h.word(addr::STATUS) & status::RESULT_OVERRUN != 0, "stays set");
    h.write(addr::CLEAR_ERROR, 1, ms(5));
    assert_eq!(h.word(addr::STATUS) & status::RESULT_OVERRUN, 0);
}

#[test]
fn result_sequence_wraps_from_65535_to_1() {
    let mut h = hs(1);
    for _ in 0..65535u32 {
        let id = trigger(&mut h, 0).unwrap();
        h.complete(id, Outcome::Parts { parts: vec![], processing_ms: 0.0 }, ms(0));
        let seq = h.word(addr::RESULT_SEQ);
        h.write(addr::RESULT_ACK, seq, ms(0));
    }
    let id = trigger(&mut h, 0).unwrap();
    h.complete(id, Outcome::Parts { parts: vec![], processing_ms: 0.0 }, ms(0));
    assert_eq!(h.word(addr::RESULT_SEQ), 1);
}

#[test]
fn expected_type_turns_other_types_into_wrong_type_rejects() {
    let mut h = hs(8);
    h.write(addr::EXPECTED_TYPE, 2, ms(0));
    let id = trigger(&mut h, 0).unwrap();
    h.complete(id, Outcome::Parts { parts: vec![part(2, 1.0), part(3, 2.0)], processing_ms: 1.0 }, ms(1));
    assert_eq!((h.word(addr::DECISION), h.word(addr::REASON)), (1, 0));
    h.write(addr::RESULT_ACK, 1, ms(2));
    assert_eq!((h.word(addr::DECISION), h.word(addr::REASON), h.word(addr::TYPE_ID)), (2, map::reason_code(Reason::WrongType), 3));
}

#[test]
fn picking_order_is_made_after_the_expected_type_rule() {
    let mut h = hs(8);
    h.write(addr::EXPECTED_TYPE, 2, ms(0));
    let id = trigger(&mut h, 0).unwrap();
    // Detection order: a clevis (3) left of a lever (2), a rejected part in between.
    let mut rejected = part(1, 1.5);
    (rejected.accepted, rejected.reason) = (false, Reason::Covered);
    let done = h.complete(id, Outcome::Parts { parts: vec![part(3, 1.0), rejected, part(2, 2.0)], processing_ms: 1.0 }, ms(1));
    let got: Vec<_> = done.iter().map(|r| (r.index, r.part.type_id, r.part.accepted, r.part.reason, r.detection)).collect();
    assert_eq!(
        got,
        vec![(1, 2, true, Reason::Ok, Some(2)), (2, 3, false, Reason::WrongType, Some(0)), (3, 1, false, Reason::Covered, Some(1)),],
        "the one part the PLC may pick comes first; the rest by x"
    );
    assert_eq!((h.word(addr::PART_INDEX), h.word(addr::TYPE_ID), h.word(addr::DECISION)), (1, 2, 1));
}

#[test]
fn complete_returns_the_final_results_every_consumer_takes() {
    let mut h = hs(1);
    h.write(addr::EXPECTED_TYPE, 2, ms(0));
    let id = trigger(&mut h, 0).unwrap();
    let done = h.complete(id, Outcome::Parts { parts: vec![part(2, 1.0), part(3, 2.0)], processing_ms: 1.0 }, ms(1));
    let got: Vec<_> = done.iter().map(|r| (r.seq, r.index, r.count, r.part.accepted, r.part.reason, r.is_part())).collect();
    // The queue holds one: the second result is made (and returned) but dropped for the PLC.
    assert_eq!(got, vec![(1, 1, 2, true, Reason::Ok, true), (0, 2, 2, false, Reason::WrongType, true)]);
    h.write(addr::RESULT_ACK, 1, ms(2));
    let id = trigger(&mut h, 3).unwrap();
    let none = h.complete(id, Outcome::Parts { parts: vec![], processing_ms: 1.0 }, ms(4));
    assert_eq!((none.len(), none[0].is_part(), none[0].part.reason), (1, false, Reason::NoPart));
    assert!(h.complete(id, Outcome::Parts { parts: vec![part(2, 1.0)], processing_ms: 1.0 }, ms(5)).is_empty(), "not running");
}

#[test]
fn a_fault_names_its_error_code_and_stops_acquiring_until_cleared() {
    for (fault, code) in [(Fault::Camera, error_code::CAMERA), (Fault::Frame, error_code::FRAME)] {
        let mut h = hs(8);
        assert!(h.ready());
        let id = trigger(&mut h, 0).unwrap();
        assert!(!h.ready(), "busy");
        h.complete(id, Outcome::Failed { fault }, ms(1));
        assert_eq!(h.word(addr::ERROR_CODE), code);
        assert!(!h.ready(), "{fault:?}: a frame now would be consumed unseen");
        assert_eq!(h.word(addr::STATUS) & (status::READY | status::ERROR), status::ERROR, "{fault:?}: READY while ERROR");
        h.write(addr::CLEAR_ERROR, 1, ms(2));
        assert!(h.ready());
        assert!(h.word(addr::STATUS) & status::READY != 0, "{fault:?}: READY again once cleared");
    }
}

#[test]
fn heartbeat_floats_and_stale_reports() {
    let mut h = low_first();
    h.tick(Duration::from_millis(65_537_500));
    assert_eq!(h.word(addr::HEARTBEAT), 1, "65537 s wraps to 1");
    assert_eq!(h.word(addr::MAP_VERSION), lfi_bridge::registers::MAP_VERSION);
    assert_eq!(h.word(addr::TYPES_ENROLLED), 3);
    let id = trigger(&mut h, 0).unwrap();
    h.complete(id + 7, Outcome::Parts { parts: vec![part(1, 1.0)], processing_ms: 1.0 }, ms(1));
    assert!(h.busy(), "a report for another acquisition is ignored");
    h.complete(id, Outcome::Parts { parts: vec![part(1, 123.25)], processing_ms: 1.0 }, ms(1));
    let w = h.read(addr::X_F32, 2);
    assert_eq!(f32::from_bits(((w[1] as u32) << 16) | w[0] as u32), 123.25, "low word first");
}

mod over_tcp {
    use super::common::appliance::*;
    use lfi_bridge::registers::{addr, status};
    use std::time::Duration;

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_thousand_cycles_lose_duplicate_and_reorder_nothing() {
        let running = start(&config("", "")).await;
        let mut ctx = plc(running.modbus_addr, 1).await;
        let mut last_seq = 0u16;
        let mut results = 0u32;
        let mut multi = 0u32;
        for n in 1..=1000u16 {
            for block in cycle(&mut ctx).await {
                let (seq, acq, count) = (block[100], block[101], block[111]);
                assert_eq!(seq, last_seq.wrapping_add(1), "cycle {n}: sequence");
                assert_eq!(acq, n, "cycle {n}: result of another acquisition");
                if count > 1 {
                    multi += 1;
                }
                last_seq = seq;
                results += 1;
            }
        }
        let s = read(&mut ctx, 100, 7).await;
        assert_eq!((s[3], s[5], s[6]), (1000, 0, 0), "ACQ_COUNT, OVERRUN_COUNT, MISSED_TRIGGERS");
        assert!(results >= 1000 && multi > 0, "{results} results, {multi} from multi-part frames");
        running.stop().await;
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn two_masters_at_once_never_clobber_each_other() {
        let running = start(&config("", "")).await;
        let addr0 = running.modbus_addr;
        let observer = tokio::spawn(async move {
            let mut ctx = plc(addr0, 1).await;
            let mut checks = 0;
            for i in 0..400u16 {
                write(&mut ctx, addr::EXPECTED_TYPE, 0).await;
                let b = read(&mut ctx, 100, 121).await;
                // One snapshot: RESULT_VALID agrees with RESULTS_PENDING and the result block.
                assert_eq!(b[0] & status::RESULT_VALID != 0, b[4] > 0, "snapshot {i}");
                assert_eq!(b[4] > 0, b[100] != 0, "snapshot {i}");
                checks += 1;
            }
            checks
        });
        let mut ctx = plc(addr0, 1).await;
        for _ in 0..100 {
            cycle(&mut ctx).await;
        }
        assert_eq!(observer.await.unwrap(), 400);
        let s = read(&mut ctx, 103, 4).await;
        assert_eq!((s[0], s[3]), (100, 0), "every trigger acquired, none missed");
        running.stop().await;
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn overrun_over_tcp_and_clear_error() {
        let mut cfg = config("", "");
        cfg.queue_depth = 2;
        let running = start(&cfg).await;
        let mut ctx = plc(running.modbus_addr, 1).await;
        for _ in 0..4 {
            wait_status(&mut ctx, |s| s & status::READY != 0, Duration::from_secs(10)).await;
            write(&mut ctx, addr::TRIGGER, 1).await;
            wait_status(&mut ctx, |s| s & status::BUSY == 0 && s & status::TRIGGER_ACK != 0, Duration::from_secs(10)).await;
            write(&mut ctx, addr::TRIGGER, 0).await;
        }
        let s = read(&mut ctx, 100, 6).await;
        assert!(s[0] & status::RESULT_OVERRUN != 0);
        assert_eq!(s[4], 2);
        assert!(s[5] >= 2, "OVERRUN_COUNT {}", s[5]);
        write(&mut ctx, addr::CLEAR_ERROR, 1).await;
        assert_eq!(read(&mut ctx, 100, 1).await[0] & status::RESULT_OVERRUN, 0);
        running.stop().await;
    }
}

#[test]
fn the_debris_count_of_the_frame_is_served_with_its_results() {
    let mut h = Handshake::new(Settings {
        queue_depth: 4,
        online: true,
        word_order: WordOrder::HighFirst,
        types_enrolled: 3,
        picking_order: PickingOrder::XAscending,
        boot_id: 77,
        job_id: 1,
    });
    let Some(Command::Acquire { acq_id }) = h.write(addr::TRIGGER, 1, Duration::ZERO) else { panic!("no acquisition") };
    h.set_debris(3);
    h.complete(acq_id, Outcome::Parts { parts: vec![], processing_ms: 1.0 }, Duration::from_millis(5));
    assert_eq!(h.word(addr::DEBRIS_COUNT), 3);
    h.set_debris(70_000);
    assert_eq!(h.word(addr::DEBRIS_COUNT), 65535, "saturates");
}

#[test]
fn user_data_is_latched_at_the_trigger_edge_and_comes_back_with_every_result_of_its_frame() {
    let mut h = hs(8);
    // 0x0001_2345 = 74565: over 16 bits, high word first.
    h.write_block(addr::USER_DATA, &[0x0001, 0x2345], ms(0));
    assert_eq!(h.read(addr::USER_DATA, 2), vec![0x0001, 0x2345], "reads back as written");
    let id = trigger(&mut h, 1).unwrap();
    h.write_block(addr::USER_DATA, &[0x0009, 0x9999], ms(2)); // the belt moves on during BUSY
    h.complete(id, Outcome::Parts { parts: vec![part(1, 1.0), part(2, 2.0)], processing_ms: 1.0 }, ms(3));
    for _ in 0..2 {
        assert_eq!(h.read(219, 2), vec![0x0001, 0x2345], "the value at the trigger, in every result of the frame");
        let seq = h.word(addr::RESULT_SEQ);
        h.write(addr::RESULT_ACK, seq, ms(4));
    }
    let id = trigger(&mut h, 5).unwrap();
    h.complete(id, Outcome::Failed { fault: Fault::Camera }, ms(6));
    assert_eq!((h.word(addr::REASON), h.read(219, 2)), (map::reason_code(Reason::FrameError), vec![0x0009, 0x9999]), "frame errors too");
    assert_eq!(h.read(219, 2), h.read(addr::USER_DATA, 2));
}

#[test]
fn one_fc16_writing_user_data_and_trigger_latches_the_new_value() {
    let mut h = hs(8);
    h.write_block(addr::USER_DATA, &[0, 1], ms(0));
    // TRIGGER=1, RESULT_ACK=0, CLEAR_ERROR=0, ONLINE=1, EXPECTED_TYPE=0, USER_DATA=0x0002_0003.
    let cmd = h.write_block(addr::TRIGGER, &[1, 0, 0, 1, 0, 2, 3], ms(1));
    let Some(Command::Acquire { acq_id }) = cmd else { panic!("the trigger edge starts an acquisition") };
    h.write(addr::TRIGGER, 0, ms(1));
    let done = h.complete(acq_id, Outcome::Parts { parts: vec![], processing_ms: 1.0 }, ms(2));
    assert_eq!(done[0].user_data, 0x0002_0003);
    assert_eq!(h.read(219, 2), vec![2, 3]);
}

#[test]
fn user_data_follows_the_float_word_order() {
    let mut h = low_first();
    h.write_block(addr::USER_DATA, &[0x5678, 0x1234], ms(0));
    assert_eq!(h.user_data(), 0x1234_5678);
    let Some(Command::Acquire { acq_id }) = h.free_run(ms(1)) else { panic!("free-run latches when the frame is taken") };
    h.complete(acq_id, Outcome::Parts { parts: vec![part(1, 1.0)], processing_ms: 1.0 }, ms(2));
    assert_eq!(h.read(219, 2), vec![0x5678, 0x1234]);
    assert_eq!(h.word(addr::BOOT_ID), 77);
}

/// OPC UA's vision state follows the flags STATUS shows: never seen a camera, preoperational;
/// ERROR outranks offline; a trigger makes single execution until the frame completes; a
/// job change is initialised; free-run is continuous.
#[test]
fn the_vision_state_follows_status() {
    use lfi_bridge::handshake::{AutoMode, VisionState};
    let mut h = hs(4);
    assert_eq!(h.vision_state(false), VisionState::Preoperational);
    h.set_camera_ok(true);
    assert_eq!(h.vision_state(false), VisionState::Operational(AutoMode::Ready));
    assert_eq!(h.vision_state(true), VisionState::Operational(AutoMode::ContinuousExecution));
    let acq = trigger(&mut h, 10).expect("an acquisition");
    assert_eq!(h.vision_state(false), VisionState::Operational(AutoMode::SingleExecution));
    h.complete(acq, Outcome::Parts { parts: vec![part(1, 5.0)], processing_ms: 3.0 }, ms(20));
    assert_eq!(h.vision_state(false), VisionState::Operational(AutoMode::Ready));
    h.write(addr::ONLINE, 0, ms(30));
    assert_eq!(h.vision_state(false), VisionState::Halted);
    h.set_camera_ok(false); // seen working, then lost: a camera fault
    assert_eq!(h.vision_state(false), VisionState::Error);
    h.set_camera_ok(true);
    h.write(addr::CLEAR_ERROR, 1, ms(40));
    assert_eq!(h.vision_state(false), VisionState::Halted);
    h.write(addr::ONLINE, 1, ms(50));
    h.write(addr::JOB_REQUEST, 2, ms(60));
    assert_eq!(h.vision_state(false), VisionState::Operational(AutoMode::Initialized));
    h.job_changed(2, JobOutcome::InForce { expected_type: None });
    assert_eq!(h.vision_state(false), VisionState::Operational(AutoMode::Ready));
}
