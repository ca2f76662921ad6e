//! Enrolling a template from the current frame is the appliance's, testable without HTTP: the
//! operator view only carries the request in.

mod common;

use common::appliance::{config, cycle, plc, read, start};
use lfi_bridge::appliance::enrol::{EnrolError, EnrolRequest};
use lfi_bridge::registers::addr;
use lfi_bridge::vision::Face;

fn request(part: usize, type_name: &str, id: u16) -> EnrolRequest {
    EnrolRequest { part, type_name: type_name.into(), id, face: Face::Up, by: "a test".into(), acq_id: None }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_part_of_the_current_frame_becomes_a_template_of_the_running_camera() {
    let mut cfg = config("", "");
    cfg.http = None;
    let running = start(&cfg).await;
    let cam = &running.cameras[0];
    assert!(matches!(cam.enrol(request(1, "newpart", 9)).await, Err(EnrolError::NoFrame)), "before any frame");

    let mut ctx = plc(running.modbus_addr, 1).await;
    let results = cycle(&mut ctx).await;
    assert!(!results.is_empty());
    let before = cam.job().templates.entries.len();
    let job_before = cam.job();

    for missing in [0, 7] {
        let e = cam.enrol(request(missing, "x", 10)).await.unwrap_err();
        assert!(matches!(e, EnrolError::NoPart { part, .. } if part == missing) && e.is_request(), "{e}");
    }
    let e = cam.enrol(request(1, "newpart", 1)).await.unwrap_err();
    assert!(e.is_conflict(), "id 1 belongs to another type: {e}");
    assert!(std::sync::Arc::ptr_eq(&job_before, &cam.job()), "a refused enrolment changes nothing");

    let done = cam.enrol(request(1, "newpart", 9)).await.unwrap();
    assert!(!done.replaced);
    assert!(done.saved.contains("in memory"), "{}", done.saved);
    let job = cam.job();
    let kb = &job.templates;
    assert_eq!(kb.entries.len(), before + 1);
    let new = kb.entries.last().unwrap();
    assert_eq!((new.template.type_name.as_str(), new.template.type_id, new.template.face), ("newpart", 9, Face::Up));
    assert!(new.source.starts_with("a test: "), "{}", new.source);
    assert!(!std::sync::Arc::ptr_eq(&job_before, &job), "the job in force is replaced whole");
    assert_eq!(job.estimator.templates().count(), before + 1, "with an estimator on the new templates");
    assert_eq!(read(&mut ctx, addr::TYPES_ENROLLED, 1).await[0], 4, "the handshake knows the new type");
    assert!(cam.enrol(request(1, "newpart", 9)).await.unwrap().replaced, "the same type and face again replaces it");
    running.stop().await;
}

fn lfi(args: &[&str]) -> std::process::Output {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_lfi-bridge")).args(args).output().expect("binary runs");
    assert_ne!(out.status.code(), Some(101), "panicked: {}", String::from_utf8_lossy(&out.stderr));
    out
}

/// A catalogue's folder enrolled in one command writes the same knowledge base as enrolling
/// its templates one by one, ids in type-name order; a sub-folder and a file that is not a
/// `TYPE_FACE` image are named and left out; `ids.toml` gives the ids; one image that fails
/// writes nothing and is named.
#[test]
fn a_folder_enrols_like_its_templates_one_by_one() {
    let shared = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/samples/templates");
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("catalogue");
    std::fs::create_dir_all(dir.join("unknown")).unwrap();
    for t in ["A", "B", "C"] {
        for f in ["up", "down"] {
            std::fs::copy(shared.join(format!("{t}_{f}.png")), dir.join(format!("{t}_{f}.png"))).unwrap();
        }
    }
    // Never enrolled: a type under unknown/ and a file that is not a template.
    std::fs::copy(shared.join("C_up.png"), dir.join("unknown/U_up.png")).unwrap();
    std::fs::write(dir.join("notes.txt"), "not a template").unwrap();
    let s = |p: &std::path::Path| p.to_str().unwrap().to_string();

    let folder_kb = tmp.path().join("folder.kb.toml");
    let out = lfi(&["enroll", "--kb", &s(&folder_kb), "--dir", &s(&dir)]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("notes.txt") && stderr.contains("unknown"), "the ignored file and folder are named: {stderr}");

    let one_kb = tmp.path().join("one.kb.toml");
    for (id, t) in ["A", "B", "C"].iter().enumerate() {
        for f in ["up", "down"] {
            let id = (id + 1).to_string();
            let img = s(&dir.join(format!("{t}_{f}.png")));
            let out = lfi(&["enroll", "--kb", &s(&one_kb), "--type", t, "--id", &id, "--face", f, &img]);
            assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        }
    }
    // The entries in the same order (by type, up before down) and nothing else differs.
    let read = |p: &std::path::Path| std::fs::read_to_string(p).unwrap();
    assert_eq!(read(&folder_kb), read(&one_kb));
    assert!(!read(&folder_kb).contains("U_up"), "nothing under unknown/ is enrolled");

    // ids.toml gives new types their ids; a type it leaves out is named and nothing is written.
    let map = dir.join("ids.toml");
    std::fs::write(&map, "# catalogue ids\nA = 101\nB = 102\n").unwrap();
    let mapped_kb = tmp.path().join("mapped.kb.toml");
    let out = lfi(&["enroll", "--kb", &s(&mapped_kb), "--dir", &s(&dir)]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && stderr.contains("\"C\"") && stderr.contains("ids.toml"), "{stderr}");
    assert!(!mapped_kb.exists(), "nothing written");
    // An id given twice is named with its key.
    std::fs::write(&map, "A = 101\nB = 102\nC = 101\n").unwrap();
    let out = lfi(&["enroll", "--kb", &s(&mapped_kb), "--dir", &s(&dir)]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && stderr.contains("\"C\"") && stderr.contains("101"), "{stderr}");
    std::fs::write(&map, "A = 101\nB = 102\nC = 103\n").unwrap();
    assert!(lfi(&["enroll", "--kb", &s(&mapped_kb), "--dir", &s(&dir)]).status.success());
    let kb = lfi_bridge::kb::KnowledgeBase::load(&mapped_kb).unwrap();
    let ids: Vec<u16> = kb.entries.iter().map(|e| e.template.type_id).collect();
    assert_eq!(ids, [101, 101, 102, 102, 103, 103]);
    std::fs::remove_file(&map).unwrap();

    // One image that cannot be read fails the whole folder, naming it; the knowledge base stays.
    std::fs::write(dir.join("D_up.png"), b"not a png").unwrap();
    let before = read(&folder_kb);
    let out = lfi(&["enroll", "--kb", &s(&folder_kb), "--dir", &s(&dir)]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && stderr.contains("D_up.png"), "{stderr}");
    assert_eq!(read(&folder_kb), before, "a failed folder writes nothing");
}

/// Enrolling a template that no stretch of outline tells from an enrolled one warns, naming
/// both; templates unlike any other are enrolled without a word about it.
#[test]
fn a_template_no_outline_tells_from_another_is_reported_at_enrolment() {
    let shared = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/samples/templates");
    let tmp = tempfile::tempdir().unwrap();
    let kb = tmp.path().join("kb.toml");
    let (kb, img) = (kb.to_str().unwrap().to_string(), shared.join("A_up.png").to_str().unwrap().to_string());
    let out = lfi(&["enroll", "--kb", &kb, "--type", "A", "--id", "1", "--face", "up", &img]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(!String::from_utf8_lossy(&out.stdout).contains("alike"), "{}", String::from_utf8_lossy(&out.stdout));
    let other = shared.join("B_up.png").to_str().unwrap().to_string();
    let out = lfi(&["enroll", "--kb", &kb, "--type", "B", "--id", "2", "--face", "up", &other]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success() && !stdout.contains("warning"), "{stdout}");
    // The same part under another name: nothing tells them apart.
    let out = lfi(&["enroll", "--kb", &kb, "--type", "Acopy", "--id", "3", "--face", "up", &img]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(stdout.contains("warning: A up and Acopy up: no stretch of outline tells them apart"), "{stdout}");
}
