//! Bit-exact re-execution: rebuilds the controller from a log's own configuration and URDF, feeds
//! every logged `TickInput` through `Controller::step` and compares each output with the logged one,
//! byte for byte in its CDR form; at the first difference it names the tick and the field with both
//! values.

use super::cdr::{CdrType, CdrWriter, Scalar};
use super::messages::encode_output;
use super::reader::{LogFile, ReadError};
use crate::config::Config;

/// The outcome of a replay.
#[derive(Clone, Debug, PartialEq)]
pub enum Verdict {
    /// Every tick's output was reproduced to the bit.
    Identical {
        /// Ticks replayed.
        ticks: u64,
    },
    /// The first tick whose output differs.
    Diverged {
        /// Tick index.
        tick: u64,
        /// Field path, e.g. `output.joint_command.position[3]`.
        field: String,
        /// Value in the log.
        logged: String,
        /// Value the replay computed.
        replayed: String,
    },
}

/// Why a log could not be replayed.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// Reading failed.
    #[error(transparent)]
    Read(#[from] ReadError),
    /// The controller could not be built from the logged configuration.
    #[error("{0}")]
    Build(String),
    /// The log does not start at tick 0 or has a hole (dropped ticks cannot be replayed past).
    #[error("{file}: expected tick {expected}, found {found}{hint}")]
    Gap {
        /// The file.
        file: String,
        /// The tick that should come next.
        expected: u64,
        /// The tick found.
        found: u64,
        /// What to do about it.
        hint: &'static str,
    },
    /// No ticks (`file`: the log, or empty when no file was given).
    #[error("{file}: no ticks in the log (cut short before its first chunk was closed?)")]
    Empty {
        /// The file (the last part, for rotated parts).
        file: String,
    },
}

/// Replays `files` (one log, or the rotated parts of one in order) with the logged configuration.
pub fn verify(files: &[LogFile]) -> Result<Verdict, ReplayError> {
    verify_with(files, |_| {})
}

/// As [`verify`], after `change` has altered the configuration (to show that a replay notices).
pub fn verify_with(files: &[LogFile], change: impl FnOnce(&mut Config)) -> Result<Verdict, ReplayError> {
    let first = files.first().ok_or(ReplayError::Empty { file: String::new() })?;
    let mut cfg = first.config()?;
    change(&mut cfg);
    let mut controller = cfg.robot.build_controller(&cfg.controller_settings()).map_err(|e| ReplayError::Build(e.to_string()))?;
    let (mut replayed_bytes, mut logged_bytes) = (CdrWriter::new(), CdrWriter::new());
    let mut expected = 0u64;
    for file in files {
        for tick in file.ticks() {
            let tick = tick?;
            if tick.input.tick != expected {
                let hint = if expected == 0 {
                    ": a rotated part; pass the earlier parts first"
                } else {
                    ": ticks were dropped (Status.log_drops); the replay cannot go past a hole"
                };
                return Err(ReplayError::Gap { file: file.path.display().to_string(), expected, found: tick.input.tick, hint });
            }
            let out = controller.step(&tick.input);
            encode_output(&mut replayed_bytes, &out);
            encode_output(&mut logged_bytes, &tick.output);
            if replayed_bytes.bytes() != logged_bytes.bytes() {
                let (mut a, mut b) = (Vec::new(), Vec::new());
                tick.output.flatten("output", &mut a);
                out.flatten("output", &mut b);
                let (field, logged, replayed) = first_difference(&a, &b);
                return Ok(Verdict::Diverged { tick: expected, field, logged, replayed });
            }
            expected += 1;
        }
    }
    if expected == 0 {
        return Err(ReplayError::Empty { file: files.last().map_or(String::new(), |f| f.path.display().to_string()) });
    }
    Ok(Verdict::Identical { ticks: expected })
}

fn first_difference(a: &[(String, Scalar)], b: &[(String, Scalar)]) -> (String, String, String) {
    for i in 0..a.len().max(b.len()) {
        match (a.get(i), b.get(i)) {
            (Some((pa, va)), Some((pb, vb))) if pa == pb && va == vb => continue,
            (Some((pa, va)), Some((pb, vb))) if pa == pb => return (pa.clone(), va.to_string(), vb.to_string()),
            (x, y) => {
                let show = |v: Option<&(String, Scalar)>| v.map_or("(absent)".to_string(), |(p, s)| format!("{p} = {s}"));
                let path = x.or(y).map_or(String::new(), |(p, _)| p.clone());
                return (path, show(x), show(y));
            }
        }
    }
    ("(encoding)".to_string(), "?".to_string(), "?".to_string())
}
