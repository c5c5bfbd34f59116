//! The interpreter's firmware codes and Klipper's extended commands, acted on against the firmware
//! state of [`super::super::dialect`] (retraction, feed and flow percentages, tool, limits).

use std::collections::VecDeque;

use super::super::block::Block;
use super::super::codes::FirmwareM;
use super::super::dialect::{Dialect, PERCENT_RANGE, SPECIAL_TOOLS};
use super::super::lexer::{ExtendedParam, Fault, bounded};
use super::super::limits::{self, FEED_LIMITED, Outcome, in_range, non_negative, positive};
use super::super::{GcodeSegment, MM};
use super::Interpreter;
use strand_core::{Segment, SegmentKind};

impl Interpreter {
    /// `G10` (retract) or `G11` (recover) with the firmware's retracted flag: a second `G10`
    /// before a `G11` does nothing, as in Marlin and Klipper, and so does a `G11` with nothing to
    /// recover. The move is a dwell carrying the filament, like an E-only move; unlike one, it is
    /// not scaled by `M220`/`M221` (Marlin's fwretract unscales both).
    pub(super) fn firmware_retract(
        &mut self,
        retract: bool,
        line: usize,
        column: usize,
        out: &mut VecDeque<GcodeSegment>,
    ) -> Result<(), Fault> {
        let settings = self.firmware.retraction;
        let check = |v: f64, what: &str| non_negative(v, column, &format!("firmware retraction {what}"));
        let (filament, speed, kind) = match (retract, self.firmware.retracted) {
            (true, Some(_)) => {
                self.notes.record("G10 while retracted", line, column, || {
                    "G10 while already retracted: nothing done, as the firmware does".into()
                });
                return Ok(());
            }
            (false, None) => {
                self.notes.record("G11 while not retracted", line, column, || "G11 without a G10 before it: nothing to recover".into());
                return Ok(());
            }
            (true, None) => {
                let length = check(settings.length, "length")?;
                self.firmware.retracted = Some(length);
                (-length, settings.speed, "G10")
            }
            (false, Some(length)) => {
                self.firmware.retracted = None;
                ((length + settings.extra_prime).max(0.0), settings.prime_speed, "G11")
            }
        };
        let speed = positive(speed, column, "firmware retraction speed")?;
        self.notes.record(kind, line, column, || {
            let (what, length, speed) = match retract {
                true => ("retraction", settings.length, settings.speed),
                false => ("recovery", settings.length + settings.extra_prime, settings.prime_speed),
            };
            format!("firmware {what}: {} mm of filament at {} mm/s, as a dwell", length / MM, speed / MM)
        });
        if filament != 0.0 {
            let duration = self.limit_extruder_time(filament, filament.abs() / speed, line);
            let duration = super::dwell_time(duration, filament, column, kind)?;
            let segment = Segment { kind: SegmentKind::Dwell, end: self.machine.position, filament, duration, ..Segment::default() };
            self.emit(segment, line, out);
        }
        Ok(())
    }

    /// A `T` word as a tool selection: any tool before filament is pushed, then only that one.
    /// Special tools (`T255` and up) are reported and change nothing.
    pub(super) fn select_tool(&mut self, block: &mut Block, line: usize) -> Result<(), Fault> {
        let Some(param) = block.take_param(b'T') else { return Ok(()) };
        let number = param.number(b'T')?;
        if number < 0.0 || number.fract() != 0.0 || number > 1e6 {
            return Err(Fault::new(param.column, format!("T{number}: a tool is a whole number")));
        }
        if number >= SPECIAL_TOOLS {
            let kind = format!("T{number}");
            self.warnings.record(&kind, line, param.column, || format!("{kind}: a firmware special tool, not an extruder: not acted on"));
            return Ok(());
        }
        let tool = number as u32;
        if self.firmware.tool_used && tool != self.firmware.tool {
            let message = format!("tool change to T{tool} after extruding with T{}: multi-tool jobs are not supported", self.firmware.tool);
            return Err(Fault::new(param.column, message));
        }
        self.firmware.tool = tool;
        self.warnings.record(&format!("T{tool}"), line, param.column, || format!("tool T{tool} selected: jobs use one tool"));
        Ok(())
    }

