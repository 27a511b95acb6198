//! What a frame header says: its scalars, and where each known data item lies
//! in the blob and how to read it.
//!
//! A sensor sends the same header with every frame but for two values, the
//! frame `index` and the `timestamp`. Reading YAML costs several times what the
//! rest of a frame's decoding does, so the last header that decoded is kept as
//! a [`Template`]: a header equal to it except for those two values, each still
//! one plain scalar at the end of its line, means the same as the template with
//! the new values, and is decoded without a parse. Anything else (another
//! layout, another serial, a quoted or commented value, a frame that does not
//! decode) takes the full parse, which also produces every error, so what
//! `decode_frame` returns does not depend on what it read before.

use std::cell::RefCell;
use std::ops::Range;

use super::yaml::{self, TopScalar, Yaml, YamlError, YamlErrorKind};
use super::{INITIALIZE_PROGRESS, Tac3dError, Tac3dFrame, Tac3dItem, Tac3dValue};

thread_local! {
    /// The last header decoded on this thread (receive tasks decode one
    /// sensor's frames one after the other).
    static LAST: RefCell<Option<Template>> = const { RefCell::new(None) };
}

/// Decode a frame whose header `text` is ASCII.
pub(super) fn decode(text: &str, blob: &[u8]) -> Result<Tac3dFrame, Tac3dError> {
    if let Some(frame) = LAST.with_borrow(|t| t.as_ref().and_then(|t| t.decode(text, blob))) {
        return Ok(frame);
    }
    let (frame, template) = decode_parsed(text, blob)?;
    if let Some(t) = template {
        LAST.set(Some(t));
    }
    Ok(frame)
}

/// Forget the remembered header (tests compare with and without it).
#[cfg(test)]
pub(super) fn forget() {
    LAST.set(None);
}

/// The frame as the remembered header reads it, if it does.
#[cfg(test)]
pub(super) fn remembered(text: &str, blob: &[u8]) -> Option<Tac3dFrame> {
    LAST.with_borrow(|t| t.as_ref().and_then(|t| t.decode(text, blob)))
}

/// How a known item's bytes are read.
#[derive(Debug, Clone, Copy)]
enum ItemKind {
    Mat { rows: usize, cols: usize },
    F64,
    I32,
    Img,
}

/// One known item of a header.
#[derive(Debug, Clone)]
struct ItemSpec {
    name: String,
    kind: ItemKind,
    offset: u64,
    length: u64,
}

/// The item's bytes, or the error naming it when they run past the blob.
fn blob_range<'b>(name: &str, offset: u64, length: u64, blob: &'b [u8]) -> Result<&'b [u8], Tac3dError> {
    match offset.checked_add(length).filter(|e| *e <= blob.len() as u64) {
        Some(end) => Ok(&blob[offset as usize..end as usize]),
        None => Err(Tac3dError::Length {
            item: name.to_string(),
            what: format!("offset {offset} + length {length} runs past the {} B blob", blob.len()),
        }),
    }
}

impl ItemSpec {
    fn decode(&self, blob: &[u8]) -> Result<Tac3dItem, Tac3dError> {
        let bytes = blob_range(&self.name, self.offset, self.length, blob)?;
        let size_error = |ty: &str, size: usize| Tac3dError::Length {
            item: self.name.clone(),
            what: format!("{ty} needs {size} B, length says {}", self.length),
        };
        let value = match self.kind {
            ItemKind::Mat { rows, cols } => {
                let data = bytes
                    .chunks_exact(8)
                    .map(|c| f64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]))
                    .collect();
                Tac3dValue::Mat { rows, cols, data }
            }
            ItemKind::F64 => Tac3dValue::F64(f64::from_le_bytes(bytes.try_into().map_err(|_| size_error("f64", 8))?)),
            ItemKind::I32 => Tac3dValue::I32(i32::from_le_bytes(bytes.try_into().map_err(|_| size_error("i32", 4))?)),
            ItemKind::Img => Tac3dValue::Img(bytes.to_vec()),
        };
        if self.name == INITIALIZE_PROGRESS {
            let progress = match value {
                Tac3dValue::I32(p) => f64::from(p),
                Tac3dValue::F64(p) => p,
                _ => 100.0,
            };
            if progress != 100.0 {
                return Err(Tac3dError::Initializing { progress });
            }
        }
        Ok(Tac3dItem { name: self.name.clone(), value })
    }
}

