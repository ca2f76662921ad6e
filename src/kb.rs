//! The knowledge base file: enrolled templates as human-readable TOML.
//!
//! ```toml
//! format = "lfi-bridge knowledge base"
//! version = 1
//! template_count = 6            # how many [[template]] tables follow (catches a cut-off file)
//!
//! [[template]]
//! type = "bracket"
//! id = 1
//! face = "up"
//! source = "templates/bracket_up.png"
//! image_size = [681, 681]
//! origin = [340.0, 340.0]       # the point reported as the part's position
//! centroid = [340.5, 339.4]     # of the filled outline
//! area_px = 145870.0
//! outline = [[x, y], ...]       # sub-pixel, template pixels
//! segments = [[x1, y1, x2, y2, width], ...]
//! interior = [[x, y, nx, ny], ...]   # edges inside the part, normal bright -> dark (optional)
//! keep_out = [[x, y, r], ...]   # optional: the gripper's keep-out circles, template pixels
//! ```
//!
//! Loading checks everything it reads and names the file, the template and the field at fault.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::vision::{Face, KeepOut, Pt, Segment, Template};

/// The `format` line every knowledge base starts with: a TOML file of another kind is refused by name.
pub const FORMAT: &str = "lfi-bridge knowledge base";
/// The layout this build reads and writes; bumped when an older build would misread a file.
pub const VERSION: u32 = 1;
/// Largest template image side accepted from a file (a part filling a 16k-pixel sensor).
pub const MAX_SIDE: usize = 16384;