    /// Feed (m/s) of a line or arc after the program's velocity limits (see [`Limits::feed`]),
    /// counting the feeds lowered.
    pub(super) fn limit_feed(&mut self, feed: f64, shares: [f64; 4], line: usize) -> f64 {
        let limited = self.firmware.limits.feed(feed, shares);
        if limited < feed {
            self.notes.record(FEED_LIMITED.0, line, 0, || FEED_LIMITED.1.into());
        }
        limited
    }

    /// Duration (s) of an extruder-only move after `M203 E`, counting the moves slowed.
    pub(super) fn limit_extruder_time(&mut self, filament: f64, duration: f64, line: usize) -> f64 {
        let limited = self.firmware.limits.extruder_time(filament, duration);
        if limited > duration {
            self.notes.record(FEED_LIMITED.0, line, 0, || FEED_LIMITED.1.into());
        }
        limited
    }

    /// An M-code the firmware dialect acts on; its words are its parameters.
    pub(super) fn firmware_m(&mut self, code: FirmwareM, block: &mut Block, line: usize, column: usize) -> Result<(), Fault> {
        let limit = match code {
            FirmwareM::FeedOverride => return self.feed_override(block, line, column),
            FirmwareM::FlowOverride => return self.flow_override(block, line, column),
            FirmwareM::RetractSettings => return self.retract_settings(block, line, column),
            FirmwareM::Limit(limit) => limit,
        };
        match self.firmware.limits.m_code(limit, block, self.modal.unit, line)? {
            Outcome::Acted(name) => self.notes.record(name, line, column, || limits::message(name).into()),
            Outcome::NothingToDo(name, message) => self.warnings.record(name, line, column, || message),
        }
        Ok(())
    }

    /// M220: `S` percent of programmed feeds from here on; Marlin's `B` backs the percentage up and
    /// `R` restores it (in that order, then `S`).
    fn feed_override(&mut self, block: &mut Block, line: usize, column: usize) -> Result<(), Fault> {
        let backup = block.take_param(b'B').is_some();
        let restore = block.take_param(b'R').is_some();
        if backup {
            self.firmware.feed_backup = self.firmware.feed_percent;
        }
        if restore {
            self.firmware.feed_percent = self.firmware.feed_backup;
        }
        let s = block.take(b'S')?;
        if let Some(s) = s {
            self.firmware.feed_percent = in_range(s, PERCENT_RANGE, block.column(b'S'), "M220 S (feed %)")?;
        }
        if s.is_none() && !backup && !restore {
            self.warnings.record("M220", line, column, || "M220 without S: reports the feed percentage, nothing to do".into());
            return Ok(());
        }
        self.notes.record("M220", line, column, || format!("feed override: later feeds × {} %", self.firmware.feed_percent));
        Ok(())
    }

    /// M221: `S` percent of programmed filament from here on (for the selected tool).
    fn flow_override(&mut self, block: &mut Block, line: usize, column: usize) -> Result<(), Fault> {
        if let Some(t) = block.take(b'T')?
            && t != f64::from(self.firmware.tool)
        {
            self.warnings.record("M221 T", line, column, || "flow for another tool than the selected one not acted on".into());
            return Ok(());
        }
        let Some(s) = block.take(b'S')? else {
            self.warnings.record("M221", line, column, || "M221 without S: reports the flow percentage, nothing to do".into());
            return Ok(());
        };
        self.firmware.flow_percent = in_range(s, PERCENT_RANGE, block.column(b'S'), "M221 S (flow %)")?;
        self.notes.record("M221", line, column, || format!("flow override: later filament × {} %", self.firmware.flow_percent));
        Ok(())
    }

