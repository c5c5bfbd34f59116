//! Motion limits a program sets for itself: the velocity limits the parser honours (Marlin's `M203`
//! per axis, Klipper's `SET_VELOCITY_LIMIT VELOCITY` on the path) and the settings it only records
//! for the caller ([`ProgramLimits`]: accelerations, jerk, corner velocity, pressure advance), so
//! offline tools can apply them as min(config, program). A program can make the machine gentler
//! this way, never harsher: a clamp only lowers a feed, a recorded limit is only ever the lowest.

use super::MM;
use super::block::Block;
use super::lexer::Fault;

/// A firmware M-code that sets a motion limit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum LimitM {
    /// M203: per-axis maximum feed (units/s).
    AxisFeeds,
    /// M201: per-axis maximum acceleration (units/s²).
    AxisAccelerations,
    /// M204: print / travel acceleration (units/s²).
    Accelerations,
    /// M205: jerk (units/s) and junction deviation (units).
    Jerk,
    /// M566: RepRapFirmware jerk (units/min).
    JerkPerMinute,
    /// M900: Marlin linear advance K (s).
    LinearAdvance,
    /// M572: RepRapFirmware pressure advance (s).
    PressureAdvance,
}

/// A value the program requested and where.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProgramSetting {
    /// SI value (m/s, m/s², m or s as the field says).
    pub value: f64,
    /// Line (1-based) of the request that set it.
    pub line: usize,
    /// The code that set it, e.g. `"M204 P"` or `"SET_VELOCITY_LIMIT ACCEL"`.
    pub source: &'static str,
}

/// Motion settings the program asked for. Limits keep the lowest value requested anywhere in the
/// program; pressure advance and its smooth time keep the last.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ProgramLimits {
    /// Lowest path velocity limit (m/s): `SET_VELOCITY_LIMIT VELOCITY`, or the lowest XYZ value
    /// of `M203`. Already honoured by the parser (feeds are clamped); here for information.
    pub velocity: Option<ProgramSetting>,
    /// Lowest acceleration (m/s²): `M204 P/T/S`, the lowest XYZ value of `M201`,
    /// `SET_VELOCITY_LIMIT ACCEL`.
    pub acceleration: Option<ProgramSetting>,
    /// Lowest jerk (m/s): the lowest XYZ value of Marlin's `M205` or RepRapFirmware's `M566`.
    pub jerk: Option<ProgramSetting>,
    /// Lowest junction deviation (m): Marlin's `M205 J`.
    pub junction_deviation: Option<ProgramSetting>,
    /// Lowest square-corner velocity (m/s): `SET_VELOCITY_LIMIT SQUARE_CORNER_VELOCITY`.
    pub square_corner_velocity: Option<ProgramSetting>,
    /// Last pressure advance (s): `SET_PRESSURE_ADVANCE ADVANCE`, Marlin's `M900 K`,
    /// RepRapFirmware's `M572 S`.
    pub pressure_advance: Option<ProgramSetting>,
    /// Last pressure-advance smooth time (s): `SET_PRESSURE_ADVANCE SMOOTH_TIME`.
    pub smooth_time: Option<ProgramSetting>,
}

/// Pressure advance accepted (s): Marlin's `M900` range.
const ADVANCE_RANGE: (f64, f64) = (0.0, 10.0);
/// Pressure-advance smooth time accepted (s): Klipper's range.
const SMOOTH_TIME_RANGE: (f64, f64) = (0.0, 0.2);

/// The velocity limits in force and the settings recorded so far.
#[derive(Default)]
pub(super) struct Limits {
    /// `M203` maximum feed per axis X, Y, Z, E (m/s), as last set (the firmware's semantics: a
    /// later `M203` replaces an earlier one).
    axis: [Option<f64>; 4],
    /// `SET_VELOCITY_LIMIT VELOCITY` (m/s), as last set.
    velocity: Option<f64>,
    pub(super) recorded: ProgramLimits,
}

