//! Interpretation: the modal state of a program and the segments each block makes. The state and
//! every method on it live here and in the children (`arcs`: `G2`/`G3`; `firmware`: the firmware
//! codes and Klipper's extended commands; `rotary`: the rotary words `A`/`B`/`C` and the tool
//! direction; `tags`: the slicers' annotations). The pure helpers they use — arc geometry, the code
//! tables, the dialects' and the limits' state, the rotary mapping, the lexer — sit beside this
//! module and never name the interpreter, so the parser's modules import each other without a loop.

mod arcs;
mod firmware;
mod rotary;
mod tags;

use std::collections::VecDeque;

use nalgebra::Vector3;

use super::arc::segment_length;
use super::block::{Block, Code};
use super::codes::{FirmwareM, GAction, MAction, Motion, Plane, classify_g, classify_m, ignored_g_message, ignored_m_message};
use super::dialect::{Dialect, Firmware};
use super::lexer::{Fault, Value, bounded, code_name, finite};
use super::report::Reports;
use super::{GcodeOptions, GcodeSegment, MM, Tags, ZERO_LENGTH};
use rotary::{Rotary, Tool, ZERO_ANGLE};
use strand_core::{Segment, SegmentFlags, SegmentKind};

/// Modes that persist from line to line.
pub(super) struct Modal {
    pub(super) motion: Option<Motion>,
    pub(super) plane: Plane,
    /// Metres per program length unit.
    pub(super) unit: f64,
    pub(super) absolute: bool,
    pub(super) absolute_e: bool,
    pub(super) absolute_arc_centres: bool,
    /// Modal feed (m/s).
    pub(super) feed: Option<f64>,
    /// Last feed given on a line executing G0 (m/s).
    pub(super) rapid_feed: Option<f64>,
    /// The numbers of those two `F` words as written: a move of the rotary axes alone reads them
    /// as degrees per minute.
    pub(super) feed_number: Option<f64>,
    pub(super) rapid_feed_number: Option<f64>,
}

/// Where the machine is.
pub(super) struct Machine {
    /// Physical position (m).
    pub(super) position: Vector3<f64>,
    /// physical = program · unit + offset (m), set by G92.
    pub(super) offset: Vector3<f64>,
    /// Extruder position (m of filament), as G92 E sets it.
    pub(super) extruder: f64,
}

/// The codes of one line, sorted by what they do.
#[derive(Default)]
pub(super) struct Plan {
    pub(super) motion: Option<(Motion, usize)>,
    pub(super) cancel_motion: bool,
    pub(super) dwell: Option<usize>,
    pub(super) plane: Option<Plane>,
    pub(super) unit: Option<f64>,
    pub(super) absolute: Option<bool>,
    pub(super) absolute_arc_centres: Option<bool>,
    pub(super) set_position: Option<usize>,
    pub(super) reset_offsets: bool,
    pub(super) absolute_e: Option<bool>,
    pub(super) program_end: bool,
    /// A code that owns the line's leftover parameters (all of them, axes too, if the flag is set).
    pub(super) owner: Option<(usize, bool)>,
    /// `G10` (true) or `G11` (false) as firmware retraction, and its column.
    pub(super) retract: Option<(bool, usize)>,
    /// A firmware M-code acted on, and its column.
    pub(super) firmware: Option<(FirmwareM, usize)>,
    /// `F` is an M-code's parameter, not the modal feed (firmware dialect, or `M207 F`).
    pub(super) f_is_parameter: bool,
    /// `T` selects a tool (no M-code on the line but M6); otherwise it is an M-code's parameter.
    pub(super) t_is_tool: bool,
}

/// Which modal group a code is in, for the one-per-line check.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(super) enum Group {
    Motion,
    Plane,
    Units,
    Distance,
    ArcDistance,
    Extruder,
    Retraction,
}

