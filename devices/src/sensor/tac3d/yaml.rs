//! The YAML of a Tac3D frame header, read with `saphyr-parser` (a YAML 1.2
//! parser) into a small tree, and the two scalar writers the header encoder
//! uses.
//!
//! The tree keeps what the decoder needs and a generic loader drops: whether a
//! scalar was quoted (a quoted `'12'` is text, a plain `12` may be a number)
//! and the scalar's text as written (`SN: 0065` stays `0065`). Building the
//! tree from the parser's events also lets the header's limits
//! (docs/hardening.md) stop a hostile document early: nesting, entries per
//! collection, duplicate keys. Aliases, anchors, tags and block scalars have
//! no place in a frame header and are refused.

use std::borrow::Cow;
use std::ops::Range;

use saphyr_parser::{Event, Parser, ScalarStyle, ScanError, Span};

#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Yaml<'a> {
    /// A scalar; `quoted` scalars are always strings, plain ones may be numbers.
    Scalar {
        text: Cow<'a, str>,
        quoted: bool,
    },
    Map(Vec<(Cow<'a, str>, Yaml<'a>)>),
    Seq(Vec<Yaml<'a>>),
}

/// Limits (docs/hardening.md): a Tac3D header is a few kilobytes, nested four
/// levels deep, with a dozen keys; anything far beyond is refused before it can
/// cost stack or time. Nesting counts block and flow collections alike.
pub(crate) const MAX_DEPTH: usize = 16;
pub(crate) const MAX_HEADER_BYTES: usize = 256 * 1024;
pub(crate) const MAX_ENTRIES: usize = 4096;

/// A header that is not the YAML a frame header may be, with the line it
/// stopped at.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("line {line}: {kind}")]
pub struct YamlError {
    /// 1-based line in the header text.
    pub line: usize,
    #[source]
    pub kind: YamlErrorKind,
}

/// What was wrong with a header's YAML.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum YamlErrorKind {
    /// Not YAML at all (the parser's own message).
    #[error("{}", .0.info())]
    Syntax(ScanError),
    #[error("header of {bytes} bytes exceeds the limit of {MAX_HEADER_BYTES}")]
    TooLarge { bytes: usize },
    #[error("empty document")]
    Empty,
    #[error("more than one document")]
    ExtraDocument,
    #[error("header is not a mapping")]
    NotMapping,
    #[error("nesting deeper than {MAX_DEPTH} levels")]
    TooDeep,
    #[error("more than {MAX_ENTRIES} entries in a collection")]
    TooManyEntries,
    #[error("duplicate key `{0}`")]
    DuplicateKey(String),
    #[error("collection used as a key")]
    CollectionKey,
    #[error("unsupported YAML construct: {0}")]
    Unsupported(&'static str),
}

impl<'a> Yaml<'a> {
    pub fn get(&self, key: &str) -> Option<&Yaml<'a>> {
        match self {
            Yaml::Map(entries) => entries.iter().find(|(k, _)| k == key).map(|(_, v)| v),
            _ => None,
        }
    }

    /// The text of a scalar (quoted or not).
    pub fn as_str(&self) -> Option<&str> {
        match self {
            Yaml::Scalar { text, .. } => Some(text),
            _ => None,
        }
    }

    /// A plain scalar read as an unsigned integer (decimal).
    pub fn as_u64(&self) -> Option<u64> {
        match self {
            Yaml::Scalar { text, quoted: false } => text.strip_prefix('+').unwrap_or(text).parse().ok(),
            _ => None,
        }
    }

    /// A plain scalar read as a number (YAML 1.2 core schema, including
    /// `.nan` and `.inf`, which the caller then rejects as not finite).
    pub fn as_f64(&self) -> Option<f64> {
        match self {
            Yaml::Scalar { text, quoted: false } => match text.as_ref() {
                ".nan" | ".NaN" | ".NAN" => Some(f64::NAN),
                ".inf" | ".Inf" | ".INF" | "+.inf" | "+.Inf" | "+.INF" => Some(f64::INFINITY),
                "-.inf" | "-.Inf" | "-.INF" => Some(f64::NEG_INFINITY),
                t if t.bytes().all(|b| b.is_ascii_digit() || matches!(b, b'.' | b'-' | b'+' | b'e' | b'E'))
                    && t.bytes().any(|b| b.is_ascii_digit()) =>
                {
                    t.parse().ok()
                }
                _ => None,
            },
            _ => None,
        }
    }
}

/// A collection whose end event has not come yet.
enum Open<'a> {
    /// Entries so far, and the key read for the next value.
    Map(Vec<(Cow<'a, str>, Yaml<'a>)>, Option<Cow<'a, str>>),
    Seq(Vec<Yaml<'a>>),
}

/// A key of the root mapping whose value is a plain scalar, and the value's
/// range in the text (characters, which are bytes in an ASCII header).
pub(crate) type TopScalar<'a> = (Cow<'a, str>, Range<usize>);

/// Builds the tree from the parser's events, checking the limits as it goes.
struct Builder<'a> {
    open: Vec<Open<'a>>,
    root: Option<Yaml<'a>>,
    top: Vec<TopScalar<'a>>,
}