/// Why a knowledge base cannot be read, written or extended; each names the file or the type.
#[derive(Debug, thiserror::Error)]
pub enum KbError {
    /// The file cannot be read.
    #[error("cannot read knowledge base {path}")]
    Read {
        /// The knowledge-base file.
        path: PathBuf,
        /// Why the system refused it.
        source: std::io::Error,
    },
    /// The file cannot be written.
    #[error("cannot write knowledge base {path}")]
    Write {
        /// The knowledge-base file.
        path: PathBuf,
        /// Why the system refused it.
        source: std::io::Error,
    },
    /// Not TOML (or not this file's keys).
    #[error("knowledge base {path} is not valid TOML: {message}")]
    Parse {
        /// The knowledge-base file.
        path: PathBuf,
        /// The parser's complaint, with line and column.
        message: String,
    },
    /// Some other TOML file.
    #[error("{path} is not a knowledge base: format = {found:?}, expected {FORMAT:?}")]
    Format {
        /// The knowledge-base file.
        path: PathBuf,
        /// Its `format` value.
        found: String,
    },
    /// Written by a build with another layout.
    #[error("knowledge base {path} has version {found}; this build reads version {VERSION}")]
    Version {
        /// The knowledge-base file.
        path: PathBuf,
        /// Its `version` value.
        found: u32,
    },
    /// A template with an out-of-range or inconsistent value.
    #[error("knowledge base {path}, template {index} ({what}): {message}")]
    Invalid {
        /// The knowledge-base file.
        path: PathBuf,
        /// The template's position in the file, from 0.
        index: usize,
        /// Which template ("bracket up").
        what: String,
        /// What is wrong, naming the field.
        message: String,
    },
    /// A type enrolled again under another id.
    #[error("type {type_name:?} already has id {existing}; cannot enroll it with id {requested}")]
    IdConflict {
        /// The type.
        type_name: String,
        /// Its id in the knowledge base.
        existing: u16,
        /// The id asked for.
        requested: u16,
    },
    /// A type name outside the safe set.
    #[error("type name {name:?} {problem}")]
    TypeName {
        /// The name as given.
        name: String,
        /// What is wrong with it.
        problem: String,
    },
    /// An id taken by another type.
    #[error("id {id} already belongs to type {existing:?}; cannot give it to {requested:?}")]
    NameConflict {
        /// The id.
        id: u16,
        /// The type that has it.
        existing: String,
        /// The type that asked for it.
        requested: String,
    },
    /// A catalogue folder that cannot be listed.
    #[error("cannot list template folder {path}")]
    Folder {
        /// The folder.
        path: PathBuf,
        /// Why the system refused it.
        source: std::io::Error,
    },
    /// An entry of a catalogue's id map that is not `TYPE = ID`.
    #[error("id map {path}, key {key:?}: {message}")]
    IdMap {
        /// The map file.
        path: PathBuf,
        /// The type name (empty when the file is not TOML at all).
        key: String,
        /// What is wrong with it.
        message: String,
    },
    /// A folder with no `TYPE_FACE` image, or a type the id map does not name.
    #[error("template folder {path}: {message}")]
    Catalogue {
        /// The folder.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct KbFile {
    format: String,
    version: u32,
    /// Number of templates written; absent in files from before it existed.
    #[serde(default, rename = "template_count", skip_serializing_if = "Option::is_none")]
    count: Option<usize>,
    #[serde(default, rename = "template")]
    templates: Vec<Record>,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Record {
    #[serde(rename = "type")]
    type_name: String,
    id: u16,
    face: String,
    source: String,
    image_size: [usize; 2],
    origin: [f64; 2],
    centroid: [f64; 2],
    area_px: f64,
    outline: Vec<[f64; 2]>,
    segments: Vec<[f64; 5]>,
    /// Interior edges [x, y, nx, ny], template pixels (optional: earlier builds wrote none).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    interior: Vec<[f64; 4]>,
    /// Gripper keep-out circles [x, y, r], template pixels (optional).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    keep_out: Vec<[f64; 3]>,
}

/// One enrolled template and the image it came from.
#[derive(Debug, Clone, PartialEq)]
pub struct Entry {
    /// The template.
    pub template: Template,
    /// Where it came from (image file and region, or "simulator"), for the log and the page.
    pub source: String,
}

/// The templates of a knowledge base file.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct KnowledgeBase {
    /// Templates in enrolment order.
    pub entries: Vec<Entry>,
}

/// Two enrolled templates alike overall, as enrolment, the command line and the operator view
/// report them: where a frame can tell them apart, or that nothing can.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AlikePair {
    /// The two, as "TYPE face".
    pub first: String,
    /// See `first`.
    pub second: String,
    /// `second`'s outline registered onto `first`'s: the worse of inliers and coverage.
    pub fit: f64,
    /// Some stretch of outline tells them apart in a clean frame.
    pub told_apart: bool,
    /// Length of outline apart, first's and second's, px.
    pub apart_px: (f64, f64),
    /// The largest distance of either outline from the other, px (at most the registration's
    /// reach).
    pub largest_px: f64,
    /// Where they differ most, degrees around `first`'s centroid in its own frame.
    pub at_deg: f64,
}

impl AlikePair {
    /// The line the operator reads; with `mm_per_px` (a calibrated camera), the largest
    /// difference in mm too.
    pub fn describe(&self, mm_per_px: Option<f64>) -> String {
        let largest = match mm_per_px {
            Some(s) => format!("{:.0} px, {:.1} mm", self.largest_px, self.largest_px * s),
            None => format!("{:.0} px", self.largest_px),
        };
        let (x, y) = (&self.first, &self.second);
        if self.told_apart {
            format!(
                "{x} and {y} are alike (fit {:.2}); told apart where they differ: {:.0} + {:.0} px of outline, up to {largest} apart, at {:.0} deg of {x}",
                self.fit, self.apart_px.0, self.apart_px.1, self.at_deg
            )
        } else {
            format!(
                "warning: {x} and {y}: no stretch of outline tells them apart (fit {:.2}, largest difference {largest}): a part of either is rejected ambiguous unless its line features tell",
                self.fit
            )
        }
    }
}

fn r3(v: f64) -> f64 {
    (v * 1000.0).round() / 1000.0
}

