//! The tools run from anywhere (`strand::config::locate`): copied out of the build tree and run in a
//! fresh folder outside the repository, with `$STRAND_CONFIG_DIR` unset and the cache in a scratch
//! folder, they find the default config, the robot files and URDFs in the copy built into them;
//! `$STRAND_CONFIG_DIR`, `./config` and `<prefix>/share/strand/config` come first, in that order;
//! a config the user names that does not exist is an error naming it.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use strand_testkit::{root, temp_dir};

/// A scratch folder with `bin/` (copies of the binaries), `work/` (the working directory) and
/// `cache/` (`$XDG_CACHE_HOME`).
struct Place {
    dir: PathBuf,
}

impl Drop for Place {
    fn drop(&mut self) {
        // Three copied binaries are a third of a gigabyte: never leave them behind.
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

impl Place {
    fn new(name: &str) -> Place {
        let dir = temp_dir("anywhere", name);
        assert!(!dir.starts_with(root().canonicalize().unwrap()), "{} lies in the repository", dir.display());
        std::fs::create_dir_all(dir.join("bin")).unwrap();
        std::fs::create_dir_all(dir.join("work")).unwrap();
        for name in ["strand", "strand-plan", "strand-kin"] {
            let from = Path::new(env!("CARGO_BIN_EXE_strand-plan")).with_file_name(name);
            assert!(from.exists(), "{} missing: build the workspace (cargo test --workspace builds it)", from.display());
            std::fs::copy(&from, dir.join("bin").join(name)).unwrap();
        }
        Place { dir }
    }

    fn cache(&self) -> PathBuf {
        self.dir.join("cache")
    }

    /// Runs a copied binary in `work/` with a clean configuration environment (`env`: extra).
    fn run(&self, bin: &str, args: &[&str], env: &[(&str, &Path)]) -> Output {
        let mut c = Command::new(self.dir.join("bin").join(bin));
        c.args(args)
            .current_dir(self.dir.join("work"))
            .env_remove("STRAND_CONFIG_DIR")
            .env("XDG_CACHE_HOME", self.cache())
            .env("HOME", self.dir.join("home"))
            .env("RUST_BACKTRACE", "0");
        for (k, v) in env {
            c.env(k, v);
        }
        c.output().unwrap()
    }
}

fn ok(out: &Output) -> String {
    let (stdout, stderr) = (String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "exit {:?}\nstdout: {stdout}\nstderr: {stderr}", out.status.code());
    stdout.to_string()
}

fn refused(out: &Output) -> String {
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(!out.status.success(), "succeeded: {}", String::from_utf8_lossy(&out.stdout));
    assert!(!stderr.contains("panicked"), "{stderr}");
    stderr
}

/// The built-in copy's folder under `cache` (one per version and contents).
fn built_in(cache: &Path) -> PathBuf {
    let d = cache.join("strand");
    let mut found: Vec<PathBuf> = std::fs::read_dir(&d)
        .unwrap_or_else(|e| panic!("{}: {e}", d.display()))
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.file_name().unwrap().to_string_lossy().starts_with("config-"))
        .collect();
    assert_eq!(found.len(), 1, "{found:?}");
    found.pop().unwrap()
}

#[test]
fn copied_binaries_run_outside_the_repository_on_the_built_in_config() {
    let p = Place::new("built-in");
    let job = root().join("tests/data/gcode/slic3r/box35.gcode").canonicalize().unwrap();
    let out = ok(&p.run("strand-plan", &["time", job.to_str().unwrap()], &[]));
    // 16236 moves and dwells, and the five heat segments (M190, M104, M109; M104 S0, M140 S0 at the end).
    assert!(out.contains("segments        16241"), "{out}");
    // The copy is whole: robot files and URDFs beside the configs, as in the repository.
    let copy = built_in(&p.cache());
    for f in ["default.toml", "free-flyer.toml", "robots/iiwa7.toml", "robots/iiwa7.urdf", "robots/meca500.urdf", "sim/default.toml"] {
        assert_eq!(std::fs::read(copy.join(f)).unwrap(), std::fs::read(root().join("config").join(f)).unwrap(), "{f}");
    }
    let out = ok(&p.run("strand", &["check-config"], &[]));
    assert!(out.contains(&format!("{}: ok", copy.join("default.toml").display())), "{out}");
    let out = ok(&p.run("strand", &["check-config", "free-flyer"], &[]));
    assert!(out.contains("free-flyer.toml: ok") && out.contains("base Tracked"), "{out}");
    let out = ok(&p.run("strand-kin", &["check", "iiwa7"], &[]));
    assert!(out.contains(&copy.join("robots/iiwa7.urdf").display().to_string()), "{out}");
    assert!(out.contains("7 joints"), "{out}");
    // A second run reuses the copy; one changed by hand is put right.
    std::fs::write(copy.join("robots/iiwa7.toml"), "junk").unwrap();
    ok(&p.run("strand-kin", &["check", "iiwa7"], &[]));
    assert_eq!(built_in(&p.cache()), copy);
}

#[test]
fn a_config_the_user_names_must_exist() {
    let p = Place::new("missing");
    let job = root().join("tests/data/gcode/slic3r/box35.gcode").canonicalize().unwrap();
    let e = refused(&p.run("strand-plan", &["time", job.to_str().unwrap(), "--config", "/nope.toml"], &[]));
    assert!(e.contains("/nope.toml: no such file"), "{e}");
    let e = refused(&p.run("strand", &["check-config", "/nope.toml"], &[]));
    assert!(e.contains("/nope.toml"), "{e}");
    let e = refused(&p.run("strand-kin", &["check", "/nope/robot.toml"], &[]));
    assert!(e.contains("/nope/robot.toml"), "{e}");
    // An unknown NAME: every place tried is named.
    let e = refused(&p.run("strand", &["check-config", "no-such-robot"], &[]));
    for part in ["no-such-robot.toml", "config/no-such-robot.toml", "share/strand/config/no-such-robot.toml", "built-in copy"] {
        assert!(e.contains(part), "{part} not in {e}");
    }
    // $STRAND_CONFIG_DIR must be a folder.
    let e = refused(&p.run("strand", &["check-config"], &[("STRAND_CONFIG_DIR", Path::new("/nope"))]));
    assert!(e.contains("/nope") && e.contains("STRAND_CONFIG_DIR"), "{e}");
}

/// A copy of the repository's config/ at `dir` whose default.toml runs the controller at `rate` Hz.
fn config_copy(dir: &Path, rate: &str) {
    for (name, bytes) in strand::config::locate::bundled_files() {
        let p = dir.join(name);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(&p, bytes).unwrap();
    }
    let d = std::fs::read_to_string(dir.join("default.toml")).unwrap().replace("rate_hz = 1000.0", &format!("rate_hz = {rate}"));
    std::fs::write(dir.join("default.toml"), d).unwrap();
}

#[test]
fn the_search_order_is_env_then_working_directory_then_prefix_then_built_in() {
    let p = Place::new("order");
    let rate = |out: &str| out.lines().find(|l| l.starts_with("service:")).unwrap_or("").to_string();
    // <prefix>/share/strand/config, with the binaries in <prefix>/bin.
    config_copy(&p.dir.join("share/strand/config"), "500.0");
    let out = ok(&p.run("strand", &["check-config"], &[]));
    assert!(rate(&out).contains("500 Hz"), "{out}");
    // ./config in the working directory comes before it.
    config_copy(&p.dir.join("work/config"), "2000.0");
    let out = ok(&p.run("strand", &["check-config"], &[]));
    assert!(out.starts_with("config/default.toml: ok"), "{out}");
    assert!(rate(&out).contains("2000 Hz"), "{out}");
    // $STRAND_CONFIG_DIR before both.
    let env_dir = p.dir.join("mine");
    config_copy(&env_dir, "4000.0");
    let out = ok(&p.run("strand", &["check-config"], &[("STRAND_CONFIG_DIR", &env_dir)]));
    assert!(rate(&out).contains("4000 Hz"), "{out}");
    // None of them needed the built-in copy.
    assert!(!p.cache().exists());
}
