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
use strand_core::{HeatRequest, HeatWait, Heater, MAX_TEMPERATURE, OPEN_BAND, Segment, SegmentKind};

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
    pub(super) fn firmware_m(
        &mut self,
        code: FirmwareM,
        block: &mut Block,
        line: usize,
        column: usize,
        out: &mut VecDeque<GcodeSegment>,
    ) -> Result<(), Fault> {
        let limit = match code {
            FirmwareM::Heat { bed, wait } => return self.heat_m(bed, wait, block, line, column, out),
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

    /// M104/M109 (hot end), M140/M190 (bed), as Marlin reads them: `S` sets the target (°C); on
    /// M109/M190 `S` waits only while heating and `R` waits either way. `T` naming another tool
    /// than the selected one is reported and not acted on (jobs use one tool). A heat segment is
    /// emitted where the line stands in the program: the controller applies it there, and holds
    /// the job at a wait until the temperature has settled.
    fn heat_m(
        &mut self,
        bed: bool,
        wait: bool,
        block: &mut Block,
        line: usize,
        column: usize,
        out: &mut VecDeque<GcodeSegment>,
    ) -> Result<(), Fault> {
        let name = match (bed, wait) {
            (false, false) => "M104",
            (false, true) => "M109",
            (true, false) => "M140",
            (true, true) => "M190",
        };
        if !bed
            && let Some(t) = block.take(b'T')?
            && t != f64::from(self.firmware.tool)
        {
            self.warnings.record(&format!("{name} T"), line, column, || {
                format!("{name} T{t}: a temperature for another tool than the selected one is not acted on (jobs use one tool)")
            });
            return Ok(());
        }
        let s = block.take(b'S')?;
        let r = if wait { block.take(b'R')? } else { None };
        let (value, at, mode) = match (s, r) {
            (Some(_), Some(_)) => {
                return Err(Fault::new(
                    block.column(b'R'),
                    format!("{name}: S and R both given; S waits while heating, R either way: give one"),
                ));
            }
            (Some(v), None) => (v, block.column(b'S'), if wait { HeatWait::Heating } else { HeatWait::None }),
            (None, Some(v)) => (v, block.column(b'R'), HeatWait::Both),
            (None, None) => {
                self.warnings.record(name, line, column, || format!("{name} without S: no target, nothing to do"));
                return Ok(());
            }
        };
        let letter = if mode == HeatWait::Both { 'R' } else { 'S' };
        let target = in_range(value, (0.0, MAX_TEMPERATURE), at, &format!("{name} {letter} (°C)"))?;
        let heater = if bed { Heater::Bed } else { Heater::HotEnd };
        self.notes.record(name, line, column, || match mode {
            HeatWait::None => format!("{name}: heater target set where it stands in the job"),
            _ => format!("{name}: heater target set, and the job holds until the temperature has settled"),
        });
        self.emit_heat(HeatRequest { heater, wait: mode, target, band: OPEN_BAND }, line, out);
        Ok(())
    }

    /// A heat segment at the machine's position.
    fn emit_heat(&mut self, heat: HeatRequest, line: usize, out: &mut VecDeque<GcodeSegment>) {
        let segment = Segment { kind: SegmentKind::Heat, end: self.machine.position, heat, ..Segment::default() };
        self.emit(segment, line, out);
    }

    /// Klipper's `SET_HEATER_TEMPERATURE HEATER= TARGET=` (TARGET absent: 0, off, as Klipper) and
    /// `TEMPERATURE_WAIT SENSOR= MINIMUM= MAXIMUM=` (at least one bound). `extruder` and
    /// `heater_bed` are acted on; other heaters and sensors are reported.
    fn klipper_heat(
        &mut self,
        name: &str,
        params: &[ExtendedParam],
        line: usize,
        column: usize,
        out: &mut VecDeque<GcodeSegment>,
    ) -> Result<(), Fault> {
        let set = name == "SET_HEATER_TEMPERATURE";
        let which_key = if set { "HEATER" } else { "SENSOR" };
        let mut which: Option<&ExtendedParam> = None;
        let mut numbers: [Option<(f64, usize)>; 3] = [None; 3];
        for param in params {
            let slot = match (set, param.key.as_str()) {
                (_, k) if k == which_key => {
                    which = Some(param);
                    continue;
                }
                (true, "TARGET") => 0,
                (false, "MINIMUM") => 1,
                (false, "MAXIMUM") => 2,
                _ => {
                    let kind = format!("{name} parameters");
                    self.warnings
                        .record(&kind, line, param.column, || format!("{name}: parameters other than the ones acted on are not acted on"));
                    continue;
                }
            };
            numbers[slot] = Some((extended_number(name, param)?, param.column));
        }
        let Some(which) = which else {
            return Err(Fault::new(column, format!("{name}: {which_key}= is required (extruder or heater_bed)")));
        };
        let heater = match which.value.trim() {
            "extruder" => Heater::HotEnd,
            "heater_bed" => Heater::Bed,
            other => {
                let kind = format!("{name} {other}");
                self.warnings.record(&kind, line, which.column, || {
                    format!("{name} {which_key}={other}: only extruder and heater_bed are acted on (jobs use one tool)")
                });
                return Ok(());
            }
        };
        let request = if set {
            let (target, at) = numbers[0].unwrap_or((0.0, column));
            let target = in_range(target, (0.0, MAX_TEMPERATURE), at, &format!("{name} TARGET (°C)"))?;
            HeatRequest { heater, wait: HeatWait::None, target, band: OPEN_BAND }
        } else {
            if numbers[1].is_none() && numbers[2].is_none() {
                return Err(Fault::new(column, format!("{name}: MINIMUM= or MAXIMUM= is required")));
            }
            let (low, at_low) = numbers[1].unwrap_or((OPEN_BAND[0], column));
            let (high, at_high) = numbers[2].unwrap_or((OPEN_BAND[1], column));
            let low = in_range(low, (OPEN_BAND[0], MAX_TEMPERATURE), at_low, &format!("{name} MINIMUM (°C)"))?;
            let high = in_range(high, (OPEN_BAND[0], OPEN_BAND[1]), at_high, &format!("{name} MAXIMUM (°C)"))?;
            if low > high {
                return Err(Fault::new(at_high, format!("{name}: MINIMUM {low} is above MAXIMUM {high}")));
            }
            HeatRequest { heater, wait: HeatWait::Range, target: -1.0, band: [low, high] }
        };
        self.notes.record(name, line, column, || match set {
            true => format!("{name}: heater target set where it stands in the job"),
            false => format!("{name}: the job holds until the temperature is in range and has settled"),
        });
        self.emit_heat(request, line, out);
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
        out: &mut VecDeque<GcodeSegment>,
    ) -> Result<(), Fault> {
        if self.firmware.dialect == Dialect::Rs274ngc {
            return Err(Fault::new(column, format!("{name}: not an RS274/NGC word (a Klipper command in a .ngc/.nc/.tap file?)")));
        }
        let acted = matches!(
            name,
            "SET_VELOCITY_LIMIT" | "SET_PRESSURE_ADVANCE" | "SET_RETRACTION" | "SET_HEATER_TEMPERATURE" | "TEMPERATURE_WAIT"
        );
        if !acted {
            self.warnings.record(name, line, column, || format!("extended command {name} not acted on"));
            return Ok(());
        }
        if let Some(fault) = malformed {
            return Err(fault);
        }
        if matches!(name, "SET_HEATER_TEMPERATURE" | "TEMPERATURE_WAIT") {
            return self.klipper_heat(name, params, line, column, out);
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
