//! The OPC UA server: each camera as an OPC 40100-1 vision system, beside the PLC's Modbus.
//!
//! Isolation, as the operator view's: its own thread and runtime at a lower priority, limits on
//! sessions, subscriptions and monitored items; whatever its clients do, the camera workers and
//! the Modbus service keep their threads. It reads the handshakes and writes to them only as
//! the PLC would (`CameraHandle::write_as_plc`): the state machines stay the only deciders.

pub mod auth;
pub mod model;

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use async_opcua::server::node_manager::memory::{InMemoryNodeManager, InMemoryNodeManagerBuilder};
use async_opcua::server::{ServerBuilder, ServerEndpoint};
use async_opcua::types::{AttributeId, StatusCode, Variant};

use crate::appliance::{CameraHandle, Running, StartError};
use crate::config::{OpcuaConfig, Trigger};
use crate::registers::addr;
use model::{Call, CameraNodes, Vision};

/// How often the cameras' states are read into the model (a change shows within this).
const STATE_PERIOD: Duration = Duration::from_millis(100);

/// The endpoint URL clients connect to for `bind`.
pub fn endpoint_url(bind: SocketAddr) -> String {
    let host = if bind.ip().is_unspecified() { hostname() } else { bind.ip().to_string() };
    let host = if host.contains(':') { format!("[{host}]") } else { host };
    format!("opc.tcp://{host}:{}/", bind.port())
}

fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname").map(|h| h.trim().to_string()).unwrap_or_else(|_| "localhost".into())
}

/// Starts the OPC UA server beside a running appliance (which stops it with itself), on its own
/// thread and runtime; returns the endpoint URL.
pub async fn attach(running: &mut Running, cfg: &OpcuaConfig, triggers: Vec<Trigger>) -> Result<String, StartError> {
    let bind_err = |source| StartError::Bind { addr: cfg.bind, source };
    let listener = std::net::TcpListener::bind(cfg.bind).map_err(bind_err)?;
    listener.set_nonblocking(true).map_err(bind_err)?;
    let addr = listener.local_addr().map_err(bind_err)?;
    let url = endpoint_url(addr);
    std::fs::create_dir_all(&cfg.pki_dir)
        .map_err(|source| StartError::Opcua { message: format!("cannot make the PKI folder {}: {source}", cfg.pki_dir.display()) })?;
    let cameras = running.cameras.clone();
    let handler: model::Handler = {
        let cameras = cameras.clone();
        Arc::new(move |camera, call, args, user| handle(&cameras[camera], call, args, user))
    };
    let imports = model::imports().map_err(|message| StartError::Opcua { message })?;
    let (server, handle) = builder(cfg, addr)
        .with_node_manager(InMemoryNodeManagerBuilder::new(Vision::build(imports, handler)))
        .with_authenticator(Arc::new(auth::Users::new(cfg.users.clone(), cfg.allow_anonymous_read)))
        .build()
        .map_err(|message| StartError::Opcua { message: format!("the OPC UA server cannot be built: {message}") })?;
    let manager = handle
        .node_managers()
        .get_of_type::<InMemoryNodeManager<Vision>>()
        .ok_or_else(|| StartError::Opcua { message: "the vision node manager is missing".into() })?;
    let mut nodes: Vec<CameraNodes> = Vec::new();
    {
        let tt = handle.type_tree().read();
        for (i, c) in cameras.iter().enumerate() {
            nodes.push(model::add_camera(&manager, &*tt, i, &c.name).map_err(|message| StartError::Opcua { message })?);
        }
    }
    tracing::info!(
        "OPC UA server on {url} ({} vision system(s) under Objects/DeviceSet; anonymous {}; {} user(s); PKI {})",
        nodes.len(),
        if cfg.allow_anonymous_read { "may read" } else { "refused" },
        cfg.users.len(),
        cfg.pki_dir.display()
    );
    let shutdown = running.shutdown.clone();
    let thread = std::thread::Builder::new()
        .name("opcua".into())
        .spawn(move || {
            crate::appliance::lower_priority("OPC UA server");
            let rt = match tokio::runtime::Builder::new_current_thread().enable_all().build() {
                Ok(rt) => rt,
                Err(e) => return tracing::error!("OPC UA server not started: no runtime: {e}"),
            };
            rt.block_on(async move {
                let listener = match tokio::net::TcpListener::from_std(listener) {
                    Ok(l) => l,
                    Err(e) => return tracing::error!("OPC UA server not started: {e}"),
                };
                let updates = follow_states(&manager, &handle, &cameras, &nodes, &triggers, shutdown.clone());
                let cancel = handle.token().clone();
                let stop = async move {
                    shutdown.cancelled().await;
                    cancel.cancel();
                };
                let (served, _, _) = tokio::join!(server.run_with(listener), updates, stop);
                if let Err(e) = served {
                    tracing::error!("OPC UA server stopped: {e}");
                }
            });
        })
        .map_err(bind_err)?;
    running.add_task(tokio::task::spawn_blocking(move || {
        let _ = thread.join();
    }));
    Ok(url)
}

