//! The shape of the source tree, checked: no module of the harness crates
//! (tgs-dataset, tgs-train, tgs) depends on a module that depends back on
//! it, and no Rust file grows past 500 lines unless its first lines say
//! why. Reads the sources as text; needs no device.
//!
//! A module's dependencies are the modules its `crate::a::b` and `super::`
//! paths name (the longest prefix that is a module of the crate), and for
//! a `mod.rs` / `lib.rs` its `use child::...` lines; a module never
//! depends on its own ancestors (they declare it).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

type Module = Vec<String>;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())).map(|e| e.unwrap().path()).collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            if p.file_name().is_some_and(|n| n != "target") {
                rust_files(&p, out);
            }
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

/// The module a source file of the crate rooted at `src` is.
fn module_of(src: &Path, file: &Path) -> Module {
    let rel = file.strip_prefix(src).unwrap().with_extension("");
    let mut m: Module = rel.iter().map(|c| c.to_string_lossy().into_owned()).collect();
    if matches!(m.last().map(String::as_str), Some("mod" | "lib" | "main")) {
        m.pop();
    }
    m
}

/// Source text without `//` comments (doc comments name paths in prose).
fn code(text: &str) -> String {
    text.lines().map(|l| l.split("//").next().unwrap_or("")).collect::<Vec<_>>().join("\n")
}

/// The longest prefix of `path` that is a module in `mods`.
fn resolve(mods: &BTreeSet<Module>, path: &[String]) -> Option<Module> {
    (0..=path.len()).rev().map(|k| path[..k].to_vec()).find(|m| mods.contains(m))
}

/// Every `::`-joined path starting at `at` in `s` (identifiers only; a
/// `{a, b}` group gives one path per member).
fn paths_after(s: &str, at: usize) -> Vec<Vec<String>> {
    let rest = &s[at..];
    let mut head: Vec<String> = Vec::new();
    let mut i = 0;
    let b = rest.as_bytes();
    loop {
        let start = i;
        while i < b.len() && (b[i].is_ascii_alphanumeric() || b[i] == b'_') {
            i += 1;
        }
        if i > start {
            head.push(rest[start..i].to_string());
        }
        if rest[i..].starts_with("::") {
            i += 2;
            if rest[i..].starts_with('{') {
                let end = rest[i..].find('}').map(|e| i + e).unwrap_or(rest.len());
                return rest[i + 1..end]
                    .split(',')
                    .map(|item| {
                        head.iter()
                            .cloned()
                            .chain(item.trim().split("::").map(|x| x.trim().to_string()).filter(|x| !x.is_empty() && x.chars().all(|c| c.is_alphanumeric() || c == '_')))
                            .collect()
                    })
                    .collect();
            }
            continue;
        }
        return vec![head];
    }
}

fn graph(src: &Path) -> BTreeMap<Module, BTreeSet<Module>> {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    let mods: BTreeSet<Module> = files.iter().map(|f| module_of(src, f)).collect();
    let mut g: BTreeMap<Module, BTreeSet<Module>> = BTreeMap::new();
    for f in &files {
        let m = module_of(src, f);
        let is_dir = matches!(f.file_stem().and_then(|s| s.to_str()), Some("mod" | "lib" | "main"));
        let text = code(&std::fs::read_to_string(f).unwrap());
        let mut deps = BTreeSet::new();
        let mut add = |path: Vec<String>| {
            if let Some(t) = resolve(&mods, &path) {
                if t != m && !m.starts_with(&t) {
                    deps.insert(t);
                }
            }
        };
        for (at, _) in text.match_indices("crate::") {
            for p in paths_after(&text, at + "crate::".len()) {
                add(p);
            }
        }
        for (at, _) in text.match_indices("super::") {
            if text[..at].ends_with("super::") {
                continue;
            }
            let mut ups = 1;
            let mut from = at + "super::".len();
            while text[from..].starts_with("super::") {
                ups += 1;
                from += "super::".len();
            }
            // A file's parent is its module's parent; a mod.rs's is too.
            let base: Module = m[..m.len().saturating_sub(ups)].to_vec();
            for p in paths_after(&text, from) {
                add(base.iter().cloned().chain(p).collect());
            }
        }
        if is_dir {
            for (at, _) in text.match_indices("use ") {
                if at > 0 && text.as_bytes()[at - 1].is_ascii_alphanumeric() {
                    continue;
                }
                for p in paths_after(&text, at + 4) {
                    if p.first().is_some_and(|h| !["crate", "super", "self", "std"].contains(&h.as_str())) {
                        add(m.iter().cloned().chain(p).collect());
                    }
                }
            }
        }
        g.insert(m, deps);
    }
    g
}

