//! A camera's acquisitions as OPC 40100 results: one `ResultReadyEventType` event per
//! acquisition, whatever triggered it (the PLC, a method call, free-run), carrying the parts
//! exactly as the PLC reads them (the camera worker's published [`Acquisition`]).

use std::sync::Arc;

use async_opcua::nodes::{BaseEventType, Event};
use async_opcua::types::event_field::EventField;
use async_opcua::types::{
    AttributeId, ByteString, DateTime, NodeId, NumericRange, ObjectTypeId, QualifiedName, Variant, VariantScalarTypeId,
};

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

/// InternalConfigurationId of every result: the program that made it.
const CONFIGURATION: &str = concat!("lfi-bridge ", env!("CARGO_PKG_VERSION"));

/// One result: what its ResultReady event carries and GetResultById returns.
#[derive(Debug, Clone, PartialEq)]
pub struct Kept {
    /// ResultId and JobId (see [`job_id`]).
    pub id: String,
    /// What StartSingleJob asked to come back.
    pub ids: Ids,
    /// InternalRecipeId: the job in force, decimal.
    pub recipe: String,
    /// ResultState ([`STATE_ESTIMATED`] or [`STATE_NO_FRAME`]).
    pub state: i32,
    /// When the results were final.
    pub at: DateTime,
    /// ResultContent (see [`content`]).
    pub content: Vec<String>,
    /// The event's Message.
    pub message: String,
}

impl Kept {
    /// The result of acquisition `acq` of camera `camera` (whose handshake has `boot_id`).
    pub fn new(camera: &str, boot_id: u16, acq: &Acquisition, ids: Ids) -> Self {
        let id = job_id(camera, boot_id, acq.acq_id);
        let message = match &acq.error {
            Some(e) => format!("{camera}: acquisition {} has no usable frame: {e}", acq.acq_id),
            None => format!("{camera}: acquisition {}: {} part(s)", acq.acq_id, acq.parts.len()),
        };
        Self {
            content: content(acq, &id, &ids),
            id,
            ids,
            recipe: acq.job_id.to_string(),
            state: if acq.error.is_some() { STATE_NO_FRAME } else { STATE_ESTIMATED },
            at: opcua_time(acq.at),
            message,
        }
    }

    /// The fields a result has, in the order of `ResultReadyEventType`'s own.
    const FIELDS: [&'static str; 11] = [
        "ResultId",
        "JobId",
        "MeasId",
        "PartId",
        "InternalRecipeId",
        "InternalConfigurationId",
        "ResultState",
        "IsPartial",
        "IsSimulated",
        "CreationTime",
        "ResultContent",
    ];

    /// The value of field `name` (one of [`Kept::FIELDS`]; any other is null), as the event
    /// carries it: one mapping for ResultReady and `ResultDataType`.
    fn field(&self, types: &LateTypes, mv: u16, name: &str) -> Result<Variant, String> {
        let id = |t: u32, v: &str| types.id(mv, t, v);
        Ok(match name {
            "ResultId" => id(types::RESULT_ID, &self.id)?,
            "JobId" => id(types::JOB_ID, &self.id)?,
            "MeasId" => id(types::MEAS_ID, &self.ids.meas_id)?,
            "PartId" => id(types::PART_ID, &self.ids.part_id)?,
            "InternalRecipeId" => id(types::RECIPE_ID_INTERNAL, &self.recipe)?,
            "InternalConfigurationId" => id(types::CONFIGURATION_ID, CONFIGURATION)?,
            "IsPartial" | "IsSimulated" => Variant::from(false),
            "ResultState" => Variant::from(self.state),
            "CreationTime" => Variant::from(self.at),
            "ResultContent" => content_array(self.content.iter().map(|c| Variant::from(c.as_str())), VariantScalarTypeId::String)?,
            _ => Variant::Empty,
        })
    }

