//! An OPC UA client of the appliance (async-opcua's), as the OPC UA tests use it, and the load
//! of OPC UA clients that `tests/opcua.rs` and `cargo bench --bench plc` (which takes this file
//! by its path) measure the PLC beside.

#![allow(dead_code)]

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use async_opcua::client::{ClientBuilder, IdentityToken, Password, Session};
use async_opcua::crypto::SecurityPolicy;
use async_opcua::types::{
    BrowsePath, MessageSecurityMode, MonitoredItemCreateRequest, NodeId, QualifiedName, ReadValueId, ReferenceTypeId, RelativePath,
    RelativePathElement, StatusCode, TimestampsToReturn, UserTokenPolicy, VariableId, Variant,
};

pub const MV: &str = "http://opcfoundation.org/UA/MachineVision";
pub const DI: &str = "http://opcfoundation.org/UA/DI/";

/// A session on the None endpoint, anonymous or as `user`.
pub async fn session(url: &str, dir: &Path, user: Option<(&str, &str)>) -> Result<Arc<Session>, StatusCode> {
    let mut client = ClientBuilder::new()
        .application_name("lfi-bridge test client")
        .application_uri("urn:lfi-bridge:test-client")
        .pki_dir(dir.join("client-pki"))
        .create_sample_keypair(true)
        .trust_server_certs(true)
        .session_retry_limit(0)
        .client()
        .expect("client");
    let (policy, token) = match user {
        None => (UserTokenPolicy::anonymous(), IdentityToken::Anonymous),
        Some((u, p)) => (
            UserTokenPolicy { token_type: async_opcua::types::UserTokenType::UserName, ..UserTokenPolicy::anonymous() },
            IdentityToken::UserName(u.to_string(), Password::new(p.to_string())),
        ),
    };
    let (session, event_loop) = client
        .connect_to_matching_endpoint((url, SecurityPolicy::None.to_str(), MessageSecurityMode::None, policy), token)
        .await
        .map_err(|e| e.status())?;
    let handle = event_loop.spawn();
    tokio::select! {
        ok = session.wait_for_connection() => if !ok { return Err(StatusCode::BadNotConnected) },
        r = handle => return Err(r.unwrap_or(StatusCode::BadUnexpectedError)),
    }
    Ok(session)
}

pub async fn namespace(session: &Session, uri: &str) -> u16 {
    let v = value(session, &VariableId::Server_NamespaceArray.into()).await;
    let Variant::Array(a) = v else { panic!("NamespaceArray is {v:?}") };
    a.values.iter().position(|u| matches!(u, Variant::String(s) if s.as_ref() == uri)).expect("namespace") as u16
}

pub async fn value(session: &Session, node: &NodeId) -> Variant {
    let r = session.read(&[ReadValueId::new_value(node.clone())], TimestampsToReturn::Neither, 0.0).await.expect("read");
    r[0].value.clone().unwrap_or(Variant::Empty)
}

/// The node at `path` (browse names, each with its namespace) below Objects.
pub async fn browse_to(session: &Session, path: &[(u16, &str)]) -> NodeId {
    let elements = path
        .iter()
        .map(|&(ns, name)| RelativePathElement {
            reference_type_id: ReferenceTypeId::HierarchicalReferences.into(),
            is_inverse: false,
            include_subtypes: true,
            target_name: QualifiedName::new(ns, name),
        })
        .collect();
    let r = session
        .translate_browse_paths_to_node_ids(&[BrowsePath {
            starting_node: async_opcua::types::ObjectId::ObjectsFolder.into(),
            relative_path: RelativePath { elements: Some(elements) },
        }])
        .await
        .expect("translate");
    let targets = r[0].targets.clone().unwrap_or_default();
    assert!(!targets.is_empty(), "nothing at Objects/{path:?}: {:?}", r[0].status_code);
    targets[0].target_id.node_id.clone()
}

/// A subscription publishing every 50 ms (keep-alive 20, a lifetime of `lifetime` publishing
/// intervals) that hands each event's selected fields to `on_event`.
pub async fn event_subscription(
    session: &Session,
    lifetime: u32,
    mut on_event: impl FnMut(Option<Vec<Variant>>) + Send + Sync + 'static,
) -> u32 {
    let callback = async_opcua::client::EventCallback::new(move |fields, _| on_event(fields));
    session.create_subscription(Duration::from_millis(50), lifetime, 20, 1000, 0, true, callback).await.expect("a subscription")
}

