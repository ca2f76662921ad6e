//! The `dir` source: each file a camera drops into the folder becomes exactly one frame.

mod common;

use std::path::Path;
use std::time::Duration;

use common::appliance::*;
use lfi_bridge::config::Config;
use lfi_bridge::registers::{addr, status};
use lfi_bridge::sim::{SimConfig, Simulator};

fn dir_config(inbox: &Path, trigger: &str) -> Config {
    let text = format!(
        "[modbus]\nbind = \"127.0.0.1:0\"\n[http]\nenabled = false\n[result]\nqueue_depth = 100\n[log]\nlevel = \"warn\"\n[[camera]]\nunit_id = 1\ntrigger = \"{trigger}\"\nkb = \"kb.toml\"\n[camera.source]\nkind = \"dir\"\npath = \"{}\"\nsettle_ms = 50\ntimeout_ms = 500\n",
        inbox.display()
    );
    Config::from_toml(&text, &inbox.parent().unwrap().join("appliance.toml")).unwrap()
}

/// A knowledge base of the small simulator beside the inbox, and its scenes as PNG bytes.
fn setup(root: &Path) -> Vec<Vec<u8>> {
    let sim = Simulator::new(SimConfig { width: 640, height: 480, seed: 4, noise: None }).unwrap();
    let mut kb = lfi_bridge::kb::KnowledgeBase::default();
    for t in common::enrolled(&sim) {
        kb.enroll(t, "sim".into()).unwrap();
    }
    kb.save(&root.join("kb.toml")).unwrap();
    (0..6).map(|i| lfi_bridge::imageio::encode_png(&sim.scene(i).unwrap().image).unwrap()).collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn free_running_folder_processes_each_dropped_file_exactly_once() {
    let root = tempfile::tempdir().unwrap();
    let inbox = root.path().join("inbox");
    std::fs::create_dir(&inbox).unwrap();
    let frames = setup(root.path());
    let running = start(&dir_config(&inbox, "free-run")).await;
    let mut ctx = plc(running.modbus_addr, 1).await;
    // Files arrive one by one; one is written slowly, in pieces, like a camera streaming it out;
    // one is corrupt.
    for (i, png) in frames.iter().enumerate() {
        let path = inbox.join(format!("frame{i:02}.png"));
        if i == 2 {
            let mut f = std::fs::File::create(&path).unwrap();
            for chunk in png.chunks(png.len() / 4 + 1) {
                std::io::Write::write_all(&mut f, chunk).unwrap();
                std::io::Write::flush(&mut f).unwrap();
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
        } else {
            std::fs::write(&path, png).unwrap();
        }
        tokio::time::sleep(Duration::from_millis(30)).await;
    }
    std::fs::write(inbox.join("broken.png"), b"\x89PNG\r\n\x1a\n broken").unwrap();
    // The broken file sets ERROR; while it is set, new files wait in the inbox.
    let s = wait_status(&mut ctx, |s| s & status::ERROR != 0, Duration::from_secs(20)).await;
    assert_eq!(s & status::ERROR, status::ERROR);
    std::fs::write(inbox.join("late.png"), &frames[0]).unwrap();
    // Settled after 50 ms; a worker that took files in ERROR would have taken it within its
    // 50 ms poll after that: five times that long it is still there.
    tokio::time::sleep(Duration::from_millis(250)).await;
    assert!(inbox.join("late.png").exists(), "a file arriving during ERROR is kept for later");
    assert_eq!(read(&mut ctx, 102, 1).await[0], 2, "ERROR_CODE 2: frame");
    write(&mut ctx, addr::CLEAR_ERROR, 1).await;
    // Wait until all eight files are gone from the inbox.
    let until = tokio::time::Instant::now() + Duration::from_secs(20);
    loop {
        let left: Vec<_> = std::fs::read_dir(&inbox).unwrap().flatten().filter(|e| e.path().is_file()).collect();
        if left.is_empty() {
            break;
        }
        assert!(tokio::time::Instant::now() < until, "files left in the inbox: {left:?}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // The last file's result follows its move out of the inbox.
    let until = tokio::time::Instant::now() + Duration::from_secs(5);
    while read(&mut ctx, addr::ACQ_COUNT, 1).await[0] < 8 && tokio::time::Instant::now() < until {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    tokio::time::sleep(Duration::from_millis(100)).await;
    let s = read(&mut ctx, 100, 5).await;
    assert_eq!(s[3], 8, "ACQ_COUNT: one acquisition per file");
    let done = std::fs::read_dir(inbox.join("done")).unwrap().count();
    let failed = std::fs::read_dir(inbox.join("failed")).unwrap().count();
    assert_eq!((done, failed), (7, 1));
    running.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_trigger_with_no_file_is_a_camera_error() {
    let root = tempfile::tempdir().unwrap();
    let inbox = root.path().join("inbox");
    std::fs::create_dir(&inbox).unwrap();
    setup(root.path());
    let running = start(&dir_config(&inbox, "modbus")).await;
    let mut ctx = plc(running.modbus_addr, 1).await;
    write(&mut ctx, addr::TRIGGER, 1).await;
    let s = wait_status(&mut ctx, |s| s & status::RESULT_VALID != 0, Duration::from_secs(5)).await;
    assert!(s & status::ERROR != 0);
    let b = read(&mut ctx, 102, 1).await;
    assert_eq!(b[0], 1, "ERROR_CODE 1: camera");
    assert_eq!(read(&mut ctx, addr::REASON, 1).await[0], 7, "frame error result");
    // READY is 0 while ERROR is set: a PLC that waits for READY does not trigger into it.
    write(&mut ctx, addr::TRIGGER, 0).await;
    let s = read(&mut ctx, addr::STATUS, 1).await[0];
    assert_eq!(s & (status::READY | status::ERROR), status::ERROR, "STATUS {s:#010b}");
    let missed = read(&mut ctx, addr::MISSED_TRIGGERS, 1).await[0];
    write(&mut ctx, addr::TRIGGER, 1).await;
    write(&mut ctx, addr::TRIGGER, 0).await;
    assert_eq!(read(&mut ctx, addr::MISSED_TRIGGERS, 1).await[0], missed + 1, "a trigger in ERROR is missed");
    write(&mut ctx, addr::CLEAR_ERROR, 1).await;
    wait_status(&mut ctx, |s| s & status::READY != 0, Duration::from_secs(5)).await;
    running.stop().await;
}

/// A JPEG the camera stopped writing halfway (its size then stays put, so it looks settled) is a
/// frame error moved to `failed/`: a lost frame must never read as an empty belt.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_half_written_jpeg_is_a_frame_error_not_an_empty_belt() {
    let root = tempfile::tempdir().unwrap();
    let inbox = root.path().join("inbox");
    std::fs::create_dir(&inbox).unwrap();
    setup(root.path());
    let sim = Simulator::new(SimConfig { width: 640, height: 480, seed: 4, noise: None }).unwrap();
    let mat = sim.scene(0).unwrap().image.to_mat().unwrap();
    let jpeg = lfi_bridge::imageio::encode_mat(&mat, ".jpg").unwrap();
    let running = start(&dir_config(&inbox, "modbus")).await;
    let mut ctx = plc(running.modbus_addr, 1).await;
    std::fs::write(inbox.join("cut.jpg"), &jpeg[..jpeg.len() * 2 / 3]).unwrap();
    tokio::time::sleep(Duration::from_millis(200)).await;
    write(&mut ctx, addr::TRIGGER, 1).await;
    let s = wait_status(&mut ctx, |s| s & status::RESULT_VALID != 0 && s & status::BUSY == 0, Duration::from_secs(5)).await;
    assert!(s & status::ERROR != 0, "STATUS {s:#010b}");
    assert_eq!(read(&mut ctx, addr::ERROR_CODE, 1).await[0], 2, "ERROR_CODE 2: frame");
    assert_eq!(read(&mut ctx, addr::REASON, 1).await[0], 7, "a frame-error result, not \"no part\"");
    assert!(inbox.join("failed/cut.jpg").exists(), "kept for a look in failed/");
    running.stop().await;
}
