//! The architecture, checked by the build's own test run (DESIGN.md's layout, ARCH):
//!
//! - the core (`strand-core`) depends only on the math, the trajectory generator, URDF text, the
//!   config derives and the wire contract, and its source names no clock, file, thread, network,
//!   printing or tracing;
//! - the wire contract (`strand-wire`) links no transport, and neither do the crates that use only it
//!   (the core, the offline job crate, the drivers' shared `strand-robot`): no iceoryx2 in their
//!   dependency trees (from `Cargo.lock`);
//! - the client crate (`strand-ipc`) depends on iceoryx2 and nothing of the controller;
//! - the offline job crate (`strand-job`) does not depend on the service crate;
//! - the service's folders (check, config, io, log) import each other without a loop;
//! - the tools' `bin/` mains are thin (the command line and the exit code; the work is in the tool's
//!   module), and no library code returns a bare `String` error (typed errors; text at the edge).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The `[dependencies]` names of a crate's manifest.
fn dependencies(manifest: &Path) -> BTreeSet<String> {
    let text = std::fs::read_to_string(manifest).unwrap();
    let doc: toml::Table = text.parse().unwrap();
    doc.get("dependencies").and_then(|d| d.as_table()).map(|t| t.keys().cloned().collect()).unwrap_or_default()
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

#[test]
fn the_core_depends_on_nothing_of_the_shell() {
    let allowed: BTreeSet<String> = ["nalgebra", "urdf-rs", "libm", "serde", "thiserror", "rsruckig", "strand-wire", "strand-limits"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let deps = dependencies(&root().join("src/core/Cargo.toml"));
    let extra: Vec<_> = deps.difference(&allowed).collect();
    assert!(extra.is_empty(), "strand-core may not depend on {extra:?}: the core does no I/O");
    let mut files = Vec::new();
    rust_files(&root().join("src/core"), &mut files);
    assert!(files.len() > 10, "found the core's sources");
    let forbidden = [
        "std::fs",
        "std::io",
        "std::net",
        "std::thread",
        "std::time",
        "std::env",
        "std::process",
        "Instant",
        "SystemTime",
        "println!",
        "eprintln!",
        "print!",
        "tracing",
        "iceoryx2",
        "mcap",
    ];
    let mut found = Vec::new();
    for f in &files {
        let text = std::fs::read_to_string(f).unwrap();
        for (n, line) in text.lines().enumerate() {
            let code = line.split("//").next().unwrap_or("");
            for word in forbidden {
                if code.contains(word) {
                    found.push(format!("{}:{}: {word}", f.strip_prefix(root()).unwrap().display(), n + 1));
                }
            }
        }
    }
    assert!(found.is_empty(), "the core names I/O, a clock or printing:\n{}", found.join("\n"));
}

/// Every package `name` depends on, directly or not, by `Cargo.lock`.
fn locked_tree(name: &str) -> BTreeSet<String> {
    let lock: toml::Table = std::fs::read_to_string(root().join("Cargo.lock")).unwrap().parse().unwrap();
    let packages = lock["package"].as_array().unwrap();
    let deps_of = |n: &str| -> Vec<String> {
        packages
            .iter()
            .filter(|p| p["name"].as_str() == Some(n))
            .flat_map(|p| p.get("dependencies").and_then(|d| d.as_array()).cloned().unwrap_or_default())
            .map(|d| d.as_str().unwrap().split(' ').next().unwrap().to_string())
            .collect()
    };
    let (mut seen, mut todo) = (BTreeSet::new(), vec![name.to_string()]);
    while let Some(n) = todo.pop() {
        for d in deps_of(&n) {
            if seen.insert(d.clone()) {
                todo.push(d);
            }
        }
    }
    seen
}

#[test]
fn the_wire_contract_and_the_crates_on_it_link_no_transport() {
    let wire = dependencies(&root().join("wire/Cargo.toml"));
    let allowed: BTreeSet<String> = ["iceoryx2-bb-derive-macros", "iceoryx2-bb-elementary-traits"].iter().map(|s| s.to_string()).collect();
    assert!(wire.is_subset(&allowed), "strand-wire depends on {:?}: the types only", wire.difference(&allowed).collect::<Vec<_>>());
    // What every robot driver shares: on the wire types, not on the service or a transport.
    let robot = dependencies(&root().join("tools/robot/Cargo.toml"));
    let allowed: BTreeSet<String> = ["strand-wire", "strand-limits", "thiserror", "serde"].iter().map(|s| s.to_string()).collect();
    assert!(robot.is_subset(&allowed), "strand-robot depends on {:?}", robot.difference(&allowed).collect::<Vec<_>>());
    // The joint limits both the controller and the drivers' guard keep: on nothing at all.
    assert!(dependencies(&root().join("limits/Cargo.toml")).is_empty(), "strand-limits depends on nothing");
    for name in ["strand-wire", "strand-limits", "strand-core", "strand-job", "strand-robot"] {
        let tree = locked_tree(name);
        assert!(
            tree.contains("nalgebra") || name == "strand-wire" || name == "strand-limits" || name == "strand-robot",
            "{name}'s tree read from Cargo.lock: {tree:?}"
        );
        for transport in ["iceoryx2", "iceoryx2-cal", "strand-ipc"] {
            assert!(!tree.contains(transport), "{name} links {transport}");
        }
    }
}

#[test]
fn the_client_crate_does_not_link_the_controller() {
    let deps = dependencies(&root().join("ipc/Cargo.toml"));
    for name in ["strand", "strand-core", "strand-job", "nalgebra", "rsruckig", "mcap"] {
        assert!(!deps.contains(name), "strand-ipc depends on {name}");
    }
    assert!(deps.contains("iceoryx2"), "strand-ipc opens the iceoryx2 ports itself");
    let job = dependencies(&root().join("tools/job/Cargo.toml"));
    assert!(!job.contains("strand"), "strand-job depends on the service crate");
}

#[test]
fn the_service_folders_import_each_other_without_a_loop() {
    let modules = ["check", "config", "io", "log"];
    let mut graph: BTreeMap<&str, BTreeSet<&str>> = BTreeMap::new();
    for m in modules {
        let mut files = Vec::new();
        let dir = root().join("src").join(m);
        if dir.is_dir() {
            rust_files(&dir, &mut files);
        }
        let file = root().join("src").join(format!("{m}.rs"));
        if file.exists() {
            files.push(file);
        }
        assert!(!files.is_empty(), "src/{m}");
        let uses = graph.entry(m).or_default();
        for f in files {
            let text = std::fs::read_to_string(&f).unwrap();
            for other in modules {
                if other != m && text.contains(&format!("crate::{other}::")) {
                    uses.insert(other);
                }
            }
        }
    }
    // Depth-first search for a cycle.
    fn visit<'a>(m: &'a str, graph: &BTreeMap<&'a str, BTreeSet<&'a str>>, stack: &mut Vec<&'a str>, done: &mut BTreeSet<&'a str>) {
        if let Some(i) = stack.iter().position(|s| *s == m) {
            panic!("import loop: {} -> {m}", stack[i..].join(" -> "));
        }
        if done.contains(m) {
            return;
        }
        stack.push(m);
        for next in &graph[m] {
            visit(next, graph, stack, done);
        }
        stack.pop();
        done.insert(m);
    }
    let mut done = BTreeSet::new();
    for m in modules {
        visit(m, &graph, &mut Vec::new(), &mut done);
    }
}

#[test]
fn the_tool_mains_are_thin() {
    let mut mains = Vec::new();
    rust_files(&root().join("tools/src/bin"), &mut mains);
    assert!(mains.len() >= 7, "{mains:?}");
    for main in mains {
        let text = std::fs::read_to_string(&main).unwrap();
        let code = text.split("#[cfg(test)]").next().unwrap_or("");
        let functions = code.lines().filter(|l| l.starts_with("fn ") || l.starts_with("pub fn ")).count();
        if main.file_name().is_some_and(|n| n == "args.rs") {
            // Beside a main: clap types and their `From` into the tool's options, nothing else.
            assert_eq!(functions, 0, "{}: a main's args.rs holds declarations and conversions only", main.display());
            continue;
        }
        // A main holds its clap types, the mapping to the tool's options and the exit codes: a
        // screen or four. More means the tool's work has crept back into the binary.
        let lines = text.lines().count();
        assert!(lines <= 250, "{}: {lines} lines; move the work into the tool's module under tools/src/", main.display());
        assert!(functions <= 4, "{}: {functions} functions; a main parses, calls the tool and reports", main.display());
    }
}

#[test]
fn clap_stays_in_the_mains() {
    // The tools' modules take plain options structs; only `bin/` knows the command line.
    let mut files = Vec::new();
    rust_files(&root().join("tools/src"), &mut files);
    let bin = root().join("tools/src/bin");
    let offenders: Vec<String> = files
        .iter()
        .filter(|f| !f.starts_with(&bin))
        .filter(|f| std::fs::read_to_string(f).unwrap().contains("clap::"))
        .map(|f| f.display().to_string())
        .collect();
    assert!(offenders.is_empty(), "clap outside tools/src/bin: {offenders:?}");
}

#[test]
fn library_code_returns_typed_errors() {
    // `Result<_, String>` in a public signature of a library crate (the core, the client crate, the
    // job crate, the service's library and the tools' modules) hides what failed from the caller.
    let mut files = Vec::new();
    for dir in [
        "src/core",
        "wire/src",
        "ipc/src",
        "tools/job/src",
        "src/check",
        "src/config",
        "src/io",
        "src/log",
        "tools/src",
        "tools/driver/src",
    ] {
        rust_files(&root().join(dir), &mut files);
    }
    files.extend(["src/lib.rs", "src/config.rs"].map(|f| root().join(f)));
    let mut offenders = Vec::new();
    for file in files.iter().filter(|f| !f.starts_with(root().join("tools/src/bin")) && !f.starts_with(root().join("tools/driver/src/bin")))
    {
        let text = std::fs::read_to_string(file).unwrap();
        let code = text.split("#[cfg(test)]").next().unwrap_or("");
        for (n, line) in code.lines().enumerate() {
            let line = line.trim_start();
            if line.starts_with("pub fn ") && line.contains(", String>") && line.contains("Result<") {
                offenders.push(format!("{}:{}: {line}", file.display(), n + 1));
            }
        }
    }
    assert!(offenders.is_empty(), "public functions with a String error:\n{}", offenders.join("\n"));
}
