//! Where configuration files come from, so that every binary runs from any directory — in the
//! repository, installed with `cargo install`, or copied anywhere on its own.
//!
//! The whole `config/` tree (service configs, `robots/*.toml` and their URDFs, `sim/*.toml`) is
//! built into the `strand` library. A config is asked for by NAME — a path inside that tree such as
//! `default.toml`, `iiwa7.toml`, `robots/iiwa7.toml` or `sim/free-flyer.toml` — or given as a path.
//! The search order:
//!
//! 1. a path given by the user (`--config FILE`, `strand check-config FILE`, `strand-kin check
//!    FILE`): used as it is; an error naming it if it does not exist. (A bare word such as `iiwa7`
//!    — one path component without an extension, and no such file in the working directory — is
//!    a NAME, not a path: `iiwa7.toml`, or `robots/iiwa7.toml` where a robot file is asked for.)
//! 2. `$STRAND_CONFIG_DIR/NAME` (when set it must be a directory);
//! 3. `./config/NAME` in the working directory (the repository root);
//! 4. `<executable's dir>/../share/strand/config/NAME` (an installed prefix);
//! 5. the built-in copy, written once per version and contents into
//!    `$XDG_CACHE_HOME/strand/config-<version>-<hash>/` (else `$HOME/.cache/strand/…`, else
//!    `<temp dir>/strand-<uid>/…`), so that the relative paths inside the files (a config's
//!    `robot = "robots/iiwa7.toml"`, a robot file's URDF) resolve for every loader as they do in the
//!    repository.
//!
//! The first that has the file wins. Errors name every file tried.

use std::path::{Component, Path, PathBuf};
use std::sync::OnceLock;

use super::ConfigError;

mod bundled {
    include!(concat!(env!("OUT_DIR"), "/bundled_config.rs"));
}

/// NAME of the default service configuration.
pub const DEFAULT: &str = "default.toml";

/// The environment variable of step 2.
pub(crate) const ENV_DIR: &str = "STRAND_CONFIG_DIR";

/// The built-in files: their NAME (`/`-separated path inside `config/`) and bytes.
pub fn bundled_files() -> &'static [(&'static str, &'static [u8])] {
    bundled::FILES
}

/// Names of the built-in service configs (`default`, `iiwa7`, `free-flyer`, …), for messages.
pub(crate) fn bundled_configs() -> Vec<&'static str> {
    bundled::FILES.iter().filter_map(|(n, _)| n.strip_suffix(".toml")).filter(|n| !n.contains('/')).collect()
}

/// True for a bare word (`iiwa7`): one normal path component without an extension. Such an argument
/// is a NAME to search for unless a file or folder of that name is in the working directory;
/// anything else is a path.
pub(crate) fn is_name(arg: &Path) -> bool {
    let mut parts = arg.components();
    matches!((parts.next(), parts.next()), (Some(Component::Normal(_)), None))
        && arg.extension().is_none()
        && !arg.to_string_lossy().starts_with('.')
}

/// True for a NAME inside the config tree with folders (`cells/kr6-turntable`): relative, every
/// component a normal one, no extension, not starting with a dot.
pub(crate) fn is_tree_name(arg: &Path) -> bool {
    arg.components().all(|c| matches!(c, Component::Normal(_)))
        && arg.components().count() > 1
        && arg.extension().is_none()
        && !arg.to_string_lossy().starts_with('.')
}

/// A path the user gave: itself if it exists, else an error naming it.
pub fn explicit(path: &Path) -> Result<PathBuf, ConfigError> {
    if path.exists() { Ok(path.to_path_buf()) } else { Err(ConfigError::new(path, "no such file")) }
}

/// The service config for a `--config` argument: the default ([`DEFAULT`]) when absent, `NAME.toml`
/// for a bare NAME (`iiwa7`, `free-flyer`; see [`is_name`]) or a NAME in a folder of the tree
/// (`cells/kr6-turntable`) that is not a file here, else the path as given (which must exist).
pub fn service_config(arg: Option<&Path>) -> Result<PathBuf, ConfigError> {
    service_config_or(arg, DEFAULT)
}

