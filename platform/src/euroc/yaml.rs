//! The YAML subset of Kalibr/EuRoC `sensor.yaml` files, by hand.
//!
//! Accepted: a `%YAML:1.0` directive and `---` on their own lines; `#` comments (whole-line, or
//! after whitespace); `key: scalar`; `key: [a, b, ...]` flow lists that may span lines until the
//! closing `]`; `key:` followed by more-indented `key: ...` lines (a nested map, e.g. `T_BS:` with
//! `cols`, `rows`, `data`); scalars in single or double quotes. Anything else (block lists, tabs
//! in indentation, a line without `key:`, a duplicate key, an unterminated list or quote) is a
//! parse error with its 1-based line.

use crate::error::IoError;
use std::path::{Path, PathBuf};

/// A value and the line it starts on.
#[derive(Debug, Clone, PartialEq)]
pub enum Node {
    /// A scalar, unquoted.
    Scalar(String, usize),
    /// A flow list of scalars, each with its line.
    List(Vec<(String, usize)>, usize),
    /// A nested map.
    Map(Map, usize),
}

impl Node {
    fn line(&self) -> usize {
        match self {
            Node::Scalar(_, l) | Node::List(_, l) | Node::Map(_, l) => *l,
        }
    }
}

/// Keys in file order with their values.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Map(Vec<(String, Node)>);

/// A parsed file with typed accessors whose errors name the file and line.
#[derive(Debug, Clone)]
pub struct Doc {
    path: PathBuf,
    root: Map,
    last_line: usize,
}

fn perr(path: &Path, line: usize, msg: impl Into<String>) -> IoError {
    IoError::Parse {
        path: path.into(),
        line,
        msg: msg.into(),
    }
}

/// Strips a comment: `#` at the start or after whitespace, outside quotes.
fn strip_comment(s: &str) -> &str {
    let mut quote: Option<char> = None;
    let mut prev_ws = true;
    for (i, c) in s.char_indices() {
        match quote {
            Some(q) if c == q => quote = None,
            Some(_) => {}
            None if c == '"' || c == '\'' => quote = Some(c),
            None if c == '#' && prev_ws => return &s[..i],
            None => {}
        }
        prev_ws = c.is_whitespace();
    }
    s
}

fn unquote(path: &Path, line: usize, s: &str) -> Result<String, IoError> {
    let s = s.trim();
    for q in ['"', '\''] {
        if let Some(rest) = s.strip_prefix(q) {
            return rest
                .strip_suffix(q)
                .map(str::to_owned)
                .ok_or_else(|| perr(path, line, format!("unterminated quote in {s:?}")));
        }
    }
    Ok(s.to_owned())
}

struct Line {
    no: usize,
    indent: usize,
    text: String,
}

impl Doc {
    /// Reads and parses a file.
    pub fn read(path: &Path) -> Result<Doc, IoError> {
        let text = std::fs::read_to_string(path).map_err(|e| IoError::io(path, e))?;
        Doc::parse(path, &text)
    }

    /// Parses text (the path is only used in errors).
    pub fn parse(path: &Path, text: &str) -> Result<Doc, IoError> {
        let mut lines = Vec::new();
        let mut last_line = 0;
        for (i, raw) in text.lines().enumerate() {
            let no = i + 1;
            last_line = no;
            if no == 1 && raw.trim_end().starts_with("%YAML") {
                continue;
            }
            let body = strip_comment(raw).trim_end();
            if body.trim().is_empty() || body.trim() == "---" {
                continue;
            }
            let indent = body.len() - body.trim_start_matches(' ').len();
            if body[indent..].starts_with('\t') {
                return Err(perr(path, no, "tab in indentation"));
            }
            lines.push(Line {
                no,
                indent,
                text: body[indent..].to_owned(),
            });
        }
        let mut pos = 0;
        let root = parse_map(path, &lines, &mut pos, 0)?;
        if let Some(l) = lines.get(pos) {
            return Err(perr(path, l.no, "unexpected indentation"));
        }
        Ok(Doc {
            path: path.into(),
            root,
            last_line,
        })
    }

    /// The top-level map.
    pub fn root(&self) -> &Map {
        &self.root
    }

    /// A missing required key: reported at the last line of the file.
    fn missing(&self, key: &str) -> IoError {
        perr(
            &self.path,
            self.last_line.max(1),
            format!("required key {key:?} is missing"),
        )
    }

    /// A scalar number, `None` when the key is absent.
    pub fn opt_f64(&self, map: &Map, key: &str) -> Result<Option<f64>, IoError> {
        match map.get(key) {
            None => Ok(None),
            Some(Node::Scalar(s, line)) => parse_f64(&self.path, *line, key, s).map(Some),
            Some(n) => Err(perr(
                &self.path,
                n.line(),
                format!("{key} must be a number"),
            )),
        }
    }

