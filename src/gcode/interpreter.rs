//! Interpretation: the modal state of a program and the segments each block makes.

use std::collections::VecDeque;

use nalgebra::Vector3;

use super::block::{Block, Code};
use super::lexer::{Fault, code_name, code_tenths};
use super::report::Reports;
use super::{GcodeOptions, GcodeSegment, INCH, MM, Tags, ZERO_LENGTH};
use crate::core::path::{Segment, SegmentFlags, SegmentKind};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Motion {
    Rapid,
    Linear,
    Clockwise,
    CounterClockwise,
}

impl Motion {
    pub(super) fn name(self) -> &'static str {
        match self {
            Motion::Rapid => "G0",
            Motion::Linear => "G1",
            Motion::Clockwise => "G2",
            Motion::CounterClockwise => "G3",
        }
    }

    pub(super) fn is_arc(self) -> bool {
        matches!(self, Motion::Clockwise | Motion::CounterClockwise)
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Plane {
    Xy,
    Zx,
    Yz,
}

/// An arc plane as LinuxCNC orders it: (first, second, normal) form a right-handed frame, and G3
/// turns from first towards second.
pub(super) struct PlaneAxes {
    pub(super) first: usize,
    pub(super) second: usize,
    pub(super) normal: usize,
    /// Centre-offset letters along first, second and normal.
    pub(super) offsets: [u8; 3],
    pub(super) name: &'static str,
}

impl Plane {
    pub(super) fn axes(self) -> PlaneAxes {
        match self {
            Plane::Xy => PlaneAxes { first: 0, second: 1, normal: 2, offsets: [b'I', b'J', b'K'], name: "XY plane (G17)" },
            Plane::Zx => PlaneAxes { first: 2, second: 0, normal: 1, offsets: [b'K', b'I', b'J'], name: "ZX plane (G18)" },
            Plane::Yz => PlaneAxes { first: 1, second: 2, normal: 0, offsets: [b'J', b'K', b'I'], name: "YZ plane (G19)" },
        }
    }
}

/// What a G-code does here.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum GAction {
    Motion(Motion),
    CancelMotion,
    Dwell,
    Plane(Plane),
    Units(f64),
    Absolute(bool),
    AbsoluteArcCentres(bool),
    SetPosition,
    ResetOffsets,
    /// Not acted on; true if it takes axis words (`G28 X0`).
    Ignored {
        takes_axes: bool,
    },
    /// Acting on it would change the path, ignoring it too: an error.
    Unsupported(&'static str),
}

pub(super) fn classify_g(tenths: u32) -> GAction {
    use GAction::*;
    match tenths {
        0 => Motion(self::Motion::Rapid),
        10 => Motion(self::Motion::Linear),
        20 => Motion(self::Motion::Clockwise),
        30 => Motion(self::Motion::CounterClockwise),
        1..=39 => Unsupported("unknown motion variant"),
        40 => Dwell,
        170 => Plane(self::Plane::Xy),
        180 => Plane(self::Plane::Zx),
        190 => Plane(self::Plane::Yz),
        200 => Units(INCH),
        210 => Units(MM),
        800 => CancelMotion,
        900 => Absolute(true),
        910 => Absolute(false),
        901 => AbsoluteArcCentres(true),
        911 => AbsoluteArcCentres(false),
        920 => SetPosition,
        921 | 922 => ResetOffsets,
        50..=53 => Unsupported("spline motion"),
        60 => Unsupported("direct stepper motion"),
        70 => Unsupported("lathe diameter mode"),
        330 | 331 => Unsupported("spindle-synchronised motion"),
        382..=385 => Unsupported("probing motion"),
        410 | 411 | 420 | 421 => Unsupported("cutter radius compensation"),
        510 => Unsupported("scaling"),
        520 => Unsupported("local coordinate offset"),
        530 => Unsupported("motion in machine coordinates"),
        680 => Unsupported("coordinate rotation"),
        700..=722 | 730 | 740 | 760 | 810..=890 => Unsupported("canned cycle"),
        930 => Unsupported("inverse-time feed"),
        950 => Unsupported("feed per revolution"),
        100 | 110 | 120 | 260 | 270 | 280 | 281 | 290..=299 | 300 | 301 | 310 | 320 | 340 | 350 => Ignored { takes_axes: true },
        _ => Ignored { takes_axes: false },
    }
}

/// A short description of a code not acted on, for the first warning of its kind.
pub(super) fn ignored_g_message(tenths: u32) -> &'static str {
    match tenths {
        280 | 281 | 300 | 301 => "homing / predefined position not acted on: position unchanged",
        290..=299 => "bed levelling not acted on",
        100 | 110 => "G10/G11 (offsets or firmware retraction) not acted on",
        400 => "cutter compensation off: nothing to do",
        430..=432 | 490 => "tool length offset not acted on",
        540..=593 => "work coordinate system not acted on",
        610 | 611 | 640 => "path control mode not acted on (blending is the path engine's)",
        80 => "lathe radius mode: X is read as a radius, as always here",
        940 => "units-per-minute feed mode: the only one supported",
        _ => "G-code not acted on",
    }
}