pub(super) struct Interpreter {
    pub(super) options: GcodeOptions,
    pub(super) modal: Modal,
    pub(super) machine: Machine,
    pub(super) tags: Tags,
    pub(super) layer_marker_pending: bool,
    /// A line or arc was emitted since the last layer marker (two markers with no motion between
    /// them, e.g. Orca's `;LAYER_CHANGE` and `; CHANGE_LAYER`, are one layer change).
    pub(super) moved_since_marker: bool,
    pub(super) firmware: Firmware,
    pub(super) next_seq: u64,
    pub(super) warnings: Reports,
    pub(super) notes: Reports,
    /// A `%` or code was seen: a later `%` ends the program.
    pub(super) started: bool,
    /// M2, M30 or a closing `%` was executed.
    pub(super) ended: bool,
    pub(super) groups_seen: Vec<(Group, usize)>,
    /// The rotary axes (`A`/`B`/`C`) and the tool direction.
    rotary: Rotary,
    tool: Tool,
}

pub(super) const AXES: [u8; 3] = [b'X', b'Y', b'Z'];
pub(super) const POSITION_WORDS: [u8; 4] = [b'X', b'Y', b'Z', b'E'];
pub(super) const ARC_WORDS: [u8; 4] = [b'I', b'J', b'K', b'R'];
pub(super) const UNSUPPORTED_AXES: [u8; 6] = [b'A', b'B', b'C', b'U', b'V', b'W'];

impl Interpreter {
    pub(super) fn new(options: GcodeOptions) -> Self {
        Interpreter {
            modal: Modal {
                motion: None,
                plane: Plane::Xy,
                unit: MM,
                absolute: true,
                absolute_e: true,
                absolute_arc_centres: false,
                feed: None,
                rapid_feed: None,
                feed_number: None,
                rapid_feed_number: None,
            },
            machine: Machine { position: options.start, offset: Vector3::zeros(), extruder: 0.0 },
            tags: Tags::default(),
            layer_marker_pending: false,
            moved_since_marker: false,
            firmware: Firmware::new(options.dialect, options.firmware_retraction),
            next_seq: options.first_seq,
            warnings: Reports::default(),
            notes: Reports::default(),
            started: false,
            ended: false,
            groups_seen: Vec::with_capacity(8),
            rotary: Rotary::default(),
            tool: Tool { current: options.orientation, target: options.orientation },
            options,
        }
    }

    /// A `%` line: the first, before any code, opens the program; a later one ends it.
    pub(super) fn percent(&mut self) {
        if self.started {
            self.ended = true;
        }
        self.started = true;
    }

    /// After the program's end: count lines that still hold code.
    pub(super) fn count_after_end(&mut self, bytes: &[u8], line: usize) {
        let text = String::from_utf8_lossy(bytes);
        let code = text.trim_start();
        if !code.is_empty() && !code.starts_with([';', '(', '%']) {
            self.warnings.record("after end", line, 1, || "code after the program's end (M2, M30 or %) not executed".into());
        }
    }

    /// Executes one block in RS274/NGC order: feed, tool, unacted codes, extruder mode, dwell,
    /// retraction, modes, G92, firmware M-code, motion, words left over, program end. `unread` is a
    /// word the lexer could not read on an M-code line: an error unless the line's codes are all
    /// ones the parser does not act on (whose parameters it does not read).
    pub(super) fn execute(
        &mut self,
        block: &mut Block,
        line: usize,
        unread: Option<Fault>,
        out: &mut VecDeque<GcodeSegment>,
    ) -> Result<(), Fault> {
        self.started = true;
        let plan = self.plan(block, line)?;
        if let Some(fault) = unread
            && (!block.g.is_empty() || plan.firmware.is_some() || plan.absolute_e.is_some() || plan.program_end)
        {
            return Err(fault);
        }
        let motion = self.motion_to_execute(&plan, block)?;
        self.read_tool_direction(block, &plan, motion, line)?;
        if !plan.f_is_parameter {
            self.set_feed(block, motion.map(|(m, _)| m), &plan)?;
        }
        if plan.t_is_tool {
            self.select_tool(block, line)?;
        }
        if let Some(absolute_e) = plan.absolute_e {
            self.modal.absolute_e = absolute_e;
        }
        if let Some(column) = plan.dwell {
            self.dwell(block, line, column, out)?;
        }
        if let Some((retract, column)) = plan.retract {
            self.firmware_retract(retract, line, column, out)?;
        }
        self.apply_modes(&plan);
        if plan.set_position.is_some() {
            self.set_position(block, line)?;
        }
        if plan.reset_offsets {
            self.machine.offset = Vector3::zeros();
            self.rotary.offset = Default::default();
        }
        if let Some((code, column)) = plan.firmware {
            self.firmware_m(code, block, line, column, out)?;
        }
        if let Some((motion, column)) = motion {
            self.move_to(block, motion, column, line, out)?;
        }
        self.report_leftovers(block, &plan, line)?;
        if plan.program_end {
            self.ended = true;
        }
        Ok(())
    }

