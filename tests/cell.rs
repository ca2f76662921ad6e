//! Fitting a cell, driven through Modbus as a PLC would: USER_DATA latched with each frame for
//! line tracking (in the result block and the robot's words), BOOT_ID across restarts, and jobs
//! switched from the PLC.

mod common;

use std::time::Duration;

use common::appliance::{config, plc, read, start, wait_status, write};
use common::fanuc::Cell;
use lfi_bridge::registers::{addr, status};
use tokio_modbus::prelude::*;

/// The encoder count of cycle `k`: above 16 bits, so both words matter.
fn encoder(k: u32) -> u32 {
    0x0001_0000 * (k + 1) + 0x0123 * k
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn user_data_written_before_each_trigger_comes_back_latched_in_every_result_and_robot_word() {
    let cell = Cell::start(Duration::from_millis(1)).await;
    let running = start(&config("", &cell.robot_toml)).await;
    let mut ctx = plc(running.modbus_addr, 1).await;
    let mut accepted: Vec<u32> = Vec::new();
    let mut results = 0;
    for k in 0..10u32 {
        let v = encoder(k);
        wait_status(&mut ctx, |s| s & status::READY != 0, Duration::from_secs(10)).await;
        ctx.write_multiple_registers(addr::USER_DATA, &[(v >> 16) as u16, v as u16]).await.unwrap().unwrap();
        write(&mut ctx, addr::TRIGGER, 1).await;
        // The belt moves on while the frame is estimated: the frame keeps the value at its trigger.
        ctx.write_multiple_registers(addr::USER_DATA, &[0xFFFF, k as u16]).await.unwrap().unwrap();
        wait_status(&mut ctx, |s| s & status::TRIGGER_ACK != 0 && s & status::BUSY == 0, Duration::from_secs(10)).await;
        write(&mut ctx, addr::TRIGGER, 0).await;
        loop {
            let b = read(&mut ctx, 100, 121).await;
            if b[0] & status::RESULT_VALID == 0 {
                break;
            }
            let latched = ((b[119] as u32) << 16) | b[120] as u32;
            assert_eq!(latched, v, "cycle {k}: result {} (PART_INDEX {}) carries the frame's USER_DATA", b[100], b[110]);
            if b[102] == 1 {
                accepted.push(latched);
            }
            results += 1;
            write(&mut ctx, addr::RESULT_ACK, b[100]).await;
        }
        assert_eq!(read(&mut ctx, addr::USER_DATA, 2).await, vec![0xFFFF, k as u16], "USER_DATA reads back the last write");
    }
    assert!(results >= 10 && accepted.len() >= 5, "{results} results, {} accepted", accepted.len());

    // One FC16 writing TRIGGER and USER_DATA together latches the value it writes.
    wait_status(&mut ctx, |s| s & status::READY != 0, Duration::from_secs(10)).await;
    ctx.write_multiple_registers(addr::TRIGGER, &[1, 0, 0, 1, 0, 0xABCD, 0x0042]).await.unwrap().unwrap();
    wait_status(&mut ctx, |s| s & status::TRIGGER_ACK != 0 && s & status::BUSY == 0, Duration::from_secs(10)).await;
    write(&mut ctx, addr::TRIGGER, 0).await;
    assert_eq!(read(&mut ctx, 219, 2).await, vec![0xABCD, 0x0042]);
    while read(&mut ctx, addr::STATUS, 1).await[0] & status::RESULT_VALID != 0 {
        let b = read(&mut ctx, 200, 21).await;
        if b[2] == 1 {
            accepted.push(0xABCD_0042);
        }
        write(&mut ctx, addr::RESULT_ACK, b[0]).await;
    }

    // The robot got each accepted part with the same value in words 8-9.
    cell.until_acknowledged(accepted.len(), Duration::from_secs(30)).await;
    running.stop().await;
    let picked = cell.picked().await;
    assert_eq!(picked.iter().map(|p| p.user_data).collect::<Vec<_>>(), accepted, "robot words 8-9");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn boot_id_is_non_zero_and_changes_across_a_restart() {
    let mut seen = Vec::new();
    for _ in 0..3 {
        let running = start(&config("", "")).await;
        let mut ctx = plc(running.modbus_addr, 1).await;
        let id = read(&mut ctx, addr::BOOT_ID, 1).await[0];
        assert_ne!(id, 0);
        assert_eq!(read(&mut ctx, addr::BOOT_ID, 1).await[0], id, "steady while running");
        seen.push(id);
        running.stop().await;
    }
    // Three draws of 65535 values: a repeat would be a 1-in-20000 event, not a flaky test.
    assert!(seen[0] != seen[1] || seen[1] != seen[2], "BOOT_ID did not change across restarts: {seen:?}");
}

/// Polls JOB_STATUS until it leaves CHANGING.
async fn job_outcome(ctx: &mut tokio_modbus::client::Context) -> u16 {
    let until = tokio::time::Instant::now() + Duration::from_secs(60);
    loop {
        let st = read(ctx, addr::JOB_STATUS, 1).await[0];
        if st != lfi_bridge::registers::job_status::CHANGING {
            return st;
        }
        assert!(tokio::time::Instant::now() < until, "the job change never ended");
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn jobs_change_from_the_plc_and_a_job_whose_kb_is_missing_fails_leaving_the_job_in_force() {
    use lfi_bridge::registers::job_status;
    let jobs = "[[camera.job]]\nid = 4\nname = \"any type\"\n\
                [[camera.job]]\nid = 12\nname = \"flanges\"\nexpected_type = 2\naccept_threshold = 0.55\n\
                [[camera.job]]\nid = 30\nname = \"gone\"\nkb_from_simulator = false\nkb = \"/nonexistent/kb.toml\"\n";
    let app = start(&config("", jobs)).await;
    let mut ctx = plc(app.modbus_addr, 1).await;
    // The lowest id is in force at start-up; nothing requested yet.
    assert_eq!(read(&mut ctx, addr::JOB_REQUEST, 1).await, [0]);
    assert_eq!(read(&mut ctx, addr::JOB_ID, 2).await, [4, job_status::IDLE]);
    // Ids outside 1..999 are refused.
    for bad in [0u16, 1000] {
        let r = ctx.write_single_register(addr::JOB_REQUEST, bad).await.unwrap();
        assert_eq!(r, Err(ExceptionCode::IllegalDataValue), "JOB_REQUEST = {bad}");
    }
    write(&mut ctx, addr::JOB_REQUEST, 12).await;
    assert_eq!(job_outcome(&mut ctx).await, job_status::DONE);
    assert_eq!(read(&mut ctx, addr::JOB_ID, 1).await, [12]);
    assert_eq!(read(&mut ctx, addr::EXPECTED_TYPE, 1).await, [2], "the job's expected type");
    assert_eq!(read(&mut ctx, addr::JOB_REQUEST, 1).await, [12], "reads back the last request");
    let mut accepted = 0;
    for _ in 0..4 {
        for b in common::appliance::cycle(&mut ctx).await {
            if b[102] == 1 {
                accepted += 1;
                assert_eq!(b[104], 2, "job 12 accepts flanges only (PART_INDEX {})", b[110]);
            }
        }
    }
    assert!(accepted > 0, "job 12 accepted no flange in four frames");
    // A job whose knowledge base is missing fails; the job in force stays and keeps working.
    write(&mut ctx, addr::JOB_REQUEST, 30).await;
    assert_eq!(job_outcome(&mut ctx).await, job_status::FAILED);
    assert_eq!(read(&mut ctx, addr::JOB_ID, 1).await, [12]);
    wait_status(&mut ctx, |s| s & status::READY != 0, Duration::from_secs(10)).await;
    assert!(!common::appliance::cycle(&mut ctx).await.is_empty());
    // So does a job id that is not configured.
    write(&mut ctx, addr::JOB_REQUEST, 5).await;
    assert_eq!(job_outcome(&mut ctx).await, job_status::FAILED);
    assert_eq!(read(&mut ctx, addr::JOB_ID, 1).await, [12]);
    let why = app.cameras[0].live.lock().unwrap().last_error.clone().unwrap_or_default();
    assert!(why.contains("job 5 is not configured") && why.contains("4, 12, 30"), "{why}");
    // Writing the id in force again reloads it.
    write(&mut ctx, addr::JOB_REQUEST, 12).await;
    assert_eq!(job_outcome(&mut ctx).await, job_status::DONE);
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_start_job_s_knowledge_base_must_load() {
    let jobs =
        "start_job = 2\n[[camera.job]]\nid = 1\n[[camera.job]]\nid = 2\nkb_from_simulator = false\nkb = \"/nonexistent/start.toml\"\n";
    let e = match lfi_bridge::start(&config("", jobs)).await {
        Ok(app) => {
            app.stop().await;
            panic!("started without the start job's knowledge base")
        }
        Err(e) => e,
    };
    let text = lfi_bridge::logging::error_chain(&e);
    assert!(text.contains("/nonexistent/start.toml"), "{text}");
}