    /// The result as MachineVision's `ResultDataType` (what GetResultById and
    /// GetResultListFiltered return); the optional fields the appliance has no value for are
    /// left out.
    pub fn data(&self, types: &LateTypes, mv: u16) -> Result<Variant, String> {
        types.structure(mv, types::RESULT, |name| match name {
            // Declared BaseDataType[]: each String inside a Variant.
            "ResultContent" => content_array(
                self.content.iter().map(|c| Variant::Variant(Box::new(Variant::from(c.as_str())))),
                VariantScalarTypeId::Variant,
            ),
            _ => self.field(types, mv, name),
        })
    }
}

/// ResultContent: an array of `values`, each of type `of`.
fn content_array(values: impl Iterator<Item = Variant>, of: VariantScalarTypeId) -> Result<Variant, String> {
    async_opcua::types::Array::new(of, values.collect::<Vec<_>>())
        .map(|a| Variant::Array(Box::new(a)))
        .map_err(|e| format!("ResultContent: {e}"))
}

/// What GetResultListFiltered asks for: results matching every filter that is set (a state
/// other than 0, an identifier that is not empty).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Filter {
    /// ResultState, 0: any.
    pub state: i32,
    /// MeasId.Id.
    pub meas_id: String,
    /// PartId.Id.
    pub part_id: String,
    /// InternalRecipeId.Id (the job, decimal).
    pub internal_recipe: String,
    /// InternalConfigurationId.Id.
    pub internal_configuration: String,
    /// JobId.Id.
    pub job: String,
    /// ExternalRecipeId, ExternalConfigurationId and ProductId: the appliance keeps none, so a
    /// result never matches one that is set.
    pub unkept: Vec<String>,
}

impl Filter {
    fn matches(&self, k: &Kept) -> bool {
        let is = |want: &str, have: &str| want.is_empty() || want == have;
        (self.state == 0 || self.state == k.state)
            && is(&self.meas_id, &k.ids.meas_id)
            && is(&self.part_id, &k.ids.part_id)
            && is(&self.internal_recipe, &k.recipe)
            && is(&self.internal_configuration, CONFIGURATION)
            && is(&self.job, &k.id)
            && self.unkept.iter().all(String::is_empty)
    }
}

/// One page of GetResultListFiltered.
#[derive(Debug, PartialEq)]
pub struct Page<'a> {
    /// Results matching the filter, in the store.
    pub count: usize,
    /// Whether this page holds the last of them.
    pub complete: bool,
    /// This page's results, newest first.
    pub results: Vec<&'a Kept>,
}

/// The newest results of one camera, for GetResultById and GetResultListFiltered.
#[derive(Debug)]
pub struct Store {
    kept: std::collections::VecDeque<Kept>,
    capacity: usize,
}

impl Store {
    /// A store keeping the newest `capacity` results (at least one).
    pub fn new(capacity: usize) -> Self {
        Self { kept: std::collections::VecDeque::new(), capacity: capacity.max(1) }
    }

    /// Keeps `k`, forgetting the oldest result when full.
    pub fn push(&mut self, k: Kept) {
        if self.kept.len() == self.capacity {
            self.kept.pop_front();
        }
        self.kept.push_back(k);
    }

    /// The result whose ResultId is `id`.
    pub fn by_id(&self, id: &str) -> Option<&Kept> {
        self.kept.iter().rev().find(|k| k.id == id)
    }

    /// The results matching `filter`, newest first, from `start` on, at most `max` (0: all).
    pub fn list(&self, filter: &Filter, max: usize, start: usize) -> Page<'_> {
        let matching: Vec<&Kept> = self.kept.iter().rev().filter(|k| filter.matches(k)).collect();
        let count = matching.len();
        let take = if max == 0 { usize::MAX } else { max };
        let results: Vec<&Kept> = matching.into_iter().skip(start).take(take).collect();
        let complete = start.saturating_add(results.len()) >= count;
        Page { count, complete, results }
    }
}

