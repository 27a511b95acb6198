//! Checks of `udev/99-easycalib.rules`: every rule restricts access to a
//! group (MODE 0660 or stricter, a GROUP, never world-accessible) and every
//! rule that creates a stable name matches vendor, product and serial, so
//! two identical controllers can never swap names.

use std::collections::HashMap;

const RULES: &str = include_str!("../udev/99-easycalib.rules");

/// One `KEY{attr}OP"value"` term of a rule.
#[derive(Debug, Clone, PartialEq)]
struct Term {
    key: String,
    op: String,
    value: String,
}

/// Split a rules file into rules (one per logical line; `\` continues a line).
fn rules(text: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    let mut cur = String::new();
    let mut start = 0;
    for (i, line) in text.lines().enumerate() {
        let t = line.trim();
        if cur.is_empty() && (t.is_empty() || t.starts_with('#')) {
            continue;
        }
        if cur.is_empty() {
            start = i + 1;
        }
        match t.strip_suffix('\\') {
            Some(part) => cur.push_str(part),
            None => {
                cur.push_str(t);
                out.push((start, std::mem::take(&mut cur)));
            }
        }
    }
    if !cur.is_empty() {
        out.push((start, cur));
    }
    out
}

/// Parse one rule into terms; `Err` names what is malformed.
fn parse_rule(rule: &str) -> Result<Vec<Term>, String> {
    let mut terms = Vec::new();
    let mut rest = rule.trim();
    while !rest.is_empty() {
        let op_at = rest.find(['=', '!', '+', '-', ':']).ok_or_else(|| format!("no operator in {rest:?}"))?;
        let key = rest[..op_at].trim().to_string();
        if key.is_empty() || !key.chars().all(|c| c.is_ascii_alphanumeric() || "{}_-.".contains(c)) {
            return Err(format!("bad key {key:?}"));
        }
        let after = &rest[op_at..];
        let op = ["==", "!=", "+=", "-=", ":=", "="]
            .into_iter()
            .find(|op| after.starts_with(op))
            .ok_or_else(|| format!("bad operator after {key}"))?;
        let after = after[op.len()..].trim_start();
        let body = after.strip_prefix('"').ok_or_else(|| format!("value of {key} is not quoted"))?;
        let end = body.find('"').ok_or_else(|| format!("value of {key} is not closed"))?;
        terms.push(Term { key, op: op.to_string(), value: body[..end].to_string() });
        rest = body[end + 1..].trim_start();
        if let Some(r) = rest.strip_prefix(',') {
            rest = r.trim_start();
        } else if !rest.is_empty() {
            return Err(format!("expected ',' before {rest:?}"));
        }
    }
    Ok(terms)
}

/// Every problem found in a rules file (empty = fine).
fn problems(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut names: HashMap<String, Vec<(String, String, String)>> = HashMap::new();
    let all = rules(text);
    if all.is_empty() {
        out.push("no rules".into());
    }
    for (line, rule) in all {
        let terms = match parse_rule(&rule) {
            Ok(t) => t,
            Err(e) => {
                out.push(format!("line {line}: {e}"));
                continue;
            }
        };
        let get = |key: &str, ops: &[&str]| {
            terms.iter().find(|t| t.key == key && ops.contains(&t.op.as_str())).map(|t| t.value.clone())
        };
        match get("MODE", &["=", ":="]) {
            None => out.push(format!("line {line}: no MODE")),
            Some(m) => match u32::from_str_radix(&m, 8) {
                Err(_) => out.push(format!("line {line}: MODE {m:?} is not octal")),
                // 0660 or stricter: no bits beyond rw for owner and group.
                Ok(bits) if bits & !0o660 != 0 => out.push(format!("line {line}: MODE {m} is wider than 0660")),
                Ok(_) => {}
            },
        }
        match get("GROUP", &["=", ":="]) {
            None => out.push(format!("line {line}: no GROUP")),
            Some(g) if g.is_empty() => out.push(format!("line {line}: empty GROUP")),
            Some(_) => {}
        }
        if terms.iter().any(|t| t.key == "OPTIONS" || t.key == "RUN" || t.key == "PROGRAM") {
            out.push(format!("line {line}: runs programs or sets options"));
        }
        let Some(link) = get("SYMLINK", &["+=", "="]) else { continue };
        let vid = get("ATTRS{idVendor}", &["=="]);
        let pid = get("ATTRS{idProduct}", &["=="]);
        let serial = get("ATTRS{serial}", &["=="]);
        for (what, v) in [("idVendor", &vid), ("idProduct", &pid)] {
            match v {
                Some(h) if h.len() == 4 && h.chars().all(|c| c.is_ascii_hexdigit() && !c.is_ascii_uppercase()) => {}
                Some(h) => out.push(format!("line {line}: {what} {h:?} is not 4 lower-case hex digits")),
                None => out.push(format!("line {line}: SYMLINK {link} without ATTRS{{{what}}}==")),
            }
        }
        match &serial {
            Some(s) if !s.is_empty() && !s.contains(['*', '?', '[']) => {}
            Some(s) => out.push(format!("line {line}: serial {s:?} is empty or a glob")),
            None => out.push(format!("line {line}: SYMLINK {link} without ATTRS{{serial}}==")),
        }
        names.entry(link).or_default().push((
            vid.unwrap_or_default(),
            pid.unwrap_or_default(),
            serial.unwrap_or_default(),
        ));
    }
    // Two different names must never be able to match the same device.
    let mut keys: Vec<_> = names.iter().flat_map(|(n, v)| v.iter().map(move |k| (k.clone(), n.clone()))).collect();
    keys.sort();
    for w in keys.windows(2) {
        if w[0].0 == w[1].0 && w[0].1 != w[1].1 {
            out.push(format!("{:?} matches both {} and {}", w[0].0, w[0].1, w[1].1));
        }
    }
    out
}