    /// Sorts the line's codes; rejects unsupported ones and two of one modal group.
    pub(super) fn plan(&mut self, block: &Block, line: usize) -> Result<Plan, Fault> {
        let mut plan = Plan {
            // Marlin reads F only on G0/G1: beside an M-code it is that code's parameter (Bambu's
            // `M620.1 E F523 T240`); RS274/NGC reads F on any line.
            f_is_parameter: self.firmware.dialect == Dialect::Firmware && block.g.is_empty() && !block.m.is_empty(),
            t_is_tool: block.m.iter().all(|m| m.tenths == 60),
            ..Plan::default()
        };
        self.groups_seen.clear();
        for code in &block.g {
            self.plan_g(*code, block, &mut plan, line)?;
        }
        for code in &block.m {
            self.plan_m(*code, block, &mut plan, line)?;
        }
        Ok(plan)
    }

    pub(super) fn claim_group(&mut self, group: Group, code: Code, letter: char) -> Result<(), Fault> {
        if let Some((_, first)) = self.groups_seen.iter().find(|(g, _)| *g == group) {
            let message = format!("{} conflicts with another code of its group at column {first}", code_name(letter, code.tenths));
            return Err(Fault::new(code.column, message));
        }
        self.groups_seen.push((group, code.column));
        Ok(())
    }

    pub(super) fn plan_g(&mut self, code: Code, block: &Block, plan: &mut Plan, line: usize) -> Result<(), Fault> {
        match classify_g(code.tenths, self.firmware.dialect, block) {
            GAction::Motion(motion) => {
                self.claim_group(Group::Motion, code, 'G')?;
                plan.motion = Some((motion, code.column));
            }
            GAction::CancelMotion => {
                self.claim_group(Group::Motion, code, 'G')?;
                plan.cancel_motion = true;
            }
            GAction::Dwell => plan.dwell = Some(code.column),
            GAction::Plane(plane) => {
                self.claim_group(Group::Plane, code, 'G')?;
                plan.plane = Some(plane);
            }
            GAction::Units(unit) => {
                self.claim_group(Group::Units, code, 'G')?;
                plan.unit = Some(unit);
            }
            GAction::Absolute(absolute) => {
                self.claim_group(Group::Distance, code, 'G')?;
                plan.absolute = Some(absolute);
            }
            GAction::AbsoluteArcCentres(absolute) => {
                self.claim_group(Group::ArcDistance, code, 'G')?;
                plan.absolute_arc_centres = Some(absolute);
            }
            GAction::SetPosition => plan.set_position = Some(code.column),
            GAction::ResetOffsets => plan.reset_offsets = true,
            GAction::Retract(retract) => {
                self.claim_group(Group::Retraction, code, 'G')?;
                plan.retract = Some((retract, code.column));
                plan.owner = Some(merge_owner(plan.owner, code.column, true));
            }
            GAction::Ignored { takes_axes } => {
                let name = code_name('G', code.tenths);
                self.warnings.record(&name, line, code.column, || ignored_g_message(code.tenths).to_string());
                plan.owner = Some(merge_owner(plan.owner, code.column, takes_axes));
            }
            GAction::Unsupported(what) => {
                return Err(Fault::new(code.column, format!("unsupported motion {} ({what})", code_name('G', code.tenths))));
            }
        }
        Ok(())
    }