/// A ResultReady event.
pub struct ResultReady {
    base: BaseEventType,
    mv: u16,
    fields: Vec<(&'static str, Variant)>,
}

impl ResultReady {
    /// The event of result `k` on camera `camera` (its object `source`), MachineVision
    /// namespace `mv`.
    pub fn new(types: &Arc<LateTypes>, mv: u16, source: &NodeId, camera: &str, k: &Kept) -> Self {
        let mut event_id = k.id.as_bytes().to_vec();
        event_id.extend(k.at.checked_ticks().to_be_bytes());
        let base = BaseEventType::new(NodeId::new(mv, RESULT_READY), ByteString::from(event_id), k.message.clone(), k.at)
            .set_source_node(source.clone())
            .set_source_name(camera.into())
            .set_severity(if k.state == STATE_NO_FRAME { 500 } else { 100 });
        let fields = Kept::FIELDS
            .iter()
            .map(|&name| {
                let v = k.field(types, mv, name).unwrap_or_else(|e| {
                    tracing::warn!("OPC UA ResultReady: {e}");
                    Variant::Empty
                });
                (name, v)
            })
            .collect();
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

#[cfg(test)]
mod tests {
    use super::*;

    fn kept(acq: u16, meas: &str, state: i32) -> Kept {
        Kept {
            id: job_id("cam", 7, acq),
            ids: Ids { meas_id: meas.into(), part_id: String::new() },
            recipe: "1".into(),
            state,
            at: DateTime::now(),
            content: Vec::new(),
            message: String::new(),
        }
    }

    fn ids(page: &Page) -> Vec<String> {
        page.results.iter().map(|k| k.id.clone()).collect()
    }

    #[test]
    fn the_store_keeps_the_newest_and_finds_them_by_id() {
        let mut store = Store::new(3);
        for acq in 1..=5 {
            store.push(kept(acq, "", STATE_ESTIMATED));
        }
        assert!(store.by_id("cam/7/2").is_none(), "forgotten once three newer came");
        assert_eq!(store.by_id("cam/7/3").map(|k| k.id.as_str()), Some("cam/7/3"));
        assert!(store.by_id("cam/7/3 ").is_none());
        let all = store.list(&Filter::default(), 0, 0);
        assert_eq!((all.count, all.complete), (3, true));
        assert_eq!(ids(&all), ["cam/7/5", "cam/7/4", "cam/7/3"], "newest first");
    }

    #[test]
    fn a_list_pages_and_filters_by_every_identifier_set() {
        let mut store = Store::new(10);
        for acq in 1..=6 {
            store.push(kept(acq, if acq % 2 == 0 { "even" } else { "odd" }, if acq == 5 { STATE_NO_FRAME } else { STATE_ESTIMATED }));
        }
        let first = store.list(&Filter::default(), 4, 0);
        assert_eq!((first.count, first.complete, ids(&first).len()), (6, false, 4));
        let second = store.list(&Filter::default(), 4, 4);
        assert_eq!((second.complete, ids(&second)), (true, vec!["cam/7/2".to_string(), "cam/7/1".into()]));
        let past = store.list(&Filter::default(), 4, 8);
        assert_eq!((past.count, past.complete, past.results.len()), (6, true, 0));

        let even = Filter { meas_id: "even".into(), ..Filter::default() };
        assert_eq!(ids(&store.list(&even, 0, 0)), ["cam/7/6", "cam/7/4", "cam/7/2"]);
        let failed = Filter { state: STATE_NO_FRAME, ..Filter::default() };
        assert_eq!(ids(&store.list(&failed, 0, 0)), ["cam/7/5"]);
        let job = Filter { job: "cam/7/3".into(), ..Filter::default() };
        assert_eq!(ids(&store.list(&job, 0, 0)), ["cam/7/3"]);
        let recipe = Filter { internal_recipe: "2".into(), ..Filter::default() };
        assert_eq!(store.list(&recipe, 0, 0).count, 0, "no result of job 2");
        let config = Filter { internal_configuration: CONFIGURATION.into(), ..Filter::default() };
        assert_eq!(store.list(&config, 0, 0).count, 6);
        let product = Filter { unkept: vec![String::new(), "P-7".into(), String::new()], ..Filter::default() };
        assert_eq!(store.list(&product, 0, 0).count, 0, "the appliance keeps no product id: nothing matches one");
    }
}
