//! The image archive, driven through Modbus as a PLC would: which frames it keeps, that it keeps
//! to `max_files`, and that each sidecar carries what ties the frame to the PLC's results.

mod common;

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::atomic::Ordering::Relaxed;

use common::appliance::{config, cycle, plc, start};
use lfi_bridge::registers::addr;

/// The sidecars in `dir`, by ACQ_ID, and how many images there are.
fn sidecars(dir: &Path) -> (BTreeMap<u16, serde_json::Value>, usize) {
    let mut out = BTreeMap::new();
    let mut images = 0;
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        match p.extension().and_then(|x| x.to_str()) {
            Some("json") => {
                let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
                let image = dir.join(v["image"].as_str().unwrap());
                assert!(image.is_file(), "{} names {}, which is not there", p.display(), image.display());
                out.insert(v["acq_id"].as_u64().unwrap() as u16, v);
            }
            Some("png") => images += 1,
            _ => panic!("the archive wrote {}", p.display()),
        }
    }
    (out, images)
}

/// Whether the history shows the sixth frame yet.
fn counters_saved_at_least(list: &[serde_json::Value]) -> bool {
    list.first().is_some_and(|v| v["acq_id"] == 6)
}

/// Six cycles with USER_DATA set: the PLC's view of each, by ACQ_ID (each result's block).
async fn six_cycles(cfg: &lfi_bridge::config::Config) -> (BTreeMap<u16, Vec<Vec<u16>>>, lfi_bridge::appliance::Running) {
    let app = start(cfg).await;
    let mut ctx = plc(app.modbus_addr, 1).await;
    use tokio_modbus::prelude::Writer;
    ctx.write_multiple_registers(addr::USER_DATA, &[0x0001, 0x2345]).await.unwrap().unwrap();
    let mut seen: BTreeMap<u16, Vec<Vec<u16>>> = BTreeMap::new();
    for _ in 0..6 {
        for block in cycle(&mut ctx).await {
            seen.entry(block[101]).or_default().push(block);
        }
    }
    (seen, app)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_archive_keeps_to_max_files_newest_frames_with_their_results() {
    let dir = tempfile::tempdir().unwrap();
    let extra = format!("[camera.archive]\ndir = {:?}\nsave = \"all\"\nmax_files = 3\n", dir.path().join("frames"));
    let (seen, app) = six_cycles(&config("", &extra)).await;
    let counters = app.cameras[0].archive.clone().expect("an archive is configured").counters;
    // The operator view reads the archive back: the newest frames first, each image by the
    // name its sidecar gives, and nothing but the archive's own files.
    let h = app.http_addr.expect("http enabled");
    let history = tokio::task::spawn_blocking(move || {
        let get = |path: &str| common::http::http(h, "GET", path, &[], "");
        // The writer may still be at the last frame: wait for three sidecars.
        let until = std::time::Instant::now() + std::time::Duration::from_secs(10);
        let list = loop {
            let (st, ct, body) = get("/api/camera/1/archive?limit=2");
            assert_eq!((st, ct.as_str()), (200, "application/json"));
            let list: Vec<serde_json::Value> = serde_json::from_slice(&body).unwrap();
            if counters_saved_at_least(&list) || std::time::Instant::now() > until {
                break list;
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        };
        let image = list[0]["image"].as_str().unwrap().to_string();
        let (st, ct, png) = get(&format!("/api/camera/1/archive/{image}"));
        assert_eq!((st, ct.as_str(), &png[1..4]), (200, "image/png", &b"PNG"[..]));
        assert_eq!(get("/api/camera/1/archive/..%2Ftest.toml").0, 404);
        assert_eq!(get("/api/camera/1/archive/notes.txt").0, 404);
        list.iter().map(|v| v["acq_id"].as_u64().unwrap() as u16).collect::<Vec<_>>()
    })
    .await
    .unwrap();
    app.stop().await; // the writer finishes what was queued
    assert_eq!(seen.len(), 6);
    assert_eq!(counters.saved.load(Relaxed), 6);
    assert_eq!(counters.deleted.load(Relaxed), 3);
    assert_eq!(counters.dropped.load(Relaxed) + counters.failed.load(Relaxed), 0);
    let (kept, images) = sidecars(&dir.path().join("frames"));
    assert_eq!((kept.len(), images), (3, 3), "max_files = 3 frames, each an image and a sidecar");
    let newest: Vec<u16> = seen.keys().rev().take(3).rev().copied().collect();
    assert_eq!(history, seen.keys().rev().take(2).copied().collect::<Vec<_>>(), "the page's history: newest first");
    assert_eq!(kept.keys().copied().collect::<Vec<_>>(), newest, "the oldest frames were deleted first");
    for (acq, v) in &kept {
        let plc = &seen[acq];
        assert_eq!(v["user_data"], 0x0001_2345, "ACQ_ID {acq}: USER_DATA as latched");
        assert_eq!(v["job_id"], 1);
        assert!(v["time"].as_str().unwrap().ends_with('Z'), "{}", v["time"]);
        let parts = v["parts"].as_array().unwrap();
        // The PLC's results of that frame, in the same order: DECISION (202) and TYPE_ID (204).
        let part_results: Vec<&Vec<u16>> = plc.iter().filter(|b| b[110] > 0).collect();
        assert_eq!(parts.len(), part_results.len(), "ACQ_ID {acq}: one part per part result");
        for (p, b) in parts.iter().zip(part_results) {
            assert_eq!(p["accepted"].as_bool().unwrap(), b[102] == 1, "ACQ_ID {acq} PART_INDEX {}", b[110]);
            assert_eq!(p["type_id"].as_u64().unwrap(), b[104] as u64);
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rejects_keeps_exactly_the_frames_with_a_rejected_result() {
    let dir = tempfile::tempdir().unwrap();
    // EXPECTED_TYPE 2 makes every other type a reject, so both kinds of frame occur.
    let extra = format!("[camera.archive]\ndir = {:?}\n", dir.path());
    let cfg = config("", &extra);
    let app = start(&cfg).await;
    let mut ctx = plc(app.modbus_addr, 1).await;
    common::appliance::write(&mut ctx, addr::EXPECTED_TYPE, 2).await;
    let mut rejected = Vec::new();
    let mut accepted_only = Vec::new();
    for _ in 0..8 {
        let blocks = cycle(&mut ctx).await;
        let acq = blocks[0][101];
        if blocks.iter().any(|b| b[102] == 2) { rejected.push(acq) } else { accepted_only.push(acq) }
    }
    app.stop().await;
    assert!(!rejected.is_empty() && !accepted_only.is_empty(), "both kinds: rejected {rejected:?}, accepted only {accepted_only:?}");
    let (kept, images) = sidecars(dir.path());
    assert_eq!(images, kept.len());
    assert_eq!(kept.keys().copied().collect::<Vec<_>>(), rejected, "save = \"rejects\" (the default)");
}