/// A monitored item for the ResultReady events of `node` (MachineVision namespace `mv`),
/// selecting `fields` (ResultReadyEventType's browse names) and keeping up to `queue` events
/// between publishes.
pub fn result_ready_item(node: NodeId, mv: u16, fields: &[&str], queue: u32) -> MonitoredItemCreateRequest {
    use async_opcua::types::{AttributeId, ContentFilter, EventFilter, ExtensionObject, NumericRange, SimpleAttributeOperand};
    let select = fields
        .iter()
        .map(|name| SimpleAttributeOperand {
            type_definition_id: NodeId::new(mv, 1024u32),
            browse_path: Some(vec![QualifiedName::new(mv, *name)]),
            attribute_id: AttributeId::Value as u32,
            index_range: NumericRange::None,
        })
        .collect();
    let filter = EventFilter { where_clause: ContentFilter { elements: None }, select_clauses: Some(select) };
    let mut item: MonitoredItemCreateRequest = node.into();
    item.item_to_monitor.attribute_id = AttributeId::EventNotifier as u32;
    item.requested_parameters.queue_size = queue;
    item.requested_parameters.filter = ExtensionObject::from_message(filter);
    item
}

/// OPC UA clients on a thread of their own at the lowest priority (they are other machines):
/// `subscribers` anonymous sessions subscribed to camera `camera`'s ResultReady events, each
/// counting what it receives, and, while `churn` is set, one client connecting and
/// disconnecting as fast as it can.
pub struct OpcuaLoad {
    pub received: Vec<Arc<std::sync::atomic::AtomicUsize>>,
    pub subscribed: Arc<std::sync::atomic::AtomicUsize>,
    pub churn: Arc<std::sync::atomic::AtomicBool>,
    pub churned: Arc<std::sync::atomic::AtomicUsize>,
    pub stop: Arc<std::sync::atomic::AtomicBool>,
    pub thread: std::thread::JoinHandle<()>,
}

impl OpcuaLoad {
    pub fn start(url: String, dir: std::path::PathBuf, camera: &str, subscribers: usize) -> Self {
        let camera = camera.to_string();
        use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering::Relaxed};
        let received: Vec<_> = (0..subscribers).map(|_| Arc::new(AtomicUsize::new(0))).collect();
        let (subscribed, churn, churned, stop) = (
            Arc::new(AtomicUsize::new(0)),
            Arc::new(AtomicBool::new(false)),
            Arc::new(AtomicUsize::new(0)),
            Arc::new(AtomicBool::new(false)),
        );
        let (r2, s2, c2, n2, st2) = (received.clone(), subscribed.clone(), churn.clone(), churned.clone(), stop.clone());
        let thread = std::thread::spawn(move || {
            // SAFETY: setpriority on this thread's own id.
            unsafe { libc::setpriority(libc::PRIO_PROCESS, libc::gettid() as libc::id_t, 19) };
            let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
            rt.block_on(async move {
                let mut sessions = Vec::new();
                for counter in r2 {
                    let s = session(&url, &dir, None).await.expect("a subscriber's session");
                    let (mv, di, own) = (namespace(&s, MV).await, namespace(&s, DI).await, namespace(&s, "urn:lfi-bridge:vision").await);
                    let system = browse_to(&s, &[(di, "DeviceSet"), (own, camera.as_str())]).await;
                    let sub = event_subscription(&s, 100, move |_| {
                        counter.fetch_add(1, Relaxed);
                    })
                    .await;
                    let item = result_ready_item(system, mv, &["ResultContent"], 100);
                    let r = s.create_monitored_items(sub, TimestampsToReturn::Neither, vec![item]).await.expect("monitored item");
                    assert!(r[0].result.status_code.is_good());
                    sessions.push(s);
                    s2.fetch_add(1, Relaxed);
                }
                while !st2.load(Relaxed) {
                    if c2.load(Relaxed) {
                        if let Ok(s) = session(&url, &dir, None).await {
                            let _ = s.disconnect().await;
                            n2.fetch_add(1, Relaxed);
                        }
                    } else {
                        tokio::time::sleep(Duration::from_millis(5)).await;
                    }
                }
                for s in sessions {
                    let _ = s.disconnect().await;
                }
            });
        });
        Self { received, subscribed, churn, churned, stop, thread }
    }
}
