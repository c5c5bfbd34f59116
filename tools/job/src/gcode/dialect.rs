//! Dialects: the commands that printer firmwares (Marlin, RepRapFirmware, Klipper) and slicers add
//! to RS274/NGC, and what the parser does with them. The core interpreter knows RS274/NGC; this
//! module holds the firmware state that sits beside it — firmware retraction, feed and flow
//! percentages, the selected tool, the motion limits (kept by the `limits` module) — and acts on
//! the firmware codes and Klipper's extended commands. See the module documentation of
//! [`crate::gcode`] for the table of what is honoured and how.

use std::path::Path;

use super::MM;
use super::limits::Limits;

/// Which G-code language a program is written in. The two differ where the same code means
/// different things: `G4 P` (milliseconds in firmware, seconds in RS274/NGC), `G10`/`G11`
/// (firmware retraction, or LinuxCNC's "set offsets"), `F` on an M-code line (a parameter, or the
/// modal feed), the firmware M-codes and Klipper's extended commands (acted on, or not RS274/NGC).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Dialect {
    /// Printer firmware as slicers write for it: Marlin, RepRapFirmware, Klipper, Prusa, Bambu.
    #[default]
    Firmware,
    /// RS274/NGC as LinuxCNC reads it.
    Rs274ngc,
}

impl Dialect {
    /// The dialect a file's extension implies: `.ngc`, `.nc` and `.tap` (case-insensitive) are
    /// RS274/NGC (LinuxCNC and CAM output), anything else is printer firmware G-code.
    pub fn from_path(path: &Path) -> Dialect {
        let extension = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
        match extension.as_deref() {
            Some("ngc" | "nc" | "tap") => Dialect::Rs274ngc,
            _ => Dialect::Firmware,
        }
    }
}

/// Firmware retraction (`G10`/`G11`) settings, in SI units. The program may change them with
/// `M207` (Marlin, RepRapFirmware) or Klipper's `SET_RETRACTION`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FirmwareRetraction {
    /// Filament pulled back by `G10` (m).
    pub length: f64,
    /// Speed of the pull (m/s of filament).
    pub speed: f64,
    /// Filament pushed by `G11` beyond what `G10` pulled (m; may be negative, not below −length).
    pub extra_prime: f64,
    /// Speed of the push (m/s of filament).
    pub prime_speed: f64,
}

impl Default for FirmwareRetraction {
    /// Marlin's defaults (Configuration_adv.h: `RETRACT_LENGTH 3`, `RETRACT_FEEDRATE 45`,
    /// `RETRACT_RECOVER_LENGTH 0`, `RETRACT_RECOVER_FEEDRATE 8`): the firmware a program that uses
    /// `G10` without `M207` most likely expects. A job for a direct-drive extruder should set its own.
    fn default() -> Self {
        FirmwareRetraction { length: 3.0 * MM, speed: 45.0 * MM, extra_prime: 0.0, prime_speed: 8.0 * MM }
    }
}

/// Feed and flow percentages accepted by `M220`/`M221` (outside: an error).
pub(super) const PERCENT_RANGE: (f64, f64) = (1.0, 1000.0);
/// Tool numbers from here up are firmware special tools, not extruders: Bambu's `T255` (unload)
/// and `T1000` (nozzle-prime mode, in its default start code after the purge with `T0`).
pub(super) const SPECIAL_TOOLS: f64 = 255.0;

/// Firmware state beside the RS274/NGC modal state.
pub(super) struct Firmware {
    pub(super) dialect: Dialect,
    pub(super) retraction: FirmwareRetraction,
    /// Filament pulled back by the last `G10` (m), until `G11`: a second `G10` does nothing.
    pub(super) retracted: Option<f64>,
    /// `M220` feed percentage, and its `M220 B` backup.
    pub(super) feed_percent: f64,
    pub(super) feed_backup: f64,
    /// `M221` flow percentage.
    pub(super) flow_percent: f64,
    pub(super) limits: Limits,
    /// Selected tool, and whether it has pushed filament (then another tool is an error).
    pub(super) tool: u32,
    pub(super) tool_used: bool,
}

impl Firmware {
    pub(super) fn new(dialect: Dialect, retraction: FirmwareRetraction) -> Self {
        Firmware {
            dialect,
            retraction,
            retracted: None,
            feed_percent: 100.0,
            feed_backup: 100.0,
            flow_percent: 100.0,
            limits: Limits::default(),
            tool: 0,
            tool_used: false,
        }
    }

    /// Factor on programmed feeds (`M220`).
    pub(super) fn feed_factor(&self) -> f64 {
        self.feed_percent / 100.0
    }

    /// Factor on programmed filament (`M221`).
    pub(super) fn flow_factor(&self) -> f64 {
        self.flow_percent / 100.0
    }
}
