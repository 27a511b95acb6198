//! The small subset of YAML that a Tac3D frame header uses: a block mapping of
//! scalars with one block (or flow) sequence of mappings under `data`. Writing
//! a full YAML parser is not the point, and the workspace carries no YAML crate;
//! this reads block mappings and sequences (including `- key: value` items),
//! flow collections on one line, plain / single- / double-quoted scalars and
//! comments, and rejects anything else with the line it stopped at.

use std::fmt;

#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Yaml {
    /// A scalar; `quoted` scalars are always strings, plain ones may be numbers.
    Scalar {
        text: String,
        quoted: bool,
    },
    Map(Vec<(String, Yaml)>),
    Seq(Vec<Yaml>),
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct YamlError {
    /// 1-based line in the header text.
    pub line: usize,
    pub what: String,
}

impl fmt::Display for YamlError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "line {}: {}", self.line, self.what)
    }
}

/// Limits (docs/hardening.md): a Tac3D header is a few kilobytes, nested four
/// levels deep, with a dozen keys; anything far beyond is refused before it can
/// cost stack or time. Nesting is bounded in both the block and the flow reader.
pub(crate) const MAX_DEPTH: usize = 16;
pub(crate) const MAX_HEADER_BYTES: usize = 256 * 1024;
pub(crate) const MAX_ENTRIES: usize = 4096;

fn err<T>(line: usize, what: impl Into<String>) -> Result<T, YamlError> {
    Err(YamlError { line, what: what.into() })
}

impl Yaml {
    pub fn get(&self, key: &str) -> Option<&Yaml> {
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
            Yaml::Scalar { text, quoted: false } => match text.as_str() {
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

#[derive(Debug, Clone)]
struct Line<'a> {
    no: usize,
    indent: usize,
    text: &'a str,
}

/// Remove a trailing comment (`#` at the start or after whitespace, outside quotes).
fn strip_comment(s: &str) -> &str {
    let bytes = s.as_bytes();
    let mut quote: Option<u8> = None;
    let mut i = 0;
    while i < bytes.len() {
        let b = bytes[i];
        match quote {
            Some(q) => {
                if b == b'\\' && q == b'"' {
                    i += 1;
                } else if b == q {
                    quote = None;
                }
            }
            None => {
                if b == b'\'' || b == b'"' {
                    quote = Some(b);
                } else if b == b'#' && (i == 0 || bytes[i - 1] == b' ' || bytes[i - 1] == b'\t') {
                    return s[..i].trim_end();
                }
            }
        }
        i += 1;
    }
    s.trim_end()
}

fn lines(text: &str) -> Result<Vec<Line<'_>>, YamlError> {
    let mut out = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let no = i + 1;
        let body = raw.trim_start_matches(' ');
        if body.starts_with('\t') {
            return err(no, "tab in indentation");
        }
        let indent = raw.len() - body.len();
        let body = strip_comment(body);
        if body.is_empty() {
            continue;
        }
        if indent == 0 && (body == "---" || body == "..." || body.starts_with("%YAML")) {
            continue;
        }
        out.push(Line { no, indent, text: body });
    }
    Ok(out)
}

/// Parse a header document. An empty document is an error: a frame header is never empty.
pub(crate) fn parse(text: &str) -> Result<Yaml, YamlError> {
    if text.len() > MAX_HEADER_BYTES {
        return err(1, format!("header of {} bytes exceeds the limit of {MAX_HEADER_BYTES}", text.len()));
    }
    let mut ls = lines(text)?;
    if ls.is_empty() {
        return err(1, "empty document");
    }
    let mut pos = 0;
    let indent = ls[0].indent;
    let v = block(&mut ls, &mut pos, indent, 0)?;
    if let Some(l) = ls.get(pos) {
        return err(l.no, format!("unexpected indentation {}", l.indent));
    }
    Ok(v)
}

fn is_seq_item(s: &str) -> bool {
    s == "-" || s.starts_with("- ")
}

fn too_deep<T>(no: usize) -> Result<T, YamlError> {
    err(no, format!("nesting deeper than {MAX_DEPTH} levels"))
}

