//! `[log]`: the logger's section of the service config (the log module reads it; the config owns
//! its type so that config and log do not import each other).

use serde::{Deserialize, Serialize};
use strand_core::InvalidSetting;

/// Chunk compression.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum LogCompression {
    /// zstd (smallest files; default).
    #[default]
    Zstd,
    /// lz4 (faster, larger).
    Lz4,
    /// None.
    None,
}

/// What the file keeps of each tick for replay (`[log] record`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum ReplayRecord {
    /// `/strand/ticks` (`strand_msgs/msg/TickBlock`): every tick's input and timing whole, its output
    /// as a 16-bit digest (whole for each block's first tick), blocks closed with each chunk. A
    /// replay recomputes the outputs and checks every digest; readers get them by replaying. About a
    /// fifth of `full` (default).
    #[default]
    Compact,
    /// `/strand/tick` (`strand_msgs/msg/Tick`): every tick's input, output and timing whole, for
    /// scripts that read the outputs without replaying (and logs a build cannot replay).
    Full,
}

/// `[log]`: where and how ticks are written.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct LogConfig {
    /// Write a log at all.
    pub enabled: bool,
    /// Folder for log files (relative to the working directory); created if missing.
    pub dir: String,
    /// File name without `.mcap`; empty: `strand-<UTC start time>`. Rotated parts add `-001`, `-002`...
    pub name: String,
    /// Ticks the queue between the tick and the writer holds (each slot is about 13 kB, allocated at
    /// start), 64 to 65536.
    pub queue_ticks: usize,
    /// Longest time a chunk stays open (s), 0.005 to 0.1: a crash loses at most this much.
    pub chunk_interval: f64,
    /// Uncompressed size at which a chunk is closed earlier (bytes), 4 KiB to 64 MiB.
    pub chunk_bytes: u64,
    /// Chunk compression.
    pub compression: LogCompression,
    /// Start a new file after this many bytes (0: never).
    pub rotate_bytes: u64,
    /// Start a new file after this long (s; 0: never).
    pub rotate_seconds: f64,
    /// `fdatasync` after each chunk (survives a power loss, costs writer time).
    pub fsync: bool,
    /// The replay record: `"compact"` (inputs whole, outputs as digests; default) or `"full"`.
    pub record: ReplayRecord,
    /// Free space (bytes) on the log's disk below which only the replay record and the segments
    /// are written (`LogState::RecordOnly`), so that a filling disk costs the viewing channels long
    /// before it stops the log; checked at most once a second, resumed above 1.1 × this. 0: never.
    pub min_free_bytes: u64,
    /// Rate (Hz) at which the file gets the channels that follow from the replay record (always
    /// every tick): `/joint_states`, `/joint_command`, `/tcp/target`, `/tcp/actual`,
    /// `/base/measured`, `/base/estimated`, `/base/command`, `/extruder`, `/heaters`, `/status`
    /// (`/status` also on every change of run state, fault, job outcome or layer), and the scene's
    /// snapshots `/tf` and `/joints/normalized` (`/path/ahead` at most every 5 s). 0: every
    /// tick. `strand-replay regenerate` writes them at the full rate again from the replay record;
    /// the live view is fed every tick either way (it keeps its own `[view] rates`).
    pub derived_rate_hz: f64,
    /// With the robot clock, a tick whose record finds the queue full waits for a slot instead of
    /// dropping the record: for a simulator that clocks the service faster than real time (the
    /// demo), so the log stays complete. Leave it off on a real robot, where a late command is
    /// worse than a lost record. The free-run clock always waits; the timer clock never does.
    pub wait_when_full: bool,
}

impl Default for LogConfig {
    fn default() -> Self {
        LogConfig {
            enabled: true,
            dir: "logs".to_string(),
            name: String::new(),
            queue_ticks: 2048,
            chunk_interval: 0.1,
            chunk_bytes: 1 << 20,
            compression: LogCompression::Zstd,
            rotate_bytes: 0,
            rotate_seconds: 0.0,
            fsync: false,
            record: ReplayRecord::Compact,
            min_free_bytes: 1 << 30,
            derived_rate_hz: 10.0,
            wait_when_full: false,
        }
    }
}

impl LogConfig {
    /// Checks every key; the message names it and its allowed range.
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        if !(64..=65536).contains(&self.queue_ticks) {
            return Err(InvalidSetting::new("log", format!("[log] queue_ticks = {}: must lie in [64, 65536]", self.queue_ticks)));
        }
        if !(self.chunk_interval.is_finite() && (0.005..=0.1).contains(&self.chunk_interval)) {
            return Err(InvalidSetting::new("log", format!("[log] chunk_interval = {}: must lie in [0.005, 0.1] s", self.chunk_interval)));
        }
        if !(4096..=64 << 20).contains(&self.chunk_bytes) {
            return Err(InvalidSetting::new("log", format!("[log] chunk_bytes = {}: must lie in [4096, 67108864]", self.chunk_bytes)));
        }
        if self.rotate_bytes != 0 && self.rotate_bytes < 1 << 16 {
            return Err(InvalidSetting::new(
                "log",
                format!("[log] rotate_bytes = {}: must be 0 (off) or at least 65536", self.rotate_bytes),
            ));
        }
        if !(self.rotate_seconds.is_finite() && (self.rotate_seconds == 0.0 || self.rotate_seconds >= 1.0)) {
            return Err(InvalidSetting::new(
                "log",
                format!("[log] rotate_seconds = {}: must be 0 (off) or at least 1 s", self.rotate_seconds),
            ));
        }
        if !(self.derived_rate_hz.is_finite() && self.derived_rate_hz >= 0.0) {
            return Err(InvalidSetting::new(
                "log",
                format!("[log] derived_rate_hz = {}: must be 0 (every tick) or a rate > 0 Hz", self.derived_rate_hz),
            ));
        }
        if self.name.contains(['/', '\\']) {
            return Err(InvalidSetting::new("log", format!("[log] name = {:?}: a file name, without folders (use dir)", self.name)));
        }
        Ok(())
    }
}
