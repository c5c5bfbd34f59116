//! Bit-exact re-execution: rebuilds the controller from a log's own configuration and URDF, feeds
//! every logged `TickInput` through `Controller::step` and compares each output with the logged one:
//! byte for byte in its CDR form where the log holds it whole, by its 16-bit digest where the
//! compact record keeps only that. At the first difference it names the tick, and the field with
//! both values (for a digest, at the next whole output the log holds: the first of its block).

use super::cdr::{CdrType, CdrWriter, Scalar};
use super::messages::encode_output;
use super::reader::{LogFile, ReadError};
use super::record::{LoggedOutput, output_digest};
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
    // The first tick whose digest differed: (tick, logged, replayed).
    let mut digest_differed: Option<(u64, u32, u32)> = None;
    for file in files {
        for record in file.records() {
            let record = record?;
            if record.input.tick != expected {
                let hint = if expected == 0 {
                    ": a rotated part; pass the earlier parts first"
                } else {
                    ": ticks were dropped (Status.log_drops); the replay cannot go past a hole"
                };
                return Err(ReplayError::Gap { file: file.path.display().to_string(), expected, found: record.input.tick, hint });
            }
            let out = controller.step(&record.input);
            let logged = match &record.output {
                LoggedOutput::Whole(o) | LoggedOutput::Keyframe(o) => o,
                LoggedOutput::Digest(d) => {
                    let replayed = output_digest(&mut replayed_bytes, &out);
                    if digest_differed.is_none() && replayed != *d {
                        digest_differed = Some((expected, *d, replayed));
                    }
                    expected += 1;
                    continue;
                }
            };
            encode_output(&mut replayed_bytes, &out);
            encode_output(&mut logged_bytes, logged);
            if replayed_bytes.bytes() != logged_bytes.bytes() {
                let (mut a, mut b) = (Vec::new(), Vec::new());
                logged.flatten("output", &mut a);
                out.flatten("output", &mut b);
                let (field, logged, replayed) = first_difference(&a, &b);
                return Ok(match digest_differed {
                    Some((tick, ..)) => Verdict::Diverged {
                        tick,
                        field: format!("{field} (at tick {expected}: tick {tick}'s output differed by its digest)"),
                        logged,
                        replayed,
                    },
                    None => Verdict::Diverged { tick: expected, field, logged, replayed },
                });
            }
            if let Some(d) = digest_differed {
                return Ok(diverged_by_digest(d, Some(expected)));
            }
            expected += 1;
        }
    }
    if expected == 0 {
        return Err(ReplayError::Empty { file: files.last().map_or(String::new(), |f| f.path.display().to_string()) });
    }
    if let Some(d) = digest_differed {
        return Ok(diverged_by_digest(d, None));
    }
    Ok(Verdict::Identical { ticks: expected })
}

/// A divergence only a digest saw: no whole output after it differs (`agreed_at`: the whole output
/// that agreed again, if any).
fn diverged_by_digest((tick, logged, replayed): (u64, u32, u32), agreed_at: Option<u64>) -> Verdict {
    let after = match agreed_at {
        Some(t) => format!("the next whole output, at tick {t}, agrees"),
        None => "no whole output logged after it".to_string(),
    };
    Verdict::Diverged {
        tick,
        field: format!("output (its digest; {after})"),
        logged: format!("digest {logged:04x}"),
        replayed: format!("digest {replayed:04x}"),
    }
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
