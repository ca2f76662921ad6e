//! Starting the appliance in-process for socket-level tests, and a PLC-side client.

#![allow(dead_code)]

use std::net::SocketAddr;
use std::path::Path;
use std::time::Duration;

use lfi_bridge::appliance::Running;
use lfi_bridge::config::Config;
use tokio_modbus::prelude::*;

/// A small simulated camera (fast to render and estimate) at unit id 1, plus extra TOML.
pub fn config(extra_modbus: &str, camera_extra: &str) -> Config {
    let text = format!(
        "[modbus]\nbind = \"127.0.0.1:0\"\n{extra_modbus}\n[http]\nbind = \"127.0.0.1:0\"\ntoken = \"test-token-123\"\n[log]\nlevel = \"warn\"\n[[camera]]\nunit_id = 1\nkb_from_simulator = true\nmm_per_px = 0.5\n{camera_extra}\n[camera.source]\nkind = \"sim\"\nwidth = 640\nheight = 480\nscenes = 9\nseed = 4\n"
    );
    Config::from_toml(&text, Path::new("test.toml")).expect("test configuration is valid")
}

/// The appliance as the binary runs it: OpenCV on one thread (`lfi-bridge`'s default
/// `--cv-threads 1`), so that the camera worker and the operator view's encoder share no OpenCV
/// worker pool here either (a pool's threads take the priority of whoever started them).
pub async fn start(cfg: &Config) -> Running {
    opencv::core::set_num_threads(1).expect("OpenCV threads");
    lfi_bridge::start(cfg).await.expect("appliance starts")
}

pub async fn plc(addr: SocketAddr, unit: u8) -> client::Context {
    tcp::connect_slave(addr, Slave(unit)).await.expect("connect")
}

pub async fn read(ctx: &mut client::Context, a: u16, n: u16) -> Vec<u16> {
    ctx.read_holding_registers(a, n).await.expect("io").expect("no exception")
}

pub async fn write(ctx: &mut client::Context, a: u16, v: u16) {
    ctx.write_single_register(a, v).await.expect("io").expect("no exception");
}

/// Polls STATUS until `pred` holds (or panics after `limit`).
pub async fn wait_status(ctx: &mut client::Context, pred: impl Fn(u16) -> bool, limit: Duration) -> u16 {
    let until = tokio::time::Instant::now() + limit;
    loop {
        let s = read(ctx, 100, 1).await[0];
        if pred(s) {
            return s;
        }
        assert!(tokio::time::Instant::now() < until, "STATUS {s:#010b} never satisfied the condition");
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
}

/// One PLC cycle: waits for READY, triggers, waits for the acknowledgement and BUSY = 0, releases
/// TRIGGER, then consumes every queued result. Returns each result's block of registers 100..220
/// (index 0 is STATUS, index 100 RESULT_SEQ), in the order consumed.
pub async fn cycle(ctx: &mut client::Context) -> Vec<Vec<u16>> {
    use lfi_bridge::registers::{addr, status};
    wait_status(ctx, |s| s & status::READY != 0, Duration::from_secs(10)).await;
    write(ctx, addr::TRIGGER, 1).await;
    wait_status(ctx, |s| s & status::TRIGGER_ACK != 0 && s & status::BUSY == 0, Duration::from_secs(10)).await;
    write(ctx, addr::TRIGGER, 0).await;
    let mut results = Vec::new();
    loop {
        let block = read(ctx, 100, 121).await;
        if block[0] & status::RESULT_VALID == 0 {
            return results;
        }
        write(ctx, addr::RESULT_ACK, block[100]).await;
        results.push(block);
    }
}
