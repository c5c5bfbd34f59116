//! The interpreter's 5-axis words: the rotary words `A`/`B`/`C` that
//! [`GcodeOptions::rotary`](super::super::GcodeOptions::rotary) maps onto the external axes (their
//! modal position in degrees under `G90`/`G91`, `G92` offsets, the axes a segment carries, and a
//! move of the rotary axes alone as a dwell), and the tool-direction dialect's `I J K` on `G0`/`G1`
//! ([`GcodeOptions::tool_direction`](super::super::GcodeOptions::tool_direction): the modal tool
//! orientation). It owns the state of both ([`Rotary`], [`Tool`]) and every method that reads or
//! applies them; the module documentation of [`crate::gcode`] states the rules.

use std::collections::VecDeque;
use std::f64::consts::PI;

use nalgebra::{Unit, UnitQuaternion, Vector3};

use super::super::GcodeSegment;
use super::super::block::Block;
use super::super::codes::Motion;
use super::super::lexer::{Fault, Value};
use super::super::rotary::{MAX_ANGLE, ROTARY_AXES};
use super::{Interpreter, MAX_DWELL, Plan, dwell_time, first_column};
use strand_core::{Segment, SegmentKind};

/// Where the rotary axes are, in the program's degrees.
#[derive(Default)]
pub(super) struct Rotary {
    /// Each mapped axis's position (degrees) with its `G92` offset applied: what the word would be
    /// with no offset. Entries without a word stay 0.
    pub(super) machine: [f64; ROTARY_AXES],
    /// `G92` offsets (degrees): machine = program + offset.
    pub(super) offset: [f64; ROTARY_AXES],
    /// A move has named a mapped rotary word: every later segment carries the axes.
    pub(super) used: bool,
}

/// The tool's orientation under the tool-direction dialect.
pub(super) struct Tool {
    /// Orientation at the end of the last line or arc: dwells carry it (the tool cannot turn in place).
    pub(super) current: UnitQuaternion<f64>,
    /// Orientation of the modal tool direction: the next line or arc carries it.
    pub(super) target: UnitQuaternion<f64>,
}

/// Rotary speed (degrees per minute) of a `G0` that turns the rotary axes alone, when the program
/// has given no `F` on a `G0` line: 90°/s.
pub(super) const RAPID_ROTARY_FEED: f64 = 5400.0;
/// Turns smaller than this (degrees) count as none.
pub(super) const ZERO_ANGLE: f64 = 1e-9;
/// The tool-direction words.
const DIRECTION_WORDS: [u8; 3] = [b'I', b'J', b'K'];

impl Interpreter {
    /// The mapped rotary letters with the entry each drives.
    fn rotary_letters(&self) -> impl Iterator<Item = (usize, u8)> + use<> {
        let mapping = self.options.rotary;
        (0..ROTARY_AXES).filter_map(move |k| mapping[k].map(|axis| (k, axis.word as u8)))
    }

    /// True if the line has a mapped rotary word.
    pub(super) fn has_rotary_word(&self, block: &Block) -> bool {
        self.rotary_letters().any(|(_, letter)| block.has(letter))
    }

    /// Column of the first mapped rotary word (0 if none).
    pub(super) fn rotary_column(&self, block: &Block) -> usize {
        self.rotary_letters().map(|(_, l)| block.column(l)).filter(|c| *c > 0).min().unwrap_or(0)
    }

    /// The axes a segment carries: None until a move has named a rotary word, then every mapped
    /// axis's position (rad), unmapped entries 0.
    pub(super) fn axes(&self) -> Option<[f64; ROTARY_AXES]> {
        if !self.rotary.used {
            return None;
        }
        let mapping = self.options.rotary;
        Some(std::array::from_fn(|k| mapping[k].map_or(0.0, |axis| axis.axis(self.rotary.machine[k]))))
    }

    /// The mapped rotary words of a move (marking them used): moves the rotary axes and returns the
    /// largest turn (degrees), or None if the line names none. Absolute under `G90`, increments
    /// under `G91`.
    pub(super) fn rotary_target(&mut self, block: &mut Block) -> Result<Option<f64>, Fault> {
        let mut next = self.rotary.machine;
        let mut any = false;
        for (k, letter) in self.rotary_letters() {
            let Some(value) = block.take(letter)? else { continue };
            let column = block.column(letter);
            let value = angle(letter, value, column)?;
            let position = if self.modal.absolute { value + self.rotary.offset[k] } else { self.rotary.machine[k] + value };
            if !position.is_finite() || position.abs() > MAX_ANGLE {
                let message = format!("{}{value}: the axis would be at {position}°, beyond ±{MAX_ANGLE:e}°", letter as char);
                return Err(Fault::new(column, message));
            }
            next[k] = position;
            any = true;
        }
        if !any {
            return Ok(None);
        }
        let turn = next.iter().zip(&self.rotary.machine).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        self.rotary.machine = next;
        self.rotary.used = true;
        Ok(Some(turn))
    }

    /// `G92` with rotary words: each given axis takes the given value where it stands. A letter
    /// without a number is left as it is, with a note, as for XYZ.
    pub(super) fn rotary_set_position(&mut self, block: &mut Block, line: usize) -> Result<(), Fault> {
        for (k, letter) in self.rotary_letters() {
            let Some(param) = block.take_param(letter) else { continue };
            if param.value == Value::Bare {
                let kind = format!("G92 {}", letter as char);
                self.notes.record(&kind, line, param.column, || format!("{kind} without a number: left unchanged, as Marlin does"));
                continue;
            }
            let value = angle(letter, param.number(letter)?, param.column)?;
            self.rotary.offset[k] = self.rotary.machine[k] - value;
        }
        Ok(())
    }