pub(super) fn ignored_m_message(tenths: u32) -> &'static str {
    match tenths {
        0 | 10 | 600 => "program pause not acted on",
        30 | 40 | 50 => "spindle / torch not acted on",
        60 => "tool change not acted on",
        70..=90 => "coolant not acted on",
        180 | 840 => "motors off not acted on",
        1040 | 1090 => "hotend temperature not acted on",
        1400 | 1900 => "bed temperature not acted on",
        1060 | 1070 => "fan not acted on",
        2200 => "feed override not acted on: feeds as programmed",
        2210 => "flow override not acted on: filament as programmed",
        _ => "M-code not acted on",
    }
}

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
    /// An E word or M82/M83 has been seen: G4 P is in milliseconds.
    pub(super) slicer_dialect: bool,
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
    /// An unacted code that owns the line's leftover parameters (all of them if it takes axes).
    pub(super) owner: Option<(usize, bool)>,
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
}

pub(super) struct Interpreter {
    pub(super) options: GcodeOptions,
    pub(super) modal: Modal,
    pub(super) machine: Machine,
    pub(super) tags: Tags,
    pub(super) layer_marker_pending: bool,
    pub(super) next_seq: u64,
    pub(super) warnings: Reports,
    pub(super) notes: Reports,
    /// A `%` or code was seen: a later `%` ends the program.
    pub(super) started: bool,
    /// M2, M30 or a closing `%` was executed.
    pub(super) ended: bool,
    pub(super) groups_seen: Vec<(Group, usize)>,
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
                slicer_dialect: false,
            },
            machine: Machine { position: options.start, offset: Vector3::zeros(), extruder: 0.0 },
            tags: Tags::default(),
            layer_marker_pending: false,
            next_seq: options.first_seq,
            warnings: Reports::default(),
            notes: Reports::default(),
            started: false,
            ended: false,
            groups_seen: Vec::with_capacity(8),
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

    /// Executes one block in RS274/NGC order: feed, unacted codes, extruder mode, dwell, modes,
    /// G92, motion, words left over, program end.
    pub(super) fn execute(&mut self, block: &mut Block, line: usize, out: &mut VecDeque<GcodeSegment>) -> Result<(), Fault> {
        self.started = true;
        let plan = self.plan(block, line)?;
        let motion = self.motion_to_execute(&plan, block)?;
        self.set_feed(block, motion.map(|(m, _)| m), &plan)?;
        if let Some(absolute_e) = plan.absolute_e {
            self.modal.absolute_e = absolute_e;
        }
        if block.has(b'E') || plan.absolute_e.is_some() {
            self.modal.slicer_dialect = true;
        }
        if let Some(column) = plan.dwell {
            self.dwell(block, line, column, out)?;
        }
        self.apply_modes(&plan);
        if plan.set_position.is_some() {
            self.set_position(block)?;
        }
        if plan.reset_offsets {
            self.machine.offset = Vector3::zeros();
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
        let mut plan = Plan::default();
        self.groups_seen.clear();
        for code in &block.g {
            self.plan_g(*code, &mut plan, line)?;
        }
        for code in &block.m {
            self.plan_m(*code, &mut plan, line)?;
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

    pub(super) fn plan_g(&mut self, code: Code, plan: &mut Plan, line: usize) -> Result<(), Fault> {
        match classify_g(code.tenths) {
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

    pub(super) fn plan_m(&mut self, code: Code, plan: &mut Plan, line: usize) -> Result<(), Fault> {
        match code.tenths {
            820 | 830 => {
                self.claim_group(Group::Extruder, code, 'M')?;
                plan.absolute_e = Some(code.tenths == 820);
            }
            20 | 300 => plan.program_end = true,
            _ => {
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
            if plan.set_position.is_some() && block.has_any(&POSITION_WORDS) {
                return Err(Fault::new(column, format!("{} and G92 on one line both use the axis words", motion.name())));
            }
            return Ok(moves(block, motion).then_some((motion, column)));
        }
        let axes_taken = plan.set_position.is_some() || plan.owner.is_some_and(|(_, takes_axes)| takes_axes);
        let wants_motion = block.has_any(&POSITION_WORDS) || (self.modal.motion.is_some_and(Motion::is_arc) && block.has_any(&ARC_WORDS));
        if axes_taken || !wants_motion {
            return Ok(None);
        }
        let column = first_column(block, &POSITION_WORDS).max(first_column(block, &ARC_WORDS));
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
        if motion == Some(Motion::Rapid) || (motion.is_none() && plan.motion.is_some_and(|(m, _)| m == Motion::Rapid)) {
            self.modal.rapid_feed = Some(feed);
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

    /// G4: S seconds; P milliseconds in slicer dialect, else seconds.
    pub(super) fn dwell(&mut self, block: &mut Block, line: usize, column: usize, out: &mut VecDeque<GcodeSegment>) -> Result<(), Fault> {
        let seconds = block.take(b'S')?;
        let p = block.take(b'P')?;
        let duration = match (seconds, p) {
            (Some(_), Some(_)) => return Err(Fault::new(block.column(b'P'), "G4 with both P and S: which is the dwell time?")),
            (Some(s), None) => s,
            (None, Some(p)) if self.modal.slicer_dialect => p / 1000.0,
            (None, Some(p)) => p,
            (None, None) => 0.0,
        };
        if duration < 0.0 {
            return Err(Fault::new(column, format!("negative dwell time {duration} s")));
        }
        let segment = Segment { kind: SegmentKind::Dwell, end: self.machine.position, duration, ..Segment::default() };
        self.emit(segment, line, out);
        Ok(())
    }

    /// G92: the given axes (all, E included, if none) take the given values at the current position.
    pub(super) fn set_position(&mut self, block: &mut Block) -> Result<(), Fault> {
        let unit = self.modal.unit;
        if !block.has_any(&POSITION_WORDS) {
            self.machine.offset = self.machine.position;
            self.machine.extruder = 0.0;
            return Ok(());
        }
        for (axis, letter) in AXES.iter().enumerate() {
            if let Some(value) = block.take(*letter)? {
                let offset = self.machine.position[axis] - value * unit;
                self.machine.offset[axis] = finite(offset, block.column(*letter))?;
            }
        }
        if let Some(e) = block.take(b'E')? {
            self.machine.extruder = finite(e * unit, block.column(b'E'))?;
        }
        Ok(())
    }

    /// Physical target of the XYZ words (m), marking them used.
    pub(super) fn target(&self, block: &mut Block) -> Result<Vector3<f64>, Fault> {
        let mut target = self.machine.position;
        for (axis, letter) in AXES.iter().enumerate() {
            if let Some(value) = block.take(*letter)? {
                let metres = value * self.modal.unit;
                let coordinate = if self.modal.absolute { metres + self.machine.offset[axis] } else { target[axis] + metres };
                target[axis] = finite(coordinate, block.column(*letter))?;
            }
        }
        Ok(target)
    }

    /// Filament pushed by the E word (m), updating the extruder position.
    pub(super) fn extrusion(&mut self, block: &mut Block) -> Result<f64, Fault> {
        let Some(e) = block.take(b'E')? else { return Ok(0.0) };
        let column = block.column(b'E');
        let metres = e * self.modal.unit;
        let (delta, extruder) = match self.modal.absolute_e {
            true => (metres - self.machine.extruder, metres),
            false => (metres, self.machine.extruder + metres),
        };
        self.machine.extruder = finite(extruder, column)?;
        finite(delta, column)
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

    pub(super) fn move_to(
        &mut self,
        block: &mut Block,
        motion: Motion,
        column: usize,
        line: usize,
        out: &mut VecDeque<GcodeSegment>,
    ) -> Result<(), Fault> {
        let feed = self.feed_for(motion, column)?;
        let target = self.target(block)?;
        let filament = self.extrusion(block)?;
        if motion.is_arc() {
            let arc = self.arc(block, motion, column, target)?;
            let segment = Segment {
                kind: SegmentKind::Arc,
                end: target,
                centre: arc.centre,
                normal: arc.normal,
                sweep: arc.sweep,
                ..Segment::default()
            };
            self.emit_move(segment, feed, filament, line, out);
            return Ok(());
        }
        let length = (target - self.machine.position).norm();
        if length >= ZERO_LENGTH {
            self.emit_move(Segment { kind: SegmentKind::Line, end: target, ..Segment::default() }, feed, filament, line, out);
            return Ok(());
        }
        if filament != 0.0 {
            let duration = finite(filament.abs() / feed, column)?;
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
        self.machine.position = segment.end;
        self.emit(segment, line, out);
    }

    pub(super) fn emit(&mut self, mut segment: Segment, line: usize, out: &mut VecDeque<GcodeSegment>) {
        segment.seq = self.next_seq;
        self.next_seq = self.next_seq.wrapping_add(1);
        segment.orientation = self.options.orientation;
        segment.source_line = u32::try_from(line).unwrap_or(u32::MAX);
        out.push_back(GcodeSegment { segment, line, tags: self.tags.clone() });
    }

    /// Words no code acted on: parameters of an unacted code, or warned once per kind; unsupported
    /// axes are an error.
    pub(super) fn report_leftovers(&mut self, block: &mut Block, plan: &Plan, line: usize) -> Result<(), Fault> {
        block.take(b'F')?;
        if plan.owner.is_some() {
            block.mark_all_used();
        }
        for (letter, param) in block.unused() {
            if UNSUPPORTED_AXES.contains(&letter) {
                return Err(Fault::new(param.column, format!("unsupported axis word {}", letter as char)));
            }
            if letter == b'T' {
                let kind = match param.value.and_then(code_tenths) {
                    Some(tenths) => code_name('T', tenths),
                    None => "T".to_string(),
                };
                self.warnings.record(&kind, line, param.column, || "tool selection not acted on".into());
            } else {
                let kind = format!("word {}", letter as char);
                let context =
                    if letter == b'S' { "spindle speed / S parameter not acted on" } else { "word not used by any code on its line" };
                self.warnings.record(&kind, line, param.column, || context.into());
            }
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

/// True if an explicit `motion` code on this block moves: position words, or centre words for an
/// arc (`G2 I.5 J.5` is a full circle where it stands).
pub(super) fn moves(block: &Block, motion: Motion) -> bool {
    block.has_any(&POSITION_WORDS) || (motion.is_arc() && block.has_any(&ARC_WORDS))
}

/// Column of the first of `letters` present (0 if none).
pub(super) fn first_column(block: &Block, letters: &[u8]) -> usize {
    letters.iter().map(|l| block.column(*l)).filter(|c| *c > 0).min().unwrap_or(0)
}

pub(super) fn finite(value: f64, column: usize) -> Result<f64, Fault> {
    if value.is_finite() { Ok(value) } else { Err(Fault::new(column, "value out of range (not finite)")) }
}