impl KnowledgeBase {
    /// The templates alone, for an estimator.
    pub fn templates(&self) -> Vec<Template> {
        self.entries.iter().map(|e| e.template.clone()).collect()
    }

    /// The templates alike overall ([`crate::vision::differ::alike`], at the clean fit
    /// tolerance and the fit a type is named at), each pair once; with `only`, those alike to
    /// that type and face.
    pub fn alike(&self, params: &crate::vision::Params, only: Option<(&str, Face)>) -> Vec<AlikePair> {
        let templates = self.templates();
        let lib = crate::vision::Library::new(&templates, params.signal_bins);
        let name = |i: usize| format!("{} {}", templates[i].type_name, templates[i].face);
        let is = |i: usize, (n, f): (&str, Face)| templates[i].type_name == n && templates[i].face == f;
        crate::vision::differ::alike(&lib, params.fit_tolerance, params.min_fit)
            .into_iter()
            .filter(|a| only.is_none_or(|o| is(a.a, o) || is(a.b, o)))
            .map(|a| AlikePair {
                first: name(a.a),
                second: name(a.b),
                fit: a.fit,
                told_apart: a.told_apart(),
                apart_px: (a.a_len, a.b_len),
                largest_px: a.largest,
                at_deg: a.at_deg,
            })
            .collect()
    }

    /// Distinct enrolled types.
    pub fn type_count(&self) -> usize {
        let mut names: Vec<&str> = self.entries.iter().map(|e| e.template.type_name.as_str()).collect();
        names.sort_unstable();
        names.dedup();
        names.len()
    }

    /// Adds a template, replacing the same type and face. Returns true when it replaced one.
    pub fn enroll(&mut self, template: Template, source: String) -> Result<bool, KbError> {
        valid_type_name(&template.type_name)?;
        for e in &self.entries {
            let t = &e.template;
            if t.type_name == template.type_name && t.type_id != template.type_id {
                return Err(KbError::IdConflict { type_name: t.type_name.clone(), existing: t.type_id, requested: template.type_id });
            }
            if t.type_id == template.type_id && t.type_name != template.type_name {
                return Err(KbError::NameConflict { id: t.type_id, existing: t.type_name.clone(), requested: template.type_name.clone() });
            }
        }
        let pos = self.entries.iter().position(|e| e.template.type_name == template.type_name && e.template.face == template.face);
        let entry = Entry { template, source };
        Ok(match pos {
            Some(i) => {
                self.entries[i] = entry;
                true
            }
            None => {
                self.entries.push(entry);
                false
            }
        })
    }

    /// The file's text.
    pub fn to_toml(&self) -> String {
        let file = KbFile {
            format: FORMAT.into(),
            version: VERSION,
            count: Some(self.entries.len()),
            templates: self
                .entries
                .iter()
                .map(|e| {
                    let t = &e.template;
                    Record {
                        type_name: t.type_name.clone(),
                        id: t.type_id,
                        face: t.face.as_str().into(),
                        source: e.source.clone(),
                        image_size: [t.image_width, t.image_height],
                        origin: [r3(t.origin.x), r3(t.origin.y)],
                        centroid: [r3(t.centroid.x), r3(t.centroid.y)],
                        area_px: r3(t.area),
                        outline: t.outline.iter().map(|p| [r3(p.x), r3(p.y)]).collect(),
                        segments: t.segments.iter().map(|s| [r3(s.a.x), r3(s.a.y), r3(s.b.x), r3(s.b.y), r3(s.width)]).collect(),
                        interior: t.interior.iter().map(|(p, n)| [r3(p.x), r3(p.y), r3(n.x), r3(n.y)]).collect(),
                        keep_out: t.keep_out.iter().map(|k| [r3(k.c.x), r3(k.c.y), r3(k.r)]).collect(),
                    }
                })
                .collect(),
        };
        toml::to_string(&file).expect("knowledge base records always serialise")
    }