    pub(super) fn plan_m(&mut self, code: Code, block: &Block, plan: &mut Plan, line: usize) -> Result<(), Fault> {
        match classify_m(code.tenths, self.firmware.dialect) {
            MAction::ExtruderMode { absolute } => {
                self.claim_group(Group::Extruder, code, 'M')?;
                plan.absolute_e = Some(absolute);
            }
            MAction::ProgramEnd => plan.program_end = true,
            MAction::Firmware(firmware) => {
                if block.has_other_code(code.column) {
                    let message = format!("{} must be alone on its line: its words are its parameters", code_name('M', code.tenths));
                    return Err(Fault::new(code.column, message));
                }
                plan.firmware = Some((firmware, code.column));
                plan.f_is_parameter = true;
                plan.owner = Some(merge_owner(plan.owner, code.column, true));
            }
            MAction::Ignored => {
                let name = code_name('M', code.tenths);
                self.warnings.record(&name, line, code.column, || ignored_m_message(code.tenths).to_string());
                plan.owner = Some(merge_owner(plan.owner, code.column, true));
            }
        }
        Ok(())
    }

    /// The motion this line executes, if any: its own G0..G3 when it has position words (or, for an
    /// arc, centre words), else the modal motion when it has such words that nothing else owns.
    pub(super) fn motion_to_execute(&mut self, plan: &Plan, block: &Block) -> Result<Option<(Motion, usize)>, Fault> {
        if plan.cancel_motion {
            self.modal.motion = None;
        }
        if let Some((motion, column)) = plan.motion {
            self.modal.motion = Some(motion);
            if plan.set_position.is_some() && self.has_position_word(block) {
                return Err(Fault::new(column, format!("{} and G92 on one line both use the axis words", motion.name())));
            }
            return Ok(self.moves(block, motion).then_some((motion, column)));
        }
        let axes_taken = plan.set_position.is_some() || plan.owner.is_some_and(|(_, takes_axes)| takes_axes);
        let wants_motion = self.has_position_word(block) || (self.modal.motion.is_some_and(Motion::is_arc) && block.has_any(&ARC_WORDS));
        if axes_taken || !wants_motion {
            return Ok(None);
        }
        let position_column = match (first_column(block, &POSITION_WORDS), self.rotary_column(block)) {
            (0, c) | (c, 0) => c,
            (a, b) => a.min(b),
        };
        let column = position_column.max(first_column(block, &ARC_WORDS));
        match self.modal.motion {
            Some(motion) => Ok(Some((motion, column))),
            None => Err(Fault::new(column, "axis words but no motion mode (G0, G1, G2, G3) is active")),
        }
    }

    /// F: the modal feed, and the rapid feed if this line executes a G0.
    pub(super) fn set_feed(&mut self, block: &mut Block, motion: Option<Motion>, plan: &Plan) -> Result<(), Fault> {
        let Some(f) = block.take(b'F')? else { return Ok(()) };
        if f <= 0.0 {
            return Err(Fault::new(block.column(b'F'), format!("F{f} is an error: the feed must be > 0")));
        }
        let unit = plan.unit.unwrap_or(self.modal.unit);
        let feed = f * unit / 60.0;
        if feed <= 0.0 {
            return Err(Fault::new(block.column(b'F'), format!("F{f} is too small to be a feed")));
        }
        self.modal.feed = Some(feed);
        self.modal.feed_number = Some(f);
        if motion == Some(Motion::Rapid) || (motion.is_none() && plan.motion.is_some_and(|(m, _)| m == Motion::Rapid)) {
            self.modal.rapid_feed = Some(feed);
            self.modal.rapid_feed_number = Some(f);
        }
        Ok(())
    }

    pub(super) fn apply_modes(&mut self, plan: &Plan) {
        if let Some(plane) = plan.plane {
            self.modal.plane = plane;
        }
        if let Some(unit) = plan.unit {
            self.modal.unit = unit;
        }
        if let Some(absolute) = plan.absolute {
            self.modal.absolute = absolute;
            self.modal.absolute_e = absolute;
        }
        if let Some(absolute) = plan.absolute_arc_centres {
            self.modal.absolute_arc_centres = absolute;
        }
    }

