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
//! - in every crate of the workspace, the modules under each module import each other without a
//!   loop (a child may use its parent's items, and a parent its children's);
//! - the tools' mains are thin (the command line and the exit code; the work is in the tool's
//!   library), and no library code returns a bare `String` error (typed errors; text at the edge).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use strand_testkit::root;

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

/// Every crate's folder and source folder (`src/`, or the folder itself for the core), from the
/// workspace's members.
fn crate_sources() -> Vec<(PathBuf, PathBuf)> {
    let doc: toml::Table = std::fs::read_to_string(root().join("Cargo.toml")).unwrap().parse().unwrap();
    let members = doc["workspace"]["members"].as_array().unwrap();
    let dirs: Vec<(PathBuf, PathBuf)> = members
        .iter()
        .map(|m| root().join(m.as_str().unwrap()))
        .map(|d| if d.join("src").is_dir() { (d.clone(), d.join("src")) } else { (d.clone(), d) })
        .collect();
    assert!(dirs.len() >= 18 && dirs.iter().all(|(_, s)| s.join("lib.rs").is_file() || s.join("main.rs").is_file()), "{dirs:?}");
    dirs
}

/// The module path (`a::b`) of a library source file under `src` (None for a binary's files and
/// for the files of another member inside this one's folder, as the core's inside the service's).
fn module_of(member: &Path, src: &Path, file: &Path, members: &[(PathBuf, PathBuf)]) -> Option<Vec<String>> {
    if members.iter().any(|(m, _)| m != member && m.starts_with(member) && file.starts_with(m)) {
        return None;
    }
    let rel = file.strip_prefix(src).ok()?;
    let mut parts: Vec<String> = rel.iter().map(|c| c.to_string_lossy().trim_end_matches(".rs").to_string()).collect();
    if parts.first().is_some_and(|p| p == "bin") || parts == ["main"] {
        return None;
    }
    if parts.last().is_some_and(|l| l == "mod" || l == "lib") {
        parts.pop();
    }
    Some(parts)
}

/// The modules a file's code names (`crate::a::b::…`, `super::…`), as module paths (the longest
/// prefix that is a module of the crate).
fn references(text: &str, here: &[String], is_dir_module: bool, modules: &BTreeSet<Vec<String>>) -> BTreeSet<Vec<String>> {
    let mut out = BTreeSet::new();
    let code: String =
        text.split("#[cfg(test)]").next().unwrap_or("").lines().map(|l| l.split("//").next().unwrap_or("")).collect::<Vec<_>>().join("\n");
    let bytes = code.as_bytes();
    let ident = |i: usize| bytes[i].is_ascii_alphanumeric() || bytes[i] == b'_';
    for (start, word) in [("crate::", true), ("super::", false)] {
        let mut from = 0;
        while let Some(k) = code[from..].find(start) {
            let at = from + k;
            from = at + start.len();
            if at > 0 && (ident(at - 1) || bytes[at - 1] == b':') {
                continue;
            }
            // The path after the prefix: identifiers joined by `::`, and `super::super::…`.
            let mut path: Vec<String> = if word {
                Vec::new()
            } else {
                // A file module's parent is its folder's module; a folder module's (mod.rs) is one up.
                let mut p = here.to_vec();
                if !is_dir_module || !p.is_empty() {
                    p.pop();
                }
                p
            };
            let mut rest = &code[at + start.len()..];
            loop {
                let len = rest.bytes().take_while(|b| b.is_ascii_alphanumeric() || *b == b'_').count();
                if len == 0 {
                    break;
                }
                let name = &rest[..len];
                if name == "super" {
                    path.pop();
                } else {
                    path.push(name.to_string());
                }
                rest = &rest[len..];
                match rest.strip_prefix("::") {
                    Some(r) => rest = r,
                    None => break,
                }
            }
            while !path.is_empty() && !modules.contains(&path) {
                path.pop();
            }
            out.insert(path);
        }
    }
    out
}

