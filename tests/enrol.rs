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
    assert!(matches!(cam.enrol(&request(1, "newpart", 9)), Err(EnrolError::NoFrame)), "before any frame");

    let mut ctx = plc(running.modbus_addr, 1).await;
    let results = cycle(&mut ctx).await;
    assert!(!results.is_empty());
    let before = cam.templates.lock().unwrap().entries.len();
    let estimator_before = cam.estimator.read().unwrap().clone();

    for missing in [0, 7] {
        let e = cam.enrol(&request(missing, "x", 10)).unwrap_err();
        assert!(matches!(e, EnrolError::NoPart { part, .. } if part == missing) && e.is_request(), "{e}");
    }
    let e = cam.enrol(&request(1, "newpart", 1)).unwrap_err();
    assert!(e.is_conflict(), "id 1 belongs to another type: {e}");
    assert_eq!(cam.templates.lock().unwrap().entries.len(), before, "a refused enrolment changes nothing");

    let done = cam.enrol(&request(1, "newpart", 9)).unwrap();
    assert!(!done.replaced);
    assert!(done.saved.contains("in memory"), "{}", done.saved);
    let kb = cam.templates.lock().unwrap().clone();
    assert_eq!(kb.entries.len(), before + 1);
    let new = kb.entries.last().unwrap();
    assert_eq!((new.template.type_name.as_str(), new.template.type_id, new.template.face), ("newpart", 9, Face::Up));
    assert!(new.source.starts_with("a test: "), "{}", new.source);
    assert!(!std::sync::Arc::ptr_eq(&estimator_before, &cam.estimator.read().unwrap()), "the estimator is swapped");
    assert_eq!(cam.estimator.read().unwrap().templates().count(), before + 1);
    assert_eq!(read(&mut ctx, addr::TYPES_ENROLLED, 1).await[0], 4, "the handshake knows the new type");
    assert!(cam.enrol(&request(1, "newpart", 9)).unwrap().replaced, "the same type and face again replaces it");
    running.stop().await;
}