/// The server's settings: endpoints None and Basic256Sha256 (Sign, SignAndEncrypt) at `/`,
/// the certificate made at first start in the PKI folder, the limits.
fn builder(cfg: &OpcuaConfig, addr: SocketAddr) -> ServerBuilder {
    use async_opcua::crypto::SecurityPolicy;
    use async_opcua::types::MessageSecurityMode;
    let host = if addr.ip().is_unspecified() { hostname() } else { addr.ip().to_string() };
    let endpoint = |policy: SecurityPolicy, mode: MessageSecurityMode| {
        let mut e = ServerEndpoint::from(("/", policy, mode, &[][..]));
        e.password_security_policy = Some(auth::password_policy());
        e
    };
    let mut b = ServerBuilder::new()
        .application_name("lfi-bridge")
        .application_uri(format!("urn:{host}:lfi-bridge"))
        .product_uri("urn:lfi-bridge")
        .host(host)
        .port(addr.port())
        .pki_dir(&cfg.pki_dir)
        .create_sample_keypair(true)
        .certificate_path("own/cert.der")
        .private_key_path("private/private.pem")
        .trust_client_certs(cfg.trust_client_certs)
        .discovery_urls(vec!["/".to_owned()])
        .add_endpoint("none", endpoint(SecurityPolicy::None, MessageSecurityMode::None))
        .add_endpoint("basic256sha256_sign", endpoint(SecurityPolicy::Basic256Sha256, MessageSecurityMode::Sign))
        .add_endpoint("basic256sha256_sign_encrypt", endpoint(SecurityPolicy::Basic256Sha256, MessageSecurityMode::SignAndEncrypt))
        .max_sessions(cfg.max_sessions)
        .diagnostics_enabled(true);
    let limits = b.limits_mut();
    limits.subscriptions.max_subscriptions_per_session = cfg.max_subscriptions_per_session;
    limits.subscriptions.max_monitored_items_per_sub = cfg.max_monitored_items_per_subscription;
    b
}

/// Reads every camera's state into the model while the server runs: the handshake decides,
/// this only copies (a change shows within [`STATE_PERIOD`]).
async fn follow_states(
    manager: &InMemoryNodeManager<Vision>,
    handle: &async_opcua::server::ServerHandle,
    cameras: &[CameraHandle],
    nodes: &[CameraNodes],
    triggers: &[Trigger],
    shutdown: tokio_util::sync::CancellationToken,
) {
    let mut last = vec![None; cameras.len()];
    let mut tick = tokio::time::interval(STATE_PERIOD);
    loop {
        tokio::select! {
            _ = shutdown.cancelled() => break,
            _ = tick.tick() => {}
        }
        for (i, cam) in cameras.iter().enumerate() {
            let free_run = triggers.get(i) == Some(&Trigger::FreeRun);
            let state = cam.handshake.lock().unwrap_or_else(|p| p.into_inner()).vision_state(free_run);
            if last[i] == Some(state) {
                continue;
            }
            last[i] = Some(state);
            tracing::debug!(camera = %cam.name, "OPC UA state: {state:?}");
            let values = model::state_values(&nodes[i], state);
            if let Err(e) = manager.set_attributes(handle.subscriptions(), values.iter().map(|(id, v)| (id, AttributeId::Value, v.clone())))
            {
                tracing::warn!(camera = %cam.name, "OPC UA state not updated: {e}");
            }
        }
    }
}

/// A method call on camera `cam`, carried out as the PLC's register write would be.
fn handle(cam: &CameraHandle, call: Call, _args: &[Variant], user: &str) -> Result<Vec<Variant>, StatusCode> {
    let (register, value) = match call {
        Call::Halt => (addr::ONLINE, 0),
        Call::Reset => (addr::CLEAR_ERROR, 1),
        Call::SelectModeAutomatic => (addr::ONLINE, 1),
    };
    match cam.write_as_plc(register, value) {
        Ok(()) => {
            tracing::info!(camera = %cam.name, user, "OPC UA {call:?}");
            Ok(Vec::new())
        }
        Err(e) => {
            tracing::warn!(camera = %cam.name, user, "OPC UA {call:?} refused: {e}");
            Err(StatusCode::BadInvalidState)
        }
    }
}
