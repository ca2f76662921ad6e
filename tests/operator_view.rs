//! The operator view over HTTP: every endpoint, the token rule, and one end-to-end check in a
//! real headless Chromium that the page shows a frame and the registers the PLC reads.

mod common;

use std::time::Duration;

use common::appliance::*;
use common::http::http;
use lfi_bridge::registers::{self as map, addr, status};

async fn one_frame(running: &lfi_bridge::appliance::Running) {
    let mut ctx = plc(running.modbus_addr, 1).await;
    write(&mut ctx, addr::TRIGGER, 1).await;
    wait_status(&mut ctx, |s| s & status::RESULT_VALID != 0 && s & status::BUSY == 0, Duration::from_secs(10)).await;
    write(&mut ctx, addr::TRIGGER, 0).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_endpoint_answers_with_its_content_type() {
    let running = start(&config("", "")).await;
    let h = running.http_addr.expect("http enabled");
    let get = |p: &str| {
        let p = p.to_string();
        async move { tokio::task::spawn_blocking(move || http(h, "GET", &p, &[], "")).await.unwrap() }
    };
    let (st, ct, body) = get("/").await;
    assert_eq!(st, 200);
    assert!(ct.starts_with("text/html"), "{ct}");
    assert!(String::from_utf8_lossy(&body).contains("lfi-bridge operator view"));
    let (st, ct, body) = get("/healthz").await;
    assert_eq!((st, ct.starts_with("text/plain"), body.as_slice()), (200, true, &b"ok\n"[..]));
    let (st, _, _) = get("/api/camera/1/frame.jpg").await;
    assert_eq!(st, 404, "no frame before the first trigger");
    one_frame(&running).await;
    let (st, ct, body) = get("/api/camera/1/frame.jpg").await;
    assert_eq!((st, ct.as_str()), (200, "image/jpeg"));
    assert_eq!(&body[..2], &[0xFF, 0xD8]);
    let (st, ct, body) = get("/api/state").await;
    assert_eq!((st, ct.as_str()), (200, "application/json"));
    let v: serde_json::Value = serde_json::from_slice(&body).unwrap();
    let cam = &v["cameras"][0];
    assert_eq!(cam["registers"].as_array().unwrap().len(), map::MAP.len());
    assert_eq!(cam["frames"], 1);
    assert!(cam["status"].as_array().unwrap().iter().any(|l| l["name"] == "RESULT_VALID" && l["on"] == true));
    let (st, ct, body) = get("/metrics").await;
    assert_eq!(st, 200);
    assert!(ct.starts_with("text/plain; version=0.0.4"), "{ct}");
    let text = String::from_utf8(body).unwrap();
    for family in ["lfi_modbus_clients", "lfi_frames_total", "lfi_parts_rejected_total", "lfi_cycle_time_ms"] {
        assert!(text.contains(&format!("# TYPE {family} ")), "{family} missing from /metrics");
    }
    assert!(text.contains("lfi_frames_total{camera=\"camera1\",unit_id=\"1\"} 1"), "{text}");
    let (st, ct, body) = get("/api/camera/1/templates").await;
    assert_eq!((st, ct.as_str()), (200, "application/json"));
    assert_eq!(serde_json::from_slice::<serde_json::Value>(&body).unwrap().as_array().unwrap().len(), 6);
    let (st, ct, body) = get("/api/camera/1/template/0").await;
    assert_eq!((st, ct.as_str()), (200, "image/png"));
    assert_eq!(&body[1..4], b"PNG");
    assert_eq!(get("/api/camera/1/template/99").await.0, 404);
    assert_eq!(get("/api/camera/9/frame.jpg").await.0, 404);
    assert_eq!(get("/nowhere").await.0, 404);
    running.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn enrolling_needs_the_token_and_shows_in_the_registers() {
    let running = start(&config("", "")).await;
    let h = running.http_addr.unwrap();
    one_frame(&running).await;
    let body = r#"{"part": 1, "type": "newpart", "id": 9, "face": "up"}"#;
    let post = |hdrs: Vec<(&'static str, &'static str)>, b: &'static str| async move {
        tokio::task::spawn_blocking(move || {
            http(h, "POST", "/api/camera/1/enroll", &[&[("Content-Type", "application/json")], hdrs.as_slice()].concat(), b)
        })
        .await
        .unwrap()
    };
    assert_eq!(post(vec![], body).await.0, 401, "no token");
    assert_eq!(post(vec![("Authorization", "Bearer wrong-token-00")], body).await.0, 401, "wrong token");
    let (st, _, resp) = post(vec![("Authorization", "Bearer test-token-123")], body).await;
    assert_eq!(st, 200, "{}", String::from_utf8_lossy(&resp));
    let mut ctx = plc(running.modbus_addr, 1).await;
    assert_eq!(read(&mut ctx, addr::TYPES_ENROLLED, 1).await[0], 4);
    let (st, _, resp) = post(vec![("Authorization", "Bearer test-token-123")], r#"{"part": 7, "type": "x", "id": 10, "face": "up"}"#).await;
    assert_eq!(st, 400, "{}", String::from_utf8_lossy(&resp));
    // A name that would forge a log line is refused before anything is cut or written.
    let forged = r#"{"part": 1, "type": "x\nINFO accept", "id": 11, "face": "up"}"#;
    let (st, _, resp) = post(vec![("Authorization", "Bearer test-token-123")], forged).await;
    let resp = String::from_utf8_lossy(&resp);
    assert_eq!(st, 400, "{resp}");
    assert!(resp.contains("letters, digits"), "{resp}");
    assert_eq!(read(&mut ctx, addr::TYPES_ENROLLED, 1).await[0], 4, "nothing enrolled");
    running.stop().await;

    // Without a token in the configuration the view is read-only.
    let mut cfg = config("", "");
    cfg.http.as_mut().unwrap().token = None;
    let running = start(&cfg).await;
    one_frame(&running).await;
    let h = running.http_addr.unwrap();
    let (st, _, _) = tokio::task::spawn_blocking(move || {
        http(h, "POST", "/api/camera/1/enroll", &[("Content-Type", "application/json"), ("Authorization", "Bearer test-token-123")], body)
    })
    .await
    .unwrap();
    assert_eq!(st, 403);
    running.stop().await;
}

fn chromium(args: &[&str]) -> std::process::Output {
    let profile = tempfile::tempdir().unwrap();
    let mut cmd = std::process::Command::new("chromium");
    cmd.args([
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--hide-scrollbars",
    ]);
    cmd.arg(format!("--user-data-dir={}", profile.path().display()));
    cmd.args(args);
    cmd.output().unwrap_or_else(|e| panic!("cannot run chromium ({e}); install it with LFI_WITH_BROWSER=1 scripts/deps.sh"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn headless_chromium_shows_the_frame_and_the_registers_the_plc_reads() {
    let running = start(&config("", "")).await;
    one_frame(&running).await;
    let url = format!("http://{}/", running.http_addr.unwrap());
    let dom = {
        let url = url.clone();
        tokio::task::spawn_blocking(move || chromium(&["--virtual-time-budget=8000", "--dump-dom", &url])).await.unwrap()
    };
    let html = String::from_utf8_lossy(&dom.stdout).to_string();
    assert!(html.contains("data-updated"), "the page never updated:\n{}", String::from_utf8_lossy(&dom.stderr));
    // The picture arrived (its onload marks the frame sequence).
    let loaded = html
        .split("id=\"frame\"")
        .nth(1)
        .and_then(|s| s.split("data-loaded=\"").nth(1))
        .and_then(|s| s.split('"').next())
        .unwrap_or("0")
        .to_string();
    assert_ne!(loaded, "0", "the frame picture did not load");
    // Every register the page shows equals what the PLC reads (the heartbeat excepted: it ticks).
    let mut ctx = plc(running.modbus_addr, 1).await;
    let mut words = read(&mut ctx, 0, 120).await;
    words.extend(read(&mut ctx, 120, 120).await);
    let mut checked = 0;
    for r in map::MAP.iter().filter(|r| r.addr != addr::HEARTBEAT) {
        let cell = format!("id=\"reg-{}\">", r.addr);
        let shown =
            html.split(&cell).nth(1).and_then(|s| s.split('<').next()).unwrap_or_else(|| panic!("register {} not on the page", r.name));
        let expect: Vec<String> = (0..r.kind.words()).map(|i| words[(r.addr + i) as usize].to_string()).collect();
        assert_eq!(shown, expect.join(" "), "{} on the page vs Modbus", r.name);
        checked += 1;
    }
    assert_eq!(checked, map::MAP.len() - 1);
    assert!(html.contains("class=\"accept\"") || html.contains("class=\"reject\""), "the part table is empty");
    // A screenshot for the record (target/operator-view.png).
    let shot = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("target/operator-view.png");
    let arg = format!("--screenshot={}", shot.display());
    let out = tokio::task::spawn_blocking(move || chromium(&["--virtual-time-budget=8000", "--window-size=1400,1300", &arg, &url]))
        .await
        .unwrap();
    assert!(shot.exists(), "no screenshot: {}", String::from_utf8_lossy(&out.stderr));
    running.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_shows_the_job_and_changes_it_behind_the_token_as_the_plc_would() {
    let jobs = "[[camera.job]]\nid = 1\nname = \"any\"\n[[camera.job]]\nid = 2\nname = \"flanges\"\nexpected_type = 2\n";
    let running = start(&config("", jobs)).await;
    let h = running.http_addr.unwrap();
    let call = |method: &'static str, path: &'static str, token: &'static str, body: &'static str| async move {
        tokio::task::spawn_blocking(move || {
            let auth = format!("Bearer {token}");
            let hdrs: Vec<(&str, &str)> = if token.is_empty() { vec![] } else { vec![("Authorization", auth.as_str())] };
            http(h, method, path, &[&[("Content-Type", "application/json")], hdrs.as_slice()].concat(), body)
        })
        .await
        .unwrap()
    };
    let job = || async {
        let (_, _, body) = call("GET", "/api/state", "", "").await;
        let v: serde_json::Value = serde_json::from_slice(&body).unwrap();
        v["cameras"][0]["job"].clone()
    };
    let j = job().await;
    assert_eq!((j["id"].as_u64(), j["name"].as_str(), j["status"].as_str()), (Some(1), Some("any"), Some("idle")));
    assert_eq!(j["jobs"], serde_json::json!([[1, "any"], [2, "flanges"]]));
    assert_eq!(call("POST", "/api/camera/1/job", "", r#"{"id": 2}"#).await.0, 401, "no token");
    assert_eq!(call("POST", "/api/camera/1/job", "test-token-123", r#"{"id": 0}"#).await.0, 400, "the register's rule");
    let (st, _, resp) = call("POST", "/api/camera/1/job", "test-token-123", r#"{"id": 2}"#).await;
    assert_eq!(st, 202, "{}", String::from_utf8_lossy(&resp));
    let until = std::time::Instant::now() + Duration::from_secs(60);
    while job().await["status"] == "changing" {
        assert!(std::time::Instant::now() < until, "the change never ended");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let j = job().await;
    assert_eq!(
        (j["id"].as_u64(), j["name"].as_str(), j["status"].as_str(), j["request"].as_u64()),
        (Some(2), Some("flanges"), Some("done"), Some(2))
    );
    // The PLC sees the same change.
    let mut ctx = plc(running.modbus_addr, 1).await;
    assert_eq!(read(&mut ctx, addr::JOB_REQUEST, 1).await, [2]);
    assert_eq!(read(&mut ctx, addr::JOB_ID, 2).await, [2, map::job_status::DONE]);
    assert_eq!(read(&mut ctx, addr::EXPECTED_TYPE, 1).await, [2]);
    running.stop().await;
}