    /// G4: S seconds; P milliseconds in the firmware dialect (Marlin, RepRapFirmware, Klipper),
    /// seconds in RS274/NGC (LinuxCNC).
    pub(super) fn dwell(&mut self, block: &mut Block, line: usize, column: usize, out: &mut VecDeque<GcodeSegment>) -> Result<(), Fault> {
        let seconds = block.take(b'S')?;
        let p = block.take(b'P')?;
        let duration = match (seconds, p) {
            (Some(_), Some(_)) => return Err(Fault::new(block.column(b'P'), "G4 with both P and S: which is the dwell time?")),
            (Some(s), None) => s,
            (None, Some(p)) if self.firmware.dialect == Dialect::Firmware => p / 1000.0,
            (None, Some(p)) => p,
            (None, None) => 0.0,
        };
        if duration < 0.0 {
            return Err(Fault::new(column, format!("negative dwell time {duration} s")));
        }
        let duration = dwell_time(duration, 0.0, column, "G4 dwell time")?;
        let segment = Segment { kind: SegmentKind::Dwell, end: self.machine.position, duration, ..Segment::default() };
        self.emit(segment, line, out);
        Ok(())
    }

    /// G92: the given axes (all, E included, if none) take the given values at the current
    /// position. An axis letter without a number is left as it is, as Marlin does (its G92 reads
    /// only axes with a value), with a note.
    pub(super) fn set_position(&mut self, block: &mut Block, line: usize) -> Result<(), Fault> {
        let unit = self.modal.unit;
        if !self.has_position_word(block) {
            self.machine.offset = self.machine.position;
            self.machine.extruder = 0.0;
            self.rotary.offset = self.rotary.machine;
            return Ok(());
        }
        for (axis, letter) in POSITION_WORDS.iter().enumerate() {
            let Some(param) = block.take_param(*letter) else { continue };
            if param.value == Value::Bare {
                let kind = format!("G92 {}", *letter as char);
                self.notes.record(&kind, line, param.column, || format!("{kind} without a number: left unchanged, as Marlin does"));
                continue;
            }
            let value = bounded(param.number(*letter)? * unit, param.column)?;
            match axis {
                3 => self.machine.extruder = value,
                _ => self.machine.offset[axis] = bounded(self.machine.position[axis] - value, param.column)?,
            }
        }
        self.rotary_set_position(block, line)
    }

    /// Physical target of the XYZ words (m), marking them used.
    pub(super) fn target(&self, block: &mut Block) -> Result<Vector3<f64>, Fault> {
        let mut target = self.machine.position;
        for (axis, letter) in AXES.iter().enumerate() {
            if let Some(value) = block.take(*letter)? {
                let metres = value * self.modal.unit;
                let coordinate = if self.modal.absolute { metres + self.machine.offset[axis] } else { target[axis] + metres };
                target[axis] = bounded(coordinate, block.column(*letter))?;
            }
        }
        Ok(target)
    }

    /// Filament pushed by the E word (m) after the flow percentage (`M221`), updating the
    /// extruder position (which, as in firmware, stays the program's: unscaled).
    pub(super) fn extrusion(&mut self, block: &mut Block) -> Result<f64, Fault> {
        let Some(e) = block.take(b'E')? else { return Ok(0.0) };
        let column = block.column(b'E');
        let metres = e * self.modal.unit;
        let (delta, extruder) = match self.modal.absolute_e {
            true => (metres - self.machine.extruder, metres),
            false => (metres, self.machine.extruder + metres),
        };
        self.machine.extruder = bounded(extruder, column)?;
        bounded(delta * self.firmware.flow_factor(), column)
    }

