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
    // The PLC sees RESULT_VALID a moment before the page's copy of the frame is stored.
    let until = std::time::Instant::now() + Duration::from_secs(10);
    let (st, ct, body) = loop {
        let r = get("/api/camera/1/frame.jpg").await;
        if r.0 != 404 || std::time::Instant::now() > until {
            break r;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    };
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
    let (st, ct, body) = get("/api/camera/1/alike").await;
    assert_eq!((st, ct.as_str()), (200, "application/json"));
    assert!(serde_json::from_slice::<serde_json::Value>(&body).unwrap().is_array());
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
    // The knowledge-base panel: the part enrolled again under a new name is alike to the type
    // it is, and nothing tells them apart.
    let (st, ct, resp) = tokio::task::spawn_blocking(move || http(h, "GET", "/api/camera/1/alike", &[], "")).await.unwrap();
    assert_eq!((st, ct.as_str()), (200, "application/json"));
    let alike: Vec<serde_json::Value> = serde_json::from_slice(&resp).unwrap();
    let twin = alike.iter().find(|a| a["first"] == "newpart up" || a["second"] == "newpart up");
    let twin = twin.unwrap_or_else(|| panic!("newpart not reported alike: {alike:?}"));
    assert_eq!(twin["told_apart"], false, "{twin}");
    assert!(twin["text"].as_str().unwrap().starts_with("warning: "), "{twin}");
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

/// Two cameras: the simulator at unit 1 (every condition in turn, rejects among them) and a
/// folder camera at unit 2 whose inbox stays empty, so that its trigger times out: a camera
/// fault for the banner.
fn two_cameras(root: &std::path::Path) -> lfi_bridge::config::Config {
    let sim = lfi_bridge::sim::Simulator::new(lfi_bridge::sim::SimConfig { width: 640, height: 480, seed: 4, noise: None }).unwrap();
    let mut kb = lfi_bridge::kb::KnowledgeBase::default();
    for t in common::enrolled(&sim) {
        kb.enroll(t, "sim".into()).unwrap();
    }
    kb.save(&root.join("kb.toml")).unwrap();
    std::fs::create_dir_all(root.join("inbox")).unwrap();
    let text = "[modbus]\nbind = \"127.0.0.1:0\"\n[http]\nbind = \"127.0.0.1:0\"\ntoken = \"test-token-123\"\n[log]\nlevel = \"warn\"\n\
        [[camera]]\nunit_id = 1\nkb_from_simulator = true\nmm_per_px = 0.5\n[camera.source]\nkind = \"sim\"\nwidth = 640\nheight = 480\nscenes = 9\nseed = 4\n\
        [[camera]]\nunit_id = 2\nname = \"belt2\"\nkb = \"kb.toml\"\n[camera.source]\nkind = \"dir\"\npath = \"inbox\"\ntimeout_ms = 300\n";
    lfi_bridge::config::Config::from_toml(text, &root.join("appliance.toml")).unwrap()
}

/// The page in a real browser (headless Chromium through chromedriver), against what the PLC
/// reads: the latest frame's parts (PART_INDEX, DECISION, TYPE_ID, ANGLE, X, Y) as the result
/// registers give them and every register's raw value; a reject in the history with its why
/// panel; a camera fault as a banner; every control refused without the token and doing, with
/// it, what the PLC then reads. Screenshots at 1600 x 1200 and 800 x 1000 go to target/.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn in_chromium_the_page_shows_what_the_plc_reads_the_history_with_its_why_a_fault_and_the_controls() {
    let root = tempfile::tempdir().unwrap();
    let running = start(&two_cameras(root.path())).await;
    let mut ctx = plc(running.modbus_addr, 1).await;
    let mut blocks = Vec::new();
    for _ in 0..9 {
        blocks = cycle(&mut ctx).await;
    }
    let acq = blocks[0][(addr::ACQ_ID - 100) as usize];
    let url = format!("http://{}/", running.http_addr.unwrap());
    let browser = tokio::task::spawn_blocking(common::webdriver::Browser::start).await.unwrap();
    let b = std::sync::Arc::new(browser);
    let on = |f: Box<dyn FnOnce(&common::webdriver::Browser) -> serde_json::Value + Send>| {
        let b = b.clone();
        async move { tokio::task::spawn_blocking(move || f(&b)).await.unwrap() }
    };
    let long = Duration::from_secs(20);
    let stamp = format!("ACQ_ID {acq} ");
    on(Box::new(move |b| {
        b.goto(&url);
        b.wait(&format!("return document.getElementById('stamp').textContent.startsWith({stamp:?}) && document.getElementById('frame').dataset.loaded !== '0' && document.querySelectorAll('#parts tbody tr').length > 0"), long)
    }))
    .await;

    // The parts as the PLC read them for the same frame.
    let rows = on(Box::new(|b| {
        b.js("return [...document.querySelectorAll('#parts tbody tr')].map(r => [Number(r.dataset.index), r.dataset.decision, Number(r.dataset.type), Number(r.dataset.angle), Number(r.dataset.x), Number(r.dataset.y)])")
    }))
    .await;
    let rows = rows.as_array().unwrap();
    assert_eq!(rows.len(), blocks.len(), "one row per result: {rows:?}");
    let at = |blk: &Vec<u16>, a: u16| blk[(a - 100) as usize];
    for (row, blk) in rows.iter().zip(&blocks) {
        let decision = if at(blk, addr::DECISION) == 1 { "accept" } else { "reject" };
        assert_eq!(row[0].as_u64(), Some(at(blk, addr::PART_INDEX) as u64), "PART_INDEX: {row}");
        assert_eq!(row[1].as_str(), Some(decision), "DECISION: {row}");
        assert_eq!(row[2].as_u64(), Some(at(blk, addr::TYPE_ID) as u64), "TYPE_ID: {row}");
        assert!((row[3].as_f64().unwrap() - at(blk, addr::ANGLE) as i16 as f64 / 100.0).abs() < 0.006, "ANGLE: {row}");
        assert!((row[4].as_f64().unwrap() - at(blk, addr::X) as i16 as f64 / 10.0).abs() < 0.11, "X: {row}");
        assert!((row[5].as_f64().unwrap() - at(blk, addr::Y) as i16 as f64 / 10.0).abs() < 0.11, "Y: {row}");
    }
    // Every register the page shows equals what the PLC reads (HEARTBEAT ticks, so not it).
    let cells = on(Box::new(|b| {
        b.js("return Object.fromEntries([...document.querySelectorAll('[id^=reg-]')].map(e => [e.id.slice(4), e.textContent]))")
    }))
    .await;
    let mut words = read(&mut ctx, 0, 120).await;
    words.extend(read(&mut ctx, 120, 120).await);
    for r in map::MAP.iter().filter(|r| r.addr != addr::HEARTBEAT) {
        let expect: Vec<String> = (0..r.kind.words()).map(|i| words[(r.addr + i) as usize].to_string()).collect();
        assert_eq!(cells[r.addr.to_string()].as_str(), Some(expect.join(" ").as_str()), "{} on the page vs Modbus", r.name);
    }

    // Screenshots, and the layout: two columns at 1600, the result block in view at 1280 x 800,
    // one column at 800.
    let target = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("target");
    let shot = target.join("operator-view-1600.png");
    on(Box::new(move |b| {
        b.screenshot(&shot);
        b.size(1280, 800);
        b.wait("return document.querySelector('#parts tbody tr').getBoundingClientRect().bottom <= window.innerHeight", long)
    }))
    .await;
    let shot = target.join("operator-view-800.png");
    let columns = on(Box::new(move |b| {
        b.size(800, 1000);
        let c = b.wait(
            "const c = getComputedStyle(document.querySelector('main')).gridTemplateColumns.split(' ').length; return c === 1 && c",
            long,
        );
        b.screenshot(&shot);
        b.size(1600, 1200);
        c
    }))
    .await;
    assert_eq!(columns, 1);

    // A reject in the history, and its why panel with the measure that failed.
    let why = on(Box::new(move |b| {
        // Thumbnails from memory; with "rejects only", acquisitions with a reject only.
        b.wait("const i = document.querySelector('.hitem img'); return i && i.complete && i.naturalWidth > 0", long);
        b.click("#rejects");
        b.wait("const h = [...document.querySelectorAll('.hitem')]; return h.length > 0 && h.length < 9 && h.every(e => e.dataset.rejected !== '0')", long);
        b.click(".hitem[data-rejected]:not([data-rejected=\"0\"])");
        b.wait("return document.getElementById('why').className === 'on' && document.querySelector('#measures tr[data-pass=false]') && document.getElementById('whyverdict').textContent", long)
    }))
    .await;
    assert!(why.as_str().unwrap().contains("reject"), "why: {why}");
    let shot = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("target/operator-view-why.png");
    on(Box::new(move |b| {
        b.js("document.getElementById('why').scrollIntoView(); return 1");
        b.screenshot(&shot);
        serde_json::Value::Null
    }))
    .await;

    // Camera 2's trigger finds no frame: ERROR, shown as a banner with its text.
    let mut ctx2 = plc(running.modbus_addr, 2).await;
    write(&mut ctx2, addr::TRIGGER, 1).await;
    wait_status(&mut ctx2, |s| s & status::ERROR != 0, Duration::from_secs(10)).await;
    write(&mut ctx2, addr::TRIGGER, 0).await;
    let banner = on(Box::new(move |b| {
        b.js("const s = document.getElementById('cam'); s.value = '2'; s.dispatchEvent(new Event('change')); return 1");
        b.wait("const e = document.getElementById('banner'); return e.className === 'error' && e.textContent", long)
    }))
    .await;
    assert!(banner.as_str().unwrap().contains("camera (no frame)"), "banner: {banner}");

    // Controls: refused without the token, done with it, as the PLC then reads.
    let press = |token: &'static str, button: &'static str| {
        let b = b.clone();
        async move {
            tokio::task::spawn_blocking(move || {
                b.js(&format!("document.getElementById('token').value = {token:?}; document.getElementById('cresult').removeAttribute('data-status'); return 1"));
                b.click(button);
                b.wait("return document.getElementById('cresult').dataset.status", Duration::from_secs(10))
            })
            .await
            .unwrap()
        }
    };
    assert_eq!(press("", "button[data-action=clear_error]").await, "401");
    assert_eq!(press("test-token-123", "button[data-action=clear_error]").await, "200");
    assert_eq!(read(&mut ctx2, addr::STATUS, 1).await[0] & status::ERROR, 0, "ERROR cleared from the page");
    on(Box::new(|b| b.js("const s = document.getElementById('cam'); s.value = '1'; s.dispatchEvent(new Event('change')); return 1"))).await;
    for (button, register, expect) in
        [("button[data-action=online][data-value='0']", addr::ONLINE, 0), ("button[data-action=online][data-value='1']", addr::ONLINE, 1)]
    {
        assert_eq!(press("", button).await, "401");
        assert_eq!(read(&mut ctx, register, 1).await[0], 1 - expect, "nothing changed without the token");
        assert_eq!(press("test-token-123", button).await, "200");
        assert_eq!(read(&mut ctx, register, 1).await[0], expect, "{button}");
    }
    on(Box::new(|b| b.js("document.getElementById('etypesel').value = '2'; return 1"))).await;
    assert_eq!(press("", "#setexp").await, "401");
    assert_eq!(press("test-token-123", "#setexp").await, "200");
    assert_eq!(read(&mut ctx, addr::EXPECTED_TYPE, 1).await[0], 2);
    let acq0 = read(&mut ctx, addr::ACQ_COUNT, 1).await[0];
    assert_eq!(press("", "button[data-action=trigger]").await, "401");
    assert_eq!(press("test-token-123", "button[data-action=trigger]").await, "200");
    wait_status(&mut ctx, |s| s & status::RESULT_VALID != 0 && s & status::BUSY == 0, Duration::from_secs(10)).await;
    assert_eq!(read(&mut ctx, addr::ACQ_COUNT, 1).await[0], acq0.wrapping_add(1), "one acquisition from the page's trigger");
    let seq = read(&mut ctx, addr::RESULT_SEQ, 1).await[0];
    assert_eq!(press("", "button[data-action=ack]").await, "401");
    assert_eq!(press("test-token-123", "button[data-action=ack]").await, "200");
    assert_ne!(read(&mut ctx, addr::RESULT_SEQ, 1).await[0], seq, "the result acknowledged from the page");
    drop(b);
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
