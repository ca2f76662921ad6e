//! Every register, encoding and exception of the PLC map, against the real server on
//! 127.0.0.1; and the document that describes them.

mod common;

use std::io::{Read, Write};
use std::time::Duration;

use common::appliance::*;
use lfi_bridge::registers::{self as map, Access, MAP, addr, status};
use tokio_modbus::ExceptionCode;
use tokio_modbus::prelude::*;

/// The whole document, robot section included, is what `lfi-bridge register-map` prints. After
/// a change to the table, refresh it with `LFI_BLESS=1 cargo test --test register_map`.
#[test]
fn register_map_md_is_generated_from_the_table() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/register-map.md");
    let generated = format!("{}{}", map::markdown(), lfi_bridge::robot::markdown());
    if std::env::var_os("LFI_BLESS").is_some() {
        std::fs::write(path, &generated).expect("register-map.md written");
    }
    let doc = std::fs::read_to_string(path).expect("register-map.md exists");
    if doc != generated {
        let line =
            doc.lines().zip(generated.lines()).position(|(a, b)| a != b).unwrap_or(doc.lines().count().min(generated.lines().count()));
        panic!(
            "register-map.md differs from `lfi-bridge register-map` from line {}:\n  document:  {:?}\n  generated: {:?}\nrefresh it: LFI_BLESS=1 cargo test --test register_map",
            line + 1,
            doc.lines().nth(line),
            generated.lines().nth(line)
        );
    }
}

/// The codes the estimator can give are the codes the map documents (MAP_VERSION 2: covered,
/// no clearance, the debris count; MAP_VERSION 3: READY in ERROR, USER_DATA, BOOT_ID).
#[test]
fn the_map_documents_every_reject_reason_and_the_debris_count() {
    // The REASON codes are the estimator's reasons, word for word (the page shows these words),
    // and their numbers are the ones PLC programs were written against: never renumbered.
    use lfi_bridge::vision::{Face, Reason};
    let reason = map::lookup(addr::REASON).unwrap();
    let words: Vec<(u16, &str)> = Reason::ALL.iter().map(|r| (map::reason_code(*r), r.as_str())).collect();
    let mut sorted = words.clone();
    sorted.sort();
    assert_eq!(reason.codes.to_vec(), sorted);
    let numbers: Vec<(u16, Reason)> = Reason::ALL.iter().map(|r| (map::reason_code(*r), *r)).collect();
    use Reason::*;
    let on_the_wire = [Ok, NoPart, UnknownType, LowConfidence, Ambiguous, Touching, WrongType, FrameError, AtBorder, Covered, NoClearance];
    assert_eq!(numbers, on_the_wire.iter().enumerate().map(|(i, r)| (i as u16, *r)).collect::<Vec<_>>());
    let face = map::lookup(addr::FACE).unwrap();
    assert_eq!(face.codes.to_vec(), vec![(0, "unknown"), (1, "up"), (2, "down")]);
    for f in [Face::Up, Face::Down] {
        assert_eq!(map::code_word(face, map::face_code(Some(f))), Some(f.as_str()));
    }
    assert_eq!(map::MAP_VERSION, 4);
    assert_eq!(map::lookup(119).unwrap().name, "DEBRIS_COUNT");
    let doc = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/register-map.md")).unwrap();
    for needle in [
        "9 covered",
        "10 no clearance",
        "| 119 | 400120 | DEBRIS_COUNT |",
        "| 5-6 | 400006-400007 | USER_DATA | R/W | uint32 (2 words) |",
        "| 123 | 400124 | BOOT_ID | R |",
        "| 219-220 | 400220-400221 | RESULT_USER_DATA | R | uint32 (2 words) |",
        "MAP_VERSION = 4",
        "MAP_VERSION 4 (from 3)",
        "| 7 | 400008 | JOB_REQUEST | R/W |",
        "| 121 | 400122 | JOB_ID | R |",
        "| 122 | 400123 | JOB_STATUS | R |",
        "MAP_VERSION 3 (from 2)",
        "MAP_VERSION 2 (from 1)",
        "## After a restart",
    ] {
        assert!(doc.contains(needle), "register-map.md lacks {needle:?}");
    }
}