/// [`service_config`] with another default NAME (`free-flyer.toml` for `strand-plan base`).
pub fn service_config_or(arg: Option<&Path>, default: &str) -> Result<PathBuf, ConfigError> {
    match arg {
        None => find(default),
        Some(a) if is_name(a) && !a.exists() => find(&format!("{}.toml", a.display())),
        // A NAME inside the tree (`cells/kr6-turntable`): relative, no extension, not here.
        Some(a) if is_tree_name(a) && !a.exists() => find(&format!("{}.toml", a.display())),
        Some(a) => explicit(a),
    }
}

/// A robot file for an argument: `robots/NAME.toml` for a bare NAME (`iiwa7`), else the path as
/// given (a robot file or a URDF, which must exist).
pub fn robot_file(arg: &Path) -> Result<PathBuf, ConfigError> {
    if is_name(arg) && !arg.exists() { find(&format!("robots/{}.toml", arg.display())) } else { explicit(arg) }
}

/// `name` beside `file`'s folder (`sim/default.toml` next to the service config the user chose) if
/// it is there, else found by the search order.
pub fn beside_or_find(file: &Path, name: &str) -> Result<PathBuf, ConfigError> {
    let beside = file.parent().unwrap_or(Path::new(".")).join(name);
    if beside.is_file() {
        return Ok(beside);
    }
    find(name).map_err(|e| ConfigError { message: format!("{} (and {})", e.message, beside.display()), ..e })
}

/// The folders of steps 2 to 4, in order, as far as they apply here; an error if
/// `$STRAND_CONFIG_DIR` is set to something that is not a folder.
pub(crate) fn search_dirs() -> Result<Vec<PathBuf>, ConfigError> {
    let mut dirs = Vec::new();
    if let Some(d) = std::env::var_os(ENV_DIR).filter(|d| !d.is_empty()) {
        let d = PathBuf::from(d);
        if !d.is_dir() {
            return Err(ConfigError::new(&d, format!("${ENV_DIR} names no folder")));
        }
        dirs.push(d);
    }
    dirs.push(PathBuf::from("config"));
    if let Some(prefix) = std::env::current_exe().ok().and_then(|e| e.parent().and_then(Path::parent).map(Path::to_path_buf)) {
        dirs.push(prefix.join("share/strand/config"));
    }
    Ok(dirs)
}

/// The file `name` (a `/`-separated path inside `config/`) by the search order (steps 2 to 5).
pub fn find(name: &str) -> Result<PathBuf, ConfigError> {
    let mut tried = Vec::new();
    for dir in search_dirs()? {
        let p = dir.join(name);
        if p.is_file() {
            return Ok(p);
        }
        tried.push(p.display().to_string());
    }
    if bundled::FILES.iter().any(|(n, _)| *n == name) {
        return bundled_dir().map(|d| d.join(name));
    }
    tried.push(format!("the built-in copy (it has {})", bundled_configs().join(", ")));
    Err(ConfigError { file: name.to_string(), message: format!("not found; tried {}", tried.join(", ")) })
}

/// The built-in `config/` tree, written out (once per version and contents) to the cache folder.
pub(crate) fn bundled_dir() -> Result<PathBuf, ConfigError> {
    static DIR: OnceLock<Result<PathBuf, ConfigError>> = OnceLock::new();
    DIR.get_or_init(|| {
        let leaf = format!("config-{}-{}", env!("CARGO_PKG_VERSION"), bundled::HASH);
        materialise(&leaf, bundled::FILES)
    })
    .clone()
}

