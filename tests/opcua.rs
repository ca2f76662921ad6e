//! The OPC UA server, driven by async-opcua's client as a plant's SCADA would: the vision
//! system found by browsing, its state against the PLC's ONLINE and ERROR, and the rule that
//! only a configured user may call a method.

mod common;

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use async_opcua::client::{ClientBuilder, IdentityToken, Password, Session};
use async_opcua::crypto::SecurityPolicy;
use async_opcua::types::{
    BrowsePath, CallMethodRequest, LocalizedText, MessageSecurityMode, NodeId, QualifiedName, ReadValueId, ReferenceTypeId, RelativePath,
    RelativePathElement, StatusCode, TimestampsToReturn, UserTokenPolicy, VariableId, Variant,
};
use common::appliance::*;
use lfi_bridge::config::Config;
use lfi_bridge::registers::addr;

const MV: &str = "http://opcfoundation.org/UA/MachineVision";
const DI: &str = "http://opcfoundation.org/UA/DI/";
const PASSWORD: &str = "line-3-secret";

/// An appliance with the OPC UA server on a free port, its PKI and a user's password file in
/// `dir`, and anonymous reading as configured.
async fn appliance(dir: &Path, anonymous: bool) -> lfi_bridge::appliance::Running {
    std::fs::write(dir.join("scada.pw"), format!("{PASSWORD}\n")).unwrap();
    let text = format!(
        "[modbus]\nbind = \"127.0.0.1:0\"\n[http]\nenabled = false\n[log]\nlevel = \"warn\"\n\
         [opcua]\nenabled = true\nbind = \"127.0.0.1:0\"\nallow_anonymous_read = {anonymous}\npki_dir = \"pki\"\n\
         [[opcua.users]]\nname = \"scada\"\npassword_file = \"scada.pw\"\n\
         [[camera]]\nunit_id = 1\nname = \"line3\"\nkb_from_simulator = true\nmm_per_px = 0.5\n\
         [camera.source]\nkind = \"sim\"\nwidth = 640\nheight = 480\nscenes = 9\nseed = 4\n"
    );
    let cfg = Config::from_toml(&text, &dir.join("appliance.toml")).expect("valid configuration");
    start(&cfg).await
}

