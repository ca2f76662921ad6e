//! An OPC UA client of the appliance (async-opcua's), as the OPC UA tests use it.

use std::path::Path;
use std::sync::Arc;

use async_opcua::client::{ClientBuilder, IdentityToken, Password, Session};
use async_opcua::crypto::SecurityPolicy;
use async_opcua::types::{
    BrowsePath, MessageSecurityMode, NodeId, QualifiedName, ReadValueId, ReferenceTypeId, RelativePath, RelativePathElement, StatusCode,
    TimestampsToReturn, UserTokenPolicy, VariableId, Variant,
};

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
