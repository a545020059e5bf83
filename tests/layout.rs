//! The source layout shows the architecture: within each crate, no two modules import each other
//! through a circle (`a` uses `crate::b`, `b` uses `crate::a`, directly or through others). Test
//! code (`#[cfg(test)]` and below) and comments are not looked at; `super::` paths count; a root
//! re-export (`pub use body::{pose, ...}` in `lib.rs`) is followed to the module it names.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The crates' source folders, from the repository root.
const CRATES: [&str; 7] = [
    "model/src",
    "model/nn/src",
    "data-synth/src",
    "fitters/src",
    "train/src",
    "infer/src",
    "src",
];

fn rs_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("source folder") {
        let path = entry.expect("entry").path();
        if path.is_dir() {
            rs_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// `body/pose.rs` → `body::pose`, `body/mod.rs` → `body`, `lib.rs` → `` (the crate root).
fn module_name(root: &Path, file: &Path) -> String {
    let rel = file
        .strip_prefix(root)
        .expect("under the root")
        .with_extension("");
    let mut parts: Vec<String> = rel
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    if matches!(
        parts.last().map(String::as_str),
        Some("mod" | "lib" | "main")
    ) {
        parts.pop();
    }
    parts.join("::")
}

/// The text a module's imports are read from: up to its first `#[cfg(test)]`, without comments.
fn code(text: &str) -> String {
    let text = text.split("#[cfg(test)]").next().unwrap_or("");
    text.lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n")
}

/// `::`-separated paths that follow `prefix` in `text` (`crate::body::pose::Bounds` →
/// `["body", "pose", "Bounds"]`).
fn paths_after<'a>(text: &'a str, prefix: &str) -> Vec<Vec<&'a str>> {
    text.match_indices(prefix)
        .filter(|(i, _)| {
            // Not the tail of another identifier (`lfit_crate::`).
            !text[..*i]
                .chars()
                .next_back()
                .is_some_and(|c| c.is_alphanumeric() || c == '_')
        })
        .map(|(i, _)| {
            let rest = &text[i + prefix.len()..];
            let end = rest
                .find(|c: char| !(c.is_alphanumeric() || c == '_' || c == ':'))
                .unwrap_or(rest.len());
            rest[..end].split("::").filter(|s| !s.is_empty()).collect()
        })
        .collect()
}

/// Root re-exports of modules: `pub use body::{info, layout};` → `info` ↦ `body::info`.
fn root_aliases(lib: &str, modules: &BTreeSet<String>) -> BTreeMap<String, String> {
    let mut out = BTreeMap::new();
    for stmt in code(lib).split(';') {
        let Some(body) = stmt.trim().strip_prefix("pub use ") else {
            continue;
        };
        let (base, items) = match body.split_once("::{") {
            Some((b, items)) => (b.trim(), items.trim_end_matches('}')),
            None => match body.rsplit_once("::") {
                Some((b, item)) => (b.trim(), item),
                None => continue,
            },
        };
        for item in items.split(',') {
            let item = item.trim();
            let (name, alias) = match item.split_once(" as ") {
                Some((n, a)) => (n.trim(), a.trim()),
                None => (item, item),
            };
            let full = format!("{}::{name}", base.replace(' ', ""));
            if modules.contains(&full) {
                out.insert(alias.to_string(), full);
            }
        }
    }
    out
}

/// The modules each module imports (`crate::` and `super::` paths, longest module prefix).
fn imports(root: &Path) -> BTreeMap<String, BTreeSet<String>> {
    let mut files = Vec::new();
    rs_files(root, &mut files);
    let modules: BTreeMap<String, PathBuf> = files
        .iter()
        .map(|f| (module_name(root, f), f.clone()))
        .collect();
    let names: BTreeSet<String> = modules.keys().cloned().collect();
    let lib = ["lib.rs", "main.rs"]
        .iter()
        .find_map(|f| std::fs::read_to_string(root.join(f)).ok())
        .unwrap_or_default();
    let aliases = root_aliases(&lib, &names);
    let resolve = |parts: Vec<String>| -> Option<String> {
        let mut parts = parts;
        if let Some(full) = parts.first().and_then(|p| aliases.get(p)) {
            let mut v: Vec<String> = full.split("::").map(str::to_string).collect();
            v.extend(parts.drain(1..));
            parts = v;
        }
        (1..=parts.len())
            .rev()
            .map(|k| parts[..k].join("::"))
            .find(|c| names.contains(c))
    };
    let mut graph = BTreeMap::new();
    for (name, file) in &modules {
        let text = code(&std::fs::read_to_string(file).expect("source file"));
        let mut deps = BTreeSet::new();
        for p in paths_after(&text, "crate::") {
            deps.extend(resolve(p.iter().map(|s| s.to_string()).collect()));
        }
        // `super::` is the parent of this module (of its folder for a `mod.rs`).
        let mut parent: Vec<String> = name.split("::").map(str::to_string).collect();
        parent.pop();
        for p in paths_after(&text, "super::") {
            let mut full = parent.clone();
            full.extend(p.iter().map(|s| s.to_string()));
            deps.extend(resolve(full));
        }
        deps.remove(name);
        deps.remove("");
        graph.insert(name.clone(), deps);
    }
    graph
}

