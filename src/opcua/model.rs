//! The information model: OPC 40100-1 (machine vision) and OPC 10000-100 (devices) loaded from
//! their official NodeSets, and per camera one `VisionSystemType` object under DI's
//! `DeviceSet`, instantiated from the type's own declarations (our node ids, the NodeSet's
//! method nodes). See `opcua-model.md`.

use std::collections::HashMap;
use std::sync::Arc;

use async_opcua::nodes::TypeTree;
use async_opcua::nodes::{HasNodeId, NodeBase, NodeSetImport, NodeType, ObjectBuilder, VariableBuilder};
use async_opcua::server::address_space::{AccessLevel, AddressSpace};
use async_opcua::server::diagnostics::NamespaceMetadata;
use async_opcua::server::node_manager::memory::{InMemoryNodeManager, InMemoryNodeManagerImpl};
use async_opcua::server::node_manager::{MethodCall, RequestContext, ServerContext};
use async_opcua::sync::RwLock;
use async_opcua::types::{
    BrowseDirection, DataEncoding, LocalizedText, NodeId, NumericRange, ObjectId, QualifiedName, ReferenceTypeId, StatusCode,
    TimestampsToReturn, Variant,
};

use crate::handshake::VisionState;

/// OPC 40100-1's namespace.
pub const MV_URI: &str = "http://opcfoundation.org/UA/MachineVision";
/// OPC 10000-100's namespace (DeviceSet).
pub const DI_URI: &str = "http://opcfoundation.org/UA/DI/";
/// The appliance's own namespace: the instances' node ids.
pub const OWN_URI: &str = "urn:lfi-bridge:vision";

const DI_NODESET: &str = include_str!("../../opcua/Opc.Ua.Di.NodeSet2.xml");
const MV_NODESET: &str = include_str!("../../opcua/Opc.Ua.MachineVision.NodeSet2.xml");

/// The two NodeSets, parsed (the files are compiled in: the appliance needs nothing beside it).
pub fn imports() -> Result<Vec<Box<dyn NodeSetImport>>, String> {
    let load = |name: &str, text: &str| {
        async_opcua::nodes::NodeSet2Import::new_str("en", text, vec![]).map_err(|e| format!("NodeSet {name}: {e}"))
    };
    Ok(vec![Box::new(load("Opc.Ua.Di.NodeSet2.xml", DI_NODESET)?), Box::new(load("Opc.Ua.MachineVision.NodeSet2.xml", MV_NODESET)?)])
}

/// What a method call on a camera's object asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Call {
    /// VisionStateMachine.Halt: offline.
    Halt,
    /// VisionStateMachine.Reset: CLEAR_ERROR.
    Reset,
    /// VisionStateMachine.SelectModeAutomatic: online.
    SelectModeAutomatic,
    /// AutomaticModeStateMachine.StartSingleJob: one trigger.
    StartSingleJob,
    /// AutomaticModeStateMachine.Stop.
    Stop,
    /// AutomaticModeStateMachine.Abort.
    Abort,
    /// RecipeManagement.PrepareRecipe: JOB_REQUEST.
    PrepareRecipe,
    /// ResultManagement.GetResultById: one of the kept results.
    GetResultById,
    /// ResultManagement.GetResultListFiltered: the kept results that match.
    GetResultListFiltered,
}

impl Call {
    fn of(browse_name: &str) -> Option<Call> {
        Some(match browse_name {
            "Halt" => Call::Halt,
            "Reset" => Call::Reset,
            "SelectModeAutomatic" => Call::SelectModeAutomatic,
            "StartSingleJob" => Call::StartSingleJob,
            "Stop" => Call::Stop,
            "Abort" => Call::Abort,
            "PrepareRecipe" => Call::PrepareRecipe,
            "GetResultById" => Call::GetResultById,
            "GetResultListFiltered" => Call::GetResultListFiltered,
            _ => return None,
        })
    }
}

/// Carries out a call for camera `camera` (index in configuration order): the shell's side.
pub type Handler = Arc<dyn Fn(usize, Call, &[Variant], &str) -> Result<Vec<Variant>, StatusCode> + Send + Sync>;

/// The node manager of the vision systems: the imported NodeSets and the cameras' objects.
pub struct Vision {
    namespaces: Vec<NamespaceMetadata>,
    /// (object, method) -> (camera, call): filled when the objects are made.
    calls: RwLock<HashMap<(NodeId, NodeId), (usize, Call)>>,
    handler: Handler,
}

