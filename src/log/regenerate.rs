//! `strand-replay regenerate`: a log's derived channels at the full rate again. A service writes
//! `/joint_states`, `/joint_command`, `/tcp/*`, `/base/*`, `/extruder` and `/status` at `[log]
//! derived_rate_hz` (10 Hz by default) because every one of them follows from the replay record
//! that it writes every tick; this replays a run's files (recomputing and checking each output)
//! and rewrites them into one log with every tick's messages and the full replay record
//! (`/strand/tick`), through the same writer, so a viewer or a script that wants them all at the
//! robot's rate gets exactly what the service would have written.

use std::path::Path;

use super::reader::{LogFile, ReadError};
use super::topics;
use super::writer::{LogContext, LogError, Logger};
use crate::io::runner::TickSink;

/// What a regeneration wrote.
#[derive(Clone, Debug, Default)]
pub struct Regenerated {
    /// Ticks written.
    pub ticks: u64,
    /// Bytes of the new file.
    pub bytes: u64,
}

/// Why a regeneration failed.
#[derive(Debug, thiserror::Error)]
pub enum RegenerateError {
    /// A log could not be read.
    #[error(transparent)]
    Read(#[from] ReadError),
    /// The new log could not be written.
    #[error(transparent)]
    Write(#[from] LogError),
    /// No log given, or no tick in them.
    #[error("{0}")]
    Empty(String),
}

/// Rewrites `files` (a run's parts, in order) into `output`, every channel at every tick. The
/// messages keep the run's log times (the first tick's log time less its tick time).
pub fn regenerate(files: &[LogFile], output: &Path) -> Result<Regenerated, RegenerateError> {
    let first = files.first().ok_or_else(|| RegenerateError::Empty("no log given".into()))?;
    let cfg = first.config()?;
    let model = cfg.robot.build_model().map_err(ReadError::from)?;
    let offset = first
        .messages()
        .find(|m| m.channel.topic == topics::TICK || m.channel.topic == topics::TICKS)
        .and_then(|m| {
            let time = if m.channel.topic == topics::TICK {
                super::cdr::decode::<super::messages::Tick>(&m.data).ok()?.input.time_ns
            } else {
                super::record::decode_block(&m.data).ok()?.first()?.input.time_ns
            };
            Some(m.log_time as i128 - time as i128)
        })
        .ok_or_else(|| RegenerateError::Empty(format!("{}: no tick", first.path.display())))?;
    let mut ctx = LogContext::new(&cfg, &model);
    ctx.clock_offset_ns = Some(offset);
    // Everything at every tick, the replay record whole too (for scripts that read the outputs).
    let log_cfg = crate::config::log::LogConfig {
        enabled: true,
        derived_rate_hz: 0.0,
        rotate_bytes: 0,
        rotate_seconds: 0.0,
        record: super::ReplayRecord::Full,
        ..cfg.log.clone()
    };
    let mut logger = Logger::start_at(&log_cfg, ctx, output)?;
    let mut ticks = 0;
    for tick in super::reader::ticks_of(files) {
        let tick = tick?;
        logger.wait_for_room();
        logger.record(&tick.input, &tick.output, &tick.timing);
        ticks += 1;
    }
    let report = logger.finish();
    if let Some(e) = report.error {
        return Err(RegenerateError::Empty(format!("{}: {e}", output.display())));
    }
    Ok(Regenerated { ticks, bytes: report.bytes })
}
