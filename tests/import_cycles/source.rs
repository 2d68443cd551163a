//! Reading a crate's sources for the import-cycle check: comments, strings and `#[cfg(test)]`
//! items blanked, the module tree from the `mod` declarations (inline modules included), and
//! `use` trees expanded into paths.

use std::path::{Path, PathBuf};

/// Source text with comments, string and char literals blanked (replaced by spaces, newlines
/// kept so line numbers stay right).
pub fn strip(src: &str) -> String {
    let c: Vec<char> = src.chars().collect();
    let mut out = String::with_capacity(src.len());
    let blank = |out: &mut String, ch: char| out.push(if ch == '\n' { '\n' } else { ' ' });
    let mut i = 0;
    while i < c.len() {
        let next = c.get(i + 1).copied();
        if c[i] == '/' && next == Some('/') {
            while i < c.len() && c[i] != '\n' {
                blank(&mut out, c[i]);
                i += 1;
            }
        } else if c[i] == '/' && next == Some('*') {
            let mut depth = 0;
            while i < c.len() {
                if c[i] == '/' && c.get(i + 1) == Some(&'*') {
                    depth += 1;
                    out.push_str("  ");
                    i += 2;
                } else if c[i] == '*' && c.get(i + 1) == Some(&'/') {
                    depth -= 1;
                    out.push_str("  ");
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    blank(&mut out, c[i]);
                    i += 1;
                }
            }
        } else if c[i] == 'r'
            && (next == Some('"') || next == Some('#'))
            && (i == 0 || !is_ident(c[i - 1]))
        {
            // Raw string r"..", r#".."#.
            let mut j = i + 1;
            let mut hashes = 0;
            while c.get(j) == Some(&'#') {
                hashes += 1;
                j += 1;
            }
            if c.get(j) != Some(&'"') {
                out.push(c[i]);
                i += 1;
                continue;
            }
            j += 1;
            loop {
                match c.get(j) {
                    None => break,
                    Some('"') if (1..=hashes).all(|k| c.get(j + k) == Some(&'#')) => {
                        j += 1 + hashes;
                        break;
                    }
                    _ => j += 1,
                }
            }
            for &ch in &c[i..j.min(c.len())] {
                blank(&mut out, ch);
            }
            i = j;
        } else if c[i] == '"' {
            blank(&mut out, c[i]);
            i += 1;
            while i < c.len() && c[i] != '"' {
                if c[i] == '\\' {
                    blank(&mut out, c[i]);
                    i += 1;
                }
                if i < c.len() {
                    blank(&mut out, c[i]);
                    i += 1;
                }
            }
            if i < c.len() {
                blank(&mut out, c[i]);
                i += 1;
            }
        } else if c[i] == '\'' {
            // A char literal ('x', '\n', '\u{..}'), else a lifetime or label ('a).
            let end = if next == Some('\\') {
                (i + 2..c.len()).find(|&j| c[j] == '\'')
            } else if c.get(i + 2) == Some(&'\'') {
                Some(i + 2)
            } else {
                None
            };
            match end {
                Some(e) => {
                    for &ch in &c[i..=e] {
                        blank(&mut out, ch);
                    }
                    i = e + 1;
                }
                None => {
                    out.push(c[i]);
                    i += 1;
                }
            }
        } else {
            out.push(c[i]);
            i += 1;
        }
    }
    out
}

pub fn is_ident(ch: char) -> bool {
    ch.is_alphanumeric() || ch == '_'
}

/// The end (exclusive) of the item starting at byte `from`: its `;` or its `{ .. }` block,
/// whichever comes first at depth 0.
pub fn item_end(s: &str, from: usize) -> usize {
    let b = s.as_bytes();
    let mut i = from;
    let mut paren = 0i32;
    while i < b.len() {
        match b[i] {
            b'(' | b'[' => paren += 1,
            b')' | b']' => paren -= 1,
            b';' if paren == 0 => return i + 1,
            b'{' if paren == 0 => return block_end(s, i),
            _ => {}
        }
        i += 1;
    }
    b.len()
}

/// The end (exclusive) of the `{ .. }` block opening at byte `open`.
pub fn block_end(s: &str, open: usize) -> usize {
    let mut depth = 0;
    for (i, ch) in s.bytes().enumerate().skip(open) {
        match ch {
            b'{' => depth += 1,
            b'}' => {
                depth -= 1;
                if depth == 0 {
                    return i + 1;
                }
            }
            _ => {}
        }
    }
    s.len()
}

/// Blanks every item under `#[cfg(test)]` (newlines kept).
pub fn drop_test_items(s: &str) -> String {
    let mut out = s.to_string();
    let mut from = 0;
    while let Some(k) = out[from..].find("#[cfg(test)]") {
        let at = from + k;
        let end = item_end(&out, at + "#[cfg(test)]".len());
        let blanked: String = out[at..end]
            .chars()
            .map(|c| if c == '\n' { '\n' } else { ' ' })
            .collect();
        out.replace_range(at..end, &blanked);
        from = end;
    }
    out
}

/// The identifier starting at byte `i` (empty if none).
pub fn ident_at(s: &str, i: usize) -> &str {
    let rest = &s[i..];
    let n = rest.find(|c: char| !is_ident(c)).unwrap_or(rest.len());
    &rest[..n]
}

pub fn line_of(s: &str, byte: usize) -> usize {
    s[..byte].bytes().filter(|&b| b == b'\n').count() + 1
}

/// One module: its path from the crate root, its cleaned text (inline child modules blanked),
/// its file, and the line its text starts at in that file.
pub struct Module {
    pub path: Vec<String>,
    pub text: String,
    pub file: PathBuf,
    pub line0: usize,
}

