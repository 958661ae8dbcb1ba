//! The logic crate's modules are layers: each may use only the layers below
//! it. The crates keep their own layering through Cargo (powerstep01 and
//! settings-store depend on nothing of the workspace; stepbridge-sim on
//! powerstep01 only); inside `bridge-logic` the compiler allows any
//! `crate::` path, so this test reads the sources and fails on an import
//! that runs up a layer or sideways.
//!
//! The layers, bottom up (the table in `firmware/logic/src/lib.rs`):
//! `powerstep` and `persist` (the re-exported crates), `rate`; `motion`,
//! `ioext`; `postep60`, `ext_space`; `transport`; `bridge`.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Each module and the modules it may import.
const ALLOWED: &[(&str, &[&str])] = &[
    ("rate", &[]),
    ("motion", &["powerstep"]),
    ("ioext", &["powerstep"]),
    ("postep60", &["powerstep", "persist", "motion", "ioext"]),
    ("ext_space", &["powerstep", "ioext"]),
    (
        "transport",
        &[
            "powerstep",
            "persist",
            "motion",
            "ioext",
            "postep60",
            "ext_space",
        ],
    ),
    (
        "bridge",
        &[
            "powerstep",
            "persist",
            "rate",
            "motion",
            "ioext",
            "postep60",
            "ext_space",
            "transport",
        ],
    ),
];

fn logic_src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../firmware/logic/src")
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The top-level module a file belongs to (`motion/axis/plan.rs` → motion).
fn module_of(path: &Path) -> Option<String> {
    let rel = path.strip_prefix(logic_src()).ok()?;
    let first = rel.components().next()?.as_os_str().to_str()?;
    let name = first.strip_suffix(".rs").unwrap_or(first);
    (name != "lib").then(|| name.to_string())
}

/// Every `crate::name` in `text` (comments included: a doc link up a
/// layer is a dependency of the reader's too).
fn crate_paths(text: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    let mut rest = text;
    while let Some(i) = rest.find("crate::") {
        let tail = &rest[i + "crate::".len()..];
        let name: String = tail
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
            .collect();
        if !name.is_empty() {
            out.insert(name);
        }
        rest = tail;
    }
    out
}

/// module → the modules its files name with `crate::`.
fn import_graph() -> BTreeMap<String, BTreeSet<String>> {
    let mut files = Vec::new();
    rust_files(&logic_src(), &mut files);
    let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for file in files {
        let Some(module) = module_of(&file) else {
            continue;
        };
        let text = std::fs::read_to_string(&file).unwrap();
        let used = graph.entry(module.clone()).or_default();
        for name in crate_paths(&text) {
            if name != module {
                used.insert(name);
            }
        }
    }
    graph
}

#[test]
fn no_module_of_the_logic_crate_imports_a_layer_above_it() {
    let graph = import_graph();
    assert!(graph.len() >= ALLOWED.len(), "found the modules: {graph:?}");
    for (module, used) in &graph {
        let allowed = ALLOWED
            .iter()
            .find(|(m, _)| m == module)
            .map(|(_, a)| *a)
            .unwrap_or_else(|| panic!("module {module} is in no layer: add it to ALLOWED"));
        for name in used {
            assert!(
                allowed.contains(&name.as_str()),
                "{module} imports crate::{name}, which is not below it"
            );
        }
    }
}

#[test]
fn the_import_graph_has_no_cycle() {
    let graph = import_graph();
    // Kahn: repeatedly remove a module that imports nothing left.
    let mut left: BTreeMap<&str, BTreeSet<&str>> = graph
        .iter()
        .map(|(m, u)| {
            let inner: BTreeSet<&str> = u
                .iter()
                .map(String::as_str)
                .filter(|n| graph.contains_key(*n))
                .collect();
            (m.as_str(), inner)
        })
        .collect();
    while let Some(leaf) = left.iter().find(|(_, u)| u.is_empty()).map(|(m, _)| *m) {
        left.remove(leaf);
        for used in left.values_mut() {
            used.remove(leaf);
        }
    }
    assert!(left.is_empty(), "a cycle among {:?}", left.keys());
}

#[test]
fn the_checker_sees_crate_paths_in_code_and_docs() {
    let names = crate_paths("use crate::motion::Axis;\n/// see [`crate::bridge::Bridge`]\n");
    assert_eq!(
        names.into_iter().collect::<Vec<_>>(),
        vec!["bridge".to_string(), "motion".to_string()]
    );
}