fn fail<T>(span: &Span, kind: YamlErrorKind) -> Result<T, YamlError> {
    Err(YamlError { line: span.start.line(), kind })
}

impl<'a> Builder<'a> {
    fn event(&mut self, event: Event<'a>, span: &Span) -> Result<(), YamlError> {
        match event {
            Event::DocumentStart(_) if self.root.is_some() => fail(span, YamlErrorKind::ExtraDocument),
            Event::Alias(_) => fail(span, YamlErrorKind::Unsupported("alias")),
            Event::Scalar(text, style, anchor, tag) => {
                plain_node(span, anchor, tag.is_some())?;
                let quoted = match style {
                    ScalarStyle::Plain => false,
                    ScalarStyle::SingleQuoted | ScalarStyle::DoubleQuoted => true,
                    ScalarStyle::Literal | ScalarStyle::Folded => {
                        return fail(span, YamlErrorKind::Unsupported("block scalar"));
                    }
                };
                self.node(Yaml::Scalar { text, quoted }, span)
            }
            Event::MappingStart(anchor, tag) => self.open(Open::Map(Vec::new(), None), span, anchor, tag.is_some()),
            Event::SequenceStart(anchor, tag) => self.open(Open::Seq(Vec::new()), span, anchor, tag.is_some()),
            Event::MappingEnd | Event::SequenceEnd => match self.open.pop() {
                Some(Open::Map(entries, _)) => self.node(Yaml::Map(entries), span),
                Some(Open::Seq(items)) => self.node(Yaml::Seq(items), span),
                None => Ok(()),
            },
            Event::Nothing | Event::StreamStart | Event::StreamEnd | Event::DocumentStart(_) | Event::DocumentEnd => {
                Ok(())
            }
        }
    }

    fn open(&mut self, c: Open<'a>, span: &Span, anchor: usize, tagged: bool) -> Result<(), YamlError> {
        plain_node(span, anchor, tagged)?;
        if let Some(Open::Map(_, None)) = self.open.last() {
            return fail(span, YamlErrorKind::CollectionKey);
        }
        if self.open.len() >= MAX_DEPTH {
            return fail(span, YamlErrorKind::TooDeep);
        }
        self.open.push(c);
        Ok(())
    }

    /// A finished node: the root, the next item of a sequence, or a key or
    /// value of a mapping.
    fn node(&mut self, node: Yaml<'a>, span: &Span) -> Result<(), YamlError> {
        let in_root = self.open.len() == 1;
        match self.open.last_mut() {
            None => self.root = Some(node),
            Some(Open::Seq(items)) => {
                if items.len() == MAX_ENTRIES {
                    return fail(span, YamlErrorKind::TooManyEntries);
                }
                items.push(node);
            }
            Some(Open::Map(entries, key)) => match (key.take(), node) {
                (Some(k), value) => {
                    if in_root && matches!(value, Yaml::Scalar { quoted: false, .. }) {
                        self.top.push((k.clone(), span.start.index()..span.end.index()));
                    }
                    entries.push((k, value));
                }
                (None, Yaml::Scalar { text, .. }) => {
                    if entries.len() == MAX_ENTRIES {
                        return fail(span, YamlErrorKind::TooManyEntries);
                    }
                    if entries.iter().any(|(e, _)| *e == text) {
                        return fail(span, YamlErrorKind::DuplicateKey(text.into_owned()));
                    }
                    *key = Some(text);
                }
                (None, _) => return fail(span, YamlErrorKind::CollectionKey),
            },
        }
        Ok(())
    }
}

/// Anchors and tags are refused: a header needs neither.
fn plain_node(span: &Span, anchor: usize, tagged: bool) -> Result<(), YamlError> {
    match (anchor, tagged) {
        (0, false) => Ok(()),
        (0, true) => fail(span, YamlErrorKind::Unsupported("tag")),
        _ => fail(span, YamlErrorKind::Unsupported("anchor")),
    }
}

/// Parse a header document. An empty document is an error: a frame header is
/// never empty. A parse error at the end of the text is reported on its last
/// line.
#[cfg(test)]
pub(crate) fn parse(text: &str) -> Result<Yaml<'_>, YamlError> {
    parse_with_spans(text).map(|(y, _)| y)
}

/// [`parse`], and where the plain scalar values of the root mapping stand.
pub(crate) fn parse_with_spans(text: &str) -> Result<(Yaml<'_>, Vec<TopScalar<'_>>), YamlError> {
    if text.len() > MAX_HEADER_BYTES {
        return Err(YamlError { line: 1, kind: YamlErrorKind::TooLarge { bytes: text.len() } });
    }
    let mut b = Builder { open: Vec::new(), root: None, top: Vec::new() };
    for event in Parser::new_from_str(text) {
        let (event, span) = event.map_err(|e| scan_error(text, e))?;
        b.event(event, &span)?;
    }
    let root = b.root.ok_or(YamlError { line: 1, kind: YamlErrorKind::Empty })?;
    Ok((root, b.top))
}