/// A session on the None endpoint, anonymous or as `user`.
async fn session(url: &str, dir: &Path, user: Option<(&str, &str)>) -> Result<Arc<Session>, StatusCode> {
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

async fn namespace(session: &Session, uri: &str) -> u16 {
    let v = value(session, &VariableId::Server_NamespaceArray.into()).await;
    let Variant::Array(a) = v else { panic!("NamespaceArray is {v:?}") };
    a.values.iter().position(|u| matches!(u, Variant::String(s) if s.as_ref() == uri)).expect("namespace") as u16
}

async fn value(session: &Session, node: &NodeId) -> Variant {
    let r = session.read(&[ReadValueId::new_value(node.clone())], TimestampsToReturn::Neither, 0.0).await.expect("read");
    r[0].value.clone().unwrap_or(Variant::Empty)
}

/// The node at `path` (browse names, each with its namespace) below Objects.
async fn browse_to(session: &Session, path: &[(u16, &str)]) -> NodeId {
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

async fn state(session: &Session, machine: &NodeId) -> String {
    let Variant::LocalizedText(t) = value(session, machine).await else { panic!("CurrentState is not a text") };
    let t: LocalizedText = *t;
    t.text.as_ref().to_string()
}

/// Polls `machine`'s CurrentState until it reads `want` (changes show within a second).
async fn wait_state(session: &Session, machine: &NodeId, want: &str) {
    let until = tokio::time::Instant::now() + Duration::from_secs(2);
    loop {
        let s = state(session, machine).await;
        if s == want {
            return;
        }
        assert!(tokio::time::Instant::now() < until, "CurrentState stays {s:?}, expected {want:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_vision_state_follows_the_plc_and_only_a_user_may_change_it() {
    let dir = tempfile::tempdir().unwrap();
    let running = appliance(dir.path(), true).await;
    let url = running.opcua_url.clone().expect("OPC UA enabled");
    let anon = session(&url, dir.path(), None).await.expect("anonymous session");
    let (mv, di) = (namespace(&anon, MV).await, namespace(&anon, DI).await);
    let own = namespace(&anon, "urn:lfi-bridge:vision").await;
    let system = browse_to(&anon, &[(di, "DeviceSet"), (own, "line3")]).await;
    let machine = browse_to(&anon, &[(di, "DeviceSet"), (own, "line3"), (mv, "VisionStateMachine")]).await;
    let current = browse_to(&anon, &[(di, "DeviceSet"), (own, "line3"), (mv, "VisionStateMachine"), (0, "CurrentState")]).await;
    let auto = browse_to(
        &anon,
        &[(di, "DeviceSet"), (own, "line3"), (mv, "VisionStateMachine"), (mv, "AutomaticModeStateMachine"), (0, "CurrentState")],
    )
    .await;
    let halt = browse_to(&anon, &[(di, "DeviceSet"), (own, "line3"), (mv, "VisionStateMachine"), (mv, "Halt")]).await;
    assert_eq!(halt.namespace, mv, "the NodeSet's own method node");
    let type_def = session_type_definition(&anon, &system).await;
    assert_eq!(type_def, NodeId::new(mv, 1003u32), "a VisionSystemType");
    wait_state(&anon, &current, "Operational").await;
    wait_state(&anon, &auto, "Ready").await;

    // The PLC takes the camera offline: Halted; back online: Operational.
    let mut plc_ctx = plc(running.modbus_addr, 1).await;
    write(&mut plc_ctx, addr::ONLINE, 0).await;
    wait_state(&anon, &current, "Halted").await;
    write(&mut plc_ctx, addr::ONLINE, 1).await;
    wait_state(&anon, &current, "Operational").await;

    // Anonymous: refused, and nothing changes.
    let call = |m: &NodeId| CallMethodRequest { object_id: machine.clone(), method_id: m.clone(), input_arguments: None };
    let r = anon.call_one(call(&halt)).await.expect("call answered");
    assert_eq!(r.status_code, StatusCode::BadUserAccessDenied);
    tokio::time::sleep(Duration::from_millis(300)).await;
    assert_eq!(read_reg(&mut plc_ctx, addr::ONLINE).await, 1, "a refused Halt changed ONLINE");

    // A wrong password: no session at all.
    assert!(session(&url, dir.path(), Some(("scada", "not-the-password"))).await.is_err());

    // The user: Halt is the PLC's ONLINE = 0, SelectModeAutomatic its ONLINE = 1.
    let user = session(&url, dir.path(), Some(("scada", PASSWORD))).await.expect("user session");
    let r = user.call_one(call(&halt)).await.expect("call answered");
    assert_eq!(r.status_code, StatusCode::Good);
    assert_eq!(read_reg(&mut plc_ctx, addr::ONLINE).await, 0);
    wait_state(&anon, &current, "Halted").await;
    let auto_mode = browse_to(&anon, &[(di, "DeviceSet"), (own, "line3"), (mv, "VisionStateMachine"), (mv, "SelectModeAutomatic")]).await;
    let r = user.call_one(call(&auto_mode)).await.expect("call answered");
    assert_eq!(r.status_code, StatusCode::Good);
    assert_eq!(read_reg(&mut plc_ctx, addr::ONLINE).await, 1);
    wait_state(&anon, &current, "Operational").await;
    let _ = user.disconnect().await;
    let _ = anon.disconnect().await;
    running.stop().await;
}

async fn read_reg(ctx: &mut tokio_modbus::client::Context, a: u16) -> u16 {
    read(ctx, a, 1).await[0]
}

async fn session_type_definition(session: &Session, node: &NodeId) -> NodeId {
    let r = session
        .browse(
            &[async_opcua::types::BrowseDescription {
                node_id: node.clone(),
                browse_direction: async_opcua::types::BrowseDirection::Forward,
                reference_type_id: ReferenceTypeId::HasTypeDefinition.into(),
                include_subtypes: false,
                node_class_mask: 0,
                result_mask: 0x3f,
            }],
            10,
            None,
        )
        .await
        .expect("browse");
    let refs = r[0].references.clone().unwrap_or_default();
    refs.first().expect("a type definition").node_id.node_id.clone()
}
