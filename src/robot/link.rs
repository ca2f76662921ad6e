//! The robot link's driver: a tokio-modbus client that connects (and reconnects with back-off),
//! polls the robot's output words, and performs the [`super::Link`]'s writes.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio_modbus::prelude::*;
use tokio_util::sync::CancellationToken;

use super::{Action, Link, output};
use crate::config::RobotConfig;
use crate::handshake::Queued;
use crate::registers::RobotView;

async fn resolve(address: &str) -> std::io::Result<std::net::SocketAddr> {
    tokio::net::lookup_host(address)
        .await?
        .next()
        .ok_or_else(|| std::io::Error::new(std::io::ErrorKind::NotFound, format!("{address} resolves to no address")))
}

fn flat<T>(r: tokio_modbus::Result<T>) -> Result<T, String> {
    match r {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(e)) => Err(format!("robot answered exception {e:?}")),
        Err(e) => Err(e.to_string()),
    }
}

/// Carries the link's actions out on the connection; the first failure ends the connection.
async fn perform(
    ctx: &mut tokio_modbus::client::Context,
    cfg: &RobotConfig,
    camera: &str,
    actions: &[Action],
    link: &mut Link,
) -> Result<(), String> {
    for a in actions {
        match a {
            Action::Send { seq, words } => {
                let sent = async {
                    flat(ctx.write_multiple_registers(cfg.input_words_at + super::input::TYPE_ID, words).await)?;
                    flat(ctx.write_single_register(cfg.input_words_at + super::input::DATA_SEQ, *seq).await)
                }
                .await;
                if let Err(e) = sent {
                    link.on_send_failed();
                    return Err(format!("writing part {seq}: {e}"));
                }
                tracing::info!(
                    camera = %camera,
                    seq,
                    "part handed to the robot: type {} face {} angle {} x {} y {}",
                    words[0],
                    words[1],
                    words[2] as i16,
                    words[3] as i16,
                    words[4] as i16
                );
            }
            Action::Heartbeat { value } => {
                flat(ctx.write_single_register(cfg.input_words_at + super::input::HEARTBEAT, *value).await)
                    .map_err(|e| format!("writing heartbeat: {e}"))?;
            }
            Action::ReportAckTimeout { seq, waited } => {
                tracing::warn!(camera = %camera, "robot did not acknowledge DATA_SEQ {seq} within {:.1} s; keeping the part", waited.as_secs_f64());
            }
        }
    }
    Ok(())
}

/// Runs the link until `shutdown`; parts arrive on `parts` (the handshake's final results).
pub async fn run(
    camera: String,
    cfg: RobotConfig,
    mut parts: tokio::sync::mpsc::UnboundedReceiver<Queued>,
    view: Arc<Mutex<RobotView>>,
    shutdown: CancellationToken,
) {
    let mut link = Link::new(cfg.queue_depth, cfg.ack_timeout, cfg.word_order);
    let start = Instant::now();
    let mut backoff = Duration::from_millis(100);
    let mut last_complaint: Option<Instant> = None;
    let publish = |link: &Link| *view.lock().unwrap_or_else(|p| p.into_inner()) = link.view();
    let drain = |link: &mut Link, parts: &mut tokio::sync::mpsc::UnboundedReceiver<Queued>| {
        while let Ok(p) = parts.try_recv() {
            let (acq, index) = (p.acq_id, p.index);
            if !link.enqueue(p) {
                tracing::warn!(camera = %camera, acq, part = index, "robot queue full ({} parts): part dropped", cfg.queue_depth);
            }
        }
    };
    'outer: while !shutdown.is_cancelled() {
        drain(&mut link, &mut parts);
        publish(&link);
        let connected = match resolve(&cfg.address).await {
            Ok(addr) => tokio::time::timeout(Duration::from_secs(2), tcp::connect_slave(addr, Slave(cfg.unit_id)))
                .await
                .map_err(|_| "connect timed out".to_string())
                .and_then(|r| r.map_err(|e| e.to_string())),
            Err(e) => Err(e.to_string()),
        };
        let mut ctx = match connected {
            Ok(c) => c,
            Err(e) => {
                if last_complaint.is_none_or(|t| t.elapsed() > Duration::from_secs(30)) {
                    tracing::warn!(camera = %camera, "robot controller {} unreachable: {e}; retrying (parts waiting: {})", cfg.address, link.pending());
                    last_complaint = Some(Instant::now());
                }
                tokio::select! {
                    _ = shutdown.cancelled() => break,
                    _ = tokio::time::sleep(backoff) => {}
                }
                backoff = (backoff * 2).min(Duration::from_secs(5));
                continue;
            }
        };
        backoff = Duration::from_millis(100);
        last_complaint = None;
        link.on_connected(start.elapsed());
        tracing::info!(camera = %camera, "connected to robot controller {} (unit {})", cfg.address, cfg.unit_id);
        let why = loop {
            drain(&mut link, &mut parts);
            let outputs = if cfg.output_function == 4 {
                ctx.read_input_registers(cfg.output_words_at, output::COUNT).await
            } else {
                ctx.read_holding_registers(cfg.output_words_at, output::COUNT).await
            };
            let words = match flat(outputs) {
                Ok(w) if w.len() == 2 => w,
                Ok(w) => break format!("robot returned {} output words, expected 2", w.len()),
                Err(e) => break e,
            };
            let now = start.elapsed();
            let mut actions: Vec<Action> = link.on_outputs(words[0], words[1], now).into_iter().collect();
            if link.poll_timeout().is_some_and(|t| t <= now) {
                actions.extend(link.handle_timeout(now));
            }
            if let Err(e) = perform(&mut ctx, &cfg, &camera, &actions, &mut link).await {
                break e;
            }
            publish(&link);
            tokio::select! {
                _ = shutdown.cancelled() => {
                    let _ = ctx.disconnect().await;
                    link.on_disconnected();
                    publish(&link);
                    break 'outer;
                }
                _ = tokio::time::sleep(cfg.poll) => {}
            }
        };
        link.on_disconnected();
        publish(&link);
        let _ = ctx.disconnect().await;
        tracing::warn!(camera = %camera, "robot connection lost: {why}; reconnecting (parts waiting: {})", link.pending());
    }
    tracing::info!(camera = %camera, "robot link stopped ({} parts not delivered)", link.pending());
}