    /// Reads the text of `path` (named in errors), validating every number.
    pub fn from_toml(text: &str, path: &Path) -> Result<Self, KbError> {
        // Check the header first so a wrong file gets a wrong-file error, not a field error.
        #[derive(Deserialize)]
        struct Header {
            format: Option<String>,
            version: Option<u32>,
        }
        let header: Header = toml::from_str(text).map_err(|e| KbError::Parse { path: path.into(), message: e.to_string() })?;
        let found = header.format.unwrap_or_default();
        if found != FORMAT {
            return Err(KbError::Format { path: path.into(), found });
        }
        match header.version {
            Some(VERSION) => {}
            Some(v) => {
                return Err(KbError::Version { path: path.into(), found: v });
            }
            None => {
                return Err(KbError::Parse { path: path.into(), message: "missing key `version`".into() });
            }
        }
        let file: KbFile = toml::from_str(text).map_err(|e| KbError::Parse { path: path.into(), message: e.to_string() })?;
        match file.count {
            Some(n) if n != file.templates.len() => {
                return Err(KbError::Parse {
                    path: path.into(),
                    message: format!(
                        "`template_count = {n}` but {} [[template]] tables follow: the file is cut off or was edited by hand (fix the count)",
                        file.templates.len()
                    ),
                });
            }
            Some(_) => {}
            None => tracing::warn!(
                "knowledge base {} has no `template_count` (written before it existed): a cut-off file cannot be told; saving it again adds the count",
                path.display()
            ),
        }
        let mut kb = KnowledgeBase::default();
        for (i, r) in file.templates.into_iter().enumerate() {
            let index = i + 1;
            let what = format!("type {:?} face {:?}", r.type_name, r.face);
            let bad = |message: String| KbError::Invalid { path: path.into(), index, what: what.clone(), message };
            check_type_name(&r.type_name).map_err(|p| bad(format!("type name {p}")))?;
            if r.id == 0 {
                return Err(bad("id 0 is reserved; use 1..=65535".into()));
            }
            let face: Face = r.face.parse().map_err(bad)?;
            if r.outline.len() < 16 {
                return Err(bad(format!("outline has {} points; at least 16 are needed", r.outline.len())));
            }
            let finite =
                r.outline.iter().flatten().chain(r.segments.iter().flatten()).chain(&r.origin).chain(&r.centroid).all(|v| v.is_finite());
            if !finite {
                return Err(bad("non-finite number".into()));
            }
            let [w, h] = r.image_size;
            if !(16..=MAX_SIDE).contains(&w) || !(16..=MAX_SIDE).contains(&h) {
                return Err(bad(format!("image_size = [{w}, {h}]: each side must be 16..={MAX_SIDE} pixels")));
            }
            let span = w.max(h) as f64;
            // Every coordinate is in template pixels: on the template image, give or take one
            // image size (an origin may be set beside the part). Anything farther is a damaged
            // or hand-edited number that would blow up the matcher's tables.
            let near = |v: f64| (-span..=2.0 * span).contains(&v);
            let coords = r.outline.iter().flatten().chain(r.segments.iter().flat_map(|s| &s[..4])).chain(&r.origin).chain(&r.centroid);
            if let Some(v) = coords.copied().find(|v| !near(*v)) {
                return Err(bad(format!("coordinate {v} is outside the template's image ({w} x {h}) by more than its size")));
            }
            if let Some(s) = r.segments.iter().find(|s| !(0.0..=span).contains(&s[4])) {
                return Err(bad(format!("segment width {} must be 0..={span}", s[4])));
            }
            // An interior edge is a point on the template and a unit normal (rounded to 3 places).
            if let Some((k, e)) = r.interior.iter().enumerate().find(|(_, e)| {
                let unit = e[2].hypot(e[3]);
                !(e.iter().all(|v| v.is_finite()) && near(e[0]) && near(e[1]) && (unit - 1.0).abs() <= 0.01)
            }) {
                return Err(bad(format!("interior[{k}] = {e:?}: an edge [x, y, nx, ny] on the template image, (nx, ny) of length 1")));
            }
            if r.area_px.is_nan() || r.area_px <= 0.0 || r.area_px > (w * h) as f64 {
                return Err(bad(format!("area_px = {} must be positive and at most the image's {} pixels", r.area_px, w * h)));
            }
            for (k, c) in r.keep_out.iter().enumerate() {
                let inside = c[..2].iter().all(|v| v.is_finite() && v.abs() <= 10.0 * span);
                if !(inside && c[2] > 0.0 && c[2] <= 10.0 * span) {
                    return Err(bad(format!(
                        "keep_out[{k}] = {c:?}: a circle [x, y, r] in template pixels, within 10 image sizes ({span}) of the template, r > 0"
                    )));
                }
            }
            let template = Template {
                type_name: r.type_name.clone(),
                type_id: r.id,
                face,
                image_width: r.image_size[0],
                image_height: r.image_size[1],
                origin: Pt::new(r.origin[0], r.origin[1]),
                centroid: Pt::new(r.centroid[0], r.centroid[1]),
                area: r.area_px,
                outline: r.outline.iter().map(|p| Pt::new(p[0], p[1])).collect(),
                segments: r.segments.iter().map(|s| Segment { a: Pt::new(s[0], s[1]), b: Pt::new(s[2], s[3]), width: s[4] }).collect(),
                interior: r.interior.iter().map(|e| (Pt::new(e[0], e[1]), Pt::new(e[2], e[3]))).collect(),
                keep_out: r.keep_out.iter().map(|c| KeepOut { c: Pt::new(c[0], c[1]), r: c[2] }).collect(),
            };
            if kb.entries.iter().any(|e| e.template.type_name == template.type_name && e.template.face == template.face) {
                return Err(bad("this type and face appear twice".into()));
            }
            kb.enroll(template, r.source).map_err(|e| bad(e.to_string()))?;
        }
        Ok(kb)
    }

