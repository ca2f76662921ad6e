//! The Modbus/TCP server the PLC polls: accept loop, connection limit, idle timeout, per-client
//! sessions. Everything protocol-specific is in [`super::frame`] and [`super::service`].

use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpListener;
use tokio_modbus::ExceptionCode;
use tokio_util::sync::CancellationToken;

use super::frame;
use super::service;
use crate::handshake::{Command, Handshake};

/// Server settings (validated by the configuration).
#[derive(Debug, Clone)]
pub struct Settings {
    /// Connections served at once; a new client takes the slot of the one idle longest.
    pub max_connections: usize,
    /// A connection with no complete request for this long is closed.
    pub idle_timeout: Duration,
    /// A request must be complete this long after its first byte, else the connection closes
    /// (a client trickling bytes cannot hold a slot).
    pub frame_timeout: Duration,
    /// Clients allowed to write; empty: all.
    pub write_allow: Vec<IpAddr>,
}

/// One camera as the server sees it: its handshake and where its commands go.
pub struct Station {
    /// Its Modbus unit id.
    pub unit_id: u8,
    /// Its handshake, which every request reads and writes.
    pub handshake: Arc<Mutex<Handshake>>,
    /// Into the camera's worker (acquisitions, job changes).
    pub commands: std::sync::mpsc::Sender<Command>,
    /// The address that last wrote to this camera, and when a second writer was last logged
    /// (two writers each consume results the other never sees; logged at most once a minute).
    pub last_writer: Mutex<(Option<IpAddr>, Option<Instant>)>,
}

/// All cameras, addressed by Modbus unit id (0 and 255 reach the first).
pub struct Stations {
    stations: Vec<Station>,
    by_unit: HashMap<u8, usize>,
    started: Instant,
}

impl Stations {
    /// The stations by unit id, and the appliance's start (for HEARTBEAT).
    pub fn new(stations: Vec<Station>, started: Instant) -> Self {
        let mut by_unit: HashMap<u8, usize> = stations.iter().enumerate().map(|(i, s)| (s.unit_id, i)).collect();
        if !stations.is_empty() {
            by_unit.entry(0).or_insert(0);
            by_unit.entry(255).or_insert(0);
        }
        Self { stations, by_unit, started }
    }
    /// The station answering `unit`, if any.
    pub fn get(&self, unit: u8) -> Option<&Station> {
        self.by_unit.get(&unit).map(|&i| &self.stations[i])
    }
    /// Every station, in configuration order.
    pub fn all(&self) -> &[Station] {
        &self.stations
    }
    /// Time since the appliance started.
    pub fn since_start(&self) -> Duration {
        self.started.elapsed()
    }
}

/// Live numbers of the server (for logs and the operator view).
#[derive(Debug, Default)]
pub struct Stats {
    /// Connections open now.
    pub connected: AtomicUsize,
    /// Connections refused (none left to take over).
    pub refused: AtomicUsize,
    /// Requests answered.
    pub requests: AtomicUsize,
    /// Requests answered with an exception.
    pub exceptions: AtomicUsize,
}

/// A connection with no complete request for at least this long gives its slot to a new client
/// when all slots are taken (a PLC polls far more often).
pub const RECLAIM_IDLE: Duration = Duration::from_secs(1);

/// The open connections, so that a new client can take the slot of the longest-silent one.
#[derive(Default)]
struct Slots {
    open: Mutex<Vec<Slot>>,
    next_id: AtomicUsize,
}

struct Slot {
    id: usize,
    peer: SocketAddr,
    /// When it last completed a request (or connected), shared with its session.
    last_request: Arc<Mutex<tokio::time::Instant>>,
    close: CancellationToken,
}

impl Slots {
    /// Registers a new connection, closing the longest-silent one if all `max` slots are taken
    /// and it has been silent for [`RECLAIM_IDLE`]; None when every slot is in use.
    fn take(
        &self,
        peer: SocketAddr,
        max: usize,
        shutdown: &CancellationToken,
    ) -> Option<(usize, Arc<Mutex<tokio::time::Instant>>, CancellationToken)> {
        let mut open = self.open.lock().unwrap_or_else(|p| p.into_inner());
        if open.len() >= max {
            let now = tokio::time::Instant::now();
            let idle = |s: &Slot| now.duration_since(*s.last_request.lock().unwrap_or_else(|p| p.into_inner()));
            let (i, longest) = open.iter().enumerate().map(|(i, s)| (i, idle(s))).max_by_key(|(_, d)| *d)?;
            if longest < RECLAIM_IDLE {
                return None;
            }
            let old = open.swap_remove(i);
            tracing::warn!(
                %peer,
                "all {max} Modbus slots taken: closing {} (no complete request for {:.1} s) to serve the new client",
                old.peer,
                longest.as_secs_f64()
            );
            old.close.cancel();
        }
        let id = self.next_id.fetch_add(1, Ordering::Relaxed);
        let last_request = Arc::new(Mutex::new(tokio::time::Instant::now()));
        let close = shutdown.child_token();
        open.push(Slot { id, peer, last_request: last_request.clone(), close: close.clone() });
        Some((id, last_request, close))
    }

