//! No two modules of a crate import each other (directly or around a longer loop).
//!
//! Reads the sources of `core/src`, `platform/src` and `host-tools/src` (the module tree from
//! each crate root's `mod` declarations, `#[path]`-free; inline `mod x { .. }` blocks are modules
//! too) and draws an edge `A -> B` for every path in `A` that names `B` or an item defined in
//! `B`: `use crate::..`, `use super::..`, `use self::..` (brace trees expanded) and the same
//! prefixes written inline (`super::ins::renormalize(q)`). A path through a re-export
//! (`crate::inertial::NavState`, re-exported by `inertial/mod.rs` from `inertial::state`) is
//! followed to the module that defines the item. Comments, string literals and every item under
//! `#[cfg(test)]` are skipped (tests may import whatever they exercise).
//!
//! Edges from a module to its own descendants are not counted: a parent declaring and using its
//! submodules is composition (`estimator/mod.rs` uses `estimator::window`, whose impls use
//! `super::Estimator`). Any other loop is a cycle: each is printed with the lines that make it.
//!
//! Run `cargo test -p povins --test import_cycles -- --nocapture` to see the module count and
//! every cycle found (`POVINS_CYCLES_ROOT=<tree>` examines another checkout's sources).

mod source;

use source::{expand_use_tree, find_word, ident_at, line_of, read_crate, Module};
use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;
use std::path::PathBuf;

/// Cycles known and scheduled for removal (issue 29): each entry is the sorted module set of one
/// strongly connected component. The test fails when one of them is gone too, so that the entry
/// is removed with the cycle.
const ALLOWED: &[&[&str]] = &[];

const CRATES: &[(&str, &str)] = &[
    ("povins_core", "core/src/lib.rs"),
    ("povins_platform", "platform/src/lib.rs"),
    ("povins_host_tools", "host-tools/src/lib.rs"),
];

/// A path found in a module: its segments and where it was written.
struct Ref {
    segs: Vec<String>,
    line: usize,
    text: String,
}

/// The `use` declarations of a module's own text (not its inline submodules'), expanded.
fn uses(m: &Module) -> Vec<(Vec<String>, Option<String>, usize)> {
    let mut out = Vec::new();
    let mut from = 0;
    while let Some(at) = find_word(&m.text, "use", from) {
        let end = m.text[at..].find(';').map_or(m.text.len(), |n| at + n);
        let line = m.line0 + line_of(&m.text, at) - 1;
        for (p, bound) in expand_use_tree(&m.text[at + 3..end]) {
            out.push((p, bound, line));
        }
        from = end;
    }
    out
}

/// Every `crate::`/`super::`/`self::` path of a module: expanded `use` trees and inline paths.
fn refs(m: &Module) -> Vec<Ref> {
    let mut out: Vec<Ref> = uses(m)
        .into_iter()
        .filter(|(p, _, _)| {
            p.first()
                .is_some_and(|s| s == "crate" || s == "super" || s == "self")
        })
        .map(|(segs, _, line)| Ref {
            text: format!("use {}", segs.join("::").trim_end_matches("::self")),
            segs,
            line,
        })
        .collect();
    // Inline paths outside `use` declarations.
    let mut text = m.text.clone();
    let mut from = 0;
    while let Some(at) = find_word(&text, "use", from) {
        let end = text[at..].find(';').map_or(text.len(), |n| at + n);
        text.replace_range(at..end, &" ".repeat(end - at));
        from = end;
    }
    for head in ["crate", "super", "self"] {
        let mut from = 0;
        while let Some(at) = find_word(&text, head, from) {
            from = at + head.len();
            let mut segs = vec![head.to_string()];
            let mut j = from;
            while text[j..].starts_with("::") {
                let id = ident_at(&text, j + 2);
                if id.is_empty() {
                    break;
                }
                segs.push(id.to_string());
                j += 2 + id.len();
            }
            if segs.len() > 1 && !(head == "self" && segs[1] == "Self") {
                out.push(Ref {
                    text: segs.join("::"),
                    segs,
                    line: m.line0 + line_of(&text, at) - 1,
                });
                from = j;
            }
        }
    }
    out
}

struct Graph {
    mods: Vec<Module>,
    index: BTreeMap<Vec<String>, usize>,
    /// Per module: the names it binds by `use` (name -> path, from the module).
    bindings: Vec<BTreeMap<String, Vec<String>>>,
}

impl Graph {
    fn new(mods: Vec<Module>) -> Self {
        let index = mods
            .iter()
            .enumerate()
            .map(|(i, m)| (m.path.clone(), i))
            .collect();
        let bindings = mods
            .iter()
            .map(|m| {
                uses(m)
                    .into_iter()
                    .filter_map(|(p, bound, _)| Some((bound?, p)))
                    .collect()
            })
            .collect();
        Graph {
            mods,
            index,
            bindings,
        }
    }