    /// The feed (m/s) a motion runs at: see the module's choices for G0.
    pub(super) fn feed_for(&self, motion: Motion, column: usize) -> Result<f64, Fault> {
        let programmed = match motion {
            Motion::Rapid => self.modal.rapid_feed.or(self.modal.feed),
            _ => self.modal.feed,
        };
        match (programmed, motion) {
            (Some(feed), _) => Ok(feed),
            (None, Motion::Rapid) if self.options.rapid_feed.is_finite() && self.options.rapid_feed > 0.0 => Ok(self.options.rapid_feed),
            (None, Motion::Rapid) => {
                Err(Fault::new(column, format!("G0 before any F, and the options' rapid feed {} m/s is not > 0", self.options.rapid_feed)))
            }
            (None, _) => Err(Fault::new(column, format!("{} with no feed rate: no F given yet", motion.name()))),
        }
    }

    /// A G0..G3 move: the feed after the feed percentage (`M220`) and the velocity limits, the
    /// target, the filament; an E-only move becomes a dwell.
    pub(super) fn move_to(
        &mut self,
        block: &mut Block,
        motion: Motion,
        column: usize,
        line: usize,
        out: &mut VecDeque<GcodeSegment>,
    ) -> Result<(), Fault> {
        let feed = self.feed_for(motion, column)? * self.firmware.feed_factor();
        let start = self.machine.position;
        let target = self.target(block)?;
        let turn = self.rotary_target(block)?;
        let filament = self.extrusion(block)?;
        if motion.is_arc() {
            let arc = self.arc(block, motion, column, target)?;
            let normal_axis = self.modal.plane.axes().normal;
            let segment = Segment {
                kind: SegmentKind::Arc,
                end: target,
                centre: arc.centre,
                normal: arc.normal,
                sweep: arc.sweep,
                ..Segment::default()
            };
            let length = segment_length(&start, &segment).max(ZERO_LENGTH);
            let mut shares = [1.0, 1.0, 1.0, filament.abs() / length];
            shares[normal_axis] = (target[normal_axis] - start[normal_axis]).abs() / length;
            let feed = positive_feed(self.limit_feed(feed, shares, line), column)?;
            self.emit_move(segment, feed, filament, line, out);
            return Ok(());
        }
        let displacement = target - start;
        let length = displacement.norm();
        if length >= ZERO_LENGTH {
            let shares =
                [displacement.x.abs() / length, displacement.y.abs() / length, displacement.z.abs() / length, filament.abs() / length];
            let feed = positive_feed(self.limit_feed(feed, shares, line), column)?;
            self.emit_move(Segment { kind: SegmentKind::Line, end: target, ..Segment::default() }, feed, filament, line, out);
            return Ok(());
        }
        self.direction_waits(line, column);
        if let Some(turn) = turn.filter(|t| *t > ZERO_ANGLE) {
            return self.rotary_dwell(block, motion, turn, filament, column, line, out);
        }
        if filament != 0.0 {
            let duration = finite(filament.abs() / feed, column)?;
            let duration = self.limit_extruder_time(filament, duration, line);
            let duration = dwell_time(duration, filament, block.column(b'E').max(column), "extruder-only move")?;
            let segment = Segment { kind: SegmentKind::Dwell, end: self.machine.position, filament, duration, ..Segment::default() };
            self.emit(segment, line, out);
        } else {
            self.notes.record("zero-length", line, column, || "zero-length move skipped".into());
        }
        Ok(())
    }

    /// Emits a line or arc with its feed, filament and extrude/travel flag; moves the machine.
    pub(super) fn emit_move(&mut self, mut segment: Segment, feed: f64, filament: f64, line: usize, out: &mut VecDeque<GcodeSegment>) {
        segment.feed = feed;
        segment.filament = filament;
        segment.flags = if filament > 0.0 { SegmentFlags::EXTRUDE } else { SegmentFlags::TRAVEL };
        if self.layer_marker_pending {
            segment.flags = segment.flags.with(SegmentFlags::LAYER_START);
            self.layer_marker_pending = false;
        }
        self.moved_since_marker = true;
        self.machine.position = segment.end;
        self.tool.current = self.tool.target;
        self.emit(segment, line, out);
    }