/// Folders a built-in copy may be written to: `$XDG_CACHE_HOME/strand`, `$HOME/.cache/strand`,
/// `<temp dir>/strand-<uid>`.
pub(crate) fn cache_roots() -> Vec<PathBuf> {
    let var = |k: &str| std::env::var_os(k).filter(|v| !v.is_empty()).map(PathBuf::from).filter(|p| p.is_absolute());
    let mut roots = Vec::new();
    if let Some(x) = var("XDG_CACHE_HOME") {
        roots.push(x.join("strand"));
    }
    if let Some(h) = var("HOME") {
        roots.push(h.join(".cache/strand"));
    }
    // SAFETY: getuid(2) cannot fail.
    let uid = unsafe { libc::getuid() };
    roots.push(std::env::temp_dir().join(format!("strand-{uid}")));
    roots
}

/// Writes `files` (NAME, bytes) into `<cache root>/leaf/`, the first cache root that takes them,
/// and returns that folder. A file already there with the same bytes is left alone; any other is
/// replaced through a temporary file and a rename, so processes starting together (the demo's)
/// never read a half-written file. `leaf` should change with the contents (a version and a hash).
pub fn materialise(leaf: &str, files: &[(&str, &[u8])]) -> Result<PathBuf, ConfigError> {
    let mut tried = Vec::new();
    for root in cache_roots() {
        let dir = root.join(leaf);
        match write_tree(&dir, files) {
            Ok(()) => return Ok(dir),
            Err(e) => tried.push(format!("{}: {e}", dir.display())),
        }
    }
    Err(ConfigError { file: leaf.to_string(), message: format!("cannot write the built-in copy; tried {}", tried.join("; ")) })
}

fn write_tree(dir: &Path, files: &[(&str, &[u8])]) -> std::io::Result<()> {
    for (name, bytes) in files {
        let path = dir.join(name);
        if std::fs::read(&path).is_ok_and(|b| b == *bytes) {
            continue;
        }
        let parent = path.parent().unwrap_or(dir);
        std::fs::create_dir_all(parent)?;
        let file_name = path.file_name().map_or_else(String::new, |n| n.to_string_lossy().to_string());
        let tmp = parent.join(format!(".{file_name}.{}.tmp", std::process::id()));
        std::fs::write(&tmp, bytes)?;
        std::fs::rename(&tmp, &path).inspect_err(|_| {
            let _ = std::fs::remove_file(&tmp);
        })?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_whole_config_tree_is_built_in() {
        let names: Vec<&str> = bundled_files().iter().map(|(n, _)| *n).collect();
        for n in ["default.toml", "free-flyer.toml", "robots/iiwa7.toml", "robots/iiwa7.urdf", "sim/default.toml", "sim/free-flyer.toml"] {
            assert!(names.contains(&n), "{n} missing from {names:?}");
        }
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("config");
        for (n, bytes) in bundled_files() {
            assert_eq!(std::fs::read(root.join(n)).unwrap(), *bytes, "{n}");
        }
        assert!(bundled_configs().contains(&"iiwa7"));
    }

    #[test]
    fn names_and_paths_are_told_apart() {
        assert!(is_name(Path::new("iiwa7")));
        assert!(is_name(Path::new("free-flyer")));
        assert!(!is_name(Path::new("iiwa7.toml")));
        assert!(!is_name(Path::new("config/iiwa7.toml")));
        assert!(!is_name(Path::new("/nope")));
        assert!(!is_name(Path::new("./iiwa7")));
        assert!(!is_name(Path::new("..")));
        let e = service_config(Some(Path::new("/nope.toml"))).unwrap_err().to_string();
        assert!(e.contains("/nope.toml"), "{e}");
    }

    #[test]
    fn a_materialised_copy_loads_and_is_rewritten_when_changed() {
        let dir = std::env::temp_dir().join(format!("strand-locate-test-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        write_tree(&dir, bundled_files()).unwrap();
        let cfg = crate::config::Config::load(&dir.join("iiwa7.toml")).unwrap();
        assert_eq!(cfg.robot.file, dir.join("robots/iiwa7.toml"));
        std::fs::write(dir.join("default.toml"), "junk").unwrap();
        write_tree(&dir, bundled_files()).unwrap();
        crate::config::Config::load(&dir.join("default.toml")).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
    }
}