    /// Reads and validates the file at `path`.
    pub fn load(path: &Path) -> Result<Self, KbError> {
        let text = std::fs::read_to_string(path).map_err(|source| KbError::Read { path: path.into(), source })?;
        Self::from_toml(&text, path)
    }

    /// Loads the file, or starts an empty knowledge base if it does not exist yet.
    pub fn load_or_new(path: &Path) -> Result<Self, KbError> {
        if path.exists() { Self::load(path) } else { Ok(Self::default()) }
    }

    /// Writes the file at `path` (through a temporary file, so a crash never leaves half of one).
    pub fn save(&self, path: &Path) -> Result<(), KbError> {
        crate::imageio::write_atomic(path, self.to_toml().as_bytes()).map_err(|source| KbError::Write { path: path.into(), source })
    }
}

/// Longest type name accepted (it is shown on the page, logged and part of file names).
pub const TYPE_NAME_MAX: usize = 40;

/// One image of a catalogue folder and what it enrols.
#[derive(Debug, Clone, PartialEq)]
pub struct FolderTemplate {
    /// The type, from the file name.
    pub type_name: String,
    /// Its id: the knowledge base's own for a type it holds, else from the id map or in order.
    pub id: u16,
    /// The face, from the file name.
    pub face: Face,
    /// The image.
    pub path: PathBuf,
}

/// Image files a folder enrolment reads; anything else in the folder is listed as ignored.
const IMAGE_EXTENSIONS: [&str; 6] = ["png", "pgm", "bmp", "tif", "tiff", "jpg"];

/// The optional id map of a catalogue folder: `DIR/ids.toml`, one `TYPE = ID` per type.
pub const ID_MAP: &str = "ids.toml";