/// What happened to a limit command.
pub(super) enum Outcome {
    /// Acted on: a note of this kind says what was done.
    Acted(&'static str),
    /// Nothing to do (e.g. `M900` without `K`): a warning of this kind with this message.
    NothingToDo(&'static str, String),
}

impl Limits {
    /// `feed` (m/s) lowered so that the path speed is within `SET_VELOCITY_LIMIT VELOCITY` and each
    /// axis' share of it within `M203`. `shares` are |dX|, |dY|, |dZ|, |dE| per metre of path.
    pub(super) fn feed(&self, feed: f64, shares: [f64; 4]) -> f64 {
        let mut limited = self.velocity.map_or(feed, |v| feed.min(v));
        for (limit, share) in self.axis.iter().zip(shares) {
            if let Some(limit) = limit
                && share > 0.0
            {
                limited = limited.min(limit / share);
            }
        }
        limited
    }

    /// Duration (s) of an extruder-only move of `filament` (m), lengthened to keep within `M203 E`.
    pub(super) fn extruder_time(&self, filament: f64, duration: f64) -> f64 {
        self.axis[3].map_or(duration, |limit| duration.max(filament.abs() / limit))
    }

    /// `M203`, `M201`, `M204`, `M205`, `M566`, `M900`, `M572` with their words in `unit` (m per
    /// program unit).
    pub(super) fn m_code(&mut self, code: LimitM, block: &mut Block, unit: f64, line: usize) -> Result<Outcome, Fault> {
        let recorded = &mut self.recorded;
        let name = match code {
            LimitM::AxisFeeds => {
                for (axis, letter) in b"XYZE".iter().enumerate() {
                    if let Some(v) = block.take(*letter)? {
                        let limit = positive(v * unit, block.column(*letter), &format!("M203 {}", *letter as char))?;
                        self.axis[axis] = Some(limit);
                        if axis < 3 {
                            lower(&mut recorded.velocity, limit, line, "M203");
                        }
                    }
                }
                "M203"
            }
            LimitM::AxisAccelerations => {
                for letter in b"XYZ" {
                    if let Some(v) = block.take(*letter)? {
                        let a = positive(v * unit, block.column(*letter), &format!("M201 {}", *letter as char))?;
                        lower(&mut recorded.acceleration, a, line, "M201");
                    }
                }
                "M201"
            }
            LimitM::Accelerations => {
                for (letter, source) in [(b'P', "M204 P"), (b'T', "M204 T"), (b'S', "M204 S")] {
                    if let Some(v) = block.take(letter)? {
                        lower(&mut recorded.acceleration, positive(v * unit, block.column(letter), source)?, line, source);
                    }
                }
                "M204"
            }
            LimitM::Jerk | LimitM::JerkPerMinute => {
                let (name, per) = if code == LimitM::Jerk { ("M205", 1.0) } else { ("M566", 60.0) };
                for letter in b"XYZ" {
                    if let Some(v) = block.take(*letter)? {
                        let jerk = non_negative(v * unit / per, block.column(*letter), &format!("{name} {}", *letter as char))?;
                        lower(&mut recorded.jerk, jerk, line, name);
                    }
                }
                if code == LimitM::Jerk
                    && let Some(j) = block.take(b'J')?
                {
                    lower(&mut recorded.junction_deviation, non_negative(j * unit, block.column(b'J'), "M205 J")?, line, "M205 J");
                }
                name
            }
            LimitM::LinearAdvance | LimitM::PressureAdvance => {
                let (name, letter) = if code == LimitM::LinearAdvance { ("M900", b'K') } else { ("M572", b'S') };
                let Some(k) = block.take(letter)? else {
                    return Ok(Outcome::NothingToDo(name, format!("{name} without {}: nothing to do", letter as char)));
                };
                let what = format!("{name} {} (pressure advance, s)", letter as char);
                // Prusa's MK3 firmware runs Linear Advance 1.0, whose K (typically 20-200) is not in
                // seconds: PrusaSlicer's MK3S profiles write `M900 K30`. Reported, not recorded.
                if code == LimitM::LinearAdvance && k.is_finite() && k > ADVANCE_RANGE.1 && k <= 1000.0 {
                    return Ok(Outcome::NothingToDo(name, format!("{name} K{k}: Linear Advance 1.0 units (not seconds), not recorded")));
                }
                let advance = in_range(k, ADVANCE_RANGE, block.column(letter), &what)?;
                recorded.pressure_advance = Some(ProgramSetting { value: advance, line, source: name });
                name
            }
        };
        Ok(Outcome::Acted(name))
    }

    /// A `KEY=value` of `SET_VELOCITY_LIMIT` or `SET_PRESSURE_ADVANCE` (mm, s as Klipper writes
    /// them); false if the key is not one acted on.
    pub(super) fn extended(&mut self, command: &str, key: &str, value: f64, column: usize, line: usize) -> Result<bool, Fault> {
        let recorded = &mut self.recorded;
        match (command, key) {
            ("SET_VELOCITY_LIMIT", "VELOCITY") => {
                let v = positive(value * MM, column, "VELOCITY")?;
                self.velocity = Some(v);
                lower(&mut recorded.velocity, v, line, "SET_VELOCITY_LIMIT VELOCITY");
            }
            ("SET_VELOCITY_LIMIT", "ACCEL") => {
                lower(&mut recorded.acceleration, positive(value * MM, column, "ACCEL")?, line, "SET_VELOCITY_LIMIT ACCEL");
            }
            ("SET_VELOCITY_LIMIT", "SQUARE_CORNER_VELOCITY") => {
                let v = non_negative(value * MM, column, "SQUARE_CORNER_VELOCITY")?;
                lower(&mut recorded.square_corner_velocity, v, line, "SET_VELOCITY_LIMIT SQUARE_CORNER_VELOCITY");
            }
            ("SET_PRESSURE_ADVANCE", "ADVANCE") => {
                let advance = in_range(value, ADVANCE_RANGE, column, "ADVANCE (s)")?;
                recorded.pressure_advance = Some(ProgramSetting { value: advance, line, source: "SET_PRESSURE_ADVANCE ADVANCE" });
            }
            ("SET_PRESSURE_ADVANCE", "SMOOTH_TIME") => {
                let smooth = in_range(value, SMOOTH_TIME_RANGE, column, "SMOOTH_TIME (s)")?;
                recorded.smooth_time = Some(ProgramSetting { value: smooth, line, source: "SET_PRESSURE_ADVANCE SMOOTH_TIME" });
            }
            _ => return Ok(false),
        }
        Ok(true)
    }
}

/// What was done with a limit command, for its first note.
pub(super) fn message(name: &str) -> &'static str {
    match name {
        "M203" => "per-axis feed limits (Marlin units/s) honoured: later moves slowed so that no axis, E included, exceeds them",
        "M201" | "M204" => "acceleration recorded in program_limits() (the lowest requested), to apply as min(config, program)",
        "M205" | "M566" => "jerk / junction deviation recorded in program_limits() (the lowest requested)",
        "M900" | "M572" | "SET_PRESSURE_ADVANCE" => {
            "pressure advance applied from the next segment on (the controller clamps it to [extruder] max_pressure_advance); SMOOTH_TIME recorded"
        }
        "SET_VELOCITY_LIMIT" => {
            "VELOCITY honoured (later feeds clamped); ACCEL and SQUARE_CORNER_VELOCITY recorded in program_limits() (the lowest requested)"
        }
        _ => "acted on",
    }
}

/// The note kind and message of a lowered feed.
pub(super) const FEED_LIMITED: (&str, &str) = ("feed limited", "feed lowered to the program's velocity limits (M203, SET_VELOCITY_LIMIT)");

/// Keeps the lower of `slot` and `value`.
fn lower(slot: &mut Option<ProgramSetting>, value: f64, line: usize, source: &'static str) {
    if slot.is_none_or(|s| value < s.value) {
        *slot = Some(ProgramSetting { value, line, source });
    }
}

/// A finite number in `[min, max]`, else an error naming what was given.
pub(super) fn in_range(value: f64, (min, max): (f64, f64), column: usize, what: &str) -> Result<f64, Fault> {
    if value.is_finite() && value >= min && value <= max {
        Ok(value)
    } else {
        Err(Fault::new(column, format!("{what} {value} is out of range [{min}, {max}]")))
    }
}

/// A finite number > 0, else an error naming what was given.
pub(super) fn positive(value: f64, column: usize, what: &str) -> Result<f64, Fault> {
    if value.is_finite() && value > 0.0 { Ok(value) } else { Err(Fault::new(column, format!("{what} {value} must be > 0"))) }
}

/// A finite number ≥ 0, else an error naming what was given.
pub(super) fn non_negative(value: f64, column: usize, what: &str) -> Result<f64, Fault> {
    if value.is_finite() && value >= 0.0 { Ok(value) } else { Err(Fault::new(column, format!("{what} {value} must be ≥ 0"))) }
}