impl Vision {
    /// The node manager's implementation, built with the server (imports the NodeSets).
    pub fn build(imports: Vec<Box<dyn NodeSetImport>>, handler: Handler) -> impl FnOnce(ServerContext, &mut AddressSpace) -> Vision {
        move |context, address_space| {
            let mut namespaces: Vec<NamespaceMetadata> = Vec::new();
            let mut data_types = Vec::new();
            {
                let mut type_tree = context.type_tree.write();
                for import in &imports {
                    // AddressSpace::import_node_set, noting the data types on the way.
                    let mut map = async_opcua::types::NodeSetNamespaceMapper::new(type_tree.namespaces_mut());
                    import.register_namespaces(&mut map);
                    for ns in import.get_own_namespaces() {
                        if let Some(&idx) = map.namespaces().known_namespaces().get(&ns) {
                            address_space.add_namespace(&ns, idx);
                        }
                    }
                    for item in import.load(&map) {
                        if let NodeType::DataType(dt) = &item.node {
                            data_types.push(dt.node_id().clone());
                        }
                        address_space.import_node(item);
                    }
                    for ns in import.get_own_namespaces() {
                        if !namespaces.iter().any(|n| n.namespace_uri == ns) {
                            namespaces.push(NamespaceMetadata { namespace_uri: ns, ..Default::default() });
                        }
                    }
                }
                namespaces.push(NamespaceMetadata { namespace_uri: OWN_URI.into(), ..Default::default() });
                for ns in &mut namespaces {
                    ns.namespace_index = type_tree.namespaces_mut().add_namespace(&ns.namespace_uri);
                }
            }
            for ns in &namespaces {
                address_space.add_namespace(&ns.namespace_uri, ns.namespace_index);
            }
            inherit_definitions(address_space, &data_types);
            Vision { namespaces, calls: RwLock::new(HashMap::new()), handler }
        }
    }
}

/// A structure type the NodeSet declares without a definition of its own (MachineVision's
/// RecipeIdExternalDataType, ConfigurationIdDataType, ...: subtypes of the abstract
/// BinaryIdBaseDataType) gets its supertype's fields, with its own encoding: OPC UA 1.04 clients
/// (asyncua's `load_data_type_definitions`) build a type only from its own DataTypeDefinition.
///
/// Every structure's definition also names its binary encoding (`DefaultEncodingId`), which the
/// NodeSet's XML leaves out: a client that builds its types from the definitions (asyncua)
/// sends that id with every structure it encodes.
fn inherit_definitions(space: &mut AddressSpace, data_types: &[NodeId]) {
    use async_opcua::types::DataTypeDefinition::Structure;
    let tt = async_opcua::nodes::DefaultTypeTree::new();
    for id in data_types {
        let Some(NodeType::DataType(dt)) = space.find(id) else { continue };
        let own = dt.data_type_definition().cloned();
        let binary = space
            .find_references(id, Some((ReferenceTypeId::HasEncoding, false)), &tt, BrowseDirection::Forward)
            .map(|r| r.target_node.clone())
            .find(|e| space.find(e).is_some_and(|n| n.as_node().browse_name().name.as_ref() == "Default Binary"));
        let Some(binary) = binary else { continue };
        let def = match own {
            Some(Structure(def)) => async_opcua::types::StructureDefinition { default_encoding_id: binary, ..def },
            Some(_) => continue,
            None => {
                let parent = space
                    .find_references(id, Some((ReferenceTypeId::HasSubtype, false)), &tt, BrowseDirection::Inverse)
                    .next()
                    .map(|r| r.target_node.clone());
                let Some(parent) = parent else { continue };
                let Some(NodeType::DataType(p)) = space.find(&parent) else { continue };
                let Some(Structure(def)) = p.data_type_definition().cloned() else { continue };
                async_opcua::types::StructureDefinition { default_encoding_id: binary, base_data_type: parent, ..def }
            }
        };
        if let Some(NodeType::DataType(dt)) = space.find_mut(id) {
            dt.set_data_type_definition(Some(Structure(def)));
        }
    }
}

#[async_trait::async_trait]
impl InMemoryNodeManagerImpl for Vision {
    async fn init(&self, _address_space: &mut AddressSpace, _context: ServerContext) {}

    fn name(&self) -> &str {
        "lfi-bridge vision systems"
    }

    fn namespaces(&self) -> Vec<NamespaceMetadata> {
        self.namespaces.clone()
    }