/// The import circles of `graph`: its strongly connected components of more than one module.
fn circles(graph: &BTreeMap<String, BTreeSet<String>>) -> Vec<Vec<String>> {
    struct Tarjan<'a> {
        graph: &'a BTreeMap<String, BTreeSet<String>>,
        index: BTreeMap<&'a str, usize>,
        low: BTreeMap<&'a str, usize>,
        stack: Vec<&'a str>,
        out: Vec<Vec<String>>,
    }
    impl<'a> Tarjan<'a> {
        fn visit(&mut self, v: &'a str) {
            let i = self.index.len();
            self.index.insert(v, i);
            self.low.insert(v, i);
            self.stack.push(v);
            let graph = self.graph;
            for w in graph.get(v).into_iter().flatten() {
                let w = w.as_str();
                if !self.index.contains_key(w) {
                    self.visit(w);
                    let lw = self.low[w];
                    let lv = self.low.get_mut(v).expect("visited");
                    *lv = (*lv).min(lw);
                } else if self.stack.contains(&w) {
                    let iw = self.index[w];
                    let lv = self.low.get_mut(v).expect("visited");
                    *lv = (*lv).min(iw);
                }
            }
            if self.low[v] == self.index[v] {
                let mut component = Vec::new();
                while let Some(w) = self.stack.pop() {
                    component.push(w.to_string());
                    if w == v {
                        break;
                    }
                }
                if component.len() > 1 {
                    component.sort();
                    self.out.push(component);
                }
            }
        }
    }
    let mut t = Tarjan {
        graph,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        out: Vec::new(),
    };
    for v in graph.keys() {
        if !t.index.contains_key(v.as_str()) {
            t.visit(v);
        }
    }
    t.out
}

#[test]
fn no_crate_has_an_import_circle() {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut found = Vec::new();
    for dir in CRATES {
        let graph = imports(&repo.join(dir));
        assert!(graph.len() > 1, "{dir}: no modules read");
        for c in circles(&graph) {
            let edges: Vec<String> = c
                .iter()
                .map(|m| {
                    let within: Vec<&String> = graph[m].iter().filter(|d| c.contains(d)).collect();
                    format!("{m} -> {within:?}")
                })
                .collect();
            found.push(format!("{dir}: {}", edges.join("; ")));
        }
    }
    assert!(found.is_empty(), "import circles:\n{}", found.join("\n"));
}

/// The checker itself: a circle through a root re-export and `super::` is found, test code and
/// comments are not read, and a chain without a circle passes.
#[test]
fn the_checker_finds_circles_and_only_circles() {
    let tmp = tempfile::tempdir().expect("tmp");
    let write = |p: &str, text: &str| {
        let path = tmp.path().join(p);
        std::fs::create_dir_all(path.parent().expect("parent")).expect("mkdir");
        std::fs::write(path, text).expect("write");
    };
    write(
        "lib.rs",
        "pub mod body;\npub mod energy;\npub use body::{pose, template};\n",
    );
    write("body/mod.rs", "pub mod pose;\npub mod template;\n");
    write("body/pose.rs", "use crate::template::Template;\n");
    write(
        "body/template.rs",
        "use super::layout;\n// crate::energy is mentioned here only\n",
    );
    write(
        "energy/mod.rs",
        "use crate::body::pose::Pose;\n#[cfg(test)]\nmod tests { use crate::energy; }\n",
    );
    let graph = imports(tmp.path());
    assert_eq!(
        graph["body::pose"],
        BTreeSet::from(["body::template".to_string()])
    );
    assert!(circles(&graph).is_empty(), "{graph:?}");
    write("body/template.rs", "use super::pose::Pose;\n");
    let c = circles(&imports(tmp.path()));
    assert_eq!(
        c,
        vec![vec!["body::pose".to_string(), "body::template".to_string()]]
    );
}