fn field<'a, 'y>(y: &'a Yaml<'y>, key: &str) -> Result<&'a Yaml<'y>, Tac3dError> {
    y.get(key).ok_or_else(|| Tac3dError::MissingField { field: key.to_string() })
}

fn field_u64(y: &Yaml<'_>, key: &str, ctx: &str) -> Result<u64, Tac3dError> {
    let v = y.get(key).ok_or_else(|| Tac3dError::MissingField { field: format!("{ctx}{key}") })?;
    v.as_u64().ok_or_else(|| Tac3dError::BadField {
        field: format!("{ctx}{key}"),
        what: format!("is not an unsigned integer: {v:?}"),
    })
}

fn field_str<'a>(y: &'a Yaml<'_>, key: &str, ctx: &str) -> Result<&'a str, Tac3dError> {
    let v = y.get(key).ok_or_else(|| Tac3dError::MissingField { field: format!("{ctx}{key}") })?;
    v.as_str().ok_or_else(|| Tac3dError::BadField { field: format!("{ctx}{key}"), what: "is not a scalar".into() })
}

/// Item `k` of `data`: `None` for a type or dtype this decoder does not know.
/// Fields are checked in the order the vendor's client reads them; an item
/// running past the blob is reported before its matrix shape.
fn item_spec(it: &Yaml<'_>, k: usize, blob: &[u8]) -> Result<Option<ItemSpec>, Tac3dError> {
    let ctx = format!("data[{k}].");
    let name = field_str(it, "name", &ctx)?.to_string();
    let ty = field_str(it, "type", &ctx)?;
    let known = match ty {
        "mat" => field_str(it, "dtype", &ctx)? == "f64",
        "f64" | "i32" | "img" => true,
        _ => false,
    };
    if !known {
        return Ok(None);
    }
    let offset = field_u64(it, "offset", &ctx)?;
    let length = field_u64(it, "length", &ctx)?;
    blob_range(&name, offset, length, blob)?;
    let kind = match ty {
        "mat" => {
            let cols = field_u64(it, "width", &ctx)?;
            let rows = field_u64(it, "height", &ctx)?;
            let want = rows.checked_mul(cols).and_then(|n| n.checked_mul(8));
            if want != Some(length) {
                return Err(Tac3dError::Length {
                    item: name,
                    what: format!("{rows} x {cols} f64 matrix needs {want:?} B, length says {length}"),
                });
            }
            ItemKind::Mat { rows: rows as usize, cols: cols as usize }
        }
        "f64" => ItemKind::F64,
        "i32" => ItemKind::I32,
        _ => ItemKind::Img,
    };
    Ok(Some(ItemSpec { name, kind, offset, length }))
}