    /// A required scalar number.
    pub fn f64(&self, map: &Map, key: &str) -> Result<f64, IoError> {
        self.opt_f64(map, key)?.ok_or_else(|| self.missing(key))
    }

    /// A scalar string, `None` when absent.
    pub fn opt_str<'m>(&self, map: &'m Map, key: &str) -> Result<Option<&'m str>, IoError> {
        match map.get(key) {
            None => Ok(None),
            Some(Node::Scalar(s, _)) => Ok(Some(s)),
            Some(n) => Err(perr(
                &self.path,
                n.line(),
                format!("{key} must be a scalar"),
            )),
        }
    }

    /// A required flow list of exactly `n` numbers (any length when `n` is `None`).
    pub fn list_f64(&self, map: &Map, key: &str, n: Option<usize>) -> Result<Vec<f64>, IoError> {
        match map.get(key) {
            None => Err(self.missing(key)),
            Some(Node::List(items, line)) => {
                if let Some(n) = n {
                    if items.len() != n {
                        return Err(perr(
                            &self.path,
                            *line,
                            format!("{key} needs {n} values, found {}", items.len()),
                        ));
                    }
                }
                items
                    .iter()
                    .map(|(s, l)| parse_f64(&self.path, *l, key, s))
                    .collect()
            }
            Some(n) => Err(perr(
                &self.path,
                n.line(),
                format!("{key} must be a [..] list"),
            )),
        }
    }

    /// A nested map, `None` when absent.
    pub fn opt_map<'m>(&self, map: &'m Map, key: &str) -> Result<Option<&'m Map>, IoError> {
        match map.get(key) {
            None => Ok(None),
            Some(Node::Map(m, _)) => Ok(Some(m)),
            Some(n) => Err(perr(
                &self.path,
                n.line(),
                format!("{key} must be a nested map"),
            )),
        }
    }

    /// Line of a key (for errors about its value), or the last line when absent.
    pub fn line_of(&self, map: &Map, key: &str) -> usize {
        map.get(key).map_or(self.last_line.max(1), Node::line)
    }

    /// A parse error at `line` of this file.
    pub fn error(&self, line: usize, msg: impl Into<String>) -> IoError {
        perr(&self.path, line, msg)
    }
}

impl Map {
    /// The value of `key`.
    pub fn get(&self, key: &str) -> Option<&Node> {
        self.0.iter().find(|(k, _)| k == key).map(|(_, v)| v)
    }
}

fn parse_f64(path: &Path, line: usize, key: &str, s: &str) -> Result<f64, IoError> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(perr(
            path,
            line,
            format!("{key}: {s:?} is not a finite number"),
        )),
    }
}

fn parse_map(path: &Path, lines: &[Line], pos: &mut usize, indent: usize) -> Result<Map, IoError> {
    let mut map = Map::default();
    while let Some(l) = lines.get(*pos) {
        if l.indent < indent {
            break;
        }
        if l.indent > indent {
            return Err(perr(path, l.no, "unexpected indentation"));
        }
        if l.text.starts_with("- ") || l.text == "-" {
            return Err(perr(path, l.no, "block lists are not supported"));
        }
        let Some((key, rest)) = split_key(&l.text) else {
            return Err(perr(
                path,
                l.no,
                format!("expected `key: value`, found {:?}", l.text),
            ));
        };
        let key = unquote(path, l.no, key)?;
        if key.is_empty() {
            return Err(perr(path, l.no, "empty key"));
        }
        if map.get(&key).is_some() {
            return Err(perr(path, l.no, format!("duplicate key {key:?}")));
        }
        let rest = rest.trim();
        let start = l.no;
        *pos += 1;
        let node = if rest.is_empty() {
            match lines.get(*pos) {
                Some(next) if next.indent > indent => {
                    let child = parse_map(path, lines, pos, next.indent)?;
                    Node::Map(child, start)
                }
                _ => Node::Scalar(String::new(), start),
            }
        } else if let Some(after) = rest.strip_prefix('[') {
            parse_flow_list(path, lines, pos, start, after)?
        } else if rest.starts_with('{') {
            return Err(perr(path, l.no, "flow maps are not supported"));
        } else {
            Node::Scalar(unquote(path, l.no, rest)?, start)
        };
        map.0.push((key, node));
    }
    Ok(map)
}

/// Splits `key: value` at the first `:` followed by a space or the end of line.
fn split_key(s: &str) -> Option<(&str, &str)> {
    let b = s.as_bytes();
    (0..b.len())
        .find(|&i| b[i] == b':' && (i + 1 == b.len() || b[i + 1] == b' '))
        .map(|i| (&s[..i], &s[i + 1..]))
}