    /// A move that turns the rotary axes and leaves XYZ where they are: a dwell carrying the axes
    /// (and the move's filament) for the largest turn at `F` read as degrees per minute (`G0`: the
    /// `F` last given on a `G0` line, else [`RAPID_ROTARY_FEED`]), after the feed percentage.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn rotary_dwell(
        &mut self,
        block: &Block,
        motion: Motion,
        turn: f64,
        filament: f64,
        column: usize,
        line: usize,
        out: &mut VecDeque<GcodeSegment>,
    ) -> Result<(), Fault> {
        let number = match motion {
            Motion::Rapid => Some(self.modal.rapid_feed_number.unwrap_or(RAPID_ROTARY_FEED)),
            _ => self.modal.feed_number,
        };
        let f_column = if block.has(b'F') { block.column(b'F') } else { column };
        let Some(number) = number else {
            return Err(Fault::new(column, format!("{} turning the rotary axes alone with no F given yet", motion.name())));
        };
        let degrees_per_second = number * self.firmware.feed_factor() / 60.0;
        let duration = turn / degrees_per_second;
        if !(duration > 0.0 && duration < MAX_DWELL) {
            let message = format!(
                "{} turns the rotary axes alone by {turn}° at F{number} (degrees per minute on such a move): {duration} s is not in (0, {MAX_DWELL:e}) s",
                motion.name()
            );
            return Err(Fault::new(f_column, message));
        }
        let duration = if filament != 0.0 { self.limit_extruder_time(filament, duration, line) } else { duration };
        let duration = dwell_time(duration, filament, f_column, "rotary move with filament (after M203 E)")?;
        self.notes.record("rotary only", line, column, || {
            "a move of the rotary axes alone: a dwell of the largest turn / F (F in degrees per minute; G0: 90°/s unless F was given on a G0 line)".into()
        });
        let segment = Segment { kind: SegmentKind::Dwell, end: self.machine.position, filament, duration, ..Segment::default() };
        self.emit(segment, line, out);
        Ok(())
    }

    /// Tool-direction dialect: `I J K` on a line whose motion is `G0`/`G1` (its own, or the modal one
    /// when nothing else takes the line's axis words) set the modal tool direction. Missing words
    /// are 0; the vector must not be zero.
    pub(super) fn read_tool_direction(
        &mut self,
        block: &mut Block,
        plan: &Plan,
        motion: Option<(Motion, usize)>,
        line: usize,
    ) -> Result<(), Fault> {
        if !self.options.tool_direction || !block.has_any(&DIRECTION_WORDS) {
            return Ok(());
        }
        let axes_taken = plan.set_position.is_some() || plan.owner.is_some_and(|(_, takes_axes)| takes_axes);
        let line_motion = match (motion, plan.motion) {
            (Some((m, _)), _) | (None, Some((m, _))) => Some(m),
            (None, None) if !axes_taken => self.modal.motion,
            (None, None) => None,
        };
        if !matches!(line_motion, Some(Motion::Rapid | Motion::Linear)) {
            return Ok(());
        }
        let column = first_column(block, &DIRECTION_WORDS);
        let mut up = Vector3::zeros();
        for (i, letter) in DIRECTION_WORDS.iter().enumerate() {
            if let Some(v) = block.take(*letter)? {
                up[i] = v;
            }
        }
        let scale = up.amax();
        if !(scale.is_finite() && scale > 0.0) {
            let message =
                format!("tool direction I{} J{} K{} is not a direction: give the tool axis (up the nozzle), not zero", up.x, up.y, up.z);
            return Err(Fault::new(column, message));
        }
        let nozzle = -(up / scale).normalize();
        self.tool.target = pointing(&self.options.orientation, &nozzle);
        if motion.is_none() {
            self.direction_waits(line, column);
        }
        Ok(())
    }

    /// Notes a tool direction that a line gave but could not turn to (it does not move in XYZ).
    pub(super) fn direction_waits(&mut self, line: usize, column: usize) {
        if self.tool.target != self.tool.current {
            self.notes.record("tool direction without a move", line, column, || {
                "tool direction given on a line that does not move in XYZ: the tool turns over the next line or arc".into()
            });
        }
    }
}

/// A rotary word's value (degrees), within ±[`MAX_ANGLE`].
fn angle(letter: u8, value: f64, column: usize) -> Result<f64, Fault> {
    if value.is_finite() && value.abs() <= MAX_ANGLE {
        Ok(value)
    } else {
        Err(Fault::new(column, format!("{}{value}: an angle beyond ±{MAX_ANGLE:e}° (degrees)", letter as char)))
    }
}

/// Below this sine of the angle between the nozzle directions (≈ rad), a direction straight
/// against `base`'s z axis has no shortest rotation worth the name: its axis would be rounding noise.
const ANTIPARALLEL: f64 = 1e-9;

/// `base` turned by the shortest rotation that points its z axis along `nozzle` (unit); straight
/// against it (within [`ANTIPARALLEL`]), π about `base`'s own x axis.
pub(super) fn pointing(base: &UnitQuaternion<f64>, nozzle: &Vector3<f64>) -> UnitQuaternion<f64> {
    let z = base * Vector3::z();
    let half_turn = || UnitQuaternion::from_axis_angle(&Unit::new_normalize(base * Vector3::x()), PI);
    let turn = if z.dot(nozzle) < 0.0 && z.cross(nozzle).norm() < ANTIPARALLEL {
        half_turn()
    } else {
        UnitQuaternion::rotation_between(&z, nozzle).unwrap_or_else(half_turn)
    };
    turn * base
}