    /// The module that defines what `segs` names when written in module `from` (re-exports and
    /// imports followed), or `None` for a path outside the crate.
    fn resolve(&self, from: usize, segs: &[String], depth: usize) -> Option<usize> {
        let mut cur = self.mods[from].path.clone();
        let mut rest = segs;
        match rest.first().map(String::as_str) {
            Some("crate") => {
                cur.truncate(1);
                rest = &rest[1..];
            }
            Some("super") | Some("self") => {}
            Some(first) => {
                // A relative path: a child module, or a name bound by `use` in `from`.
                let mut child = cur.clone();
                child.push(first.to_string());
                if !self.index.contains_key(&child) {
                    let bound = self.bindings[from].get(first)?;
                    if depth > 8 || bound.as_slice() == segs {
                        return None;
                    }
                    let mut p = bound.clone();
                    p.extend(rest[1..].iter().cloned());
                    return self.resolve(from, &p, depth + 1);
                }
            }
            None => return None,
        }
        while let Some(s) = rest.first() {
            match s.as_str() {
                "super" => {
                    cur.pop();
                }
                "self" => {}
                name => {
                    let mut child = cur.clone();
                    child.push(name.to_string());
                    if self.index.contains_key(&child) {
                        cur = child;
                    } else {
                        break;
                    }
                }
            }
            rest = &rest[1..];
        }
        let at = *self.index.get(&cur)?;
        // An item named in `cur`: follow it if `cur` only imports or re-exports it.
        if let Some(item) = rest.first() {
            if let Some(bound) = self.bindings[at].get(item) {
                if depth < 8 && bound.first().is_some_and(|s| s != item) {
                    let mut p = bound.clone();
                    p.extend(rest[1..].iter().cloned());
                    if let Some(t) = self.resolve(at, &p, depth + 1) {
                        return Some(t);
                    }
                }
            }
        }
        Some(at)
    }

    /// Edges `a -> b` (b not a descendant of a) with the lines that make each.
    fn edges(&self) -> BTreeMap<(usize, usize), Vec<String>> {
        let mut e: BTreeMap<(usize, usize), Vec<String>> = BTreeMap::new();
        for (a, m) in self.mods.iter().enumerate() {
            for r in refs(m) {
                let Some(b) = self.resolve(a, &r.segs, 0) else {
                    continue;
                };
                let pb = &self.mods[b].path;
                if b == a || pb.starts_with(&m.path) {
                    continue;
                }
                e.entry((a, b)).or_default().push(format!(
                    "{}:{}: {}",
                    m.file.display(),
                    r.line,
                    r.text
                ));
            }
        }
        e
    }

    fn name(&self, i: usize) -> String {
        self.mods[i].path.join("::")
    }
}

/// Strongly connected components with more than one module (Tarjan).
fn cycles(n: usize, edges: &BTreeMap<(usize, usize), Vec<String>>) -> Vec<Vec<usize>> {
    let mut adj = vec![Vec::new(); n];
    for &(a, b) in edges.keys() {
        adj[a].push(b);
    }
    struct St {
        index: Vec<Option<usize>>,
        low: Vec<usize>,
        on: Vec<bool>,
        stack: Vec<usize>,
        next: usize,
        out: Vec<Vec<usize>>,
    }
    fn visit(v: usize, adj: &[Vec<usize>], st: &mut St) {
        st.index[v] = Some(st.next);
        st.low[v] = st.next;
        st.next += 1;
        st.stack.push(v);
        st.on[v] = true;
        for &w in &adj[v] {
            match st.index[w] {
                None => {
                    visit(w, adj, st);
                    st.low[v] = st.low[v].min(st.low[w]);
                }
                Some(iw) if st.on[w] => st.low[v] = st.low[v].min(iw),
                Some(_) => {}
            }
        }
        if Some(st.low[v]) == st.index[v] {
            let mut c = Vec::new();
            while let Some(w) = st.stack.pop() {
                st.on[w] = false;
                c.push(w);
                if w == v {
                    break;
                }
            }
            if c.len() > 1 {
                st.out.push(c);
            }
        }
    }
    let mut st = St {
        index: vec![None; n],
        low: vec![0; n],
        on: vec![false; n],
        stack: Vec::new(),
        next: 0,
        out: Vec::new(),
    };
    for v in 0..n {
        if st.index[v].is_none() {
            visit(v, &adj, &mut st);
        }
    }
    st.out
}