/// What a folder of `TYPE_FACE.png` templates enrols into `kb`, in type-name order, and the
/// files it ignores (sub-folders such as `unknown/`, files that are not an image named
/// `TYPE_up` / `TYPE_down`), so that nothing in the folder is passed over silently.
///
/// A type the knowledge base already holds keeps its id (a second id would be refused at the
/// PLC's end anyway). The others take theirs from the folder's [`ID_MAP`] when there is one (a
/// new type it does not name is an error), else the next free ids in name order: T001, T002, ...
/// become 1, 2, ... in an empty knowledge base.
pub fn plan_folder(dir: &Path, kb: &KnowledgeBase) -> Result<(Vec<FolderTemplate>, Vec<PathBuf>), KbError> {
    let listing = std::fs::read_dir(dir).map_err(|source| KbError::Folder { path: dir.into(), source })?;
    let map_path = dir.join(ID_MAP);
    let mut found = Vec::new();
    let mut ignored = Vec::new();
    for entry in listing {
        let path = entry.map_err(|source| KbError::Folder { path: dir.into(), source })?.path();
        if path == map_path {
            continue;
        }
        let parsed = path
            .extension()
            .and_then(|e| e.to_str())
            .filter(|e| IMAGE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
            .and_then(|_| path.file_stem()?.to_str())
            .and_then(|stem| stem.rsplit_once('_'))
            .and_then(|(name, face)| Some((name.to_string(), face.parse::<Face>().ok()?)))
            .filter(|(name, _)| check_type_name(name).is_ok());
        match parsed {
            Some((type_name, face)) if path.is_file() => found.push((type_name, face, path)),
            _ => ignored.push(path),
        }
    }
    found.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.cmp(&b.1)));
    ignored.sort();
    if found.is_empty() {
        return Err(KbError::Catalogue { path: dir.into(), message: "holds no TYPE_up or TYPE_down image".into() });
    }
    let map = if map_path.is_file() {
        let text = std::fs::read_to_string(&map_path).map_err(|source| KbError::Folder { path: map_path.clone(), source })?;
        Some(parse_id_map(&map_path, &text)?)
    } else {
        None
    };
    let known = |name: &str| kb.entries.iter().find(|e| e.template.type_name == name).map(|e| e.template.type_id);
    let mut next = kb.entries.iter().map(|e| e.template.type_id).max().unwrap_or(0);
    let mut given: Vec<(String, u16)> = Vec::new();
    let mut plan = Vec::with_capacity(found.len());
    for (type_name, face, path) in found {
        let id = if let Some(id) = known(&type_name).or_else(|| given.iter().find(|g| g.0 == type_name).map(|g| g.1)) {
            id
        } else if let Some(map) = &map {
            map.get(&type_name).copied().ok_or_else(|| KbError::Catalogue {
                path: dir.into(),
                message: format!("type {type_name:?} ({}) has no id in {}", path.display(), map_path.display()),
            })?
        } else {
            next = next.checked_add(1).ok_or_else(|| KbError::Catalogue {
                path: dir.into(),
                message: format!("no id left for type {type_name:?}: ids run to {}", u16::MAX),
            })?;
            next
        };
        given.push((type_name.clone(), id));
        plan.push(FolderTemplate { type_name, id, face, path });
    }
    Ok((plan, ignored))
}

/// An id map's text: a TOML table of `TYPE = ID`, ids 1..=65535, each id once.
fn parse_id_map(path: &Path, text: &str) -> Result<std::collections::BTreeMap<String, u16>, KbError> {
    let err = |key: &str, message: String| KbError::IdMap { path: path.into(), key: key.into(), message };
    let table: toml::Table = text.parse().map_err(|e: toml::de::Error| err("", e.message().to_string()))?;
    let mut map = std::collections::BTreeMap::new();
    for (name, value) in &table {
        check_type_name(name).map_err(|p| err(name, format!("type name {p}")))?;
        let id = value
            .as_integer()
            .and_then(|v| u16::try_from(v).ok())
            .filter(|&v| v > 0)
            .ok_or_else(|| err(name, format!("id {value} is not a number 1..=65535")))?;
        if let Some((other, _)) = map.iter().find(|(_, v)| **v == id) {
            return Err(err(name, format!("id {id} is also {other}'s")));
        }
        map.insert(name.clone(), id);
    }
    Ok(map)
}

