//! The demo's child processes — the service, the sim and the feeder — started next to strand-demo's
//! own executable, their output to `<out>/<name>.log`, stopped politely (SIGTERM, then SIGKILL) and
//! never left behind (a dropped child is killed).

use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use strand_cli::child::Reaped;
use strand_cli::error::{Result, ToolError};

/// `name`'s executable next to the running one (the tools are installed together).
pub(crate) fn sibling(name: &str) -> Result<PathBuf> {
    let exe = std::env::current_exe().map_err(|e| ToolError::Process(format!("cannot find the running executable: {e}")))?;
    let p = exe.with_file_name(name);
    if p.is_file() {
        Ok(p)
    } else {
        Err(ToolError::Process(format!(
            "{} not found next to {}: build everything first (cargo build --release --workspace)",
            p.display(),
            exe.file_name().map_or("strand-demo".into(), |n| n.to_string_lossy())
        )))
    }
}

/// A running child: its role (`service`, `sim`, `feed`) and the process, in the tools' guard
/// (stopped politely on request, killed and reaped if dropped).
pub(crate) struct Proc {
    pub(crate) name: &'static str,
    child: Reaped,
}

impl Proc {
    /// Starts `cmd` as `name`, its stdout and stderr to `<out>/<name>.log`.
    pub(crate) fn spawn(name: &'static str, mut cmd: Command, out: &Path) -> Result<Proc> {
        let path = out.join(format!("{name}.log"));
        let log = File::create(&path).map_err(ToolError::file(&path))?;
        let child = cmd
            .stdin(Stdio::null())
            .stdout(log.try_clone().map_err(ToolError::file(&path))?)
            .stderr(log)
            .spawn()
            .map_err(|e| ToolError::Process(format!("cannot start the {name} ({}): {e}", program(name))))?;
        Ok(Proc { name, child: Reaped(child) })
    }

    /// Its exit code if it has exited (-1: killed by a signal).
    pub(crate) fn exited(&mut self) -> Option<i32> {
        self.child.exited()
    }

    /// Waits for its exit until `deadline`; its exit code, or None if it still runs.
    pub(crate) fn wait_until(&mut self, deadline: Instant) -> Option<i32> {
        self.child.wait_until(deadline)
    }

    /// SIGTERM, then SIGKILL after `grace`; its exit code (-9 if it had to be killed).
    pub(crate) fn stop(&mut self, grace: Duration) -> i32 {
        self.child.stop(grace)
    }
}

/// The program a child runs, for messages.
pub(crate) fn program(name: &str) -> &'static str {
    match name {
        "service" => "strand",
        "sim" => "strand-sim",
        _ => "strand-feed",
    }
}

/// The last `n` lines a child wrote (its stdout and stderr go to `<out>/<name>.log`).
pub(crate) fn tail(out: &Path, name: &str, n: usize) -> Vec<String> {
    let text = std::fs::read(out.join(format!("{name}.log"))).map(|b| String::from_utf8_lossy(&b).to_string()).unwrap_or_default();
    let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
    lines[lines.len().saturating_sub(n)..].iter().map(|l| l.to_string()).collect()
}

/// A child that failed: its name, program, exit code and its own last words, on stderr.
pub(crate) fn report_child(out: &Path, name: &str, code: i32) {
    let how = if code < 0 { "was killed".to_string() } else { format!("exited with {code}") };
    eprintln!("strand-demo: the {name} ({}) {how}:", program(name));
    for l in tail(out, name, 20) {
        eprintln!("  {l}");
    }
    eprintln!("strand-demo: its whole output: {}", out.join(format!("{name}.log")).display());
}