    async fn call(
        &self,
        context: &RequestContext,
        _address_space: &RwLock<AddressSpace>,
        methods_to_call: &mut [&mut &mut MethodCall],
    ) -> Result<(), StatusCode> {
        let user = context.token.0.clone();
        for method in methods_to_call {
            let found = self.calls.read().get(&(method.object_id().clone(), method.method_id().clone())).copied();
            let Some((camera, call)) = found else {
                method.set_status(StatusCode::BadMethodInvalid);
                continue;
            };
            match (self.handler)(camera, call, method.arguments(), &user) {
                Ok(out) => {
                    method.set_outputs(out);
                    method.set_status(StatusCode::Good);
                }
                Err(status) => method.set_status(status),
            }
        }
        Ok(())
    }
}

/// The node ids of one camera's object that change while it runs.
#[derive(Debug, Clone)]
pub struct CameraNodes {
    /// The `VisionSystemType` object.
    pub system: NodeId,
    /// VisionStateMachine/CurrentState and its Id.
    pub state: (NodeId, NodeId),
    /// AutomaticModeStateMachine/CurrentState and its Id.
    pub auto_state: (NodeId, NodeId),
    /// The state nodes of the two machines' types, by browse name.
    states: HashMap<&'static str, NodeId>,
}

/// Optional members of the type the appliance has.
const OPTIONAL_KEPT: [&str; 4] = ["AutomaticModeStateMachine", "SelectModeAutomatic", "RecipeManagement", "ResultManagement"];

/// Makes camera `name`'s `VisionSystemType` object under DeviceSet.
pub fn add_camera(
    manager: &InMemoryNodeManager<Vision>,
    type_tree: &dyn TypeTree,
    index: usize,
    name: &str,
) -> Result<CameraNodes, String> {
    let space = manager.address_space();
    let mut space = space.write();
    let ns = |uri: &str| space.namespace_index(uri).ok_or_else(|| format!("namespace {uri} not loaded"));
    let (mv, di, own) = (ns(MV_URI)?, ns(DI_URI)?, ns(OWN_URI)?);
    let system_type = NodeId::new(mv, 1003u32);
    let device_set = NodeId::new(di, 5001u32);
    let system = NodeId::new(own, name.to_string());
    ObjectBuilder::new(&system, QualifiedName::new(own, name), name)
        .has_type_definition(system_type.clone())
        .component_of(device_set)
        .event_notifier(async_opcua::nodes::EventNotifier::SUBSCRIBE_TO_EVENTS)
        .insert(&mut *space);
    let mut methods = Vec::new();
    instantiate(&mut space, type_tree, &system_type, &system, name, &mut methods);
    let mut calls = manager.inner().calls.write();
    for (object, method, browse) in methods {
        if let Some(call) = Call::of(&browse) {
            calls.insert((object, method), (index, call));
        }
    }
    let child = |path: &[&str]| -> Result<NodeId, String> {
        let id = NodeId::new(own, format!("{name}/{}", path.join("/")));
        if space.node_exists(&id) { Ok(id) } else { Err(format!("the model has no {}", path.join("/"))) }
    };
    let state = (child(&["VisionStateMachine", "CurrentState"])?, child(&["VisionStateMachine", "CurrentState", "Id"])?);
    let auto_state = (
        child(&["VisionStateMachine", "AutomaticModeStateMachine", "CurrentState"])?,
        child(&["VisionStateMachine", "AutomaticModeStateMachine", "CurrentState", "Id"])?,
    );
    // The states are the types' own nodes: CurrentState/Id names one of them.
    let mut states = HashMap::new();
    for (type_id, names) in [
        (1017u32, &["Preoperational", "Halted", "Error", "Operational"][..]),
        (1021u32, &["Initialized", "Ready", "SingleExecution", "ContinuousExecution"][..]),
    ] {
        for &n in names {
            let node = space
                .find_node_by_browse_name(
                    &NodeId::new(mv, type_id),
                    Some((ReferenceTypeId::HasComponent, false)),
                    type_tree,
                    BrowseDirection::Forward,
                    QualifiedName::new(mv, n),
                )
                .ok_or_else(|| format!("the NodeSet's state machine type ns={mv};i={type_id} has no state {n}"))?;
            states.insert(n, node.node_id().clone());
        }
    }
    Ok(CameraNodes { system, state, auto_state, states })
}

