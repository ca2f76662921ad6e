//! Operator-view clients asking for the live frame over and over: the load of
//! `tests/hardening.rs` and of `cargo bench --bench plc` (which takes this file by its path).

#![allow(dead_code)]

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering::Relaxed};
use std::time::Duration;

/// The clients run on a thread of their own at the lowest priority: they are other machines,
/// whose CPU is not the appliance's, so a measurement beside them sees the appliance's share.
pub struct LiveFrameLoad {
    /// While set, every client asks again as soon as it has its answer.
    pub on: Arc<AtomicBool>,
    /// No client has a request under way.
    pub idle: Arc<AtomicBool>,
    /// Live frames answered with 200 so far.
    pub answered: Arc<AtomicUsize>,
    stop: Arc<AtomicBool>,
    thread: std::thread::JoinHandle<()>,
}

impl LiveFrameLoad {
    /// `clients` clients of the operator view at `web`, asking while `on` is set (off at first).
    pub fn start(web: SocketAddr, clients: usize) -> Self {
        let (on, idle, answered, stop) = (
            Arc::new(AtomicBool::new(false)),
            Arc::new(AtomicBool::new(true)),
            Arc::new(AtomicUsize::new(0)),
            Arc::new(AtomicBool::new(false)),
        );
        let (on2, idle2, answered2, stop2) = (on.clone(), idle.clone(), answered.clone(), stop.clone());
        let thread = std::thread::spawn(move || {
            // SAFETY: setpriority on this thread's own id.
            unsafe { libc::setpriority(libc::PRIO_PROCESS, libc::gettid() as libc::id_t, 19) };
            let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
            rt.block_on(async move {
                use tokio::io::{AsyncReadExt, AsyncWriteExt};
                while !stop2.load(Relaxed) {
                    if !on2.load(Relaxed) {
                        tokio::time::sleep(Duration::from_millis(2)).await;
                        continue;
                    }
                    idle2.store(false, Relaxed);
                    let tasks: Vec<_> = (0..clients)
                        .map(|_| {
                            let (on, answered) = (on2.clone(), answered2.clone());
                            tokio::spawn(async move {
                                while on.load(Relaxed) {
                                    let Ok(mut s) = tokio::net::TcpStream::connect(web).await else { continue };
                                    let ask = b"GET /api/camera/1/frame.jpg HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n";
                                    if s.write_all(ask).await.is_err() {
                                        continue;
                                    }
                                    let mut out = Vec::new();
                                    if let Ok(Ok(_)) = tokio::time::timeout(Duration::from_secs(20), s.read_to_end(&mut out)).await {
                                        answered.fetch_add(out.starts_with(b"HTTP/1.1 200") as usize, Relaxed);
                                    }
                                }
                            })
                        })
                        .collect();
                    for t in tasks {
                        let _ = t.await;
                    }
                    idle2.store(true, Relaxed);
                }
            })
        });
        Self { on, idle, answered, stop, thread }
    }

    /// Stops the clients; the thread to join (it ends once their last answers are in).
    pub fn stop(self) -> std::thread::JoinHandle<()> {
        self.on.store(false, Relaxed);
        self.stop.store(true, Relaxed);
        self.thread
    }
}