/// The parser's error, on the line it names (its end-of-text marker lies past
/// the last line). The scanner refuses flow nesting beyond 255 levels before
/// the builder sees the first of them: that is the nesting limit, met early.
fn scan_error(text: &str, e: ScanError) -> YamlError {
    let line = e.marker().line().clamp(1, text.lines().count().max(1));
    let kind = if e.info() == "recursion limit exceeded" { YamlErrorKind::TooDeep } else { YamlErrorKind::Syntax(e) };
    YamlError { line, kind }
}

/// Write a scalar the way a YAML emitter would: plain when that reads back as
/// the same string (so `3D_Positions` and `AD2-0065L` stay plain, as the
/// vendor writes them), single-quoted otherwise. The header's byte layout is
/// the vendor's (two-space item indentation, `''` for an empty `msg`), which a
/// generic emitter does not reproduce, so the header is written line by line.
pub(crate) fn write_str(out: &mut String, s: &str) {
    let plain = !s.is_empty()
        && s.bytes().all(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'-' | b'.'))
        && s.as_bytes()[0].is_ascii_alphanumeric()
        // A letter no YAML number can contain rules out every int/float
        // reading (hex and octal digits, exponents, `.inf` are excluded).
        && s.bytes().any(|b| b.is_ascii_alphabetic() && !b"abcdefABCDEFxXoObB".contains(&b))
        && !matches!(
            s.to_ascii_lowercase().as_str(),
            "true" | "false" | "null" | "yes" | "no" | "on" | "off" | "y" | "n"
        );
    if plain {
        out.push_str(s);
    } else {
        out.push('\'');
        for c in s.chars() {
            match c {
                '\'' => out.push_str("''"),
                // The header is ASCII on one line per key: map anything else to '?'/' '.
                c if c.is_ascii_control() => out.push(' '),
                c if !c.is_ascii() => out.push('?'),
                c => out.push(c),
            }
        }
        out.push('\'');
    }
}

/// A float that a YAML 1.1 or 1.2 loader reads back as the same float: Rust's
/// shortest round-trip decimal, never in exponent form, always with a point.
pub(crate) fn write_f64(out: &mut String, x: f64) {
    let s = format!("{x}");
    out.push_str(&s);
    if !s.contains('.') {
        out.push_str(".0");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn s(t: &str) -> Yaml<'_> {
        Yaml::Scalar { text: t.into(), quoted: false }
    }

    #[test]
    fn block_header_with_item_list() {
        let doc = "index: 12\nSN: AD2-0065L # sensor\ntimestamp: 1.5\nmsg: ''\ndata:\n  - name: 3D_Positions\n    type: mat\n    width: 3\n  - name: x\n    type: f64\n";
        let y = parse(doc).unwrap();
        assert_eq!(y.get("index").and_then(Yaml::as_u64), Some(12));
        assert_eq!(y.get("SN").and_then(Yaml::as_str), Some("AD2-0065L"));
        assert_eq!(y.get("timestamp").and_then(Yaml::as_f64), Some(1.5));
        assert_eq!(y.get("msg").and_then(Yaml::as_str), Some(""));
        let Some(Yaml::Seq(items)) = y.get("data") else { panic!("data not a sequence: {y:?}") };
        assert_eq!(items.len(), 2);
        assert_eq!(items[0].get("width"), Some(&s("3")));
        assert_eq!(items[1].get("type"), Some(&s("f64")));
    }

    #[test]
    fn sequence_at_key_indent_and_flow_forms_agree() {
        let a = parse("data:\n- {name: a, width: 3}\n- name: b\n  width: 4\n").unwrap();
        let b = parse("data: [{name: a, width: 3}, {name: 'b', width: 4}]").unwrap();
        let names = |y: &Yaml| -> Vec<String> {
            match y.get("data") {
                Some(Yaml::Seq(v)) => {
                    v.iter().map(|i| i.get("name").and_then(Yaml::as_str).unwrap_or("?").to_string()).collect()
                }
                _ => vec![],
            }
        };
        assert_eq!(names(&a), vec!["a", "b"]);
        assert_eq!(names(&b), vec!["a", "b"]);
    }

    #[test]
    fn quoted_scalars_unescape() {
        let y = parse("a: 'it''s'\nb: \"x\\ty\\u0041\"\n").unwrap();
        assert_eq!(y.get("a").and_then(Yaml::as_str), Some("it's"));
        assert_eq!(y.get("b").and_then(Yaml::as_str), Some("x\tyA"));
        assert_eq!(y.get("a").and_then(Yaml::as_u64), None);
    }

    #[test]
    fn malformed_documents_name_the_line() {
        assert_eq!(parse("a: 1\n  b: 2\n").unwrap_err().line, 2);
        assert_eq!(parse("a: 1\nb: 'open\n").unwrap_err().line, 2);
        assert_eq!(parse("a: 1\na: 2\n").unwrap_err().line, 2);
        assert_eq!(parse("a: [1, 2\n").unwrap_err().line, 1);
        assert!(parse("\n# only a comment\n").is_err());
        assert!(parse("a: |\n  text\n").is_err());
    }
}
