//! The Modbus/TCP server the PLC polls: accept loop, connection limit, idle timeout, per-client
//! sessions. Everything protocol-specific is in [`super::frame`] and [`super::service`].

use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio_modbus::ExceptionCode;
use tokio_util::sync::CancellationToken;

use super::frame;
use super::service;
use crate::handshake::{Command, Handshake};

/// Server settings (validated by the configuration).
#[derive(Debug, Clone)]
pub struct Settings {
    pub max_connections: usize,
    pub idle_timeout: Duration,
    /// Clients allowed to write; empty: all.
    pub write_allow: Vec<IpAddr>,
}

/// One camera as the server sees it: its handshake and where its commands go.
pub struct Station {
    pub unit_id: u8,
    pub handshake: Arc<Mutex<Handshake>>,
    pub commands: std::sync::mpsc::Sender<Command>,
}

/// All cameras, addressed by Modbus unit id (0 and 255 reach the first).
pub struct Stations {
    stations: Vec<Station>,
    by_unit: HashMap<u8, usize>,
    started: Instant,
}

impl Stations {
    pub fn new(stations: Vec<Station>, started: Instant) -> Self {
        let mut by_unit: HashMap<u8, usize> = stations.iter().enumerate().map(|(i, s)| (s.unit_id, i)).collect();
        if !stations.is_empty() {
            by_unit.entry(0).or_insert(0);
            by_unit.entry(255).or_insert(0);
        }
        Self { stations, by_unit, started }
    }
    pub fn get(&self, unit: u8) -> Option<&Station> {
        self.by_unit.get(&unit).map(|&i| &self.stations[i])
    }
    pub fn all(&self) -> &[Station] {
        &self.stations
    }
    pub fn since_start(&self) -> Duration {
        self.started.elapsed()
    }
}

/// Live numbers of the server (for logs and the operator view).
#[derive(Debug, Default)]
pub struct Stats {
    pub connected: AtomicUsize,
    pub refused: AtomicUsize,
    pub requests: AtomicUsize,
    pub exceptions: AtomicUsize,
}

/// Handles one request ADU and returns the response bytes.
pub fn respond(stations: &Stations, adu: &frame::Adu, peer: IpAddr, write_allow: &[IpAddr], stats: &Stats) -> Vec<u8> {
    let fc = adu.pdu.first().copied().unwrap_or(0);
    stats.requests.fetch_add(1, Ordering::Relaxed);
    let result = (|| {
        let station = stations.get(adu.unit).ok_or(ExceptionCode::GatewayTargetDevice)?;
        let req = frame::parse_request(&adu.pdu)?;
        let may_write = write_allow.is_empty() || write_allow.contains(&peer);
        let (resp, cmds) = {
            let mut hs = station.handshake.lock().unwrap_or_else(|p| p.into_inner());
            service::handle(&mut hs, &req, may_write, stations.since_start())?
        };
        for c in cmds {
            // A worker that is gone (shutting down) leaves the acquisition BUSY; nothing to do.
            let _ = station.commands.send(c);
        }
        Ok(resp)
    })();
    if let Err(e) = &result {
        stats.exceptions.fetch_add(1, Ordering::Relaxed);
        if *e == ExceptionCode::IllegalFunction && matches!(fc, 0x06 | 0x10) {
            tracing::warn!(%peer, unit = adu.unit, "write refused: {peer} is not in write_allow");
        } else {
            tracing::debug!(%peer, unit = adu.unit, fc, "exception {e:?}");
        }
    }
    frame::encode(adu.transaction, adu.unit, fc, &result)
}

/// Serves until `shutdown` is cancelled. Accept failures (e.g. out of file descriptors) are
/// logged and retried with back-off; they never end the server or other clients' sessions.
pub async fn serve(listener: TcpListener, stations: Arc<Stations>, settings: Settings, stats: Arc<Stats>, shutdown: CancellationToken) {
    let mut backoff = Duration::from_millis(10);
    loop {
        let accepted = tokio::select! {
            _ = shutdown.cancelled() => break,
            a = listener.accept() => a,
        };
        let (stream, peer) = match accepted {
            Ok(a) => {
                backoff = Duration::from_millis(10);
                a
            }
            Err(e) => {
                tracing::warn!("accepting a Modbus connection failed: {e}; retrying in {} ms", backoff.as_millis());
                tokio::select! {
                    _ = shutdown.cancelled() => break,
                    _ = tokio::time::sleep(backoff) => {}
                }
                backoff = (backoff * 2).min(Duration::from_secs(1));
                continue;
            }
        };
        if stats.connected.load(Ordering::SeqCst) >= settings.max_connections {
            stats.refused.fetch_add(1, Ordering::Relaxed);
            tracing::warn!(%peer, "Modbus connection refused: {} clients connected (max_connections)", settings.max_connections);
            drop(stream);
            continue;
        }
        stats.connected.fetch_add(1, Ordering::SeqCst);
        tracing::info!(%peer, "Modbus client connected ({} now)", stats.connected.load(Ordering::SeqCst));
        let (stations, settings, stats, shutdown) = (stations.clone(), settings.clone(), stats.clone(), shutdown.clone());
        tokio::spawn(async move {
            let why = session(stream, peer, &stations, &settings, &stats, shutdown).await;
            stats.connected.fetch_sub(1, Ordering::SeqCst);
            tracing::info!(%peer, "Modbus client disconnected: {why}");
        });
    }
    tracing::info!("Modbus server stopped accepting");
}

/// One client's request/response loop; returns why it ended.
async fn session(
    mut stream: TcpStream,
    peer: SocketAddr,
    stations: &Stations,
    settings: &Settings,
    stats: &Stats,
    shutdown: CancellationToken,
) -> String {
    let _ = stream.set_nodelay(true);
    let mut buf: Vec<u8> = Vec::with_capacity(512);
    let mut chunk = [0u8; 1024];
    loop {
        loop {
            match frame::decode(&mut buf) {
                Ok(Some(adu)) => {
                    let out = respond(stations, &adu, peer.ip(), &settings.write_allow, stats);
                    if let Err(e) = stream.write_all(&out).await {
                        return format!("write failed: {e}");
                    }
                }
                Ok(None) => break,
                Err(e) => {
                    tracing::warn!(%peer, "closing Modbus connection: {e}");
                    return format!("malformed frame: {e}");
                }
            }
        }
        let n = tokio::select! {
            _ = shutdown.cancelled() => return "server shutting down".into(),
            r = tokio::time::timeout(settings.idle_timeout, stream.read(&mut chunk)) => match r {
                Err(_) => return format!("idle for {} s", settings.idle_timeout.as_secs()),
                Ok(Err(e)) => return format!("read failed: {e}"),
                Ok(Ok(0)) => return "closed by client".into(),
                Ok(Ok(n)) => n,
            },
        };
        // The buffer never holds more than one incomplete frame (the length field is checked
        // before waiting for the rest), so a peer cannot make it grow.
        buf.extend_from_slice(&chunk[..n]);
    }
}