async fn exception<T: std::fmt::Debug>(r: tokio_modbus::Result<T>) -> ExceptionCode {
    match r {
        Ok(Err(e)) => e,
        other => panic!("expected an exception, got {other:?}"),
    }
}

/// One raw request on its own connection: the response bytes (or none if the server closed).
fn raw(addr: std::net::SocketAddr, bytes: &[u8]) -> Vec<u8> {
    let mut s = std::net::TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
    s.write_all(bytes).unwrap();
    let mut buf = [0u8; 512];
    match s.read(&mut buf) {
        Ok(n) => buf[..n].to_vec(),
        Err(_) => Vec::new(),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_register_reads_and_writes_as_documented() {
    let running = start(&config("", "")).await;
    let mut ctx = plc(running.modbus_addr, 1).await;
    // The whole map in three reads; reserved addresses read 0.
    let mut all = read(&mut ctx, 0, 125).await;
    all.extend(read(&mut ctx, 125, 125).await);
    all.extend(read(&mut ctx, 250, 50).await);
    assert_eq!(all.len(), 300);
    for (a, v) in all.iter().enumerate() {
        if map::lookup(a as u16).is_none() {
            assert_eq!(*v, 0, "reserved address {a}");
        }
    }
    assert_eq!(all[addr::MAP_VERSION as usize], map::MAP_VERSION);
    assert_eq!(all[addr::TYPES_ENROLLED as usize], 3);
    assert_eq!(all[addr::ONLINE as usize], 1);
    assert_eq!(
        all[addr::STATUS as usize] & (status::READY | status::ONLINE | status::CAMERA_OK),
        status::READY | status::ONLINE | status::CAMERA_OK
    );
    // Writable registers take values and read back (CLEAR_ERROR reads 0).
    write(&mut ctx, addr::EXPECTED_TYPE, 2).await;
    write(&mut ctx, addr::ONLINE, 0).await;
    assert_eq!(read(&mut ctx, addr::EXPECTED_TYPE, 1).await[0], 2);
    assert_eq!(read(&mut ctx, 100, 1).await[0] & (status::ONLINE | status::READY), 0);
    ctx.write_multiple_registers(addr::ONLINE, &[1, 0]).await.unwrap().unwrap();
    assert_eq!(read(&mut ctx, addr::ONLINE, 2).await, vec![1, 0]);
    write(&mut ctx, addr::CLEAR_ERROR, 1).await;
    assert_eq!(read(&mut ctx, addr::CLEAR_ERROR, 1).await[0], 0);
    // Every read-only register refuses writes; so does every reserved one.
    for r in MAP.iter().filter(|r| r.access == Access::ReadOnly) {
        assert_eq!(exception(ctx.write_single_register(r.addr, 0).await).await, ExceptionCode::IllegalDataAddress, "{}", r.name);
    }
    for a in [8u16, 99, 119, 121, 124, 199, 221, 299] {
        assert_eq!(exception(ctx.write_single_register(a, 0).await).await, ExceptionCode::IllegalDataAddress, "reserved {a}");
    }
    // Values: 0/1 only in TRIGGER, CLEAR_ERROR, ONLINE.
    for a in [addr::TRIGGER, addr::CLEAR_ERROR, addr::ONLINE] {
        assert_eq!(exception(ctx.write_single_register(a, 2).await).await, ExceptionCode::IllegalDataValue);
    }
    // JOB_REQUEST: 1..999 only.
    for v in [0u16, 1000, 65535] {
        assert_eq!(
            exception(ctx.write_single_register(addr::JOB_REQUEST, v).await).await,
            ExceptionCode::IllegalDataValue,
            "JOB_REQUEST {v}"
        );
    }
    running.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn exceptions_follow_the_specification_order() {
    let running = start(&config("", "")).await;
    let a = running.modbus_addr;
    let mut ctx = plc(a, 1).await;
    // Function.
    assert_eq!(exception(ctx.read_input_registers(0, 1).await).await, ExceptionCode::IllegalFunction);
    assert_eq!(exception(ctx.read_coils(0, 1).await).await, ExceptionCode::IllegalFunction);
    assert_eq!(exception(ctx.write_single_coil(0, true).await).await, ExceptionCode::IllegalFunction);
    assert_eq!(exception(ctx.read_write_multiple_registers(100, 1, 0, &[1]).await).await, ExceptionCode::IllegalFunction);
    // Quantity before address.
    assert_eq!(exception(ctx.read_holding_registers(0, 0).await).await, ExceptionCode::IllegalDataValue);
    assert_eq!(exception(ctx.read_holding_registers(0, 126).await).await, ExceptionCode::IllegalDataValue);
    assert_eq!(exception(ctx.read_holding_registers(5000, 126).await).await, ExceptionCode::IllegalDataValue);
    assert!(ctx.read_holding_registers(175, 125).await.unwrap().is_ok());
    // tokio-modbus's client will not even send 124 registers; a raw frame does.
    let mut big = vec![0u8, 8, 0, 0, 0, 0, 1, 0x10, 0, 0, 0, 124, 248];
    big.extend(std::iter::repeat_n(0u8, 248));
    let len = (big.len() - 6) as u16;
    big[4..6].copy_from_slice(&len.to_be_bytes());
    assert_eq!(raw(a, &big), vec![0, 8, 0, 0, 0, 3, 1, 0x90, 3]);
    // Address before value.
    assert_eq!(exception(ctx.read_holding_registers(176, 125).await).await, ExceptionCode::IllegalDataAddress);
    assert_eq!(exception(ctx.read_holding_registers(300, 1).await).await, ExceptionCode::IllegalDataAddress);
    assert_eq!(exception(ctx.read_holding_registers(65535, 1).await).await, ExceptionCode::IllegalDataAddress);
    assert_eq!(exception(ctx.write_multiple_registers(5, &[7, 7, 7, 7]).await).await, ExceptionCode::IllegalDataAddress);
    assert_eq!(exception(ctx.write_single_register(65535, 2).await).await, ExceptionCode::IllegalDataAddress);
    assert_eq!(exception(ctx.write_multiple_registers(0, &[2, 0]).await).await, ExceptionCode::IllegalDataValue);
    assert_eq!(read(&mut ctx, addr::TRIGGER, 1).await[0], 0, "a refused FC16 writes nothing");
    // Unit ids: 0 and 255 reach the first camera, others are 0x0B.
    for unit in [0u8, 255] {
        let mut c = plc(a, unit).await;
        assert_eq!(read(&mut c, addr::MAP_VERSION, 1).await[0], map::MAP_VERSION);
    }
    let mut c = plc(a, 7).await;
    assert_eq!(exception(c.read_holding_registers(100, 1).await).await, ExceptionCode::GatewayTargetDevice);
    // Raw frames: FC16 byte count not 2 x quantity, and quantity 0x8000 (tokio-modbus's
    // decoder would overflow 2 x quantity): 0x03, and the server lives on.
    let bad_count = [0, 9, 0, 0, 0, 10, 1, 0x10, 0, 4, 0, 2, 3, 0, 7, 0];
    assert_eq!(raw(a, &bad_count), vec![0, 9, 0, 0, 0, 3, 1, 0x90, 3]);
    let huge = [0, 10, 0, 0, 0, 7, 1, 0x10, 0, 0, 0x80, 0, 0];
    assert_eq!(raw(a, &huge), vec![0, 10, 0, 0, 0, 3, 1, 0x90, 3]);
    let fc8 = [0, 11, 0, 0, 0, 6, 1, 0x08, 0, 0, 0x12, 0x34];
    assert_eq!(raw(a, &fc8), vec![0, 11, 0, 0, 0, 3, 1, 0x88, 1]);
    // Garbage (wrong protocol id) closes that connection only.
    assert!(raw(a, &[1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12]).is_empty());
    assert_eq!(read(&mut ctx, addr::MAP_VERSION, 1).await[0], map::MAP_VERSION, "other clients are unaffected");
    running.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn floats_follow_the_configured_word_order_and_match_the_integers() {
    for (order, low_first) in [("high-first", false), ("low-first", true)] {
        let running = start(&config("", &format!("float_word_order = \"{order}\""))).await;
        let mut ctx = plc(running.modbus_addr, 1).await;
        // Scene 0 of the simulator is a single clean part.
        write(&mut ctx, addr::TRIGGER, 1).await;
        wait_status(&mut ctx, |s| s & status::RESULT_VALID != 0, Duration::from_secs(10)).await;
        let b = read(&mut ctx, 200, 20).await;
        let f = |i: usize| {
            let (w0, w1) = (b[i] as u32, b[i + 1] as u32);
            f32::from_bits(if low_first { (w1 << 16) | w0 } else { (w0 << 16) | w1 })
        };
        assert_eq!(b[2], 1, "scene 0 is accepted");
        assert!((f(12) as f64 * 100.0 - (b[6] as i16) as f64).abs() <= 0.51, "{order}: angle {} vs {}", f(12), b[6] as i16);
        assert!((f(14) as f64 * 10.0 - (b[7] as i16) as f64).abs() <= 0.51, "{order}: x");
        assert!((f(16) as f64 * 10.0 - (b[8] as i16) as f64).abs() <= 0.51, "{order}: y");
        assert!(b[9] <= 1000 && b[18] > 0);
        running.stop().await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn write_allow_refuses_other_clients_writes_but_not_their_reads() {
    let running = start(&config("write_allow = [\"10.1.2.3\"]", "")).await;
    let mut ctx = plc(running.modbus_addr, 1).await;
    assert_eq!(read(&mut ctx, addr::MAP_VERSION, 1).await[0], map::MAP_VERSION);
    assert_eq!(exception(ctx.write_single_register(addr::TRIGGER, 1).await).await, ExceptionCode::IllegalFunction);
    assert_eq!(exception(ctx.write_multiple_registers(addr::ONLINE, &[0]).await).await, ExceptionCode::IllegalFunction);
    assert_eq!(read(&mut ctx, addr::ACQ_COUNT, 1).await[0], 0);
    running.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn connection_limit_and_a_closed_slot_reused() {
    let running = start(&config("max_connections = 2", "")).await;
    let a = running.modbus_addr;
    let mut c1 = plc(a, 1).await;
    let mut c2 = plc(a, 1).await;
    read(&mut c1, 100, 1).await;
    read(&mut c2, 100, 1).await;
    // A third is accepted by the kernel and closed at once by the server.
    let mut c3 = tcp::connect_slave(a, Slave(1)).await.unwrap();
    assert!(!matches!(c3.read_holding_registers(100, 1).await, Ok(Ok(_))), "third connection must be refused");
    assert!(running.stats.refused.load(std::sync::atomic::Ordering::Relaxed) >= 1);
    // A client that leaves frees its slot for the next. (The idle and frame deadlines, and a
    // silent client's slot going to a new one, are tested on a paused clock in
    // `modbus::server::tests`.)
    let _ = c1.disconnect().await;
    drop(c1);
    let until = tokio::time::Instant::now() + Duration::from_secs(5);
    loop {
        let mut c4 = plc(a, 1).await;
        if let Ok(Ok(v)) = c4.read_holding_registers(addr::MAP_VERSION, 1).await {
            assert_eq!(v[0], map::MAP_VERSION);
            break;
        }
        assert!(tokio::time::Instant::now() < until, "the freed slot was never given to a new client");
    }
    running.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fifty_clients_polling_a_hundred_times_a_second_see_no_errors() {
    let running = start(&config("", "")).await;
    let a = running.modbus_addr;
    let mut clients = Vec::new();
    for _ in 0..50 {
        clients.push(tokio::spawn(async move {
            let mut ctx = plc(a, 1).await;
            let mut iv = tokio::time::interval(Duration::from_millis(10));
            let mut errors = 0;
            for _ in 0..200 {
                iv.tick().await;
                match ctx.read_holding_registers(100, 21).await {
                    Ok(Ok(v)) if v.len() == 21 && v[7] == map::MAP_VERSION => {}
                    _ => errors += 1,
                }
            }
            errors
        }));
    }
    // Meanwhile the PLC keeps triggering.
    let mut plc_ctx = plc(a, 1).await;
    for _ in 0..10 {
        cycle(&mut plc_ctx).await;
    }
    let mut total = 0;
    for c in clients {
        total += c.await.unwrap();
    }
    assert_eq!(total, 0, "read errors across 50 clients");
    running.stop().await;
}