fn parse_flow_list(
    path: &Path,
    lines: &[Line],
    pos: &mut usize,
    start: usize,
    first: &str,
) -> Result<Node, IoError> {
    let mut items: Vec<(String, usize)> = Vec::new();
    let mut chunk = first.to_owned();
    let mut line = start;
    // Whether the previous item ended with a comma (so a new item may start).
    let mut expect_item = true;
    loop {
        let (body, closed) = match chunk.find(']') {
            Some(i) => {
                if !chunk[i + 1..].trim().is_empty() {
                    return Err(perr(path, line, "text after the closing ]"));
                }
                (chunk[..i].to_owned(), true)
            }
            None => (chunk.clone(), false),
        };
        if body.contains('[') {
            return Err(perr(path, line, "nested lists are not supported"));
        }
        let parts: Vec<&str> = body.split(',').collect();
        for (k, p) in parts.iter().enumerate() {
            let p = p.trim();
            let last = k + 1 == parts.len();
            if p.is_empty() {
                // Allowed: the empty tail after a trailing comma, an empty line, or `[]`.
                if last || (k == 0 && parts.len() == 1) {
                    continue;
                }
                return Err(perr(path, line, "empty list item"));
            }
            if !expect_item {
                return Err(perr(path, line, "missing comma between list items"));
            }
            items.push((unquote(path, line, p)?, line));
            expect_item = !last;
        }
        if closed {
            if expect_item && !items.is_empty() {
                return Err(perr(path, line, "trailing comma before ]"));
            }
            return Ok(Node::List(items, start));
        }
        match lines.get(*pos) {
            Some(l) => {
                chunk = l.text.clone();
                line = l.no;
                *pos += 1;
            }
            None => return Err(perr(path, start, "unterminated [ list")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const CAM: &str = "%YAML:1.0
# General sensor definitions.
sensor_type: camera
comment: VI-Sensor cam0 (MT9M034)

T_BS:
  cols: 4
  rows: 4
  data: [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975,
         0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768,
        -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949,
         0.0, 0.0, 0.0, 1.0]

rate_hz: 20
resolution: [752, 480]
intrinsics: [458.654, 457.296, 367.215, 248.375] #fu, fv, cu, cv
distortion_model: radial-tangential
name: \"a # b\"
";

    #[test]
    fn parses_the_euroc_camera_layout() {
        let d = Doc::parse(Path::new("cam.yaml"), CAM).unwrap();
        let r = d.root();
        assert_eq!(
            d.opt_str(r, "comment").unwrap(),
            Some("VI-Sensor cam0 (MT9M034)")
        );
        assert_eq!(d.opt_str(r, "name").unwrap(), Some("a # b"));
        assert_eq!(d.f64(r, "rate_hz").unwrap(), 20.0);
        assert_eq!(
            d.list_f64(r, "intrinsics", Some(4)).unwrap(),
            vec![458.654, 457.296, 367.215, 248.375]
        );
        let t = d.opt_map(r, "T_BS").unwrap().unwrap();
        assert_eq!(d.f64(t, "rows").unwrap(), 4.0);
        let data = d.list_f64(t, "data", Some(16)).unwrap();
        assert_eq!(data[8], -0.0257744366974);
        assert_eq!(data[15], 1.0);
        match r.get("T_BS") {
            Some(Node::Map(_, line)) => assert_eq!(*line, 6),
            other => panic!("{other:?}"),
        }
    }

    fn err_line(text: &str) -> (usize, String) {
        match Doc::parse(Path::new("x.yaml"), text) {
            Err(IoError::Parse { line, msg, .. }) => (line, msg),
            other => panic!("{text:?}: expected a parse error, got {other:?}"),
        }
    }

    #[test]
    fn malformed_yaml_names_the_line() {
        assert_eq!(err_line("a: 1\nb: [1, 2,\n  3\n").0, 2);
        assert_eq!(err_line("a: 1\njust text\n").0, 2);
        assert_eq!(err_line("a: 1\na: 2\n").0, 2);
        assert_eq!(err_line("a: 1\n  b: 2\n").0, 2);
        assert_eq!(err_line("a:\n  - 1\n").0, 2);
        assert_eq!(err_line("a: [1,\n, 2]\n").0, 2);
        assert_eq!(err_line("a: \"x\n").0, 1);
        let d = Doc::parse(Path::new("x.yaml"), "c: [1 2]\na: [1,\n x]\nb: 1\n").unwrap();
        assert!(d.list_f64(d.root(), "c", None).is_err());
        match d.list_f64(d.root(), "a", None) {
            Err(IoError::Parse { line: 3, msg, .. }) => assert!(msg.contains("\"x\""), "{msg}"),
            other => panic!("{other:?}"),
        }
        match d.f64(d.root(), "zz") {
            Err(IoError::Parse { line: 4, msg, .. }) => assert!(msg.contains("missing"), "{msg}"),
            other => panic!("{other:?}"),
        }
    }
}