/// Type names are data that end up in log lines, file names and the page: only ASCII letters,
/// digits, `-` and `_`, 1 to [`TYPE_NAME_MAX`] long, so none can forge a log line, reach
/// another directory or carry markup. The one rule for the command line, the page and KB files.
pub fn check_type_name(name: &str) -> Result<(), String> {
    if name.is_empty() {
        return Err("is empty".into());
    }
    if name.len() > TYPE_NAME_MAX {
        return Err(format!("is longer than {TYPE_NAME_MAX} characters"));
    }
    if !name.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_') {
        return Err("may hold only letters, digits, '-' and '_'".into());
    }
    Ok(())
}

/// [`check_type_name`] as the error an enrolment (command line or page) reports.
pub fn valid_type_name(name: &str) -> Result<(), KbError> {
    check_type_name(name).map_err(|problem| KbError::TypeName { name: name.to_string(), problem })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tpl(name: &str, id: u16, face: Face) -> Template {
        Template {
            type_name: name.into(),
            type_id: id,
            face,
            image_width: 100,
            image_height: 80,
            origin: Pt::new(49.5, 39.5),
            centroid: Pt::new(50.0, 40.0),
            area: 1234.5,
            outline: (0..20).map(|i| Pt::new(50.0 + 20.0 * (i as f64 * 0.314).cos(), 40.0 + 20.0 * (i as f64 * 0.314).sin())).collect(),
            segments: vec![Segment { a: Pt::new(1.0, 2.0), b: Pt::new(30.0, 2.0), width: 2.5 }],
            interior: vec![(Pt::new(45.0, 38.0), Pt::new(0.6, -0.8))],
            keep_out: Vec::new(),
        }
    }

    #[test]
    fn keep_out_circles_round_trip_and_bad_ones_are_named() {
        let mut kb = KnowledgeBase::default();
        let mut t = tpl("bracket", 1, Face::Up);
        t.keep_out = vec![KeepOut { c: Pt::new(90.0, 40.0), r: 15.0 }];
        kb.enroll(t, "a.png".into()).unwrap();
        let text = kb.to_toml();
        assert!(text.contains("keep_out"), "{text}");
        let back = KnowledgeBase::from_toml(&text, Path::new("kb.toml")).unwrap();
        assert_eq!(back.entries[0].template.keep_out, kb.entries[0].template.keep_out);
        let bad = text.replace("15.0", "-1.0");
        let e = KnowledgeBase::from_toml(&bad, Path::new("kb.toml")).unwrap_err().to_string();
        assert!(e.contains("kb.toml") && e.contains("template 1") && e.contains("keep_out[0]"), "{e}");
        // Without the key, no footprint (and the file does not mention one).
        assert!(
            !KnowledgeBase { entries: vec![Entry { template: tpl("b", 2, Face::Up), source: "b".into() }] }.to_toml().contains("keep_out")
        );
    }

    #[test]
    fn round_trips_and_replaces_on_re_enrol() {
        let mut kb = KnowledgeBase::default();
        assert!(!kb.enroll(tpl("bracket", 1, Face::Up), "a.png".into()).unwrap());
        assert!(!kb.enroll(tpl("bracket", 1, Face::Down), "b.png".into()).unwrap());
        assert!(kb.enroll(tpl("bracket", 1, Face::Up), "c.png".into()).unwrap());
        assert_eq!(kb.entries.len(), 2);
        assert_eq!(kb.type_count(), 1);
        let text = kb.to_toml();
        let back = KnowledgeBase::from_toml(&text, Path::new("kb.toml")).unwrap();
        assert_eq!(back.entries.len(), 2);
        assert_eq!(back.entries[0].source, "c.png");
        assert_eq!(back.entries[0].template.outline.len(), 20);
    }

    #[test]
    fn conflicting_ids_are_refused() {
        let mut kb = KnowledgeBase::default();
        kb.enroll(tpl("bracket", 1, Face::Up), "a".into()).unwrap();
        assert!(matches!(kb.enroll(tpl("bracket", 2, Face::Down), "b".into()), Err(KbError::IdConflict { .. })));
        assert!(matches!(kb.enroll(tpl("flange", 1, Face::Up), "c".into()), Err(KbError::NameConflict { .. })));
    }

    #[test]
    fn corrupt_files_name_the_problem() {
        let p = Path::new("kb.toml");
        let e = KnowledgeBase::from_toml("this is = = not toml", p).unwrap_err();
        assert!(matches!(e, KbError::Parse { .. }), "{e}");
        let e = KnowledgeBase::from_toml("format = \"something else\"\nversion = 1\n", p).unwrap_err();
        assert!(matches!(e, KbError::Format { .. }), "{e}");
        let e = KnowledgeBase::from_toml(&format!("format = {FORMAT:?}\nversion = 9\n"), p).unwrap_err();
        assert!(e.to_string().contains("version 9"), "{e}");
        let mut kb = KnowledgeBase::default();
        kb.enroll(tpl("bracket", 1, Face::Up), "a".into()).unwrap();
        let bad_face = kb.to_toml().replace("face = \"up\"", "face = \"sideways\"");
        let e = KnowledgeBase::from_toml(&bad_face, p).unwrap_err();
        assert!(e.to_string().contains("sideways") && e.to_string().contains("template 1"), "{e}");
        let extra = kb.to_toml().replace("face = \"up\"", "face = \"up\"\ncolour = 3");
        let e = KnowledgeBase::from_toml(&extra, p).unwrap_err();
        assert!(e.to_string().contains("colour"), "{e}");
        let truncated = &kb.to_toml()[..kb.to_toml().len() / 2];
        assert!(KnowledgeBase::from_toml(truncated, p).is_err());
        // An interior edge's normal must be a unit vector.
        let text = kb.to_toml();
        assert!(text.contains("interior = [[45.0, 38.0, 0.6, -0.8]]"), "{text}");
        let bad_normal = text.replace("[45.0, 38.0, 0.6, -0.8]", "[45.0, 38.0, 3.0, 0.0]");
        let e = KnowledgeBase::from_toml(&bad_normal, p).unwrap_err();
        assert!(e.to_string().contains("interior[0]") && e.to_string().contains("length 1"), "{e}");
        // A knowledge base from an earlier build has none, and still loads.
        let earlier = text.replace("interior = [[45.0, 38.0, 0.6, -0.8]]\n", "");
        assert!(KnowledgeBase::from_toml(&earlier, p).unwrap().templates()[0].interior.is_empty());
    }

    /// A name with a newline could forge a log line; one with a slash, a file outside the KB's
    /// folder. Neither gets in, by enrolment or by editing the file.
    #[test]
    fn type_names_are_letters_digits_dash_and_underscore() {
        let mut kb = KnowledgeBase::default();
        for ok in ["A", "bracket", "flange-2", "C_down_7"] {
            let id = kb.entries.len() as u16 + 1;
            kb.enroll(tpl(ok, id, Face::Up), "a".into()).unwrap();
        }
        let long = "x".repeat(TYPE_NAME_MAX + 1);
        for bad in ["", "a b", "evil\nINFO accept", "../etc", "name;", "ä", long.as_str()] {
            let e = kb.enroll(tpl(bad, 99, Face::Up), "a".into()).unwrap_err();
            assert!(matches!(e, KbError::TypeName { .. }), "{bad:?}: {e}");
            assert!(!e.to_string().contains('\n'), "the error itself is one line: {e}");
        }
        let edited = kb.to_toml().replace("type = \"flange-2\"", "type = \"flange\\nforged\"");
        let e = KnowledgeBase::from_toml(&edited, Path::new("kb.toml")).unwrap_err().to_string();
        assert!(e.contains("kb.toml") && e.contains("template 3") && e.contains("letters, digits"), "{e}");
    }
}
