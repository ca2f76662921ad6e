//! One truth per part: for the same frames, the PLC's result registers, the robot's input words,
//! the operator view's parts, the counters in `/metrics`, the log lines and OPC UA's ResultReady
//! events all tell the same story (after EXPECTED_TYPE, in picking order, with ACQ_ID and
//! PART_INDEX).

mod common;

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use common::appliance::{config, cycle, plc, start, write};
use common::fanuc::Cell;
use common::http::http;
use lfi_bridge::registers::{self as map, addr};
use lfi_bridge::vision::Reason;

const EXPECTED_TYPE: u16 = 2;

/// A part result as each consumer reports it: (ACQ_ID, PART_INDEX, accepted, REASON, X, Y in
/// 0.1 mm).
type Row = (u16, u16, bool, u16, i32, i32);

/// The log lines, captured from the appliance's tracing events.
#[derive(Clone, Default)]
struct Capture(Arc<Mutex<Vec<u8>>>);

impl std::io::Write for Capture {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

fn field<'a>(line: &'a str, key: &str) -> Option<&'a str> {
    let at = line.find(&format!(" {key}="))? + key.len() + 2;
    line[at..].split_whitespace().next()
}

/// `(x, y)` of "... at (x, y) mm" in a log line, in 0.1 mm.
fn millimetres(line: &str) -> (i32, i32) {
    let at = line.find(" at (").expect("a position") + 5;
    let inner = &line[at..line[at..].find(") mm").expect("in mm") + at];
    let (x, y) = inner.split_once(", ").expect("x, y");
    let tenth = |v: &str| (v.parse::<f64>().expect("a number") * 10.0).round() as i32;
    (tenth(x), tenth(y))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_plc_the_robot_the_page_the_counters_and_the_log_agree_on_every_part() {
    let log = Capture::default();
    let sink = log.clone();
    tracing_subscriber::fmt().with_ansi(false).with_max_level(tracing::Level::INFO).with_writer(move || sink.clone()).init();

    let cell = Cell::start(Duration::from_millis(1)).await;
    let pki = tempfile::tempdir().unwrap();
    let opcua = format!("\n[opcua]\nenabled = true\nbind = \"127.0.0.1:0\"\npki_dir = \"{}\"\n", pki.path().display());
    let running = start(&config(&opcua, &cell.robot_toml)).await;
    let web = running.http_addr.expect("http enabled");
    // An OPC UA client subscribed to the camera's ResultReady events before the first trigger.
    let stop_opcua = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let url = running.opcua_url.clone().expect("OPC UA enabled");
    let (dir, stop) = (pki.path().to_path_buf(), stop_opcua.clone());
    let events = tokio::task::spawn_blocking(move || subscribe_results(url, dir, stop)).await.unwrap();
    let mut ctx = plc(running.modbus_addr, 1).await;
    write(&mut ctx, addr::EXPECTED_TYPE, EXPECTED_TYPE).await;

    let mut plc_rows: Vec<Row> = Vec::new();
    let mut plc_types: BTreeMap<(u16, u16), u16> = BTreeMap::new();
    let mut page_rows: Vec<Row> = Vec::new();
    let mut page_types: BTreeMap<(u16, u16), (u16, Option<String>)> = BTreeMap::new();
    for _ in 0..18 {
        let blocks = cycle(&mut ctx).await;
        let acq = blocks.first().map(|b| b[101]).expect("every acquisition gives a result");
        for b in &blocks {
            assert_eq!(b[101], acq, "one acquisition per cycle");
            let row = (b[101], b[110], b[102] == 1, b[103], b[107] as i16 as i32, b[108] as i16 as i32);
            plc_rows.push(row);
            plc_types.insert((row.0, row.1), b[104]);
        }
        // The page follows the PLC within moments: wait until it shows this acquisition.
        let end = tokio::time::Instant::now() + Duration::from_secs(5);
        let parts = loop {
            let (_, _, body) = tokio::task::spawn_blocking(move || http(web, "GET", "/api/state", &[], "")).await.unwrap();
            let v: serde_json::Value = serde_json::from_slice(&body).unwrap();
            let parts = v["cameras"][0]["parts"].as_array().cloned().unwrap_or_default();
            if parts.first().is_some_and(|p| p["acq_id"] == acq) {
                break parts;
            }
            assert!(tokio::time::Instant::now() < end, "the page never showed acquisition {acq}");
            tokio::time::sleep(Duration::from_millis(5)).await;
        };
        for p in parts {
            let reason = Reason::ALL.iter().find(|r| r.as_str() == p["reason"]).expect("a known reason");
            let reason = map::reason_code(*reason);
            let tenth = |k: &str| (p[k].as_f64().unwrap() * 10.0).round() as i32;
            let key = (p["acq_id"].as_u64().unwrap() as u16, p["index"].as_u64().unwrap() as u16);
            let detail = p["detail"].as_str().unwrap();
            if p["reason"] == Reason::WrongType.as_str() {
                assert!(detail.starts_with("wrong type (after the estimate"), "part {key:?}: the why names the final reason: {detail}");
            }
            page_rows.push((key.0, key.1, p["accepted"] == true, reason, tenth("x_mm"), tenth("y_mm")));
            page_types.insert(key, (p["type_id"].as_u64().unwrap() as u16, p["type_name"].as_str().map(str::to_string)));
        }
    }

    let accepted: Vec<&Row> = plc_rows.iter().filter(|r| r.2).collect();
    let wrong_type = plc_rows.iter().filter(|r| r.3 == map::reason_code(Reason::WrongType)).count();
    assert!(accepted.len() >= 3 && wrong_type >= 3, "the frames must test the rule: {} accepted, {wrong_type} wrong type", accepted.len());
    assert!(accepted.iter().all(|r| plc_types[&(r.0, r.1)] == EXPECTED_TYPE), "only the expected type is accepted");
    assert_eq!(page_rows, plc_rows, "the page shows what the PLC got");
    for (key, plc_type) in &plc_types {
        assert_eq!(page_types[key].0, *plc_type, "part {key:?}: TYPE_ID on the page");
    }

    // OPC UA: one ResultReady per acquisition, with the parts the PLC got, in its order.
    let plc_parts: Vec<Row> = plc_rows.iter().filter(|r| r.1 > 0).copied().collect();
    let end = tokio::time::Instant::now() + Duration::from_secs(5);
    let opcua_rows = loop {
        let rows: Vec<(Row, u16)> = events.lock().unwrap().clone();
        if rows.len() >= plc_parts.len() || tokio::time::Instant::now() > end {
            break rows;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    assert_eq!(opcua_rows.len(), plc_parts.len(), "OPC UA's parts {opcua_rows:?} against the PLC's {plc_parts:?}");
    for ((o, type_id), p) in opcua_rows.iter().zip(&plc_parts) {
        assert_eq!(*type_id, plc_types[&(p.0, p.1)], "part {:?}: type_id in ResultReady", (p.0, p.1));
        assert_eq!((o.0, o.1, o.2, o.3), (p.0, p.1, p.2, p.3), "OPC UA and PLC");
        assert!((o.4 - p.4).abs() <= 1 && (o.5 - p.5).abs() <= 1, "OPC UA position {o:?} against the PLC's {p:?}");
    }

    stop_opcua.store(true, std::sync::atomic::Ordering::Relaxed);

    // The robot took exactly the parts the PLC was told to pick, in the same order.
    cell.until_acknowledged(accepted.len(), Duration::from_secs(30)).await;

    // Counters: every final result counted once, by its final reason.
    let (_, _, body) = tokio::task::spawn_blocking(move || http(web, "GET", "/metrics", &[], "")).await.unwrap();
    let metrics = String::from_utf8(body).unwrap();
    let metric = |name: &str| -> u64 {
        let line = metrics.lines().find(|l| l.starts_with(name)).unwrap_or_else(|| panic!("{name} missing"));
        line.rsplit(' ').next().unwrap().parse().unwrap()
    };
    assert_eq!(metric("lfi_parts_accepted_total{") as usize, accepted.len());
    for r in Reason::ALL.iter().skip(1) {
        let plc = plc_rows.iter().filter(|row| !row.2 && row.3 == map::reason_code(*r)).count();
        assert_eq!(
            metric(&format!("lfi_parts_rejected_total{{camera=\"camera1\",unit_id=\"1\",reason=\"{}\"}}", r.as_str())) as usize,
            plc,
            "{r}"
        );
    }

    running.stop().await;
    let picked = cell.picked().await;
    let robot_rows: Vec<(u16, i32, i32)> = picked.iter().map(|p| (p.type_id, p.x, p.y)).collect();
    let plc_accepted: Vec<(u16, i32, i32)> = accepted.iter().map(|r| (plc_types[&(r.0, r.1)], r.4, r.5)).collect();
    assert_eq!(robot_rows, plc_accepted, "the robot picks what the PLC accepts");

    // The log: one line per part result, with the PLC's decision, reason, type and position.
    let text = String::from_utf8(log.0.lock().unwrap().clone()).unwrap();
    let mut logged: Vec<Row> = Vec::new();
    for line in text.lines().filter(|l| l.contains(" part=") && (l.contains(" accept ") || l.contains(" reject ("))) {
        let acq: u16 = field(line, "acq_id").expect("acq_id").parse().unwrap();
        let index: u16 = field(line, "part").expect("part").parse().unwrap();
        let accepted = line.contains(" accept ");
        let reason = if accepted {
            Reason::Ok
        } else {
            let r = &line[line.find(" reject (").unwrap() + 9..];
            *Reason::ALL.iter().find(|x| r.starts_with(&format!("{})", x.as_str()))).expect("a known reason")
        };
        let name = page_types[&(acq, index)].1.clone().unwrap_or_else(|| "?".into());
        assert!(line.contains(&format!(" {name} ")), "part {index} of acquisition {acq} logged under another name: {line}");
        let (x, y) = millimetres(line);
        logged.push((acq, index, accepted, map::reason_code(reason), x, y));
    }
    let plc_parts: Vec<Row> = plc_rows.iter().filter(|r| r.1 > 0).copied().collect();
    assert_eq!(logged.len(), plc_parts.len(), "one log line per part");
    for (l, p) in logged.iter().zip(&plc_parts) {
        assert_eq!((l.0, l.1, l.2, l.3), (p.0, p.1, p.2, p.3), "log and PLC");
        assert!((l.4 - p.4).abs() <= 1 && (l.5 - p.5).abs() <= 1, "log position {l:?} against the PLC's {p:?}");
    }
}

/// The parts of every ResultReady event of camera `camera1`, as rows in the order they come: an
/// anonymous client on the None endpoint, on a thread and runtime of its own (a plant's client
/// is another machine), until `stop` is set.
fn subscribe_results(url: String, dir: std::path::PathBuf, stop: Arc<std::sync::atomic::AtomicBool>) -> Arc<Mutex<Vec<(Row, u16)>>> {
    use async_opcua::types::{TimestampsToReturn, Variant};
    let rows = Arc::new(Mutex::new(Vec::new()));
    let sink = rows.clone();
    let ready = Arc::new(std::sync::Barrier::new(2));
    let ready2 = ready.clone();
    std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
        rt.block_on(async move {
            let session = common::opcua::session(&url, &dir, None).await.expect("an OPC UA session");
            let mv = common::opcua::namespace(&session, common::opcua::MV).await;
            let di = common::opcua::namespace(&session, common::opcua::DI).await;
            let own = common::opcua::namespace(&session, "urn:lfi-bridge:vision").await;
            let system = common::opcua::browse_to(&session, &[(di, "DeviceSet"), (own, "camera1")]).await;
            let sub = common::opcua::event_subscription(&session, 600, move |fields| {
                let Some(Variant::Array(content)) = fields.and_then(|f| f.into_iter().next()) else { return };
                for v in content.values.iter() {
                    let Variant::String(s) = v else { continue };
                    let p: serde_json::Value = serde_json::from_str(s.as_ref()).expect("JSON");
                    let tenth = |k: &str| (p[k].as_f64().unwrap() * 10.0).round() as i32;
                    let n = |k: &str| p[k].as_u64().unwrap() as u16;
                    let row = (n("acq_id"), n("part_index"), p["decision"] == "accept", n("reason_code"), tenth("x_mm"), tenth("y_mm"));
                    sink.lock().unwrap().push((row, n("type_id")));
                }
            })
            .await;
            let item = common::opcua::result_ready_item(system, mv, &["ResultContent"], 100);
            let r = session.create_monitored_items(sub, TimestampsToReturn::Neither, vec![item]).await.expect("a monitored item");
            assert!(r[0].result.status_code.is_good());
            ready2.wait();
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
            let _ = session.disconnect().await;
        });
    });
    ready.wait();
    rows
}