#[test]
fn shipped_rules_are_group_only_and_match_vendor_product_serial() {
    let p = problems(RULES);
    assert!(p.is_empty(), "{p:#?}");
}

#[test]
fn shipped_rules_name_the_rig_devices() {
    let mut links: HashMap<String, Vec<(String, String)>> = HashMap::new();
    for (_, rule) in rules(RULES) {
        let terms = parse_rule(&rule).unwrap();
        let get = |k: &str| terms.iter().find(|t| t.key == k).map(|t| t.value.clone()).unwrap_or_default();
        links
            .entry(get("SYMLINK"))
            .or_default()
            .push((format!("{}:{}", get("ATTRS{idVendor}"), get("ATTRS{idProduct}")), get("ATTRS{serial}")));
    }
    // Thorlabs units: FTDI vendor + Thorlabs product id, told apart by serial prefix (docs/hardware.md A.7).
    assert_eq!(links["easycalib-stage"], vec![("0403:faf0".to_string(), "27XXXXXX".to_string())]);
    assert_eq!(links["easycalib-rotation"], vec![("0403:faf0".to_string(), "55XXXXXX".to_string())]);
    let grbl: Vec<_> = links["easycalib-grbl"].iter().map(|(id, _)| id.as_str()).collect();
    for id in ["2341:0043", "2341:0001", "2a03:0043", "2341:0243", "0403:6001"] {
        assert!(grbl.contains(&id), "{id} missing from {grbl:?}");
    }
    assert_eq!(links["easycalib-sensor"][0].0, "2833:0209");
    assert!(!RULES.contains("0666") && !RULES.contains("0777"));
}

#[test]
fn checker_catches_what_it_must() {
    let ok = r#"SUBSYSTEM=="tty", ATTRS{idVendor}=="0403", ATTRS{idProduct}=="faf0", ATTRS{serial}=="27000001", SYMLINK+="easycalib-stage", GROUP="dialout", MODE="0660""#;
    assert!(problems(ok).is_empty(), "{:?}", problems(ok));
    // Stricter modes and continuation lines are fine.
    let split = ok.replace("0660", "0600").replace(", SYMLINK", ", \\\n  SYMLINK");
    assert!(problems(&split).is_empty(), "{:?}", problems(&split));
    let cases = [
        (ok.replace("0660", "0666"), "wider than 0660"),
        (ok.replace("0660", "0664"), "wider than 0660"),
        (ok.replace(r#", MODE="0660""#, ""), "no MODE"),
        (ok.replace(r#", GROUP="dialout""#, ""), "no GROUP"),
        (ok.replace(r#"ATTRS{serial}=="27000001", "#, ""), "without ATTRS{serial}"),
        (ok.replace("27000001", "27*"), "glob"),
        (ok.replace(r#"ATTRS{idProduct}=="faf0", "#, ""), "without ATTRS{idProduct}"),
        (ok.replace("faf0", "FAF0"), "lower-case hex"),
        (ok.replace(r#"MODE="0660""#, r#"MODE="0660"#), "not closed"),
        (format!("{ok}\n{}", ok.replace("easycalib-stage", "easycalib-rotation")), "matches both"),
        (ok.replace(", GROUP", ", RUN+=\"/bin/sh\", GROUP"), "runs programs"),
    ];
    for (text, want) in cases {
        let p = problems(&text);
        assert!(p.iter().any(|m| m.contains(want)), "{want}: {p:?}\n{text}");
    }
    assert_eq!(problems("# only a comment\n"), vec!["no rules".to_string()]);
}