/// Strongly connected components of more than one module (Tarjan).
fn cycles(g: &BTreeMap<Module, BTreeSet<Module>>) -> Vec<Vec<Module>> {
    struct T<'a> {
        g: &'a BTreeMap<Module, BTreeSet<Module>>,
        index: BTreeMap<&'a Module, usize>,
        low: BTreeMap<&'a Module, usize>,
        stack: Vec<&'a Module>,
        on: BTreeSet<&'a Module>,
        out: Vec<Vec<Module>>,
    }
    fn visit<'a>(t: &mut T<'a>, v: &'a Module) {
        let i = t.index.len();
        t.index.insert(v, i);
        t.low.insert(v, i);
        t.stack.push(v);
        t.on.insert(v);
        for w in &t.g[v] {
            let Some((w, _)) = t.g.get_key_value(w) else { continue };
            if !t.index.contains_key(w) {
                visit(t, w);
                let lw = t.low[w];
                let lv = t.low.get_mut(v).unwrap();
                *lv = (*lv).min(lw);
            } else if t.on.contains(w) {
                let iw = t.index[w];
                let lv = t.low.get_mut(v).unwrap();
                *lv = (*lv).min(iw);
            }
        }
        if t.low[v] == t.index[v] {
            let mut comp = Vec::new();
            loop {
                let w = t.stack.pop().unwrap();
                t.on.remove(w);
                comp.push(w.clone());
                if w == v {
                    break;
                }
            }
            if comp.len() > 1 {
                t.out.push(comp);
            }
        }
    }
    let mut t = T { g, index: BTreeMap::new(), low: BTreeMap::new(), stack: Vec::new(), on: BTreeSet::new(), out: Vec::new() };
    for v in g.keys() {
        if !t.index.contains_key(v) {
            visit(&mut t, v);
        }
    }
    t.out
}

#[test]
fn harness_crates_have_no_module_cycles() {
    for dir in ["harness/dataset/src", "harness/train/src", "harness/src"] {
        let g = graph(&root().join(dir));
        assert!(g.len() > 5, "{dir}: only {} modules found", g.len());
        let found: Vec<String> = cycles(&g).iter().map(|c| c.iter().map(|m| m.join("::")).collect::<Vec<_>>().join(" <-> ")).collect();
        assert!(found.is_empty(), "{dir}: module cycles:\n{}", found.join("\n"));
    }
}

#[test]
fn the_cycle_finder_sees_a_cycle() {
    // Two files that name each other, one through `crate::`, one through
    // `super::`, and a mod.rs that uses its child: a cycle of two, and
    // the child's use of its parent is not a dependency.
    let dir = std::env::temp_dir().join(format!("tgs-structure-{}", std::process::id()));
    std::fs::create_dir_all(dir.join("a")).unwrap();
    std::fs::write(dir.join("lib.rs"), "pub mod a;\npub mod b;\n").unwrap();
    std::fs::write(dir.join("a/mod.rs"), "mod x;\nuse x::Thing;\n").unwrap();
    std::fs::write(dir.join("a/x.rs"), "use crate::b::Other; // crate::c::nothing\npub struct Thing;\n").unwrap();
    std::fs::write(dir.join("b.rs"), "use super::a::x::{Thing, self};\npub struct Other;\n").unwrap();
    let g = graph(&dir);
    let c = cycles(&g);
    std::fs::remove_dir_all(&dir).unwrap();
    let want = vec![vec!["a".to_string(), "x".to_string()], vec!["b".to_string()]];
    assert_eq!(c.len(), 1, "{g:?}");
    let mut got = c[0].clone();
    got.sort();
    assert_eq!(got, want, "{g:?}");
}

#[test]
fn rust_files_stay_under_500_lines_or_say_why() {
    let mut files = Vec::new();
    for dir in ["engine", "pipelines", "harness", "tests", "perf"] {
        rust_files(&root().join(dir), &mut files);
    }
    assert!(files.len() > 50, "only {} Rust files found", files.len());
    let long: Vec<String> = files
        .iter()
        .filter_map(|f| {
            let text = std::fs::read_to_string(f).unwrap();
            let lines = text.lines().count();
            let head: String = text.lines().take(15).collect::<Vec<_>>().join("\n");
            (lines > 500 && !head.contains("Longer than 500 lines on purpose")).then(|| format!("{} ({lines} lines)", f.strip_prefix(root()).unwrap().display()))
        })
        .collect();
    assert!(long.is_empty(), "files over 500 lines with no reason at their top (\"Longer than 500 lines on purpose: ...\"):\n{}", long.join("\n"));
}

/// Every kernel lies in a folder named for its family (glsl/raster/,
/// glsl/sort/, ...), as pipelines/src/ does; only shared includes
/// (`*.glsl`) may lie at the top.
#[test]
fn kernels_lie_in_family_folders() {
    let glsl = root().join("glsl");
    let flat: Vec<String> = std::fs::read_dir(&glsl)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "comp"))
        .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    assert!(flat.is_empty(), "kernels outside a family folder in glsl/: {flat:?}");
    let families = std::fs::read_dir(&glsl).unwrap().filter(|e| e.as_ref().unwrap().path().is_dir()).count();
    assert!(families >= 10, "only {families} family folders in glsl/");
}