#[test]
fn no_crate_has_an_import_loop() {
    let sources = crate_sources();
    let mut loops = Vec::new();
    for (member, src) in &sources {
        let mut files = Vec::new();
        rust_files(src, &mut files);
        let mut modules: BTreeMap<Vec<String>, Vec<PathBuf>> = BTreeMap::new();
        for f in &files {
            if let Some(m) = module_of(member, src, f, &sources) {
                modules.entry(m).or_default().push(f.clone());
            }
        }
        let names: BTreeSet<Vec<String>> = modules.keys().cloned().collect();
        // Edges between siblings: a reference from `p::a::…` to `p::b::…` is `a -> b` under `p`.
        let mut graph: BTreeMap<(Vec<String>, String), BTreeSet<String>> = BTreeMap::new();
        for (m, fs) in &modules {
            for f in fs {
                let dir_module = f.file_name().is_some_and(|n| n == "mod.rs" || n == "lib.rs");
                for r in references(&std::fs::read_to_string(f).unwrap(), m, dir_module, &names) {
                    let common = m.iter().zip(&r).take_while(|(a, b)| a == b).count();
                    if common < m.len() && common < r.len() {
                        let parent = m[..common].to_vec();
                        graph.entry((parent.clone(), m[common].clone())).or_default().insert(r[common].clone());
                    }
                }
            }
        }
        // Depth-first search for a cycle among each module's children.
        fn visit(
            parent: &[String],
            m: &str,
            graph: &BTreeMap<(Vec<String>, String), BTreeSet<String>>,
            stack: &mut Vec<String>,
            done: &mut BTreeSet<String>,
            found: &mut Vec<String>,
        ) {
            if let Some(i) = stack.iter().position(|s| s == m) {
                found.push(format!(
                    "{}{} -> {m}",
                    if parent.is_empty() { String::new() } else { parent.join("::") + ": " },
                    stack[i..].join(" -> ")
                ));
                return;
            }
            if done.contains(m) {
                return;
            }
            stack.push(m.to_string());
            if let Some(next) = graph.get(&(parent.to_vec(), m.to_string())) {
                for n in next {
                    visit(parent, n, graph, stack, done, found);
                }
            }
            stack.pop();
            done.insert(m.to_string());
        }
        let parents: BTreeSet<Vec<String>> = graph.keys().map(|(p, _)| p.clone()).collect();
        for parent in parents {
            let mut done = BTreeSet::new();
            let mut found = Vec::new();
            for ((p, m), _) in graph.range((parent.clone(), String::new())..) {
                if *p != parent {
                    break;
                }
                visit(&parent, m, &graph, &mut Vec::new(), &mut done, &mut found);
            }
            loops.extend(found.into_iter().map(|l| format!("{}: {l}", src.strip_prefix(root()).unwrap().display())));
        }
    }
    assert!(loops.is_empty(), "import loops:\n{}", loops.join("\n"));
}

/// The tools' crates: one job each, a binary (or two) over a library.
const TOOL_CRATES: [&str; 8] = ["feed", "replay", "kin", "plan", "sim", "bench", "natnet", "mcu"];

/// A tool crate's mains: `src/main.rs` and everything under `src/bin/`.
fn tool_mains() -> Vec<PathBuf> {
    let mut mains = Vec::new();
    for t in TOOL_CRATES {
        let src = root().join("tools").join(t).join("src");
        if src.join("main.rs").is_file() {
            mains.push(src.join("main.rs"));
        }
        if src.join("bin").is_dir() {
            rust_files(&src.join("bin"), &mut mains);
        }
    }
    mains
}

#[test]
fn the_tool_mains_are_thin() {
    let mains = tool_mains();
    assert!(mains.len() >= 9, "{mains:?}");
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
        assert!(lines <= 250, "{}: {lines} lines; move the work into the tool's library", main.display());
        assert!(functions <= 4, "{}: {functions} functions; a main parses, calls the tool and reports", main.display());
    }
}

#[test]
fn clap_stays_in_the_mains() {
    // The tools' libraries take plain options structs; only their mains know the command line.
    let mains = tool_mains();
    let mut files = Vec::new();
    for t in TOOL_CRATES.iter().chain(&["cli"]) {
        rust_files(&root().join("tools").join(t).join("src"), &mut files);
    }
    let offenders: Vec<String> = files
        .iter()
        .filter(|f| !mains.contains(f))
        .filter(|f| std::fs::read_to_string(f).unwrap().contains("clap::"))
        .map(|f| f.display().to_string())
        .collect();
    assert!(offenders.is_empty(), "clap outside the tools' mains: {offenders:?}");
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
        "tools/cli/src",
        "tools/feed/src",
        "tools/replay/src",
        "tools/kin/src",
        "tools/plan/src",
        "tools/sim/src",
        "tools/bench/src",
        "tools/driver/src",
        "tools/natnet/src",
        "tools/calibrate/src",
        "tools/mcu/src",
    ] {
        rust_files(&root().join(dir), &mut files);
    }
    files.extend(["src/lib.rs", "src/config.rs", "src/calibrate.rs"].map(|f| root().join(f)));
    let mains = tool_mains();
    let mut offenders = Vec::new();
    for file in files.iter().filter(|f| !mains.contains(f) && !f.starts_with(root().join("tools/driver/src/bin"))) {
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
