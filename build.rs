//! Stamps the build with its git commit (STRAND_GIT_COMMIT), which every log records, and embeds the
//! whole `config/` tree (`$OUT_DIR/bundled_config.rs`: every file's path and bytes, and a hash of
//! them) so the binaries run without the repository (`strand::config::locate`).
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;

fn main() {
    println!("cargo:rerun-if-changed=.git/HEAD");
    println!("cargo:rerun-if-changed=.git/refs/heads");
    let commit = Command::new("git")
        .args(["rev-parse", "--short=12", "HEAD"])
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_default();
    println!("cargo:rustc-env=STRAND_GIT_COMMIT={commit}");
    bundle_config();
}

/// Every file under `dir` (hidden ones left out), as paths relative to `dir` with `/` separators,
/// sorted.
fn files(dir: &Path, rel: &str, out: &mut Vec<(String, PathBuf)>) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().to_string();
        if name.starts_with('.') {
            continue;
        }
        let path = e.path();
        let rel = if rel.is_empty() { name } else { format!("{rel}/{name}") };
        if path.is_dir() {
            files(&path, &rel, out);
        } else if path.is_file() {
            out.push((rel, path));
        }
    }
}

/// FNV-1a, 64 bits.
fn fnv(hash: &mut u64, bytes: &[u8]) {
    for b in bytes {
        *hash ^= u64::from(*b);
        *hash = hash.wrapping_mul(0x0100_0000_01b3);
    }
}

fn bundle_config() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"));
    let dir = manifest.join("config");
    println!("cargo:rerun-if-changed=config");
    let mut list = Vec::new();
    files(&dir, "", &mut list);
    list.sort();
    let mut hash = 0xcbf2_9ce4_8422_2325u64;
    let mut code = String::from("/// Every file of `config/`: its path inside it (`/`-separated) and its bytes.\n");
    code += "pub(super) static FILES: &[(&str, &[u8])] = &[\n";
    for (rel, path) in &list {
        let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        fnv(&mut hash, rel.as_bytes());
        fnv(&mut hash, &[0]);
        fnv(&mut hash, &(bytes.len() as u64).to_le_bytes());
        fnv(&mut hash, &bytes);
        writeln!(code, "    ({rel:?}, include_bytes!({:?})),", path.display().to_string()).expect("a String takes writes");
    }
    code += "];\n";
    writeln!(code, "/// FNV-1a (64 bits) of the paths and contents above.\npub(super) const HASH: &str = \"{hash:016x}\";")
        .expect("a String takes writes");
    let out = PathBuf::from(std::env::var("OUT_DIR").expect("cargo sets OUT_DIR")).join("bundled_config.rs");
    std::fs::write(&out, code).unwrap_or_else(|e| panic!("{}: {e}", out.display()));
}
