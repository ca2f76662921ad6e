//! Fitting a cell, driven through Modbus as a PLC would: USER_DATA latched with each frame for
//! line tracking (in the result block and the robot's words), and BOOT_ID across restarts.

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