/// The full path: parse the YAML, read the fields, decode the items; on
/// success also the header as a template for the frames that follow.
fn decode_parsed(text: &str, blob: &[u8]) -> Result<(Tac3dFrame, Option<Template>), Tac3dError> {
    let (y, top) = yaml::parse_with_spans(text)?;
    if !matches!(y, Yaml::Map(_)) {
        return Err(YamlError { line: 1, kind: YamlErrorKind::NotMapping }.into());
    }
    let index = field_u64(&y, "index", "")?;
    let sn = field_str(&y, "SN", "")?.to_string();
    let ts = field(&y, "timestamp")?;
    let timestamp = ts
        .as_f64()
        .ok_or_else(|| Tac3dError::BadField { field: "timestamp".into(), what: format!("is not a number: {ts:?}") })?;
    if !timestamp.is_finite() {
        return Err(Tac3dError::NotFinite { item: "timestamp".into(), at: 0 });
    }
    let msg = match y.get("msg") {
        None => None,
        Some(m) => Some(
            m.as_str()
                .ok_or_else(|| Tac3dError::BadField { field: "msg".into(), what: "is not a scalar".into() })?
                .to_string(),
        ),
    };
    let items_y = match field(&y, "data")? {
        Yaml::Seq(v) => v.as_slice(),
        // `data:` with nothing under it: a frame without items.
        Yaml::Scalar { text, quoted: false } if text.is_empty() => &[],
        other => {
            return Err(Tac3dError::BadField { field: "data".into(), what: format!("is not a list: {other:?}") });
        }
    };
    let mut items = Vec::with_capacity(items_y.len());
    let mut specs = Vec::with_capacity(items_y.len());
    for (k, it) in items_y.iter().enumerate() {
        let Some(spec) = item_spec(it, k, blob)? else { continue };
        items.push(spec.decode(blob)?);
        specs.push(spec);
    }
    let template = Template::new(text, &y, &top, &sn, &msg, specs);
    Ok((Tac3dFrame { index, sn, timestamp, msg, items }, template))
}

/// A value the template may take anew: a plain scalar of letters, digits and
/// `_ . + -` on one line, which YAML reads the same wherever such a value
/// stands (`-` alone would open a sequence).
fn replaceable(v: &str) -> bool {
    !v.is_empty() && v != "-" && v.bytes().all(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'.' | b'+' | b'-'))
}

/// Which header value a slot holds.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Slot {
    Index,
    Timestamp,
}

/// A header that decoded, with the byte ranges of its `index` and
/// `timestamp` values (in text order), and what the rest of it says.
#[derive(Debug)]
struct Template {
    text: String,
    slots: Vec<(Slot, Range<usize>)>,
    sn: String,
    msg: Option<String>,
    specs: Vec<ItemSpec>,
}

impl Template {
    /// `None` unless both values are replaceable plain scalars that end their line.
    fn new(
        text: &str,
        y: &Yaml<'_>,
        top: &[TopScalar<'_>],
        sn: &str,
        msg: &Option<String>,
        specs: Vec<ItemSpec>,
    ) -> Option<Self> {
        let slot = |key: &str, which: Slot| {
            let (_, r) = top.iter().find(|(k, _)| k == key)?;
            let value = text.get(r.clone())?;
            let ok = replaceable(value)
                && y.get(key).and_then(Yaml::as_str) == Some(value)
                && text.as_bytes().get(r.end) == Some(&b'\n');
            ok.then(|| (which, r.clone()))
        };
        let mut slots = vec![slot("index", Slot::Index)?, slot("timestamp", Slot::Timestamp)?];
        slots.sort_by_key(|(_, r)| r.start);
        Some(Self { text: text.to_string(), slots, sn: sn.to_string(), msg: msg.clone(), specs })
    }

    /// The frame, when `text` is this header with other replaceable values
    /// and the frame decodes; `None` sends it down the full path.
    fn decode(&self, text: &str, blob: &[u8]) -> Option<Tac3dFrame> {
        let (mut at, mut prev) = (0, 0);
        let (mut index, mut timestamp) = (None, None);
        for (which, r) in &self.slots {
            let same = &self.text[prev..r.start];
            at += text.get(at..)?.starts_with(same).then_some(same.len())?;
            let end = at + text.get(at..)?.find('\n')?;
            let value = Yaml::Scalar { text: text[at..end].into(), quoted: false };
            if !replaceable(&text[at..end]) {
                return None;
            }
            match which {
                Slot::Index => index = value.as_u64(),
                Slot::Timestamp => timestamp = value.as_f64().filter(|t| t.is_finite()),
            }
            (at, prev) = (end, r.end);
        }
        if text.get(at..)? != &self.text[prev..] {
            return None;
        }
        let (index, timestamp) = (index?, timestamp?);
        let items = self.specs.iter().map(|s| s.decode(blob)).collect::<Result<Vec<_>, _>>().ok()?;
        Some(Tac3dFrame { index, sn: self.sn.clone(), timestamp, msg: self.msg.clone(), items })
    }
}