    pub(super) fn emit(&mut self, mut segment: Segment, line: usize, out: &mut VecDeque<GcodeSegment>) {
        segment.seq = self.next_seq;
        self.next_seq = self.next_seq.wrapping_add(1);
        segment.orientation = self.tool.current;
        if segment.axes.is_none() {
            segment.axes = self.axes();
        }
        segment.source_line = u32::try_from(line).unwrap_or(u32::MAX);
        // Every segment after a pressure-advance command carries it, so a job resumed part-way
        // still prints with the program's value.
        segment.pressure_advance = self.firmware.limits.recorded.pressure_advance.map(|k| k.value);
        if segment.filament > 0.0 {
            self.firmware.tool_used = true;
        }
        out.push_back(GcodeSegment { segment, line, tags: self.tags.clone() });
    }

    /// Words no code acted on: parameters of a code that owns them, or warned once per kind; a
    /// letter without a number that no code takes as a flag, and unsupported axes, are errors.
    pub(super) fn report_leftovers(&mut self, block: &mut Block, plan: &Plan, line: usize) -> Result<(), Fault> {
        if !plan.f_is_parameter {
            block.take(b'F')?;
        }
        if plan.owner.is_some() {
            block.mark_all_used();
        }
        for (letter, param) in block.unused() {
            if UNSUPPORTED_AXES.contains(&letter) {
                return Err(Fault::new(param.column, format!("unsupported axis word {}", letter as char)));
            }
            if param.value == Value::Bare {
                return Err(Fault::new(param.column, format!("{} without a number", letter as char)));
            }
            let kind = format!("word {}", letter as char);
            let context = if letter == b'S' { "spindle speed / S parameter not acted on" } else { "word not used by any code on its line" };
            self.warnings.record(&kind, line, param.column, || context.into());
        }
        Ok(())
    }
}

/// Keeps the first owner's column; takes axes if any owner does.
pub(super) fn merge_owner(owner: Option<(usize, bool)>, column: usize, takes_axes: bool) -> (usize, bool) {
    match owner {
        Some((first, takes)) => (first, takes || takes_axes),
        None => (column, takes_axes),
    }
}

impl Interpreter {
    /// True if the line has a position word: X Y Z E, or a mapped rotary word.
    pub(super) fn has_position_word(&self, block: &Block) -> bool {
        block.has_any(&POSITION_WORDS) || self.has_rotary_word(block)
    }

    /// True if an explicit `motion` code on this block moves: position words, or centre words for
    /// an arc (`G2 I.5 J.5` is a full circle where it stands).
    pub(super) fn moves(&self, block: &Block, motion: Motion) -> bool {
        self.has_position_word(block) || (motion.is_arc() && block.has_any(&ARC_WORDS))
    }
}

/// Longest dwell (s): `Segment::check` takes durations below it.
pub(super) const MAX_DWELL: f64 = 1e6;

/// A dwell's duration (s) as `Segment::check` takes it: below [`MAX_DWELL`], and > 0 if it moves
/// filament; else an error at `column` naming `what`.
pub(super) fn dwell_time(duration: f64, filament: f64, column: usize, what: &str) -> Result<f64, Fault> {
    let moves_filament = filament != 0.0;
    if duration < MAX_DWELL && (duration > 0.0 || (!moves_filament && duration == 0.0)) {
        return Ok(duration);
    }
    let range = if moves_filament { "(0, 1e6) s (a dwell that moves filament takes time)" } else { "[0, 1e6) s" };
    Err(Fault::new(column, format!("{what}: {duration} s is not in {range}")))
}

/// A line's or arc's feed (m/s) after the percentages and limits: > 0 (a feed too small for a
/// float is an error, never a segment the path engine refuses).
fn positive_feed(feed: f64, column: usize) -> Result<f64, Fault> {
    if feed > 0.0 && feed.is_finite() { Ok(feed) } else { Err(Fault::new(column, format!("feed {feed} m/s is too small to move at"))) }
}

/// Column of the first of `letters` present (0 if none).
pub(super) fn first_column(block: &Block, letters: &[u8]) -> usize {
    letters.iter().map(|l| block.column(*l)).filter(|c| *c > 0).min().unwrap_or(0)
}