fn block(ls: &mut [Line<'_>], pos: &mut usize, indent: usize, depth: usize) -> Result<Yaml, YamlError> {
    let first = ls[*pos].clone();
    if depth >= MAX_DEPTH {
        return too_deep(first.no);
    }
    if first.indent != indent {
        return err(first.no, format!("expected indentation {indent}"));
    }
    if is_seq_item(first.text) {
        return sequence(ls, pos, indent, depth);
    }
    if split_key(first.text).is_none() {
        // A lone scalar or flow collection.
        *pos += 1;
        return value(first.text, first.no, depth);
    }
    mapping(ls, pos, indent, depth)
}

fn sequence(ls: &mut [Line<'_>], pos: &mut usize, indent: usize, depth: usize) -> Result<Yaml, YamlError> {
    let mut items = Vec::new();
    while let Some(l) = ls.get(*pos).cloned() {
        if l.indent < indent || !is_seq_item(l.text) {
            break;
        }
        if items.len() == MAX_ENTRIES {
            return err(l.no, format!("more than {MAX_ENTRIES} items in a sequence"));
        }
        if l.indent > indent {
            return err(l.no, "unexpected indentation in sequence");
        }
        let rest = l.text[1..].trim_start_matches(' ');
        if rest.is_empty() {
            *pos += 1;
            match ls.get(*pos) {
                Some(n) if n.indent > indent => {
                    let ni = n.indent;
                    items.push(block(ls, pos, ni, depth + 1)?);
                }
                _ => items.push(Yaml::Scalar { text: String::new(), quoted: false }),
            }
            continue;
        }
        // `- key: value` opens a mapping whose keys line up with `key`.
        let col = indent + (l.text.len() - rest.len());
        ls[*pos] = Line { no: l.no, indent: col, text: rest };
        items.push(block(ls, pos, col, depth + 1)?);
    }
    Ok(Yaml::Seq(items))
}

fn mapping(ls: &mut [Line<'_>], pos: &mut usize, indent: usize, depth: usize) -> Result<Yaml, YamlError> {
    let mut entries: Vec<(String, Yaml)> = Vec::new();
    while let Some(l) = ls.get(*pos).cloned() {
        if l.indent < indent {
            break;
        }
        if l.indent > indent {
            return err(l.no, "unexpected indentation in mapping");
        }
        if is_seq_item(l.text) {
            break;
        }
        let Some((k, v)) = split_key(l.text) else {
            return err(l.no, format!("expected `key: value`, found `{}`", l.text));
        };
        let key = match value(k, l.no, depth)? {
            Yaml::Scalar { text, .. } => text,
            _ => return err(l.no, "collection used as a key"),
        };
        if entries.len() == MAX_ENTRIES {
            return err(l.no, format!("more than {MAX_ENTRIES} keys in a mapping"));
        }
        if entries.iter().any(|(e, _)| *e == key) {
            return err(l.no, format!("duplicate key `{key}`"));
        }
        *pos += 1;
        let val = if !v.is_empty() {
            value(v, l.no, depth + 1)?
        } else {
            match ls.get(*pos) {
                Some(n) if n.indent > indent => {
                    let ni = n.indent;
                    block(ls, pos, ni, depth + 1)?
                }
                // YAML lets a sequence under a key sit at the key's own indentation.
                Some(n) if n.indent == indent && is_seq_item(n.text) => sequence(ls, pos, indent, depth + 1)?,
                _ => Yaml::Scalar { text: String::new(), quoted: false },
            }
        };
        entries.push((key, val));
    }
    Ok(Yaml::Map(entries))
}

/// Split `key: value` at the first `:` followed by a space or the end, outside
/// quotes and brackets. `None` when the line is not a mapping entry.
fn split_key(s: &str) -> Option<(&str, &str)> {
    let bytes = s.as_bytes();
    if matches!(bytes.first(), Some(b'{') | Some(b'[')) {
        return None;
    }
    let mut quote: Option<u8> = None;
    let mut i = 0;
    while i < bytes.len() {
        let b = bytes[i];
        match quote {
            Some(q) => {
                if b == b'\\' && q == b'"' {
                    i += 1;
                } else if b == q {
                    quote = None;
                }
            }
            None => {
                if (b == b'\'' || b == b'"') && i == 0 {
                    quote = Some(b);
                } else if b == b':' && (i + 1 == bytes.len() || bytes[i + 1] == b' ') {
                    return Some((s[..i].trim_end(), s[i + 1..].trim()));
                }
            }
        }
        i += 1;
    }
    None
}

/// A value written on one line: a scalar or a flow collection.
fn value(s: &str, no: usize, depth: usize) -> Result<Yaml, YamlError> {
    let s = s.trim();
    if s.starts_with('{') || s.starts_with('[') {
        let mut p = Flow { b: s.as_bytes(), s, i: 0, no, depth };
        let v = p.node()?;
        p.ws();
        if p.i != p.b.len() {
            return err(no, format!("text after flow collection at column {}", p.i + 1));
        }
        return Ok(v);
    }
    if s.starts_with('\'') || s.starts_with('"') {
        let (text, used) = quoted(s, no)?;
        if used != s.len() {
            return err(no, "text after quoted scalar");
        }
        return Ok(Yaml::Scalar { text, quoted: true });
    }
    if s.starts_with(['|', '>', '&', '*', '!', '%', '@', '`']) {
        return err(no, format!("unsupported YAML construct `{s}`"));
    }
    Ok(Yaml::Scalar { text: s.to_string(), quoted: false })
}

/// Read a quoted scalar at the start of `s`; returns the text and the bytes used.
fn quoted(s: &str, no: usize) -> Result<(String, usize), YamlError> {
    let q = s.as_bytes()[0];
    let mut out = String::new();
    let mut chars = s.char_indices().skip(1);
    while let Some((i, c)) = chars.next() {
        if q == b'\'' && c == '\'' {
            if s[i + 1..].starts_with('\'') {
                out.push('\'');
                chars.next();
                continue;
            }
            return Ok((out, i + 1));
        }
        if q == b'"' && c == '"' {
            return Ok((out, i + 1));
        }
        if q == b'"' && c == '\\' {
            let Some((_, e)) = chars.next() else { break };
            let hex = |n: usize, chars: &mut dyn Iterator<Item = (usize, char)>| {
                let h: String = chars.take(n).map(|(_, c)| c).collect();
                u32::from_str_radix(&h, 16).ok().filter(|_| h.len() == n).and_then(char::from_u32)
            };
            let ch = match e {
                'n' => Some('\n'),
                't' => Some('\t'),
                'r' => Some('\r'),
                '0' => Some('\0'),
                '\\' => Some('\\'),
                '"' => Some('"'),
                '/' => Some('/'),
                ' ' => Some(' '),
                'x' => hex(2, &mut chars),
                'u' => hex(4, &mut chars),
                _ => None,
            };
            match ch {
                Some(ch) => out.push(ch),
                None => return err(no, format!("bad escape `\\{e}` in double-quoted scalar")),
            }
            continue;
        }
        out.push(c);
    }
    err(no, "unterminated quoted scalar")
}

struct Flow<'a> {
    s: &'a str,
    b: &'a [u8],
    i: usize,
    no: usize,
    /// Nesting of the collection being read (block levels included).
    depth: usize,
}

impl Flow<'_> {
    fn ws(&mut self) {
        while self.i < self.b.len() && self.b[self.i] == b' ' {
            self.i += 1;
        }
    }

    fn node(&mut self) -> Result<Yaml, YamlError> {
        self.ws();
        if matches!(self.b.get(self.i), Some(b'{') | Some(b'[')) {
            if self.depth >= MAX_DEPTH {
                return too_deep(self.no);
            }
            self.depth += 1;
            let v = self.collection();
            self.depth -= 1;
            return v;
        }
        self.scalar(false)
    }

    fn collection(&mut self) -> Result<Yaml, YamlError> {
        match self.b.get(self.i) {
            Some(b'{') => {
                self.i += 1;
                let mut entries = Vec::new();
                loop {
                    self.ws();
                    if self.b.get(self.i) == Some(&b'}') {
                        self.i += 1;
                        return Ok(Yaml::Map(entries));
                    }
                    let key = match self.scalar(true)? {
                        Yaml::Scalar { text, .. } => text,
                        _ => return err(self.no, "collection used as a key"),
                    };
                    self.ws();
                    if self.b.get(self.i) != Some(&b':') {
                        return err(self.no, format!("expected `:` at column {}", self.i + 1));
                    }
                    self.i += 1;
                    let v = self.node()?;
                    if entries.len() == MAX_ENTRIES {
                        return err(self.no, format!("more than {MAX_ENTRIES} keys in a mapping"));
                    }
                    entries.push((key, v));
                    self.sep(b'}')?;
                }
            }
            Some(b'[') => {
                self.i += 1;
                let mut items = Vec::new();
                loop {
                    self.ws();
                    if self.b.get(self.i) == Some(&b']') {
                        self.i += 1;
                        return Ok(Yaml::Seq(items));
                    }
                    if items.len() == MAX_ENTRIES {
                        return err(self.no, format!("more than {MAX_ENTRIES} items in a sequence"));
                    }
                    items.push(self.node()?);
                    self.sep(b']')?;
                }
            }
            _ => self.scalar(false),
        }
    }

    /// After an entry: `,` or the closing bracket (left for the caller).
    fn sep(&mut self, close: u8) -> Result<(), YamlError> {
        self.ws();
        match self.b.get(self.i) {
            Some(b',') => {
                self.i += 1;
                Ok(())
            }
            Some(c) if *c == close => Ok(()),
            _ => err(self.no, format!("expected `,` or `{}` at column {}", close as char, self.i + 1)),
        }
    }

    fn scalar(&mut self, is_key: bool) -> Result<Yaml, YamlError> {
        self.ws();
        if matches!(self.b.get(self.i), Some(b'\'') | Some(b'"')) {
            let (text, used) = quoted(&self.s[self.i..], self.no)?;
            self.i += used;
            return Ok(Yaml::Scalar { text, quoted: true });
        }
        let start = self.i;
        while let Some(&c) = self.b.get(self.i) {
            let stop = matches!(c, b',' | b']' | b'}')
                || (c == b':' && (is_key || matches!(self.b.get(self.i + 1), Some(b' ') | None)));
            if stop {
                break;
            }
            self.i += 1;
        }
        let text = self.s[start..self.i].trim();
        if text.starts_with(['{', '[', '&', '*', '!', '|', '>']) {
            return err(self.no, format!("unsupported flow scalar `{text}`"));
        }
        Ok(Yaml::Scalar { text: text.to_string(), quoted: false })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn s(t: &str) -> Yaml {
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
