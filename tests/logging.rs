//! The log under a flood: a line repeated by a thousand clients is written a bounded number of
//! times and then counted, while every result line (what the PLC was told) is still written.

mod common;

use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use lfi_bridge::config::Config;
use lfi_bridge::logging::{self, BURST, PER_MINUTE, Throttle};
use lfi_bridge::registers::addr;

/// The log in memory.
#[derive(Clone, Default)]
struct Log(Arc<Mutex<Vec<u8>>>);

impl Write for Log {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(b);
        Ok(b.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Log {
    fn lines_with(&self, needles: &[&str]) -> usize {
        let text = String::from_utf8_lossy(&self.0.lock().unwrap()).into_owned();
        text.lines().filter(|l| needles.iter().all(|n| l.contains(n))).count()
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn repeated_lines_are_rate_limited_with_a_count_and_results_never_are() {
    let log = Log::default();
    let sink = log.clone();
    let throttle = Throttle { summary_every: Duration::from_millis(500) };
    tracing::subscriber::set_global_default(logging::subscriber("info", false, move || sink.clone(), Some(throttle))).unwrap();

    // Nobody on 127.0.0.1 may write; the camera runs free so results flow without a PLC.
    let text = "[modbus]\nbind = \"127.0.0.1:0\"\nwrite_allow = [\"10.9.9.9\"]\n[[camera]]\nunit_id = 1\nkb_from_simulator = true\nmm_per_px = 0.5\ntrigger = \"free-run\"\n[camera.source]\nkind = \"sim\"\nwidth = 640\nheight = 480\nscenes = 4\nseed = 4\ninterval_ms = 5\n";
    let cfg = Config::from_toml(text, Path::new("logging.toml")).unwrap();
    let running = common::appliance::start(&cfg).await;
    let a = running.modbus_addr;
    let t0 = Instant::now();
    let clients = 300;
    tokio::task::spawn_blocking(move || {
        for i in 0..clients {
            let mut s = TcpStream::connect(a).unwrap();
            s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
            let [hi, lo] = (i as u16).to_be_bytes();
            let [ah, al] = addr::TRIGGER.to_be_bytes();
            s.write_all(&[hi, lo, 0, 0, 0, 6, 1, 0x06, ah, al, 0, 1]).unwrap();
            let mut answer = [0u8; 9];
            s.read_exact(&mut answer).unwrap();
            assert_eq!(answer[7], 0x86, "the write is refused with an exception");
        }
    })
    .await
    .unwrap();
    let minutes = t0.elapsed().as_secs_f64() / 60.0;
    // A summary is written within its interval once lines were held back.
    tokio::time::sleep(Duration::from_millis(1200)).await;
    let until = Instant::now() + Duration::from_secs(20);
    while log.lines_with(&["lfi_bridge::appliance::camera:", "acq_id="]) < 3 * BURST as usize && Instant::now() < until {
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    running.stop().await;

    let bound = (BURST + PER_MINUTE * (minutes + 0.1) + 1.0) as usize;
    for line in ["write refused", "Modbus client connected", "Modbus client disconnected"] {
        let n = log.lines_with(&[line]) - log.lines_with(&[line, "Suppressed"]);
        assert!((1..=bound).contains(&n), "{line}: {n} lines for {clients} clients (bound {bound})");
    }
    assert!(log.lines_with(&["Suppressed", "write refused"]) >= 1, "the held-back lines are counted in a summary");
    let results = log.lines_with(&["lfi_bridge::appliance::camera:", "acq_id="]);
    assert!(results >= 3 * BURST as usize, "every result line is written: {results}");
}