    fn release(&self, id: usize) {
        self.open.lock().unwrap_or_else(|p| p.into_inner()).retain(|s| s.id != id);
    }
}

/// Handles one request ADU and returns the response bytes.
pub fn respond(stations: &Stations, adu: &frame::Adu, peer: IpAddr, write_allow: &[IpAddr], stats: &Stats) -> Vec<u8> {
    let fc = adu.pdu.first().copied().unwrap_or(0);
    stats.requests.fetch_add(1, Ordering::Relaxed);
    let result = (|| {
        let station = stations.get(adu.unit).ok_or(ExceptionCode::GatewayTargetDevice)?;
        if adu.overlong {
            return Err(ExceptionCode::IllegalDataValue);
        }
        let req = frame::parse_request(&adu.pdu)?;
        let may_write = write_allow.is_empty() || write_allow.contains(&peer);
        let (resp, cmds) = {
            let mut hs = station.handshake.lock().unwrap_or_else(|p| p.into_inner());
            service::handle(&mut hs, &req, may_write, stations.since_start())?
        };
        if matches!(fc, 0x06 | 0x10) {
            let mut last = station.last_writer.lock().unwrap_or_else(|p| p.into_inner());
            if let Some(before) = last.0.filter(|w| *w != peer)
                && last.1.is_none_or(|t| t.elapsed() >= Duration::from_secs(60))
            {
                tracing::warn!(%peer, unit = adu.unit, "a second client writes to this camera (before: {before}): two writers each consume results the other never sees; set write_allow (logged at most once a minute)");
                last.1 = Some(Instant::now());
            }
            last.0 = Some(peer);
        }
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
    let slots = Arc::new(Slots::default());
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
        let Some((id, last_request, close)) = slots.take(peer, settings.max_connections, &shutdown) else {
            stats.refused.fetch_add(1, Ordering::Relaxed);
            tracing::warn!(
                %peer,
                "Modbus connection refused: all {} slots in use by clients active within {} s (max_connections)",
                settings.max_connections,
                RECLAIM_IDLE.as_secs()
            );
            drop(stream);
            continue;
        };
        stats.connected.fetch_add(1, Ordering::SeqCst);
        tracing::info!(%peer, "Modbus client connected ({} now)", stats.connected.load(Ordering::SeqCst));
        let (stations, settings, stats, slots) = (stations.clone(), settings.clone(), stats.clone(), slots.clone());
        let _ = stream.set_nodelay(true);
        tokio::spawn(async move {
            let why = session(stream, peer, &stations, &settings, &stats, &last_request, close).await;
            slots.release(id);
            stats.connected.fetch_sub(1, Ordering::SeqCst);
            tracing::info!(%peer, "Modbus client disconnected: {why}");
        });
    }
    tracing::info!("Modbus server stopped accepting");
}

/// One client's request/response loop over any byte stream (a TCP connection; an in-memory
/// pipe in the tests, on tokio's paused clock); returns why it ended.
async fn session<S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin>(
    mut stream: S,
    peer: SocketAddr,
    stations: &Stations,
    settings: &Settings,
    stats: &Stats,
    last_request: &Mutex<tokio::time::Instant>,
    close: CancellationToken,
) -> String {
    let mut buf: Vec<u8> = Vec::with_capacity(512);
    let mut chunk = [0u8; 1024];
    // Idle time counts from the last complete request (`last_request`, which the slot table
    // reads too), not the last byte; a request under way must be complete within
    // `frame_timeout` of its first byte.
    let mut frame_since: Option<tokio::time::Instant> = None;
    loop {
        loop {
            match frame::decode(&mut buf) {
                Ok(Some(adu)) => {
                    frame_since = None;
                    *last_request.lock().unwrap_or_else(|p| p.into_inner()) = tokio::time::Instant::now();
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
        if buf.is_empty() {
            frame_since = None;
        } else if frame_since.is_none() {
            frame_since = Some(tokio::time::Instant::now());
        }
        let idle_since = *last_request.lock().unwrap_or_else(|p| p.into_inner());
        let idle_end = idle_since + settings.idle_timeout;
        let deadline = frame_since.map_or(idle_end, |t| (t + settings.frame_timeout).min(idle_end));
        let n = tokio::select! {
            _ = close.cancelled() => return "closed (server shutting down, or its slot given to a new client)".into(),
            r = tokio::time::timeout_at(deadline, stream.read(&mut chunk)) => match r {
                Err(_) if deadline < idle_end => {
                    tracing::warn!(%peer, "closing Modbus connection: a request incomplete {} ms after its first byte ({} bytes)", settings.frame_timeout.as_millis(), buf.len());
                    return format!("request incomplete after {} ms", settings.frame_timeout.as_millis());
                }
                Err(_) => return format!("no complete request for {:.1} s", settings.idle_timeout.as_secs_f64()),
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

#[cfg(test)]
mod tests {
    //! The connection's deadlines and the slot table on tokio's paused clock: an in-memory pipe
    //! stands in for the socket, and a minute of silence takes no time at all.
    use super::*;
    use crate::handshake::{PickingOrder, Settings as HsSettings, WordOrder};

    fn stations() -> Stations {
        let hs = Handshake::new(HsSettings {
            queue_depth: 4,
            online: true,
            word_order: WordOrder::HighFirst,
            types_enrolled: 3,
            picking_order: PickingOrder::XAscending,
            boot_id: 1,
            job_id: 1,
        });
        let (commands, _) = std::sync::mpsc::channel();
        let station = Station { unit_id: 1, handshake: Arc::new(Mutex::new(hs)), commands, last_writer: Mutex::new((None, None)) };
        Stations::new(vec![station], Instant::now())
    }

    fn settings() -> Settings {
        Settings {
            max_connections: 2,
            idle_timeout: Duration::from_secs(60),
            frame_timeout: Duration::from_secs(3),
            write_allow: Vec::new(),
        }
    }

    fn peer() -> SocketAddr {
        "10.0.0.7:50000".parse().unwrap()
    }

    /// FC3 of STATUS (100), one register, transaction `t`.
    fn read_status(t: u16) -> Vec<u8> {
        let [t0, t1] = t.to_be_bytes();
        vec![t0, t1, 0, 0, 0, 6, 1, 3, 0, 100, 0, 1]
    }

    /// Runs a session on one end of a pipe; the other end is the client's.
    fn open(
        stations: Arc<Stations>,
    ) -> (tokio::io::DuplexStream, tokio::task::JoinHandle<(String, tokio::time::Instant)>, Arc<Mutex<tokio::time::Instant>>) {
        let (client, server) = tokio::io::duplex(1024);
        let last = Arc::new(Mutex::new(tokio::time::Instant::now()));
        let l = last.clone();
        let task = tokio::spawn(async move {
            let why = session(server, peer(), &stations, &settings(), &Stats::default(), &l, CancellationToken::new()).await;
            (why, tokio::time::Instant::now())
        });
        (client, task, last)
    }

    #[tokio::test(start_paused = true)]
    async fn a_silent_client_is_closed_after_the_idle_timeout_counted_from_its_last_request() {
        let stations = Arc::new(stations());
        let t0 = tokio::time::Instant::now();
        let (mut client, task, _) = open(stations);
        // A request at 30 s: the idle time starts again from there.
        tokio::time::sleep(Duration::from_secs(30)).await;
        client.write_all(&read_status(1)).await.unwrap();
        let mut resp = [0u8; 11];
        client.read_exact(&mut resp).await.unwrap();
        assert_eq!(&resp[..2], &[0, 1], "the answer to transaction 1");
        let (why, ended) = task.await.unwrap();
        assert!(why.starts_with("no complete request for 60.0 s"), "{why}");
        let after = ended - t0;
        assert!(after >= Duration::from_secs(90) && after < Duration::from_secs(91), "closed {after:?} after opening");
    }

    #[tokio::test(start_paused = true)]
    async fn a_trickling_client_is_closed_at_the_frame_timeout_whatever_its_bytes() {
        let stations = Arc::new(stations());
        let t0 = tokio::time::Instant::now();
        let (mut client, task, _) = open(stations);
        // One byte a second: each restarts no timer, the request must be whole within 3 s.
        for b in read_status(2).into_iter().take(8) {
            if client.write_all(&[b]).await.is_err() {
                break; // closed by the server
            }
            tokio::time::sleep(Duration::from_secs(1)).await;
        }
        let (why, ended) = task.await.unwrap();
        assert!(why.starts_with("request incomplete after 3000 ms"), "{why}");
        let after = ended - t0;
        assert!(after >= Duration::from_secs(3) && after < Duration::from_secs(4), "closed {after:?} after the first byte");
    }

    #[tokio::test(start_paused = true)]
    async fn a_new_client_takes_the_slot_of_the_one_silent_longest_once_it_has_been_silent_a_second() {
        let slots = Slots::default();
        let shutdown = CancellationToken::new();
        let (_, a_last, a_close) = slots.take(peer(), 2, &shutdown).unwrap();
        tokio::time::advance(Duration::from_millis(300)).await;
        let (_, b_last, b_close) = slots.take(peer(), 2, &shutdown).unwrap();
        // Both active within RECLAIM_IDLE: a third is refused.
        assert!(slots.take(peer(), 2, &shutdown).is_none());
        // b keeps polling; a falls silent.
        tokio::time::advance(RECLAIM_IDLE).await;
        *b_last.lock().unwrap() = tokio::time::Instant::now();
        let third = slots.take(peer(), 2, &shutdown);
        assert!(third.is_some(), "a slot silent for {RECLAIM_IDLE:?} goes to the new client");
        assert!(a_close.is_cancelled() && !b_close.is_cancelled(), "the silent one is closed, the polling one kept");
        drop(a_last);
    }
}
