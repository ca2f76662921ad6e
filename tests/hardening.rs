//! Attacks on the PLC's Modbus service, each on its own against a running appliance on
//! 127.0.0.1, with bounded loops: whatever a client does, a PLC is served.

mod common;

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::time::{Duration, Instant};

use common::appliance::{config, plc, read, start};
use lfi_bridge::registers::{self as map, addr};

/// A raw connection with a read timeout.
fn connect(a: SocketAddr) -> TcpStream {
    let s = TcpStream::connect(a).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    s.set_nodelay(true).unwrap();
    s
}

/// FC3 of MAP_VERSION, transaction `t`.
fn read_map_version(t: u16) -> Vec<u8> {
    let [hi, lo] = t.to_be_bytes();
    vec![hi, lo, 0, 0, 0, 6, 1, 0x03, 0, addr::MAP_VERSION as u8, 0, 1]
}

/// Whether the server has closed `s` (EOF or reset) within `limit`.
fn closed_within(s: &mut TcpStream, limit: Duration) -> bool {
    s.set_read_timeout(Some(limit)).unwrap();
    let mut b = [0u8; 16];
    match s.read(&mut b) {
        Ok(0) => true,
        Ok(_) => false,
        Err(e) => !matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn clients_trickling_one_byte_a_second_in_every_slot_do_not_lock_a_plc_out() {
    let running = start(&config("max_connections = 16\nidle_timeout_s = 60", "")).await;
    let a = running.modbus_addr;
    // Every slot: a client that sends a request one byte per second (never completing one
    // within the frame deadline), the way a slow-loris attack holds a server.
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let mut tricklers = Vec::new();
    for i in 0..16u16 {
        let stop = stop.clone();
        tricklers.push(std::thread::spawn(move || {
            let mut s = connect(a);
            for b in read_map_version(i).iter().cycle().take(12) {
                if stop.load(std::sync::atomic::Ordering::Relaxed) || s.write_all(&[*b]).is_err() {
                    return;
                }
                std::thread::sleep(Duration::from_secs(1));
            }
        }));
    }
    tokio::time::sleep(Duration::from_millis(1500)).await;
    let t = Instant::now();
    let mut ctx = tokio::time::timeout(Duration::from_secs(5), plc(a, 1)).await.expect("a new PLC connects");
    let v =
        tokio::time::timeout(Duration::from_secs(5), async { read(&mut ctx, addr::MAP_VERSION, 1).await }).await.expect("and is served");
    assert_eq!(v[0], map::MAP_VERSION);
    let served = t.elapsed();
    assert!(served < Duration::from_secs(5), "served after {served:?}");
    // Polling keeps its slot while the tricklers come back (reconnecting is theirs to try).
    for _ in 0..20 {
        assert_eq!(read(&mut ctx, addr::MAP_VERSION, 1).await[0], map::MAP_VERSION);
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    for t in tricklers {
        let _ = t.join();
    }
    eprintln!("new PLC served {} ms after every slot was taken by tricklers", served.as_millis());
    running.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn silent_clients_give_their_slots_to_a_new_plc_but_busy_ones_keep_theirs() {
    let running = start(&config("max_connections = 4\nidle_timeout_s = 60", "")).await;
    let a = running.modbus_addr;
    // Four silent connections: the oldest gives way to a new client.
    let mut silent: Vec<TcpStream> = (0..4).map(|_| connect(a)).collect();
    tokio::time::sleep(Duration::from_millis(1200)).await;
    let mut s = connect(a);
    s.write_all(&read_map_version(7)).unwrap();
    let mut answer = [0u8; 11];
    s.read_exact(&mut answer).unwrap();
    assert_eq!(&answer[..2], &[0, 7], "the new client is served");
    assert_eq!(
        silent.iter_mut().map(|c| closed_within(c, Duration::from_millis(300))).filter(|c| *c).count(),
        1,
        "exactly one silent slot reclaimed"
    );
    drop(silent);
    drop(s);
    tokio::time::sleep(Duration::from_millis(300)).await;

    // Four clients polling all the time: none is closed for a newcomer, which is refused.
    let mut busy: Vec<_> = Vec::new();
    for _ in 0..4 {
        busy.push(plc(a, 1).await);
    }
    let end = Instant::now() + Duration::from_millis(1500);
    while Instant::now() < end {
        for c in &mut busy {
            read(c, addr::STATUS, 1).await;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let mut extra = connect(a);
    assert!(closed_within(&mut extra, Duration::from_millis(500)), "a fifth client is refused while four poll");
    for c in &mut busy {
        read(c, addr::STATUS, 1).await;
    }
    running.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_request_not_complete_within_the_frame_timeout_closes_its_connection() {
    let running = start(&config("frame_timeout_s = 0.5\nidle_timeout_s = 60", "")).await;
    let mut s = connect(running.modbus_addr);
    s.write_all(&read_map_version(1)[..5]).unwrap();
    let t = Instant::now();
    assert!(closed_within(&mut s, Duration::from_secs(3)), "still open after {:?}", t.elapsed());
    assert!(t.elapsed() < Duration::from_secs(2), "closed after {:?}", t.elapsed());
    // A silent connection is not a request under way: it stays until the idle timeout.
    let mut quiet = connect(running.modbus_addr);
    assert!(!closed_within(&mut quiet, Duration::from_millis(900)), "silence is not a trickle");
    quiet.write_all(&read_map_version(2)).unwrap();
    let mut answer = [0u8; 11];
    quiet.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
    quiet.read_exact(&mut answer).unwrap();
    assert_eq!(&answer[..2], &[0, 2]);
    running.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_overlong_length_field_is_answered_and_the_next_request_still_served() {
    let running = start(&config("", "")).await;
    let mut s = connect(running.modbus_addr);
    let mut long = read_map_version(1);
    long[5] = 40; // the length field claims 39 PDU bytes; the request has 5
    s.write_all(&[long, read_map_version(2)].concat()).unwrap();
    let mut first = [0u8; 9];
    s.read_exact(&mut first).unwrap();
    assert_eq!(first, [0, 1, 0, 0, 0, 3, 1, 0x83, 0x03], "exception 0x03 for the malformed frame");
    let mut second = [0u8; 11];
    s.read_exact(&mut second).unwrap();
    assert_eq!(&second[..2], &[0, 2], "the next request is its own frame");
    assert_eq!(u16::from_be_bytes([second[9], second[10]]), map::MAP_VERSION);
    running.stop().await;
}
