//! The MCAP log: every tick, on its own thread, in files that Foxglove, PlotJuggler, rosbags and
//! the `mcap` Python package read, and that `strand-replay` re-runs bit for bit.
//!
//! - [`cdr`]: CDR by hand and the [`cdr::CdrType`] trait; [`messages`]: what each channel carries;
//!   [`dynamic`]: schema-driven decoding of any channel.
//! - [`writer`]: the tick side ([`writer::Logger`], a [`crate::io::runner::TickSink`]: one copy into a
//!   preallocated slot, no allocation, no lock, a full queue is a counted drop) and the writer thread
//!   (encoding, chunks closed at least every `chunk_interval`, rotation, a write error stops logging
//!   and never control).
//! - [`record`]: the compact replay record (`/strand/ticks`): inputs whole, outputs as digests.
//! - [`reader`]: reads a log (finished or cut short) back: metadata, attachments, ticks, channels.
//! - [`recover`]: rewrites a log cut short by a crash into a valid, indexed file.
//! - [`regenerate`]: rewrites a log with its derived channels at every tick (the service writes them
//!   at `[log] derived_rate_hz`).
//! - [`scene`]: what a 3D viewer draws (URDF, `/tf`, path and bead markers), for the log and the
//!   live view alike.

pub mod cdr;
pub mod dynamic;
pub mod messages;
pub mod reader;
pub mod record;
pub mod recover;
pub mod regenerate;
pub mod replay;
pub(crate) mod scene;
pub mod writer;

/// Channel topics.
pub mod topics {
    /// Measured joint states (`sensor_msgs/msg/JointState`).
    pub const JOINT_STATES: &str = "/joint_states";
    /// Joint commands (`sensor_msgs/msg/JointState`; effort empty).
    pub const JOINT_COMMAND: &str = "/joint_command";
    /// The path's TCP target in the world frame (`geometry_msgs/msg/PoseStamped`).
    pub const TCP_TARGET: &str = "/tcp/target";
    /// The TCP from the measured joints and the estimated base, world frame.
    pub(crate) const TCP_ACTUAL: &str = "/tcp/actual";
    /// Tracking samples as received (`geometry_msgs/msg/PoseStamped`).
    pub(crate) const BASE_MEASURED: &str = "/base/measured";
    /// The base pose the controller used.
    pub const BASE_ESTIMATED: &str = "/base/estimated";
    /// A moving base's setpoint from its plan (`geometry_msgs/msg/PoseStamped`; only with a
    /// `[base] plan`; the whole `BaseCommand` is in the tick).
    pub const BASE_COMMAND: &str = "/base/command";
    /// Extruder commands (`strand_msgs/msg/ExtruderCommand`).
    pub const EXTRUDER: &str = "/extruder";
    /// Status (`strand_msgs/msg/Status`).
    pub const STATUS: &str = "/status";
    /// Segments as received (`strand_msgs/msg/Segment`).
    pub const SEGMENTS: &str = "/segments";
    /// The heaters (`strand_msgs/msg/HeatStatus`, °C): measured and target, hot end and bed, and a
    /// heat wait's band and settle time left — `Status`'s temperature fields, on their own channel
    /// so that the live view and older readers of `/status` keep their layout.
    pub const HEATERS: &str = "/heaters";
    /// Each tick's complete input, output and timing (`strand_msgs/msg/Tick`): the replay record
    /// with `[log] record = "full"`, and the live view's.
    pub const TICK: &str = "/strand/tick";
    /// The compact replay record (`strand_msgs/msg/TickBlock`, [`super::record`]): runs of ticks,
    /// inputs whole and outputs as digests; `[log] record = "compact"`, the default.
    pub const TICKS: &str = "/strand/ticks";
}

/// Attachment and metadata names.
pub mod names {
    /// The effective configuration (TOML, robot inline).
    pub(crate) const EFFECTIVE_CONFIG: &str = "effective-config.toml";
    /// The robot's URDF.
    pub const URDF: &str = "robot.urdf";
    /// The metadata record.
    pub(crate) const METADATA: &str = "strand";
}

pub use crate::config::log::{LogCompression, LogConfig, ReplayRecord};

/// Formats a Unix time (ns) as `YYYYMMDDTHHMMSSZ` (UTC), for file names.
pub fn utc_stamp(unix_ns: u64) -> String {
    let secs = unix_ns / 1_000_000_000;
    let (days, rem) = (secs / 86_400, secs % 86_400);
    // Civil date from days since 1970-01-01 (H. Hinnant's algorithm).
    let z = days as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + if m <= 2 { 1 } else { 0 };
    format!("{y:04}{m:02}{d:02}T{:02}{:02}{:02}Z", rem / 3600, rem % 3600 / 60, rem % 60)
}

/// Nanoseconds since the Unix epoch now.
pub fn unix_now_ns() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos() as u64)
}

/// The build's version: crate version and, when built from a git checkout, the commit.
pub(crate) fn build_version() -> String {
    match option_env!("STRAND_GIT_COMMIT") {
        Some(c) if !c.is_empty() => format!("{} ({c})", env!("CARGO_PKG_VERSION")),
        _ => env!("CARGO_PKG_VERSION").to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utc_stamps() {
        assert_eq!(utc_stamp(0), "19700101T000000Z");
        assert_eq!(utc_stamp(951_782_400 * 1_000_000_000), "20000229T000000Z");
        // Checked against Python: datetime.fromtimestamp(1795000000, UTC).
        assert_eq!(utc_stamp(1_795_000_000 * 1_000_000_000 + 5), "20261118T110640Z");
    }
}
