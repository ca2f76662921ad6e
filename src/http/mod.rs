//! The operator view: a small web page served by the appliance (axum), its JSON API,
//! `/metrics` (Prometheus text) and `/healthz`.
//!
//! Reading never changes anything. Enrolling a template from the current frame needs the token
//! from `[http] token` (sent as `Authorization: Bearer <token>`); without a configured token the
//! view is read-only. Every change is logged with the client's address.
//!
//! Isolation: the view runs on its own thread and runtime, serves at most `max_connections`
//! connections (the rest wait in the kernel's backlog, holding none of the appliance's file
//! descriptors), handles at most `max_in_flight` requests at once, closes a connection whose
//! headers do not arrive within `header_timeout_s`, answers 408 past `request_timeout_s`, and
//! encodes the live frame once per frame however many clients ask for it. Whatever the page's
//! clients do, the PLC's Modbus service keeps its threads and descriptors.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Instant;

use axum::Router;
use axum::extract::{ConnectInfo, Path, Query, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{Html, IntoResponse, Response};
use axum::routing::{get, post};
use serde::{Deserialize, Serialize};
use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;

use crate::appliance::enrol::{EnrolError, EnrolRequest};
use crate::appliance::{CameraHandle, Running, StartError};
use crate::config::HttpConfig;
use crate::modbus::server::Stats;
use crate::registers::{self as map};
use crate::vision::{Face, Reason};

mod views;

use views::{StateView, camera_view, history_view, nan_to_zero};

const PAGE: &str = include_str!("page.html");

/// A camera's live picture as last encoded: the frame's `Live::seq` and the JPEG.
pub type Picture = tokio::sync::Mutex<Option<(u64, axum::body::Bytes)>>;

/// What the handlers share.
#[derive(Clone)]
pub struct AppState {
    /// The appliance's cameras.
    pub cameras: Arc<Vec<CameraHandle>>,
    /// The Modbus server's counters.
    pub stats: Arc<Stats>,
    /// When the appliance started.
    pub started: Instant,
    /// Bearer token for changes; None: read-only.
    pub token: Option<String>,
    /// Per camera, the live picture encoded for the latest frame (by `Live::seq`): encoded once
    /// per frame, however many clients ask (the lock makes the others wait for that one).
    pub pictures: Arc<Vec<Picture>>,
    /// The OPC UA server's counters, when it runs.
    pub opcua: Option<Arc<crate::opcua::Stats>>,
    /// Per camera, the templates alike overall for the knowledge base of a key (see
    /// `views::templates_key`): worked out once per change of templates (the lock makes other
    /// clients wait for that one).
    pub alike: Arc<Vec<Alike>>,
}

/// A camera's alike report for a knowledge base, by its key.
pub type Alike = tokio::sync::Mutex<Option<(String, Arc<Vec<AlikeView>>)>>;

/// Starts the operator view beside a running appliance (which stops it with itself), on its own
/// thread and single-threaded runtime.
pub async fn attach(running: &mut Running, cfg: &HttpConfig, opcua: Option<Arc<crate::opcua::Stats>>) -> Result<SocketAddr, StartError> {
    let bind_err = |source| StartError::Bind { addr: cfg.bind, source };
    let listener = std::net::TcpListener::bind(cfg.bind).map_err(bind_err)?;
    listener.set_nonblocking(true).map_err(bind_err)?;
    let addr = listener.local_addr().map_err(bind_err)?;
    let pictures = Arc::new(running.cameras.iter().map(|_| tokio::sync::Mutex::new(None)).collect());
    let state = AppState {
        cameras: running.cameras.clone(),
        stats: running.stats.clone(),
        started: running.started,
        token: cfg.token.clone(),
        pictures,
        alike: Arc::new(running.cameras.iter().map(|_| tokio::sync::Mutex::new(None)).collect()),
        opcua,
    };
    tracing::info!(
        "operator view on http://{addr}/ ({})",
        if cfg.token.is_some() { "changes need the token" } else { "read-only: no token configured" }
    );
    let (limits, shutdown) = (cfg.clone(), running.shutdown.clone());
    let thread = std::thread::Builder::new()
        .name("operator-view".into())
        .spawn(move || {
            lower_priority();
            let rt = match tokio::runtime::Builder::new_current_thread().enable_all().build() {
                Ok(rt) => rt,
                Err(e) => return tracing::error!("operator view not started: no runtime: {e}"),
            };
            rt.block_on(async move {
                match TcpListener::from_std(listener) {
                    Ok(l) => serve(l, state, &limits, shutdown).await,
                    Err(e) => tracing::error!("operator view not started: {e}"),
                }
            });
        })
        .map_err(bind_err)?;
    running.add_task(tokio::task::spawn_blocking(move || {
        let _ = thread.join();
    }));
    running.http_addr = Some(addr);
    Ok(addr)
}

/// Nice value of the operator view's thread: under a flood of page requests the camera worker
/// and the Modbus service (nice 0) get the CPU first (weights 1024 against 110 in Linux's
/// scheduler), while an idle appliance still serves the page at once.
pub const NICE: i32 = crate::appliance::VIEW_NICE;

fn lower_priority() {
    crate::appliance::lower_priority("operator view");
}

/// The accept loop: one connection per permit, each served by hyper with the header timeout;
/// the router carries the request timeout and the in-flight limit.
pub async fn serve(listener: TcpListener, state: AppState, limits: &HttpConfig, shutdown: CancellationToken) {
    use tower::Service;
    let app = router(state)
        .layer(tower::limit::GlobalConcurrencyLimitLayer::new(limits.max_in_flight))
        .layer(tower_http::timeout::TimeoutLayer::with_status_code(StatusCode::REQUEST_TIMEOUT, limits.request_timeout));
    let mut make = app.into_make_service_with_connect_info::<SocketAddr>();
    let permits = Arc::new(tokio::sync::Semaphore::new(limits.max_connections));
    let mut backoff = std::time::Duration::from_millis(10);
    loop {
        // Accept only with a permit: a flood waits in the kernel's backlog, not in our descriptors.
        let permit = tokio::select! {
            _ = shutdown.cancelled() => break,
            p = permits.clone().acquire_owned() => match p { Ok(p) => p, Err(_) => break },
        };
        let (stream, peer) = tokio::select! {
            _ = shutdown.cancelled() => break,
            a = listener.accept() => match a {
                Ok(a) => {
                    backoff = std::time::Duration::from_millis(10);
                    a
                }
                Err(e) => {
                    tracing::warn!("operator view: accepting failed: {e}; retrying in {} ms", backoff.as_millis());
                    tokio::time::sleep(backoff).await;
                    backoff = (backoff * 2).min(std::time::Duration::from_secs(1));
                    continue;
                }
            },
        };
        let Ok(svc) = make.call(peer).await;
        let io = hyper_util::rt::TokioIo::new(stream);
        let (shutdown, header_timeout) = (shutdown.clone(), limits.header_timeout);
        tokio::spawn(async move {
            let _permit = permit;
            let conn = hyper::server::conn::http1::Builder::new()
                .timer(hyper_util::rt::TokioTimer::new())
                .header_read_timeout(header_timeout)
                .serve_connection(io, hyper_util::service::TowerToHyperService::new(svc));
            tokio::pin!(conn);
            tokio::select! {
                r = conn.as_mut() => if let Err(e) = r {
                    tracing::debug!(%peer, "operator view connection ended: {e}");
                },
                _ = shutdown.cancelled() => {
                    conn.as_mut().graceful_shutdown();
                    let _ = tokio::time::timeout(std::time::Duration::from_secs(2), conn).await;
                }
            }
        });
    }
}

/// The operator view's routes (also what tests drive without a socket).
pub fn router(state: AppState) -> Router {
    Router::new()
        .route("/", get(|| async { Html(PAGE) }))
        .route("/healthz", get(healthz))
        .route("/metrics", get(metrics))
        .route("/api/state", get(api_state))
        .route("/api/events", get(events))
        .route("/api/camera/{unit}/history", get(history_list))
        .route("/api/camera/{unit}/history/{id}/frame.jpg", get(history_frame))
        .route("/api/camera/{unit}/control", post(control))
        .route("/api/camera/{unit}/frame.jpg", get(frame_jpg))
        .route("/api/camera/{unit}/templates", get(templates))
        .route("/api/camera/{unit}/template/{index}", get(template_png))
        .route("/api/camera/{unit}/alike", get(alike))
        .route("/api/camera/{unit}/enroll", post(enroll))
        .route("/api/camera/{unit}/job", post(change_job))
        .route("/api/camera/{unit}/archive", get(archive_list))
        .route("/api/camera/{unit}/archive/{file}", get(archive_file))
        .with_state(state)
}

type Failure = (StatusCode, String);

fn camera(state: &AppState, unit: u8) -> Result<&CameraHandle, Failure> {
    state.cameras.iter().find(|c| c.unit_id == unit).ok_or((StatusCode::NOT_FOUND, format!("no camera with unit id {unit}")))
}

async fn healthz(State(state): State<AppState>) -> Response {
    let bad: Vec<String> = state
        .cameras
        .iter()
        .filter(|c| !c.handshake.lock().unwrap_or_else(|p| p.into_inner()).camera_ok())
        .map(|c| c.name.clone())
        .collect();
    let text = [(header::CONTENT_TYPE, "text/plain; charset=utf-8")];
    if bad.is_empty() {
        (StatusCode::OK, text, "ok\n".to_string()).into_response()
    } else {
        (StatusCode::SERVICE_UNAVAILABLE, text, format!("camera not ok: {}\n", bad.join(", "))).into_response()
    }
}

/// Metric families: name, type, help.
const FAMILIES: [(&str, &str, &str); 33] = [
    ("lfi_modbus_clients", "gauge", "Modbus/TCP clients connected."),
    ("lfi_modbus_requests_total", "counter", "Modbus requests answered."),
    ("lfi_modbus_exceptions_total", "counter", "Modbus requests answered with an exception."),
    ("lfi_modbus_refused_total", "counter", "Connections refused at max_connections."),
    ("lfi_frames_total", "counter", "Frames estimated."),
    ("lfi_frame_errors_total", "counter", "Acquisitions without a usable frame."),
    ("lfi_parts_accepted_total", "counter", "Parts accepted."),
    ("lfi_parts_rejected_total", "counter", "Parts rejected, by reason."),
    ("lfi_debris_total", "counter", "Pieces of debris seen (material too small to be a part), all frames."),
    ("lfi_debris", "gauge", "Pieces of debris in the latest frame."),
    ("lfi_cycle_time_ms", "summary", "Trigger to results queued, last 512 cycles."),
    ("lfi_results_pending", "gauge", "Results waiting for RESULT_ACK."),
    ("lfi_acquisitions_total", "counter", "Acquisitions started."),
    ("lfi_missed_triggers_total", "counter", "Triggers while busy, offline or in error."),
    ("lfi_results_dropped_total", "counter", "Results dropped because the queue was full."),
    ("lfi_camera_ok", "gauge", "1 when the camera delivers frames."),
    ("lfi_robot_connected", "gauge", "1 when the robot link is connected."),
    ("lfi_robot_queue", "gauge", "Parts waiting for the robot."),
    ("lfi_robot_delivered", "gauge", "Parts the robot acknowledged (16-bit counter)."),
    ("lfi_camera_frames_received_total", "counter", "Complete frames received from a GenICam camera."),
    ("lfi_camera_frames_dropped_total", "counter", "GenICam frames dropped in free-run because a newer one was there."),
    ("lfi_camera_frames_incomplete_total", "counter", "Incomplete or corrupt GenICam buffers (dropped)."),
    ("lfi_camera_reconnects_total", "counter", "Reconnections of a lost GenICam camera."),
    ("lfi_archive_saved_total", "counter", "Frames written to the image archive."),
    ("lfi_archive_dropped_total", "counter", "Frames not archived: the archive's queue was full (the disk is slower than the line)."),
    ("lfi_archive_failed_total", "counter", "Frames the archive could not write (logged)."),
    ("lfi_archive_deleted_total", "counter", "Archived frames deleted to keep within max_files and max_mb."),
    ("lfi_opcua_sessions", "gauge", "OPC UA sessions open."),
    ("lfi_opcua_subscriptions", "gauge", "OPC UA subscriptions."),
    ("lfi_opcua_sessions_total", "counter", "OPC UA sessions opened since start."),
    ("lfi_opcua_rejected_requests_total", "counter", "OPC UA requests the server rejected."),
    (
        "lfi_opcua_method_calls_total",
        "counter",
        "OPC UA method calls the appliance answered, by outcome (ok; refused by its checks: not READY, an unknown job, ...). An anonymous session's call is refused by the server before it and is not counted here.",
    ),
    (
        "lfi_opcua_events_total",
        "counter",
        "OPC UA ResultReady events raised (lost: acquisitions not reported because the server fell behind).",
    ),
];

async fn metrics(State(state): State<AppState>) -> Response {
    use std::fmt::Write;
    use std::sync::atomic::Ordering::Relaxed;
    let mut m = String::new();
    for (name, kind, help) in FAMILIES {
        if name.starts_with("lfi_opcua_") {
            // Only when the OPC UA server runs.
            let Some(o) = &state.opcua else { continue };
            let _ = writeln!(m, "# HELP {name} {help}\n# TYPE {name} {kind}");
            let values: Vec<(&str, u64)> = match name {
                "lfi_opcua_sessions" => vec![("", o.sessions.load(Relaxed))],
                "lfi_opcua_subscriptions" => vec![("", o.subscriptions.load(Relaxed))],
                "lfi_opcua_sessions_total" => vec![("", o.sessions_total.load(Relaxed))],
                "lfi_opcua_rejected_requests_total" => vec![("", o.rejected_requests.load(Relaxed))],
                "lfi_opcua_method_calls_total" => {
                    vec![("{outcome=\"ok\"}", o.calls_ok.load(Relaxed)), ("{outcome=\"refused\"}", o.calls_refused.load(Relaxed))]
                }
                _ => vec![("{result=\"raised\"}", o.events.load(Relaxed)), ("{result=\"lost\"}", o.events_lost.load(Relaxed))],
            };
            for (labels, v) in values {
                let _ = writeln!(m, "{name}{labels} {v}");
            }
            continue;
        }
        let _ = writeln!(m, "# HELP {name} {help}\n# TYPE {name} {kind}");
        let global = match name {
            "lfi_modbus_clients" => Some(state.stats.connected.load(Relaxed)),
            "lfi_modbus_requests_total" => Some(state.stats.requests.load(Relaxed)),
            "lfi_modbus_exceptions_total" => Some(state.stats.exceptions.load(Relaxed)),
            "lfi_modbus_refused_total" => Some(state.stats.refused.load(Relaxed)),
            _ => None,
        };
        if let Some(v) = global {
            let _ = writeln!(m, "{name} {v}");
            continue;
        }
        for c in state.cameras.iter() {
            let l = format!("camera=\"{}\",unit_id=\"{}\"", c.name.replace(['"', '\\', '\n'], "_"), c.unit_id);
            let live = c.live.lock().unwrap_or_else(|p| p.into_inner());
            let hs = c.handshake.lock().unwrap_or_else(|p| p.into_inner());
            let counters = hs.counters();
            let robot = c.robot.as_ref().map(|r| *r.lock().unwrap_or_else(|p| p.into_inner()));
            let mut line = |v: String| {
                let _ = writeln!(m, "{name}{{{l}}} {v}");
            };
            match name {
                "lfi_frames_total" => line(live.frames.to_string()),
                "lfi_frame_errors_total" => line(live.frame_errors.to_string()),
                "lfi_parts_accepted_total" => line(live.accepted.to_string()),
                "lfi_debris_total" => line(live.debris_total.to_string()),
                "lfi_debris" => line(live.debris_last.to_string()),
                "lfi_results_pending" => line(hs.queue().len().to_string()),
                "lfi_acquisitions_total" => line(counters.acquisitions.to_string()),
                "lfi_missed_triggers_total" => line(counters.missed_triggers.to_string()),
                "lfi_results_dropped_total" => line(counters.dropped.to_string()),
                "lfi_camera_ok" => line((hs.camera_ok() as u8).to_string()),
                "lfi_robot_connected" => {
                    if let Some(v) = robot {
                        line(((v.bits & map::robot_status::CONNECTED != 0) as u8).to_string())
                    }
                }
                "lfi_robot_queue" => {
                    if let Some(v) = robot {
                        line(v.queue.to_string())
                    }
                }
                "lfi_robot_delivered" => {
                    if let Some(v) = robot {
                        line(v.delivered.to_string())
                    }
                }
                "lfi_camera_frames_received_total"
                | "lfi_camera_frames_dropped_total"
                | "lfi_camera_frames_incomplete_total"
                | "lfi_camera_reconnects_total" => {
                    if let Some(g) = &c.genicam {
                        let v = match name {
                            "lfi_camera_frames_received_total" => &g.received,
                            "lfi_camera_frames_dropped_total" => &g.dropped,
                            "lfi_camera_frames_incomplete_total" => &g.incomplete,
                            _ => &g.reconnects,
                        };
                        line(v.load(Relaxed).to_string())
                    }
                }
                "lfi_archive_saved_total" | "lfi_archive_dropped_total" | "lfi_archive_failed_total" | "lfi_archive_deleted_total" => {
                    if let Some(a) = c.archive.as_ref().map(|s| &s.counters) {
                        let v = match name {
                            "lfi_archive_saved_total" => &a.saved,
                            "lfi_archive_dropped_total" => &a.dropped,
                            "lfi_archive_failed_total" => &a.failed,
                            _ => &a.deleted,
                        };
                        line(v.load(Relaxed).to_string())
                    }
                }
                "lfi_parts_rejected_total" => {
                    for r in Reason::ALL.iter().skip(1) {
                        let _ = writeln!(m, "{name}{{{l},reason=\"{}\"}} {}", r.as_str(), live.rejected[r.index()]);
                    }
                }
                _ => {
                    let v: Vec<f64> = live.cycle_ms.iter().copied().collect();
                    for q in [0.5, 0.95, 0.99] {
                        let _ = writeln!(m, "{name}{{{l},quantile=\"{q}\"}} {:.3}", nan_to_zero(crate::eval::percentile(&v, q)));
                    }
                    let _ = writeln!(m, "{name}_sum{{{l}}} {:.3}\n{name}_count{{{l}}} {}", v.iter().sum::<f64>(), v.len());
                }
            }
        }
    }
    (StatusCode::OK, [(header::CONTENT_TYPE, "text/plain; version=0.0.4; charset=utf-8")], m).into_response()
}

/// The whole page's state, as `/api/state` and every live update give it.
fn state_view(state: &AppState) -> StateView {
    use std::sync::atomic::Ordering::Relaxed;
    StateView {
        uptime_s: state.started.elapsed().as_secs_f64(),
        modbus_clients: state.stats.connected.load(Relaxed),
        modbus_requests: state.stats.requests.load(Relaxed),
        modbus_exceptions: state.stats.exceptions.load(Relaxed),
        opcua: state.opcua.as_ref().map(|o| views::OpcuaView {
            endpoint: o.endpoint.get().cloned().unwrap_or_default(),
            sessions: o.sessions.load(Relaxed),
            subscriptions: o.subscriptions.load(Relaxed),
        }),
        can_change: state.token.is_some(),
        cameras: state.cameras.iter().map(camera_view).collect(),
    }
}

async fn api_state(State(state): State<AppState>) -> Response {
    ([(header::CACHE_CONTROL, "no-store")], axum::Json(state_view(&state))).into_response()
}

/// Live updates as server-sent events: the state whenever something the page shows changes (a
/// frame, a fault, a history entry, a change made from a page; at most every 100 ms), and at
/// least once a second (the registers a PLC writes, the heartbeat).
async fn events(State(state): State<AppState>) -> Response {
    use axum::response::sse::{Event, KeepAlive, Sse};
    // Every camera shares the appliance's one change signal.
    let rx = state.cameras.first().map(|c| c.changes.subscribe());
    let stream = futures_util::stream::unfold((state, rx, true), |(state, mut rx, first)| async move {
        if !first {
            let wait = async {
                match rx.as_mut() {
                    Some(r) => {
                        let _ = r.changed().await;
                    }
                    None => std::future::pending::<()>().await,
                }
            };
            let _ = tokio::time::timeout(std::time::Duration::from_secs(1), wait).await;
            // Changes in a burst (a frame, its history entry) make one update.
            tokio::time::sleep(std::time::Duration::from_millis(100)).await;
            if let Some(r) = rx.as_mut() {
                r.mark_unchanged();
            }
        }
        let json = serde_json::to_string(&state_view(&state)).unwrap_or_else(|e| format!("{{\"error\":\"{e}\"}}"));
        let event: Result<Event, std::convert::Infallible> = Ok(Event::default().event("state").data(json));
        Some((event, (state, rx, false)))
    });
    Sse::new(stream).keep_alive(KeepAlive::default()).into_response()
}

/// `frame.jpg?grid=true`: the robot frame's grid drawn over the picture.
#[derive(Deserialize)]
struct GridQuery {
    #[serde(default)]
    grid: bool,
}

async fn frame_jpg(State(state): State<AppState>, Path(unit): Path<u8>, Query(q): Query<GridQuery>) -> Result<Response, Failure> {
    let cam = camera(&state, unit)?;
    let jpeg = |bytes| ([(header::CONTENT_TYPE, "image/jpeg"), (header::CACHE_CONTROL, "no-store")], bytes).into_response();
    let snapshot = || {
        let live = cam.live.lock().unwrap_or_else(|p| p.into_inner());
        (live.frame.clone(), live.estimate.clone(), live.seq)
    };
    if q.grid {
        // Drawn for each request: only a commissioning engineer asks for it.
        let (frame, estimate, _) = snapshot();
        let calibration = cam.job().calibration.clone();
        return Ok(jpeg(live_picture(cam, frame, estimate, Some(calibration)).await?));
    }
    let slot = state.cameras.iter().position(|c| std::ptr::eq(c, cam)).and_then(|i| state.pictures.get(i));
    let slot = slot.ok_or((StatusCode::INTERNAL_SERVER_ERROR, "no picture slot for this camera".to_string()))?;
    let mut cached = slot.lock().await;
    let (frame, estimate, seq) = snapshot();
    let bytes = match cached.as_ref() {
        Some((s, b)) if *s == seq => b.clone(),
        _ => {
            let bytes = live_picture(cam, frame, estimate, None).await?;
            *cached = Some((seq, bytes.clone()));
            bytes
        }
    };
    Ok(jpeg(bytes))
}

/// The latest frame as a JPEG at most 960 px wide, its parts drawn, and with `grid` the
/// calibration's lines of constant robot X and Y.
async fn live_picture(
    cam: &CameraHandle,
    frame: Option<Arc<crate::vision::GrayImage>>,
    estimate: Option<crate::vision::FrameEstimate>,
    grid: Option<crate::calibration::Calibration>,
) -> Result<axum::body::Bytes, Failure> {
    let (Some(frame), Some(estimate)) = (frame, estimate) else { return Err((StatusCode::NOT_FOUND, "no frame yet".into())) };
    let job = cam.job();
    let bytes = tokio::task::spawn_blocking(move || -> Result<Vec<u8>, Failure> {
        let fail = |e: opencv::Error| (StatusCode::INTERNAL_SERVER_ERROR, e.to_string());
        let scale = (960.0 / frame.width as f64).min(1.0);
        let view = frame.view().map_err(|e| (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?;
        let mut pic = crate::overlay::draw(view, &estimate, &job.estimator, scale).map_err(fail)?;
        if let Some(c) = &grid {
            crate::overlay::draw_grid(&mut pic, c, frame.width, frame.height, scale).map_err(fail)?;
        }
        crate::imageio::encode_mat(&pic, ".jpg").map_err(|e| (StatusCode::INTERNAL_SERVER_ERROR, e))
    })
    .await
    .map_err(|e| (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))??;
    Ok(axum::body::Bytes::from(bytes))
}

#[derive(Serialize)]
struct TemplateView {
    index: usize,
    type_name: String,
    type_id: u16,
    face: &'static str,
    source: String,
    outline_points: usize,
    line_features: usize,
}

async fn templates(State(state): State<AppState>, Path(unit): Path<u8>) -> Result<Response, Failure> {
    let cam = camera(&state, unit)?;
    let list: Vec<TemplateView> = cam
        .job()
        .templates
        .entries
        .iter()
        .enumerate()
        .map(|(i, e)| TemplateView {
            index: i,
            type_name: e.template.type_name.clone(),
            type_id: e.template.type_id,
            face: e.template.face.as_str(),
            source: e.source.clone(),
            outline_points: e.template.outline.len(),
            line_features: e.template.segments.len(),
        })
        .collect();
    Ok(axum::Json(list).into_response())
}

/// Two enrolled templates alike overall, as the knowledge-base panel shows them.
#[derive(Serialize)]
pub struct AlikeView {
    #[serde(flatten)]
    pair: crate::kb::AlikePair,
    /// The operator's line (the largest difference in mm too when the job is calibrated).
    text: String,
}

/// The templates alike overall in the job in force's knowledge base: where a frame tells them
/// apart, and a warning where nothing does (the same report as `enroll`).
async fn alike(State(state): State<AppState>, Path(unit): Path<u8>) -> Result<Response, Failure> {
    let cam = camera(&state, unit)?;
    let k = state.cameras.iter().position(|c| c.unit_id == unit).expect("found above");
    let job = cam.job();
    let key = views::templates_key(&job.templates);
    let mut cached = state.alike[k].lock().await;
    if let Some((have, list)) = cached.as_ref()
        && *have == key
    {
        return Ok(axum::Json(list.as_ref()).into_response());
    }
    let mm_per_px = mm_per_px(&job.calibration);
    let list = tokio::task::spawn_blocking(move || {
        job.templates
            .alike(job.estimator.params(), None)
            .into_iter()
            .map(|pair| AlikeView { text: pair.describe(mm_per_px), pair })
            .collect::<Vec<_>>()
    })
    .await
    .map_err(|e| (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?;
    let list = Arc::new(list);
    *cached = Some((key, list.clone()));
    Ok(axum::Json(list.as_ref()).into_response())
}

/// Millimetres per pixel near the image's origin, where the calibration maps pixels to mm.
fn mm_per_px(c: &crate::calibration::Calibration) -> Option<f64> {
    let (x0, y0) = c.to_robot(0.0, 0.0)?;
    let (x1, y1) = c.to_robot(100.0, 0.0)?;
    let s = (x1 - x0).hypot(y1 - y0) / 100.0;
    (s.is_finite() && s > 0.0).then_some(s)
}

#[derive(Deserialize)]
struct HistoryQuery {
    /// Only acquisitions with a reject or a fault.
    #[serde(default)]
    rejects: bool,
}

/// The kept acquisitions, newest first, each with its results and their measures.
async fn history_list(State(state): State<AppState>, Path(unit): Path<u8>, Query(q): Query<HistoryQuery>) -> Result<Response, Failure> {
    let cam = camera(&state, unit)?;
    let entries = cam.history.as_ref().map(|h| h.entries()).unwrap_or_default();
    let list: Vec<views::HistoryView> = entries
        .iter()
        .rev()
        .filter(|e| !q.rejects || e.error.is_some() || e.results.iter().any(|r| !r.part.accepted))
        .map(|e| history_view(e))
        .collect();
    Ok(([(header::CACHE_CONTROL, "no-store")], axum::Json(list)).into_response())
}

#[derive(Deserialize)]
struct FrameQuery {
    /// A part whose best-fit template outline is drawn too (PART_INDEX).
    part: Option<usize>,
    /// A thumbnail (160 px wide) instead of the kept picture's size.
    #[serde(default)]
    thumb: bool,
}

/// A kept acquisition's picture with its overlay (JPEG).
async fn history_frame(
    State(state): State<AppState>,
    Path((unit, id)): Path<(u8, u64)>,
    Query(q): Query<FrameQuery>,
) -> Result<Response, Failure> {
    let cam = camera(&state, unit)?;
    let entry =
        cam.history.as_ref().and_then(|h| h.get(id)).ok_or((StatusCode::NOT_FOUND, format!("acquisition {id} is no longer kept")))?;
    let job = cam.job();
    let bytes = tokio::task::spawn_blocking(move || -> Result<Vec<u8>, Failure> {
        use opencv::prelude::*;
        let internal = |e: String| (StatusCode::INTERNAL_SERVER_ERROR, e);
        let picture = entry.picture.as_ref().ok_or((StatusCode::NOT_FOUND, "no frame came with this acquisition".to_string()))?;
        let gray = picture.view().map_err(|e| internal(e.to_string()))?.as_mat().map_err(|e| internal(e.to_string()))?;
        let img = match &entry.estimate {
            Some(fe) => {
                let templates: Vec<_> = job.estimator.templates().collect();
                crate::overlay::annotate_gray(&gray, fe, &templates, entry.scale, q.part).map_err(|e| internal(e.to_string()))?
            }
            None => {
                let mut bgr = opencv::core::Mat::default();
                opencv::imgproc::cvt_color(&gray, &mut bgr, opencv::imgproc::COLOR_GRAY2BGR, 0).map_err(|e| internal(e.to_string()))?;
                bgr
            }
        };
        let img = if q.thumb {
            let w = 160;
            let h = (img.rows() * w / img.cols().max(1)).max(1);
            let mut small = opencv::core::Mat::default();
            opencv::imgproc::resize(&img, &mut small, opencv::core::Size::new(w, h), 0.0, 0.0, opencv::imgproc::INTER_AREA)
                .map_err(|e| internal(e.to_string()))?;
            small
        } else {
            img
        };
        crate::imageio::encode_mat(&img, ".jpg").map_err(internal)
    })
    .await
    .map_err(|e| (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))??;
    Ok(([(header::CONTENT_TYPE, "image/jpeg"), (header::CACHE_CONTROL, "max-age=3600")], bytes).into_response())
}

#[derive(Deserialize)]
struct ControlRequest {
    /// trigger, ack, clear_error, online, expected_type or job.
    action: String,
    /// The value for online (0/1), expected_type (a TYPE_ID, 0: any) and job (its id).
    value: Option<u16>,
}

/// A commissioning control, behind the token: each is the register write a PLC would make
/// (the same checks, the same handshake), logged with the client's address.
async fn control(
    State(state): State<AppState>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    Path(unit): Path<u8>,
    headers: HeaderMap,
    axum::Json(req): axum::Json<ControlRequest>,
) -> Result<Response, Failure> {
    use map::{addr, status};
    authorized(&state, &headers, peer, "a control")?;
    let cam = camera(&state, unit)?;
    let read = |a: u16| cam.handshake.lock().unwrap_or_else(|p| p.into_inner()).read(a, 1)[0];
    let needs = |what: &str| req.value.ok_or((StatusCode::BAD_REQUEST, format!("{what} needs a value")));
    let (register, value) = match req.action.as_str() {
        "trigger" => {
            let s = read(addr::STATUS);
            if s & status::READY == 0 {
                return Err((
                    StatusCode::CONFLICT,
                    format!("not READY (STATUS {s:08b}): online, not busy, camera OK and no error are needed"),
                ));
            }
            (addr::TRIGGER, 1)
        }
        "ack" => match read(addr::RESULT_SEQ) {
            0 => return Err((StatusCode::CONFLICT, "no result to acknowledge (RESULT_SEQ 0)".into())),
            seq => (addr::RESULT_ACK, seq),
        },
        "clear_error" => (addr::CLEAR_ERROR, 1),
        "online" => (addr::ONLINE, needs("online")?),
        "expected_type" => (addr::EXPECTED_TYPE, needs("expected_type")?),
        "job" => (addr::JOB_REQUEST, needs("job")?),
        other => {
            return Err((
                StatusCode::BAD_REQUEST,
                format!("unknown action {other:?}: trigger, ack, clear_error, online, expected_type or job"),
            ));
        }
    };
    cam.write_as_plc(register, value).map_err(control_failure)?;
    let name = map::lookup(register).map_or("?", |r| r.name);
    tracing::info!(camera = %cam.name, %peer, "operator view: {} ({name} = {value})", req.action);
    if register == addr::TRIGGER {
        // As a PLC does: TRIGGER back to 0 once the appliance acknowledged the edge.
        let hs = cam.handshake.clone();
        let cam_state = state.clone();
        tokio::spawn(async move {
            let until = tokio::time::Instant::now() + std::time::Duration::from_secs(5);
            while tokio::time::Instant::now() < until {
                if hs.lock().unwrap_or_else(|p| p.into_inner()).read(addr::STATUS, 1)[0] & status::TRIGGER_ACK != 0 {
                    break;
                }
                tokio::time::sleep(std::time::Duration::from_millis(10)).await;
            }
            if let Some(c) = cam_state.cameras.iter().find(|c| c.unit_id == unit)
                && let Err(e) = c.write_as_plc(addr::TRIGGER, 0)
            {
                tracing::warn!(camera = %c.name, "operator view: TRIGGER not lowered: {e}");
            }
        });
    }
    Ok(axum::Json(serde_json::json!({ "action": req.action, "register": name, "value": value })).into_response())
}

#[derive(Deserialize)]
struct JobRequest {
    id: u16,
}

/// Asks for a job change as the PLC would (JOB_REQUEST); 202: started, its outcome shows in
/// the job's status.
async fn change_job(
    State(state): State<AppState>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    Path(unit): Path<u8>,
    headers: HeaderMap,
    axum::Json(req): axum::Json<JobRequest>,
) -> Result<Response, Failure> {
    authorized(&state, &headers, peer, "a job change")?;
    let cam = camera(&state, unit)?;
    cam.write_as_plc(map::addr::JOB_REQUEST, req.id).map_err(control_failure)?;
    tracing::info!(camera = %cam.name, %peer, "job {} requested from the operator view", req.id);
    Ok((StatusCode::ACCEPTED, axum::Json(serde_json::json!({ "requested": req.id }))).into_response())
}

#[derive(Deserialize)]
struct ArchiveQuery {
    /// Sidecars returned at most (default 20, at most 200).
    limit: Option<usize>,
}

/// The image archive's newest frames, newest first: each sidecar as written (its `image` is
/// served by [`archive_file`]).
async fn archive_list(
    State(state): State<AppState>,
    Path(unit): Path<u8>,
    axum::extract::Query(q): axum::extract::Query<ArchiveQuery>,
) -> Result<Response, Failure> {
    let shelf = camera(&state, unit)?.archive.clone().ok_or((StatusCode::NOT_FOUND, format!("camera {unit} keeps no archive")))?;
    let limit = q.limit.unwrap_or(20).clamp(1, 200);
    let list = tokio::task::spawn_blocking(move || shelf.recent(limit))
        .await
        .map_err(|e| (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?
        .map_err(|e| (StatusCode::INTERNAL_SERVER_ERROR, format!("cannot read the archive: {e}")))?;
    Ok(axum::Json(list).into_response())
}

/// One archived image or sidecar, by the name its sidecar gives.
async fn archive_file(State(state): State<AppState>, Path((unit, file)): Path<(u8, String)>) -> Result<Response, Failure> {
    let shelf = camera(&state, unit)?.archive.clone().ok_or((StatusCode::NOT_FOUND, format!("camera {unit} keeps no archive")))?;
    let kind = if file.ends_with(".png") { "image/png" } else { "application/json" };
    let name = file.clone();
    let bytes = tokio::task::spawn_blocking(move || shelf.file(&name))
        .await
        .map_err(|e| (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?
        .ok_or((StatusCode::NOT_FOUND, format!("no archived file {file:?}")))?;
    Ok(([(header::CONTENT_TYPE, kind)], bytes).into_response())
}

/// A thumbnail of a template (see [`crate::overlay::thumbnail`]).
async fn template_png(State(state): State<AppState>, Path((unit, index)): Path<(u8, usize)>) -> Result<Response, Failure> {
    let cam = camera(&state, unit)?;
    let t = cam
        .job()
        .templates
        .entries
        .get(index)
        .map(|e| e.template.clone())
        .ok_or((StatusCode::NOT_FOUND, format!("no template {index}")))?;
    let img = crate::overlay::thumbnail(&t, 160).map_err(|e| (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?;
    let png = crate::imageio::encode_mat(&img, ".png").map_err(|e| (StatusCode::INTERNAL_SERVER_ERROR, e))?;
    Ok(([(header::CONTENT_TYPE, "image/png")], png).into_response())
}

#[derive(Deserialize)]
struct EnrollRequest {
    /// Index of the part in the current frame's estimate.
    part: usize,
    #[serde(rename = "type")]
    type_name: String,
    id: u16,
    face: String,
    /// The ACQ_ID of the frame the part was chosen on (a newer frame refuses the request).
    acq_id: Option<u16>,
}

/// A refused write is the client's mistake (400); a stopped worker is the appliance's (503).
fn control_failure(e: crate::appliance::ControlError) -> Failure {
    let status = match e {
        crate::appliance::ControlError::Refused { .. } => StatusCode::BAD_REQUEST,
        crate::appliance::ControlError::Stopped => StatusCode::SERVICE_UNAVAILABLE,
    };
    (status, e.to_string())
}

/// Whether `headers` carry the token for a change (`what`, for the log); a refusal is logged
/// with the client's address.
fn authorized(state: &AppState, headers: &HeaderMap, peer: SocketAddr, what: &str) -> Result<(), Failure> {
    check_token(state, headers).inspect_err(|e| tracing::warn!(%peer, "refused {what} request: {}", e.1))
}

fn check_token(state: &AppState, headers: &HeaderMap) -> Result<(), Failure> {
    let Some(token) = &state.token else {
        return Err((
            StatusCode::FORBIDDEN,
            "the operator view is read-only: set [http] token in the configuration to allow changes".into(),
        ));
    };
    let given = headers.get(header::AUTHORIZATION).and_then(|v| v.to_str().ok()).and_then(|v| v.strip_prefix("Bearer ")).unwrap_or("");
    // Compare without an early exit: the token guards a production line.
    let same = given.len() == token.len() && given.bytes().zip(token.bytes()).fold(0u8, |acc, (a, b)| acc | (a ^ b)) == 0;
    if same { Ok(()) } else { Err((StatusCode::UNAUTHORIZED, "wrong or missing token (Authorization: Bearer <token>)".into())) }
}

async fn enroll(
    State(state): State<AppState>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    Path(unit): Path<u8>,
    headers: HeaderMap,
    axum::Json(req): axum::Json<EnrollRequest>,
) -> Result<Response, Failure> {
    authorized(&state, &headers, peer, "an enrollment")?;
    let cam = camera(&state, unit)?;
    let face: Face = req.face.parse().map_err(|e: String| (StatusCode::BAD_REQUEST, e))?;
    let request = EnrolRequest {
        part: req.part,
        type_name: req.type_name.clone(),
        id: req.id,
        face,
        by: format!("operator view ({peer})"),
        acq_id: req.acq_id,
    };
    let done = cam.enrol(request).await.map_err(|e| {
        let status = if e.is_request() {
            StatusCode::BAD_REQUEST
        } else if e.is_conflict() {
            StatusCode::CONFLICT
        } else {
            StatusCode::INTERNAL_SERVER_ERROR
        };
        let message = match std::error::Error::source(&e) {
            Some(s) if !matches!(e, EnrolError::Kb(_)) => format!("{e}: {s}"),
            _ => e.to_string(),
        };
        (status, message)
    })?;
    Ok((
        StatusCode::OK,
        axum::Json(serde_json::json!({ "type": req.type_name, "face": face.as_str(), "id": req.id, "replaced": done.replaced, "saved": done.saved })),
    )
        .into_response())
}
