//! The crate's layers, read from its own sources: which top-level modules each module
//! imports (`crate::X` outside comments). Data flows one way (`src/lib.rs`), so the leaves
//! stay leaves and only the node and the CLI reach into `node`.

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::{Path, PathBuf};

/// Top-level library modules and the crate modules their code refers to.
fn imports() -> BTreeMap<String, BTreeSet<String>> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut table = BTreeMap::new();
    for entry in fs::read_dir(&src).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_stem().unwrap().to_string_lossy().into_owned();
        if matches!(name.as_str(), "lib" | "main" | "cli") {
            continue;
        }
        let mut files = Vec::new();
        collect_rust_files(&path, &mut files);
        let mut used = BTreeSet::new();
        for file in files {
            for line in fs::read_to_string(&file).unwrap().lines() {
                let code = line.trim_start();
                if code.starts_with("//") {
                    continue;
                }
                for (at, _) in code.match_indices("crate::") {
                    let rest = &code[at + "crate::".len()..];
                    let module: String = rest
                        .chars()
                        .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                        .collect();
                    if !module.is_empty() && module != name {
                        used.insert(module);
                    }
                }
            }
        }
        table.insert(name, used);
    }
    table
}

fn collect_rust_files(path: &Path, out: &mut Vec<PathBuf>) {
    if path.is_dir() {
        for entry in fs::read_dir(path).unwrap() {
            collect_rust_files(&entry.unwrap().path(), out);
        }
    } else if path.extension().is_some_and(|e| e == "rs") {
        out.push(path.to_path_buf());
    }
}

fn imported_by(table: &BTreeMap<String, BTreeSet<String>>, module: &str) -> BTreeSet<String> {
    table
        .get(module)
        .unwrap_or_else(|| panic!("no module `{module}` under src/"))
        .clone()
}

fn set(names: &[&str]) -> BTreeSet<String> {
    names.iter().map(|s| s.to_string()).collect()
}

#[test]
fn leaf_modules_import_only_their_helpers() {
    let table = imports();
    assert_eq!(imported_by(&table, "body"), set(&[]), "body is a leaf");
    assert_eq!(
        imported_by(&table, "transport"),
        set(&[]),
        "transport is a leaf"
    );
    assert_eq!(
        imported_by(&table, "tracking"),
        set(&[]),
        "tracking (person ids from boxes and looks) is a leaf"
    );
    assert_eq!(
        imported_by(&table, "picture"),
        set(&[]),
        "picture (captions) is a leaf"
    );
    assert!(
        imported_by(&table, "kernels").is_subset(&set(&["simd", "testing"])),
        "the CPU kernels import only the SIMD and test helpers: {:?}",
        imported_by(&table, "kernels")
    );
    assert!(
        imported_by(&table, "model").is_subset(&set(&["kernels", "simd", "testing"])),
        "model imports only the kernels and the SIMD and test helpers: {:?}",
        imported_by(&table, "model")
    );
    assert!(
        imported_by(&table, "perception").is_subset(&set(&["body", "kernels", "simd", "testing"])),
        "perception imports only body, the kernels and the helpers, never the avatar network: {:?}",
        imported_by(&table, "perception")
    );
    assert!(
        imported_by(&table, "splat").is_subset(&set(&["body", "simd", "testing"])),
        "splat imports only body and the helpers: {:?}",
        imported_by(&table, "splat")
    );
}

#[test]
fn only_the_node_reaches_into_the_node() {
    let table = imports();
    let offenders: Vec<&String> = table
        .iter()
        .filter(|(module, used)| module.as_str() != "node" && used.contains("node"))
        .map(|(module, _)| module)
        .collect();
    assert!(
        offenders.is_empty(),
        "modules importing node: {offenders:?}"
    );
}

#[test]
fn synchronous_layers_never_import_the_outputs() {
    let table = imports();
    for module in ["reconstruct", "body", "model", "splat", "avatar"] {
        let used = imported_by(&table, module);
        for outer in ["node", "transport", "bag"] {
            assert!(!used.contains(outer), "{module} imports {outer}");
        }
    }
}

/// The pipeline's modules a file under `src/node/pipeline/person/` refers to: `super::X` from
/// the person's `mod.rs`, `super::super::X` from its submodules, `crate::node::pipeline::X`
/// from any of them.
fn pipeline_modules_used_by_the_person() -> BTreeSet<String> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/node/pipeline/person");
    let mut files = Vec::new();
    collect_rust_files(&dir, &mut files);
    assert!(
        !files.is_empty(),
        "no person module under {}",
        dir.display()
    );
    let mut used = BTreeSet::new();
    for file in files {
        let up = if file.file_name().is_some_and(|n| n == "mod.rs") {
            "super::"
        } else {
            "super::super::"
        };
        for line in fs::read_to_string(&file).unwrap().lines() {
            let code = line.trim_start();
            if code.starts_with("//") {
                continue;
            }
            for prefix in [up, "crate::node::pipeline::"] {
                for (at, _) in code.match_indices(prefix) {
                    let before = &code[..at];
                    if prefix == "super::" && before.ends_with("super::") {
                        continue;
                    }
                    let module: String = code[at + prefix.len()..]
                        .chars()
                        .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                        .collect();
                    used.insert(module);
                }
            }
        }
    }
    used
}

/// A person's state and steps sit below the pipeline's dispatcher: they use the pipeline's
/// leaf helpers (rendering, calibration) and nothing of the rooms that route to them (intake,
/// perception, people, publishing), so a frame's path goes one way.
#[test]
fn the_person_does_not_reach_back_into_the_dispatcher() {
    let used = pipeline_modules_used_by_the_person();
    assert!(used.contains("render"), "the scan found {used:?}");
    assert!(
        used.is_subset(&set(&["render", "calibration"])),
        "the person module uses the pipeline's {used:?}"
    );
}
