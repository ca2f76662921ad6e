//! The MachineVision structures (MeasIdDataType, JobIdDataType, ...) encoded and decoded from
//! their definitions in the loaded NodeSet, not from hand-written copies: the method arguments
//! a client sends and the event fields the server sends are the NodeSet's own types.

use std::sync::{Arc, OnceLock};

use async_opcua::nodes::{DefaultTypeTree, NodeBase, NodeType, TypeTree};
use async_opcua::server::address_space::AddressSpace;
use async_opcua::types::custom::{DataTypeTree, DynamicStructure, DynamicTypeLoader, EncodingIds, ParentIds, TypeInfo};
use async_opcua::types::{
    BrowseDirection, Context, DynEncodable, EncodingResult, ExtensionObject, NodeId, ReferenceTypeId, TypeLoader, TypeLoaderPriority,
    Variant,
};

/// MachineVision's identifier structures, by their numeric id in its namespace.
pub const RESULT_ID: u32 = 3021;
/// See [`RESULT_ID`].
pub const JOB_ID: u32 = 3016;
/// See [`RESULT_ID`].
pub const MEAS_ID: u32 = 3015;
/// See [`RESULT_ID`].
pub const PART_ID: u32 = 3004;
/// See [`RESULT_ID`].
pub const RECIPE_ID_INTERNAL: u32 = 3013;
/// See [`RESULT_ID`].
pub const CONFIGURATION_ID: u32 = 3008;
/// `ResultDataType`: one result, as the result management's methods return it.
pub const RESULT: u32 = 3006;

/// A type loader filled once the NodeSets are in the address space (the server is built with
/// it, before its address space exists).
#[derive(Default)]
pub struct LateTypes {
    inner: OnceLock<(DynamicTypeLoader, Arc<DataTypeTree>)>,
}

impl LateTypes {
    /// Whether the types are loaded.
    pub fn ready(&self) -> bool {
        self.inner.get().is_some()
    }

    /// Reads the structure types of namespace `ns` from `space` (definitions, encodings,
    /// supertypes from `tt`). False while the server's type tree does not hold them yet: the
    /// node managers load it when the server starts running, after this loader is registered.
    pub fn fill(&self, space: &AddressSpace, tt: &DefaultTypeTree, ns: u16) -> Result<bool, String> {
        let mut parents = ParentIds::new();
        let mut found = Vec::new();
        let add_chain = |parents: &mut ParentIds, id: &NodeId| {
            let mut at = id.clone();
            while let Some(up) = tt.get_supertype(&at) {
                parents.add_type(at.clone(), up.clone());
                at = up.clone();
            }
        };
        let structure: NodeId = async_opcua::types::DataTypeId::Structure.into();
        let ids: Vec<NodeId> = tt.get_all_children(&structure).into_iter().filter(|id| id.namespace == ns).cloned().collect();
        if ids.is_empty() {
            return Ok(false);
        }
        for id in ids {
            let Some(NodeType::DataType(dt)) = space.find(&id) else { continue };
            let Some(def) = dt.data_type_definition() else { continue };
            add_chain(&mut parents, dt.node_id());
            if let async_opcua::types::DataTypeDefinition::Structure(s) = def {
                for f in s.fields.iter().flatten() {
                    add_chain(&mut parents, &f.data_type);
                }
            }
            let mut ids = EncodingIds::default();
            for r in space.find_references(dt.node_id(), Some((ReferenceTypeId::HasEncoding, false)), tt, BrowseDirection::Forward) {
                let Some(enc) = space.find(r.target_node) else { continue };
                match enc.as_node().browse_name().name.as_ref() {
                    "Default Binary" => ids.binary_id = r.target_node.clone(),
                    "Default XML" => ids.xml_id = r.target_node.clone(),
                    "Default JSON" => ids.json_id = r.target_node.clone(),
                    _ => {}
                }
            }
            found.push((dt.node_id().clone(), def.clone(), dt.browse_name().name.as_ref().to_string(), ids, dt.is_abstract()));
        }
        let mut infos = Vec::new();
        for (id, def, name, ids, is_abstract) in found {
            let info = TypeInfo::from_type_definition(def, name.clone(), Some(ids), is_abstract, &id, &parents)
                .map_err(|e| format!("data type {name} ({id}): {e}"))?;
            infos.push((id, info));
        }
        let mut tree = DataTypeTree::new(parents);
        for (id, info) in infos {
            tree.add_type(id, info);
        }
        let tree = Arc::new(tree);
        let _ = self.inner.set((DynamicTypeLoader::new(tree.clone()), tree));
        Ok(true)
    }

    /// A MachineVision identifier structure (`ns=mv;i=type_id`, one of the `*_ID` types) with
    /// `Id` set and its optional fields null.
    pub fn id(&self, mv: u16, type_id: u32, id: &str) -> Result<Variant, String> {
        self.structure(mv, type_id, |f| Ok(if f == "Id" { Variant::from(id) } else { Variant::Empty }))
    }

    /// The MachineVision structure `ns=mv;i=type_id` with each field's value from `value` (by
    /// the field's name; `Variant::Empty` leaves an optional field out).
    pub fn structure(&self, mv: u16, type_id: u32, value: impl Fn(&str) -> Result<Variant, String>) -> Result<Variant, String> {
        let type_id = NodeId::new(mv, type_id);
        let (_, tree) = self.inner.get().ok_or("the MachineVision types are not loaded")?;
        let info = tree.get_struct_type(&type_id).ok_or_else(|| format!("no structure type {type_id}"))?.clone();
        let values = info.fields.iter().map(|f| value(&f.name)).collect::<Result<Vec<_>, _>>()?;
        DynamicStructure::new_struct(info, tree.clone(), values)
            .map(|s| Variant::from(ExtensionObject::from_message(s)))
            .map_err(|e| format!("{type_id}: {e}"))
    }
}

/// The string field `name` of a structure a client sent (empty when absent or null).
pub fn field(value: &Variant, name: &str) -> String {
    let Variant::ExtensionObject(o) = value else { return String::new() };
    let Some(s) = o.inner_as::<DynamicStructure>() else { return String::new() };
    match s.get_field_by_name(name) {
        Some(Variant::String(v)) => v.as_ref().to_string(),
        _ => String::new(),
    }
}

impl TypeLoader for LateTypes {
    fn load_from_xml(
        &self,
        node_id: &NodeId,
        stream: &mut async_opcua::types::xml::XmlStreamReader<&mut dyn std::io::Read>,
        ctx: &Context<'_>,
        name: &str,
    ) -> Option<EncodingResult<Box<dyn DynEncodable>>> {
        self.inner.get()?.0.load_from_xml(node_id, stream, ctx, name)
    }

    fn load_from_binary(
        &self,
        node_id: &NodeId,
        stream: &mut dyn std::io::Read,
        ctx: &Context<'_>,
        length: Option<usize>,
    ) -> Option<EncodingResult<Box<dyn DynEncodable>>> {
        self.inner.get()?.0.load_from_binary(node_id, stream, ctx, length)
    }

    fn priority(&self) -> TypeLoaderPriority {
        TypeLoaderPriority::Dynamic(50)
    }
}