/// Copies the instance declarations under `decl` (mandatory ones, and the optional ones the
/// appliance has) below `parent`, with node ids `<camera>/<path>`; methods are referenced,
/// not copied (the NodeSet's own method nodes, with their declared arguments). States and
/// transitions belong to the state machine's type, not to its instances.
fn instantiate(
    space: &mut AddressSpace,
    tt: &dyn TypeTree,
    decl: &NodeId,
    parent: &NodeId,
    path: &str,
    methods: &mut Vec<(NodeId, NodeId, String)>,
) {
    let children: Vec<(NodeId, NodeId)> = space
        .find_references(decl, None::<(NodeId, bool)>, tt, BrowseDirection::Forward)
        .filter(|r| *r.reference_type == ReferenceTypeId::HasComponent || *r.reference_type == ReferenceTypeId::HasProperty)
        .map(|r| (r.target_node.clone(), r.reference_type.clone()))
        .collect();
    // A type's members also come from its supertype's declarations (VisionSystemType's
    // declarations repeat what it needs; state machine types inherit CurrentState).
    for (child, ref_type) in children {
        let Some(node) = space.find(&child) else { continue };
        let browse = node.as_node().browse_name().clone();
        let name = browse.name.as_ref().to_string();
        let rule = modelling_rule(space, tt, &child);
        let kept = match rule {
            Some(r) if r == ObjectId::ModellingRule_Mandatory => true,
            Some(r) if r == ObjectId::ModellingRule_Optional => OPTIONAL_KEPT.contains(&name.as_str()),
            _ => false,
        };
        if !kept {
            continue;
        }
        let type_def = type_definition(space, tt, &child);
        // StateType, InitialStateType, TransitionType (OPC 10000-5).
        let is_state = type_def.as_ref().is_some_and(|t| [2307u32, 2309, 2310].iter().any(|&s| *t == NodeId::new(0, s)));
        if is_state {
            continue;
        }
        let id = NodeId::new(parent.namespace, format!("{path}/{name}"));
        match node {
            NodeType::Method(_) => {
                space.insert_reference(parent, &child, ReferenceTypeId::HasComponent);
                methods.push((parent.clone(), child.clone(), name));
            }
            NodeType::Object(o) => {
                let mut b = ObjectBuilder::new(&id, browse.clone(), o.display_name().clone());
                if let Some(t) = &type_def {
                    b = b.has_type_definition(t.clone());
                }
                b.component_of(parent.clone()).insert(space);
                instantiate(space, tt, &child, &id, &format!("{path}/{name}"), methods);
            }
            NodeType::Variable(v) => {
                let value = v.value(TimestampsToReturn::Neither, &NumericRange::None, &DataEncoding::Binary, 0.0).value;
                let mut b = VariableBuilder::new(&id, browse.clone(), v.display_name().clone())
                    .data_type(v.data_type())
                    .value_rank(v.value_rank())
                    .access_level(AccessLevel::CURRENT_READ)
                    .user_access_level(AccessLevel::CURRENT_READ);
                if let Some(value) = value {
                    b = b.value(value);
                }
                if let Some(t) = &type_def {
                    b = b.has_type_definition(t.clone());
                }
                b = if ref_type == ReferenceTypeId::HasProperty { b.property_of(parent.clone()) } else { b.component_of(parent.clone()) };
                b.insert(space);
                instantiate(space, tt, &child, &id, &format!("{path}/{name}"), methods);
            }
            _ => {}
        }
    }
}

fn modelling_rule(space: &AddressSpace, tt: &dyn TypeTree, node: &NodeId) -> Option<NodeId> {
    space
        .find_references(node, Some((ReferenceTypeId::HasModellingRule, false)), tt, BrowseDirection::Forward)
        .next()
        .map(|r| r.target_node.clone())
}

fn type_definition(space: &AddressSpace, tt: &dyn TypeTree, node: &NodeId) -> Option<NodeId> {
    space
        .find_references(node, Some((ReferenceTypeId::HasTypeDefinition, false)), tt, BrowseDirection::Forward)
        .next()
        .map(|r| r.target_node.clone())
}

/// The values that show `state`: the two machines' CurrentState (text) and its Id (the
/// type's state node); the automatic mode's is empty outside Operational.
pub fn state_values(nodes: &CameraNodes, state: VisionState) -> Vec<(NodeId, Variant)> {
    let id = |n: &str| nodes.states.get(n).cloned().map(Variant::from).unwrap_or(Variant::Empty);
    let (auto_text, auto_id) = match state {
        VisionState::Operational(m) => (Variant::from(LocalizedText::new("", m.name())), id(m.name())),
        _ => (Variant::from(LocalizedText::new("", "")), Variant::from(NodeId::null())),
    };
    vec![
        (nodes.state.0.clone(), Variant::from(LocalizedText::new("", state.name()))),
        (nodes.state.1.clone(), id(state.name())),
        (nodes.auto_state.0.clone(), auto_text),
        (nodes.auto_state.1.clone(), auto_id),
    ]
}
