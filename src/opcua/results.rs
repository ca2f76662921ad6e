//! A camera's acquisitions as OPC 40100 results: one `ResultReadyEventType` event per
//! acquisition, whatever triggered it (the PLC, a method call, free-run), carrying the parts
//! exactly as the PLC reads them (the camera worker's published [`Acquisition`]).

use std::sync::Arc;

use async_opcua::nodes::{BaseEventType, Event};
use async_opcua::types::event_field::EventField;
use async_opcua::types::{AttributeId, ByteString, DateTime, NodeId, NumericRange, ObjectTypeId, QualifiedName, Variant};

use super::types::{self, LateTypes};
use crate::appliance::camera::Acquisition;

/// `ResultReadyEventType` in the MachineVision namespace.
const RESULT_READY: u32 = 1024;

/// ResultState of an estimated frame (its parts' decisions are in the content) and of an
/// acquisition without a usable frame (negative: the system's own error states).
pub const STATE_ESTIMATED: i32 = 1;
/// See [`STATE_ESTIMATED`].
pub const STATE_NO_FRAME: i32 = -1;

/// The job an acquisition is, as StartSingleJob returns it and ResultReady names it: the
/// camera, the appliance's BOOT_ID and the ACQ_ID (unique until ACQ_ID wraps within one boot).
pub fn job_id(camera: &str, boot_id: u16, acq_id: u16) -> String {
    format!("{camera}/{boot_id}/{acq_id}")
}

/// What a StartSingleJob call asked to come back with its results.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Ids {
    /// MeasId.Id.
    pub meas_id: String,
    /// PartId.Id.
    pub part_id: String,
}

/// One part of the content: the PLC's values, and what ties it to the job.
#[derive(serde::Serialize)]
struct ContentPart<'a> {
    #[serde(flatten)]
    part: &'a crate::appliance::camera::ResultPart,
    job_id: &'a str,
    job: u16,
    user_data: u32,
    meas_id: &'a str,
    part_id: &'a str,
}

/// ResultContent: one JSON object per part, in the PLC's order.
pub fn content(acq: &Acquisition, job: &str, ids: &Ids) -> Vec<String> {
    acq.parts
        .iter()
        .map(|p| {
            let c = ContentPart {
                part: p,
                job_id: job,
                job: acq.job_id,
                user_data: acq.user_data,
                meas_id: &ids.meas_id,
                part_id: &ids.part_id,
            };
            serde_json::to_string(&c).unwrap_or_else(|e| format!("{{\"error\":\"{e}\"}}"))
        })
        .collect()
}

/// `at` as OPC UA's DateTime (100 ns ticks since 1601).
fn opcua_time(at: std::time::SystemTime) -> DateTime {
    const UNIX_EPOCH_TICKS: i64 = 116_444_736_000_000_000;
    let since = at.duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
    DateTime::from(UNIX_EPOCH_TICKS + (since.as_nanos() / 100) as i64)
}

/// A ResultReady event.
pub struct ResultReady {
    base: BaseEventType,
    mv: u16,
    fields: Vec<(&'static str, Variant)>,
}

impl ResultReady {
    /// The event of `acq` on camera `camera` (its object `source`), MachineVision namespace `mv`.
    pub fn new(types: &Arc<LateTypes>, mv: u16, source: &NodeId, camera: &str, job: &str, acq: &Acquisition, ids: &Ids) -> Self {
        let time = opcua_time(acq.at);
        let s = |t: u32, id: &str| -> Variant {
            types.id(mv, t, id).unwrap_or_else(|e| {
                tracing::warn!("OPC UA ResultReady: {e}");
                Variant::Empty
            })
        };
        let state = if acq.error.is_some() { STATE_NO_FRAME } else { STATE_ESTIMATED };
        let content: Vec<Variant> = content(acq, job, ids).into_iter().map(Variant::from).collect();
        let content = async_opcua::types::Array::new(async_opcua::types::VariantScalarTypeId::String, content)
            .map(|a| Variant::Array(Box::new(a)))
            .unwrap_or(Variant::Empty);
        let message = match &acq.error {
            Some(e) => format!("{camera}: acquisition {} has no usable frame: {e}", acq.acq_id),
            None => format!("{camera}: acquisition {}: {} part(s)", acq.acq_id, acq.parts.len()),
        };
        let mut event_id = job.as_bytes().to_vec();
        event_id.extend(acq.acq_id.to_be_bytes());
        let base = BaseEventType::new(NodeId::new(mv, RESULT_READY), ByteString::from(event_id), message, time)
            .set_source_node(source.clone())
            .set_source_name(camera.into())
            .set_severity(if acq.error.is_some() { 500 } else { 100 });
        let fields = vec![
            ("ResultId", s(types::RESULT_ID, job)),
            ("JobId", s(types::JOB_ID, job)),
            ("MeasId", s(types::MEAS_ID, &ids.meas_id)),
            ("PartId", s(types::PART_ID, &ids.part_id)),
            ("InternalRecipeId", s(types::RECIPE_ID_INTERNAL, &acq.job_id.to_string())),
            ("InternalConfigurationId", s(types::CONFIGURATION_ID, concat!("lfi-bridge ", env!("CARGO_PKG_VERSION")))),
            ("ResultState", Variant::from(state)),
            ("IsPartial", Variant::from(false)),
            ("IsSimulated", Variant::from(false)),
            ("CreationTime", Variant::from(time)),
            ("ResultContent", content),
        ];
        Self { base, mv, fields }
    }

    fn own(&self, path: &[QualifiedName], attribute_id: AttributeId) -> Option<Variant> {
        match path {
            [f] if f.namespace_index == self.mv && attribute_id == AttributeId::Value => {
                self.fields.iter().find(|(n, _)| *n == f.name.as_ref()).map(|(_, v)| v.clone())
            }
            _ => None,
        }
    }
}

impl EventField for ResultReady {
    fn get_value(&self, attribute_id: AttributeId, index_range: &NumericRange, remaining_path: &[QualifiedName]) -> Variant {
        self.own(remaining_path, attribute_id).unwrap_or_else(|| self.base.get_value(attribute_id, index_range, remaining_path))
    }
}

impl Event for ResultReady {
    /// The event's own fields whichever type the select clause names (clients name
    /// ResultReadyEventType or BaseEventType), the base event's fields as BaseEventType's.
    fn get_field(
        &self,
        _type_definition_id: &NodeId,
        attribute_id: AttributeId,
        index_range: &NumericRange,
        browse_path: &[QualifiedName],
    ) -> Variant {
        self.own(browse_path, attribute_id)
            .unwrap_or_else(|| self.base.get_field(&ObjectTypeId::BaseEventType.into(), attribute_id, index_range, browse_path))
    }

    fn time(&self) -> &DateTime {
        Event::time(&self.base)
    }

    fn event_type_id(&self) -> &NodeId {
        self.base.event_type_id()
    }
}