/// The cycles of the workspace's crates: each as its sorted module names and a description.
fn workspace_cycles() -> Vec<(Vec<String>, String)> {
    // Another checkout can be examined: POVINS_CYCLES_ROOT=/path/to/tree.
    let root = std::env::var_os("POVINS_CYCLES_ROOT")
        .map_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")), PathBuf::from);
    let mut found = Vec::new();
    for (name, lib) in CRATES {
        let g = Graph::new(read_crate(name, &root.join(lib)));
        let edges = g.edges();
        println!(
            "{name}: {} modules, {} import edges",
            g.mods.len(),
            edges.len()
        );
        for c in cycles(g.mods.len(), &edges) {
            let mut names: Vec<String> = c.iter().map(|&i| g.name(i)).collect();
            names.sort();
            let set: BTreeSet<usize> = c.iter().copied().collect();
            let mut why = String::new();
            for ((a, b), lines) in &edges {
                if set.contains(a) && set.contains(b) {
                    let _ = writeln!(why, "  {} -> {}", g.name(*a), g.name(*b));
                    for l in lines {
                        let _ = writeln!(why, "      {l}");
                    }
                }
            }
            found.push((names, why));
        }
    }
    found
}

#[test]
fn no_import_cycles_between_modules() {
    let found = workspace_cycles();
    let mut msg = String::new();
    for (names, why) in &found {
        let allowed = ALLOWED.iter().any(|a| a == names);
        let _ = write!(
            msg,
            "{}cycle: {}\n{why}",
            if allowed { "allowed " } else { "" },
            names.join(" <-> ")
        );
    }
    let bad = found
        .iter()
        .filter(|(n, _)| !ALLOWED.iter().any(|a| a == n))
        .count();
    assert!(bad == 0, "{bad} import cycles between modules:\n{msg}");
    println!("{msg}");
    for a in ALLOWED {
        assert!(
            found.iter().any(|(n, _)| n == a),
            "the allowed cycle {} is gone: remove it from ALLOWED",
            a.join(" <-> ")
        );
    }
}

/// The checker itself: a two-module cycle through an inline path and a brace tree is found, a
/// re-export is followed to the defining module, comments and test items do not count, and a
/// parent using its child is no cycle.
#[test]
fn checker_finds_a_cycle_and_ignores_what_is_not_one() {
    let dir = std::env::temp_dir().join(format!("povins-import-cycles-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.join("m")).expect("temp folder");
    let files = [
        ("lib.rs", "pub mod m;\npub mod z;\npub use z::Zed;\n"),
        (
            "m/mod.rs",
            "pub mod a;\npub mod b;\npub mod c;\npub use a::A;\nuse b::B;\n",
        ),
        (
            "m/a.rs",
            "use super::{c::C, b::B};\npub struct A;\n// super::b::B in a comment\n",
        ),
        (
            "m/b.rs",
            "pub struct B;\nfn f() { let _ = super::a::A; let _ = \"crate::m::c\"; }\n",
        ),
        (
            "m/c.rs",
            "use crate::Zed;\npub struct C;\n#[cfg(test)]\nmod tests { use super::super::a::A; }\n",
        ),
        ("z.rs", "pub struct Zed;\nuse crate::m::A;\n"),
    ];
    for (f, text) in files {
        std::fs::write(dir.join(f), text).expect("write a temp file");
    }
    let g = Graph::new(read_crate("k", &dir.join("lib.rs")));
    let edges = g.edges();
    let names: BTreeSet<(String, String)> =
        edges.keys().map(|&(a, b)| (g.name(a), g.name(b))).collect();
    let e = |a: &str, b: &str| (a.to_string(), b.to_string());
    let expected: BTreeSet<(String, String)> = [
        e("k::m::a", "k::m::c"),
        e("k::m::a", "k::m::b"),
        e("k::m::b", "k::m::a"),
        // `crate::Zed` is `k::z::Zed`, `crate::m::A` is `k::m::a::A`.
        e("k::m::c", "k::z"),
        e("k::z", "k::m::a"),
    ]
    .into_iter()
    .collect();
    assert_eq!(names, expected);
    let mut found: Vec<Vec<String>> = cycles(g.mods.len(), &edges)
        .into_iter()
        .map(|c| {
            let mut n: Vec<String> = c.iter().map(|&i| g.name(i)).collect();
            n.sort();
            n
        })
        .collect();
    found.sort();
    assert_eq!(
        found,
        vec![vec![
            "k::m::a".to_string(),
            "k::m::b".to_string(),
            "k::m::c".to_string(),
            "k::z".to_string()
        ]]
    );
    let _ = std::fs::remove_dir_all(&dir);
}