/// Reads the module tree of a crate from its root file.
pub fn read_crate(name: &str, root: &Path) -> Vec<Module> {
    let src = std::fs::read_to_string(root)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", root.display()));
    let mut out = Vec::new();
    let dir = root
        .parent()
        .expect("a crate root in a folder")
        .to_path_buf();
    add_module(
        vec![name.to_string()],
        drop_test_items(&strip(&src)),
        root,
        1,
        &dir,
        &mut out,
    );
    out
}

/// Adds the module `path` with cleaned text `text` (from `file`, starting at `line0`), whose
/// submodule files live in `child_dir`, and its submodules.
pub fn add_module(
    path: Vec<String>,
    mut text: String,
    file: &Path,
    line0: usize,
    child_dir: &Path,
    out: &mut Vec<Module>,
) {
    let mut from = 0;
    while let Some(k) = find_word(&text, "mod", from) {
        from = k + 3;
        let name_at = text[from..]
            .find(|c: char| !c.is_whitespace())
            .map_or(text.len(), |n| from + n);
        let name = ident_at(&text, name_at).to_string();
        if name.is_empty() {
            continue;
        }
        let after = name_at + name.len();
        let rest = text[after..].trim_start();
        let mut child = path.clone();
        child.push(name.clone());
        if rest.starts_with(';') {
            let candidates = [
                child_dir.join(format!("{name}.rs")),
                child_dir.join(&name).join("mod.rs"),
            ];
            let f = candidates
                .iter()
                .find(|p| p.is_file())
                .unwrap_or_else(|| panic!("module {} has no file", child.join("::")));
            let src = std::fs::read_to_string(f)
                .unwrap_or_else(|e| panic!("cannot read {}: {e}", f.display()));
            let sub_dir = if f.ends_with("mod.rs") {
                f.parent().expect("a folder").to_path_buf()
            } else {
                child_dir.join(&name)
            };
            add_module(child, drop_test_items(&strip(&src)), f, 1, &sub_dir, out);
        } else if rest.starts_with('{') {
            let open = text[after..].find('{').map_or(text.len(), |n| after + n);
            let end = block_end(&text, open);
            let inner = text[open + 1..end - 1].to_string();
            let line = line0 + line_of(&text, open) - 1;
            add_module(child, inner, file, line, &child_dir.join(&name), out);
            let blanked: String = text[open + 1..end - 1]
                .chars()
                .map(|c| if c == '\n' { '\n' } else { ' ' })
                .collect();
            text.replace_range(open + 1..end - 1, &blanked);
        }
    }
    out.push(Module {
        path,
        text,
        file: file.to_path_buf(),
        line0,
    });
}

/// The next occurrence of `word` as a whole identifier at or after `from`.
pub fn find_word(s: &str, word: &str, mut from: usize) -> Option<usize> {
    while let Some(k) = s.get(from..)?.find(word) {
        let at = from + k;
        let before_ok = s[..at].chars().next_back().is_none_or(|c| !is_ident(c));
        let after_ok = s[at + word.len()..]
            .chars()
            .next()
            .is_none_or(|c| !is_ident(c));
        if before_ok && after_ok {
            return Some(at);
        }
        from = at + word.len();
    }
    None
}

/// The paths of a `use` tree (`a::{b, c::{d as e, *}}`), each with the name it binds (`None`
/// for a glob).
pub fn expand_use_tree(tree: &str) -> Vec<(Vec<String>, Option<String>)> {
    let toks = tokens(tree);
    let mut out = Vec::new();
    let mut i = 0;
    parse_tree(&toks, &mut i, &[], &mut out);
    out
}

pub fn tokens(s: &str) -> Vec<String> {
    let mut t = Vec::new();
    let mut it = s.char_indices().peekable();
    while let Some((i, c)) = it.next() {
        if c.is_whitespace() {
            continue;
        }
        if is_ident(c) {
            let id = ident_at(s, i);
            for _ in 1..id.chars().count() {
                it.next();
            }
            t.push(id.to_string());
        } else if c == ':' {
            if it.peek().is_some_and(|&(_, n)| n == ':') {
                it.next();
            }
            t.push("::".to_string());
        } else {
            t.push(c.to_string());
        }
    }
    t
}

pub fn parse_tree(
    toks: &[String],
    i: &mut usize,
    prefix: &[String],
    out: &mut Vec<(Vec<String>, Option<String>)>,
) {
    let mut path = prefix.to_vec();
    loop {
        let Some(t) = toks.get(*i) else { return };
        match t.as_str() {
            "::" => *i += 1,
            "{" => {
                *i += 1;
                loop {
                    match toks.get(*i).map(String::as_str) {
                        None => return,
                        Some("}") => {
                            *i += 1;
                            return;
                        }
                        Some(",") => *i += 1,
                        Some(_) => parse_tree(toks, i, &path, out),
                    }
                }
            }
            "*" => {
                *i += 1;
                out.push((path, None));
                return;
            }
            "," | "}" => {
                let bound = bound_name(&path);
                out.push((path, bound));
                return;
            }
            "as" => {
                let alias = toks.get(*i + 1).cloned();
                *i += 2;
                out.push((path, alias));
                return;
            }
            _ => {
                path.push(t.clone());
                *i += 1;
            }
        }
        if *i >= toks.len() {
            let bound = bound_name(&path);
            out.push((path, bound));
            return;
        }
    }
}

/// The name a `use` path binds: its last segment (the module's for `a::b::{self}`).
pub fn bound_name(path: &[String]) -> Option<String> {
    match path {
        [.., m, last] if last == "self" => Some(m.clone()),
        [.., last] => Some(last.clone()),
        [] => None,
    }
}