    /// M207: `S` length, `F` speed (units/min), and RepRapFirmware's `R` extra prime and `T` prime
    /// speed (units/min); `Z` (hop) is not acted on.
    fn retract_settings(&mut self, block: &mut Block, line: usize, column: usize) -> Result<(), Fault> {
        let unit = self.modal.unit;
        let settings = &mut self.firmware.retraction;
        if let Some(s) = block.take(b'S')? {
            settings.length = non_negative(s * unit, block.column(b'S'), "M207 S (retraction length)")?;
        }
        if let Some(f) = block.take(b'F')? {
            settings.speed = positive(f * unit / 60.0, block.column(b'F'), "M207 F (retraction feed)")?;
        }
        if let Some(r) = block.take(b'R')? {
            settings.extra_prime = bounded(r * unit, block.column(b'R'))?;
        }
        if let Some(t) = block.take(b'T')? {
            settings.prime_speed = positive(t * unit / 60.0, block.column(b'T'), "M207 T (recovery feed)")?;
        }
        if block.has(b'Z') {
            self.warnings.record("M207 Z", line, column, || "retraction Z hop not acted on".into());
        }
        self.notes.record("M207", line, column, || "firmware retraction settings changed for later G10/G11".into());
        Ok(())
    }

    /// A Klipper-style extended command: `SET_VELOCITY_LIMIT`, `SET_PRESSURE_ADVANCE` and
    /// `SET_RETRACTION` are acted on, any other is reported once per name. Not RS274/NGC.
    pub(in crate::gcode) fn extended(
        &mut self,
        name: &str,
        params: &[ExtendedParam],
        malformed: Option<Fault>,
        line: usize,
        column: usize,
    ) -> Result<(), Fault> {
        if self.firmware.dialect == Dialect::Rs274ngc {
            return Err(Fault::new(column, format!("{name}: not an RS274/NGC word (a Klipper command in a .ngc/.nc/.tap file?)")));
        }
        let acted = matches!(name, "SET_VELOCITY_LIMIT" | "SET_PRESSURE_ADVANCE" | "SET_RETRACTION");
        if !acted {
            self.warnings.record(name, line, column, || format!("extended command {name} not acted on"));
            return Ok(());
        }
        if let Some(fault) = malformed {
            return Err(fault);
        }
        let mut ignored = false;
        for param in params {
            let value = extended_number(name, param)?;
            let (key, column) = (param.key.as_str(), param.column);
            let acted = match (name, key) {
                ("SET_RETRACTION", _) => self.set_retraction(key, value, column)?,
                _ => self.firmware.limits.extended(name, key, value, column, line)?,
            };
            ignored |= !acted;
        }
        if ignored {
            let kind = format!("{name} parameters");
            self.warnings.record(&kind, line, column, || format!("{name}: parameters other than the ones acted on are not acted on"));
        }
        let message = match name {
            "SET_RETRACTION" => "firmware retraction settings changed for later G10/G11",
            _ => limits::message(name),
        };
        self.notes.record(name, line, column, || message.into());
        Ok(())
    }

    /// A `KEY=value` of Klipper's `SET_RETRACTION` (mm, mm/s); false if the key is not acted on.
    fn set_retraction(&mut self, key: &str, value: f64, column: usize) -> Result<bool, Fault> {
        let settings = &mut self.firmware.retraction;
        match key {
            "RETRACT_LENGTH" => settings.length = non_negative(value * MM, column, "RETRACT_LENGTH")?,
            "RETRACT_SPEED" => settings.speed = positive(value * MM, column, "RETRACT_SPEED")?,
            "UNRETRACT_EXTRA_LENGTH" => settings.extra_prime = bounded(value * MM, column)?,
            "UNRETRACT_SPEED" => settings.prime_speed = positive(value * MM, column, "UNRETRACT_SPEED")?,
            _ => return Ok(false),
        }
        Ok(true)
    }
}

/// The number in an extended command's `KEY=VALUE` (Klipper reads it with Python's `float`, so an
/// exponent is fine; NaN and infinities are not).
fn extended_number(name: &str, param: &ExtendedParam) -> Result<f64, Fault> {
    match param.value.trim().parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(Fault::new(param.column, format!("{name} {}={:?}: not a finite number", param.key, param.value))),
    }
}
