//! G-code intake: a streaming parser that turns a G-code program (slicer output for Marlin,
//! RepRapFirmware or Klipper, or RS274/NGC as LinuxCNC reads it) into motion [`Segment`]s in SI units.
//!
//! This module owns the reading of G-code text: the lexical rules (words, numbers, comments,
//! checksums: `lexer`), the words of a line (`block`), the modal state of the program (units,
//! distance modes, plane, feed, extruder mode, `G92` offsets, rotary axes and tool direction:
//! `interpreter`, with the code tables in `codes` and the rotary words' mapping in `rotary`), the
//! conversion of each motion block into a line, arc (`arc`) or dwell segment, the firmware commands
//! slicers add to RS274/NGC (`dialect`), slicer comments (`tags`), and the bookkeeping of what it
//! did and did not act on (`report`). It does not place the part on the bed (segments are in the
//! G-code frame, converted to metres; a later stage maps them) and it is not used by the real-time
//! loop: it allocates, but never in proportion to the length of the program. It reads one line at a
//! time from any [`BufRead`] (lines longer than [`MAX_LINE_BYTES`] are an error), holds back only the
//! segments of the current line plus one, and keeps warnings as one entry per kind with a count
//! (at most [`MAX_REPORT_KINDS`] kinds, the rest under [`OTHER_KIND`]), so a 150 000-line file costs the
//! same memory as a 10-line one (about 13 kB of heap, measured in tests/gcode.rs).
//!
//! # Output
//!
//! [`Parser`] is an iterator of [`GcodeSegment`]s: the [`Segment`] (units m, m/s, s, rad), its 1-based
//! source line and the slicer [`Tags`] in force there (feature, layer, top of layer, layer height).
//! Sequence numbers count up from [`GcodeOptions::first_seq`]; every segment carries
//! [`GcodeOptions::orientation`] (under the tool-direction dialect, the orientation of the modal
//! tool direction; with mapped rotary words, the external axes too: see "5-axis programs"); the
//! last segment of a program that ends normally (end of input, `M2`/`M30` or a closing `%`)
//! carries [`SegmentFlags::LAST`] (so the parser holds one segment back).
//! A segment is `EXTRUDE` when it moves in XYZ and pushes filament (ΔE > 0), `TRAVEL` when it moves
//! without doing so (a retract-while-moving "wipe" is a travel with negative filament), and
//! `LAYER_START` when it is the first line or arc after a layer marker.
//!
//! # Choices
//!
//! - **Feed of `G0`.** A rapid uses the last `F` given on a line that executes a `G0`, if the program
//!   ever gives one (Cura-style `G0 F9000 X.. Y..`); otherwise the modal `F` (an `F` on a `G0` line also
//!   sets the modal feed, as in Marlin and LinuxCNC); if no `F` was ever given, the machine's
//!   [`GcodeOptions::rapid_feed`] (LinuxCNC files often rapid before the first `F`). `G1`/`G2`/`G3`
//!   without any `F` ever given are an error. `F` is converted when given (mm/min or, under `G20`,
//!   in/min → m/s); `F0` or a negative `F` is an error wherever it appears.
//! - **`G4` units.** `S` is seconds. `P` is milliseconds in the firmware dialect (Marlin,
//!   RepRapFirmware, Klipper) and seconds in RS274/NGC (LinuxCNC): see [`Dialect`]. `P` and `S`
//!   together are an error. Every dwell the parser makes (`G4`, E-only and rotary-only moves,
//!   firmware retraction) lasts less than 10⁶ s, and more than 0 s if it moves filament, as
//!   `Segment::check` requires: a longer one is an error at the word that asked for it.
//! - **E-only moves** (a slicer's retraction `G1 E-1 F2100` and its undo `G1 E1`) become a `Dwell` of
//!   duration |ΔE|/F with `filament` = ΔE: the extruder moves while the arm stands still. A move with
//!   neither XYZ nor E change is skipped and counted as a note of kind `"zero-length"`. A motion line
//!   with no axis word at all (`G1 F1200`) only sets modes and the feed: it is not a move.
//! - **Extruder mode.** `M82`/`M83` set absolute/relative E; like Marlin, `G90`/`G91` set XYZ *and* E.
//!   E is in the program's length unit (mm, or inches under `G20`); `filament` is metres of filament.
//! - **Arcs** follow LinuxCNC: IJK offsets are relative to the start (`G90.1` makes them absolute),
//!   the offset along the plane normal is an error, `R < 0` is the larger arc, `P` counts turns, an end
//!   equal to the start (or omitted) is a full circle, and the normal axis moves linearly (a helix).
//!   The radii to start and end may differ by max([`GcodeOptions::arc_radius_tolerance`], 0.1 % of the
//!   radius); the path is then a spiral whose radius varies linearly with angle ([`segment_length`]).
//!   The default, 0.05 mm, lies between LinuxCNC's defaults (2·0.01·√2 ≈ 0.028 mm for mm programs,
//!   2·0.001·√2 in ≈ 0.072 mm for inch programs, plus 0.1 % relative): it accepts arcs whose end and
//!   centre were rounded to 0.01 mm, and the corpus's worst mismatch is 0.4 µm. An `R` arc may miss
//!   its end by the same tolerance (the chord then counts as a diameter). Radii below a tenth of the
//!   absolute tolerance are zero (an error), as in LinuxCNC. `P` is LinuxCNC's turn count (`P1` = the
//!   arc itself); Marlin's `P` counts *extra* circles, but slicers do not write it. Planes follow
//!   LinuxCNC: G17 is XY about +z, G18 is ZX about +y, G19 is YZ about +x; `G3` turns counter-clockwise
//!   about the plane's axis, so [`Segment::normal`] is the axis for `G3` and its negative for `G2`.
//! - **A letter always starts a word**, with or without a blank before it: packed lines
//!   (`N3G1X120.5Y121.77005E22.97101F2400*83`, as space-stripping senders and post-processors write
//!   them) read as every firmware reads them — Marlin stops a number at `E`/`e` so as not to read an
//!   exponent, Klipper splits a command at every letter, and RS274/NGC has no exponents. So numbers
//!   have no exponent: `X1e5` is `X1 E5`. Values that overflow (`X` with 400 digits) are errors, as
//!   are `#` parameters, `[...]` expressions and `O` words.
//! - **Positions** (targets, `G92` offsets, arc centres and radii, extruder positions) beyond
//!   ±[`MAX_COORDINATE`] (10⁶ m) after unit conversion are errors, so no later sum or square can
//!   overflow; so are rotary words and rotary positions beyond ±[`MAX_ANGLE`] (10⁶ degrees); every
//!   value a segment carries is finite.
//! - **Not acted on.** Codes and words the parser does not act on (fans, spindle, chamber temperatures,
//!   homing `G28`, tool length `G43`, work offsets, `S`, ...) are reported once per kind with the
//!   first line and a count ([`Parser::warnings`]). The words on a line with an M-code (or `G28`,
//!   `G29` or any G-code RS274/NGC does not define) are its parameters, not a move (Marlin's
//!   `M92 X80 E93`); with RS274/NGC's modal G-codes (`G43 H1 Z5`) the axis words still move. A letter
//!   without a number is a flag (`M84 X Y E`, `G28 X Y`, `M18 E`), accepted where a code owns it as a
//!   parameter; where it would be read as a value (`G1 X F600`, `G4 P`) it is an error. Marlin's
//!   free-text codes (`M117 text`), quoted strings (`M862.3 P "MK3S"`) and, in the firmware dialect,
//!   whatever follows an M-code the parser cannot read (`M486 AShape-Box`) are the M-code's business.
//!   `M2`/`M30` and a closing `%` end the program and any code after them is counted, not executed.
//!   Codes that would change the path if ignored (cutter compensation, splines, canned cycles,
//!   scaling, `G52`/`G53`, inverse-time feed, axes U V W, and rotary axes A B C unless
//!   [`GcodeOptions::rotary`] maps them, ...) are errors.
//! - **Errors** stop the iterator with a [`GcodeError`] naming file, line and 1-based column.
//!
//! # 5-axis programs
//!
//! Two options read the words of a 5-axis program (a positioner under the part, a tilting tool),
//! following RS274/NGC (LinuxCNC) where it has a rule:
//!
//! - **Rotary words** ([`GcodeOptions::rotary`], built from a robot file's `[positioner]` by
//!   [`GcodeOptions::with_rotary`]). Entry k maps a word `A`, `B` or `C` onto external axis k:
//!   [`Segment::axes`]`[k]` = sign · (degrees · π/180) + offset (rad). The words are degrees in
//!   every unit mode (`G20` changes lengths, not angles), absolute under `G90` and increments under
//!   `G91` (the distance mode of XYZ); `G92 C10` makes the axis read 10° where it stands (its
//!   program offset, as for XYZ; `G92` without words zeroes them with XYZ and E; `G92.1`/`G92.2`
//!   clear the offsets); homing (`G28`) is not acted on for them either. A program starts with every
//!   axis at 0°. A `G0`/`G1`/`G2`/`G3` with a mapped word moves its axis; from the first such move
//!   on, every segment (dwells included) carries [`Segment::axes`] with every mapped axis where it
//!   then is (entries without a word 0), so no segment relies on the controller remembering them;
//!   before it, segments carry None. Over a line or arc the axes turn in proportion to the path, and
//!   the feed is the tool's speed over the part (tool-centre-point following): the XYZ points are
//!   in the work frame at home. A move that turns rotary axes and leaves XYZ where they are (its XYZ
//!   displacement below 10⁻¹² m, the parser's zero length) is a `Dwell` carrying the axes and the
//!   move's filament (an `E` on it extrudes in place), of duration = the largest turn (degrees) /
//!   the feed read as degrees per minute, as RS274/NGC reads `F` on a rotary-only move: the number
//!   of the last `F` as written (whatever the length unit), after `M220`; for `G0`, the last `F`
//!   given on a `G0` line, else 90°/s. The duration must lie in (0, 10⁶) s, else an error at the
//!   `F` word (or the motion word if `F` is on an earlier line). Each such dwell counts under the
//!   note `"rotary only"`. A word that is not mapped stays an error (`unsupported axis word A`).
//! - **Tool direction** ([`GcodeOptions::tool_direction`]). On a line whose motion is `G0`/`G1`
//!   (never `G2`/`G3`, whose `I J K` are the arc's centre), `I J K` give the tool axis as a
//!   vector from the nozzle tip up the nozzle, away from the part (the usual CAM output; any
//!   length > 0; a missing word is 0; all zero is an error at the first of them). Lines and arcs
//!   from then on carry the orientation that turns [`GcodeOptions::orientation`] (whose z axis is
//!   the nozzle, pointing at the part) by the shortest rotation that points its z axis along
//!   −(I, J, K) (straight against it, within 10⁻⁹ rad: π about that orientation's own x axis). The
//!   direction is modal. Dwells keep the orientation of the last line or arc (the tool turns over
//!   moves, never in place): a direction given on a line that does not move in XYZ waits for the
//!   next line or arc, with a note `"tool direction without a move"`.
//!
//! # Dialects
//!
//! [`GcodeOptions::dialect`] says which language a program is in; callers pick it with
//! [`GcodeOptions::for_path`] (`.ngc`, `.nc`, `.tap` are RS274/NGC, anything else printer firmware).
//! In RS274/NGC the firmware commands below are reported as not acted on (`G10` is "set offsets"),
//! and a Klipper-style command is an error. In the firmware dialect:
//!
//! | what the program says | what the parser does |
//! |---|---|
//! | `G10` / `G11` (no `L`/`P` word) | firmware retraction: a dwell with −length of filament at the retraction speed, then +(length + extra) at the recovery speed ([`GcodeOptions::firmware_retraction`], Marlin's 3 mm at 45 mm/s and 8 mm/s by default; changed by `M207 S F R T` and Klipper's `SET_RETRACTION`). A second `G10` before `G11` (and a `G11` with nothing retracted) does nothing, as in Marlin and Klipper. Not scaled by `M220`/`M221` (Marlin's fwretract unscales both). `G10 L..`/`G10 P..` (offsets, RepRapFirmware tool settings) are reported |
//! | `G28`, `G29`, `G29.x`, `G80 X..` | reported; no motion, position unchanged |
//! | `G92 E` (no number) | the axis is left unchanged, as in Marlin (its `G92` reads only axes with a value); a note |
//! | `M220 S<1..1000>`, `B`, `R` | later feeds × S %; `B` backs the percentage up, `R` restores it; without any, reported. Applies to every move, E-only ones included |
//! | `M221 S<1..1000>` | later filament × S % (moves and E-only moves; the E position stays the program's); with a `T` other than the selected tool, reported |
//! | `M203 X Y Z E` (units/s, Marlin) | honoured: each later line's feed is lowered so that no axis' share of it, E included, exceeds its limit (an arc's in-plane axes are taken at their peak, the whole feed); E-only moves are lengthened. RepRapFirmware writes mm/min: read as mm/s, its limits are 60× too high and clamp nothing — the safe side |
//! | `SET_VELOCITY_LIMIT VELOCITY=` (mm/s) | honoured: later feeds clamped to it |
//! | `M201 X Y Z`, `M204 P T S`, `SET_VELOCITY_LIMIT ACCEL=` | the lowest acceleration is recorded in [`Parser::program_limits`] (m/s²) |
//! | `M205 X Y Z J`, `M566 X Y Z` (per minute), `SET_VELOCITY_LIMIT SQUARE_CORNER_VELOCITY=` | the lowest jerk, junction deviation and square-corner velocity are recorded |
//! | `M900 K`, `M572 S`, `SET_PRESSURE_ADVANCE ADVANCE=` | pressure advance (s) carried on every later segment (`Segment::pressure_advance`); the controller applies it, clamped to `[extruder] max_pressure_advance`. `SMOOTH_TIME=` is recorded |
//! | `T<n>` | selects the tool; once filament has been pushed, a different tool is an error ("multi-tool jobs are not supported"). `T` beside an M-code other than `M6` is that code's parameter (`M104 T0 S200`); `T255` and up are firmware special tools (Bambu's unload and nozzle-prime mode `T1000`): reported, tool unchanged |
//! | `F` on a line with M-codes and no G-code | the M-code's parameter (Bambu's `M620.1 E F523`), as Marlin reads F only on moves; in RS274/NGC it sets the feed |
//! | `M104 S` / `M140 S` (°C), Klipper's `SET_HEATER_TEMPERATURE HEATER=extruder\|heater_bed TARGET=` (absent: 0) | a heat segment ([`SegmentKind::Heat`], no hold) where the line stands: the controller sets the target when the path reaches it. `M104 T` of another tool than the selected one, another heater: reported. Without `S`: reported, nothing set (Marlin) |
//! | `M109 S` / `M190 S`, `M109 R` / `M190 R`, `TEMPERATURE_WAIT SENSOR=extruder\|heater_bed MINIMUM= MAXIMUM=` | a heat segment with a hold: the target set (`S`: hold while heating, no wait for cooling; `R`: hold either way, as Marlin), or the band (`TEMPERATURE_WAIT`, target unchanged, at least one bound); no later segment runs until the temperature has settled (see `strand_core`'s heat stage). `S` and `R` together, a target outside 0–500 °C, `MINIMUM` above `MAXIMUM`, a missing `HEATER=`/`SENSOR=`: errors with line and column |
//! | `M73`, `M117`/`M118` (free text), `M400`, `M105`, `M116`, chamber temperatures, fans, motors off, any other M-code | reported once per kind, never an error |
//! | Klipper extended commands (`EXCLUDE_OBJECT_*`, `PRINT_START`, `BED_MESH_CALIBRATE`, any `NAME KEY=VALUE ...`) | reported once per name, never an error (the five above are acted on) |
//!
//! Values acted on must be finite and in range (percentages 1–1000, limits > 0, jerk and corner
//! velocity ≥ 0, pressure advance 0–10 s, smooth time 0–0.2 s), else an error naming the line and
//! column; an acted-on firmware M-code must be alone on its line. Each command acted on leaves one
//! note per kind ([`Parser::notes`]) saying what was done, and a lowered feed counts under
//! `"feed limited"`. Recorded limits are for offline tools to apply as min(config, program): the
//! program can make the machine gentler, never harsher.

use std::collections::VecDeque;
use std::fmt;
use std::fs::File;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;
use std::sync::Arc;

use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use thiserror::Error;

use strand_core::{Segment, SegmentFlags};

mod arc;
mod block;
mod codes;
mod dialect;
mod interpreter;
mod lexer;
mod limits;
mod report;
mod rotary;

pub use arc::segment_length;
use block::Block;
pub use dialect::{Dialect, FirmwareRetraction};
use interpreter::Interpreter;
use lexer::{Fault, Lexed, Lexer, LineKind};
pub use limits::{ProgramLimits, ProgramSetting};
pub use rotary::{MAX_ANGLE, ROTARY_AXES, RotaryAxis, RotaryConfigError, check_mapping};

/// Metres per millimetre.
const MM: f64 = 1e-3;
/// Metres per inch.
const INCH: f64 = 0.0254;
/// Displacements shorter than this (m) count as none: a zero-length move, an arc's end on its start.
pub(crate) const ZERO_LENGTH: f64 = 1e-12;
/// Longest accepted line (bytes, without the line end).
pub(crate) const MAX_LINE_BYTES: usize = 64 * 1024;
/// Most kinds the warning and note lists keep apart; further kinds are counted under `"other"`.
pub const MAX_REPORT_KINDS: usize = 64;
/// Kind under which reports beyond [`MAX_REPORT_KINDS`] kinds are counted.
pub const OTHER_KIND: &str = "other";
/// Largest accepted magnitude of a position, offset, arc centre or extruder position (m): far
/// beyond any machine, and far enough below overflow that no later sum or square can overflow.
pub(crate) const MAX_COORDINATE: f64 = 1e6;

/// How to read a program.
#[derive(Clone, Debug, PartialEq)]
pub struct GcodeOptions {
    /// Position of the tool before the first move (m, G-code frame). Program coordinates start equal
    /// to physical ones (no `G92` offset), so this is where relative moves start from.
    pub start: Vector3<f64>,
    /// Tool orientation put on every segment (unit quaternion). Default: π about y, so the tool's z
    /// axis (along the nozzle) points down, along −z.
    pub orientation: UnitQuaternion<f64>,
    /// Absolute tolerance (m) on the difference between an arc's start and end radii, and on an `R`
    /// arc's chord exceeding 2|R|. The tolerance applied is max(this, 0.001 · radius). Default 0.05 mm.
    pub arc_radius_tolerance: f64,
    /// Feed (m/s) of a `G0` when the program has not given any `F` yet. Default 0.1 m/s.
    pub rapid_feed: f64,
    /// Sequence number of the first segment.
    pub first_seq: u64,
    /// The G-code language ([`Dialect::from_path`] picks it from a file's extension). Default:
    /// printer firmware.
    pub dialect: Dialect,
    /// What `G10`/`G11` do until the program sets its own (`M207`, `SET_RETRACTION`). Default:
    /// Marlin's, 3 mm at 45 mm/s, recovered at 8 mm/s.
    pub firmware_retraction: FirmwareRetraction,
    /// Rotary words (`A`, `B`, `C`; degrees in the program) mapped onto the external axes: entry k
    /// drives [`Segment::axes`]`[k]` (rad): sign · word · π/180 + offset (see "5-axis programs" in
    /// the module documentation). Default: none, and `A`/`B`/`C` words are errors. Build it from a
    /// robot file's `[positioner]` with [`GcodeOptions::with_rotary`].
    pub rotary: [Option<RotaryAxis>; ROTARY_AXES],
    /// The tool-direction dialect: on `G0`/`G1` the words `I J K` give the tool axis (a
    /// dimensionless vector of any length > 0, pointing from the nozzle tip up the nozzle, away
    /// from the part), and later segments carry the orientation that points the nozzle along
    /// −(I, J, K) (see "5-axis programs" in the module documentation). Default: false (`I J K` on a
    /// line are words not acted on).
    pub tool_direction: bool,
}

impl Default for GcodeOptions {
    fn default() -> Self {
        GcodeOptions {
            start: Vector3::zeros(),
            orientation: nozzle_down(),
            arc_radius_tolerance: 0.05e-3,
            rapid_feed: 0.1,
            first_seq: 0,
            dialect: Dialect::Firmware,
            firmware_retraction: FirmwareRetraction::default(),
            rotary: [None; ROTARY_AXES],
            tool_direction: false,
        }
    }
}

impl GcodeOptions {
    /// The defaults, with the dialect `path`'s extension implies (see [`Dialect::from_path`]):
    /// what every caller that reads a file should start from.
    pub fn for_path(path: &Path) -> Self {
        GcodeOptions { dialect: Dialect::from_path(path), ..GcodeOptions::default() }
    }

    /// These options with the rotary words of a robot file's `[positioner]` section: `words[k]`
    /// (`"A"`, `"B"` or `"C"`) drives external axis k with `signs[k]` (±1) and `offsets[k]` (rad);
    /// empty `signs` / `offsets` mean +1 / 0 for every word. The error names the key at fault
    /// (`gcode_words`, `gcode_signs`, `gcode_offsets`): see [`RotaryAxis::from_config`].
    pub fn with_rotary<S: AsRef<str>>(self, words: &[S], signs: &[f64], offsets: &[f64]) -> Result<Self, RotaryConfigError> {
        Ok(GcodeOptions { rotary: RotaryAxis::from_config(words, signs, offsets)?, ..self })
    }
}

/// Rotation by π about y (exact: quaternion w = 0, y = 1).
fn nozzle_down() -> UnitQuaternion<f64> {
    UnitQuaternion::new_unchecked(Quaternion::new(0.0, 0.0, 1.0, 0.0))
}

/// Slicer annotations in force at a segment's source line (the spellings each slicer uses are
/// listed in the `tags` module).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Tags {
    /// Value of the last feature comment (`;TYPE:`, `; FEATURE:`, Simplify3D's `; feature`), e.g.
    /// `"External perimeter"` (PrusaSlicer), `"WALL-OUTER"` (Cura), `"Outer wall"` (Orca). None before
    /// the first.
    pub feature: Option<Arc<str>>,
    /// Layer index (0-based): the number in Cura's `;LAYER:n` (negative for raft layers), Simplify3D's
    /// `; layer n` minus one, or the count of `;LAYER_CHANGE` / `; CHANGE_LAYER` markers minus one
    /// (markers with no move between them count once). None before the first marker (and
    /// throughout Slic3r 1.3 output, which writes no layer comments).
    pub layer: Option<i32>,
    /// The nominal top of the layer (m): the last `;Z:` or `; Z_HEIGHT:` comment, or the Z of
    /// Simplify3D's `; layer n, Z = z`.
    pub z_marker: Option<f64>,
    /// The layer height (m): the last `;HEIGHT:` or `; LAYER_HEIGHT:` comment, or the H of
    /// Simplify3D's `; tool H.. W..`.
    pub height: Option<f64>,
}

/// One segment with where it came from.
#[derive(Clone, Debug, PartialEq)]
pub struct GcodeSegment {
    /// The segment (SI units, G-code frame).
    pub segment: Segment,
    /// Source line (1-based).
    pub line: usize,
    /// Slicer annotations in force at that line.
    pub tags: Tags,
}

/// Something the parser did not act on, or a note about what it did, kept once per kind.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Warning {
    /// Line of the first occurrence (1-based).
    pub line: usize,
    /// Column of the first occurrence (1-based characters; 0 for the whole line).
    pub column: usize,
    /// What it is about: a code (`"M104"`, `"G28"`, `"T0"`), a word (`"word S"`) or a note kind
    /// (`"zero-length"`).
    pub kind: String,
    /// What was (not) done, for the first occurrence.
    pub message: String,
    /// Occurrences of this kind so far.
    pub count: u64,
}

impl fmt::Display for Warning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "line {}:{}: {}: {} (×{})", self.line, self.column, self.kind, self.message, self.count)
    }
}

/// Why the program cannot be read, and where.
#[derive(Clone, Debug, Error, PartialEq, Eq)]
#[error("{file}:{line}:{column}: {message}")]
pub struct GcodeError {
    /// File name as given to the parser.
    pub file: String,
    /// Line (1-based; 0 if the file could not be opened or the options are invalid).
    pub line: usize,
    /// Column of the offending word (1-based characters; 0 for the whole line).
    pub column: usize,
    /// What is wrong.
    pub message: String,
}

/// Opens `path` and returns a parser over it.
pub fn parse_file(path: &Path, options: GcodeOptions) -> Result<Parser<BufReader<File>>, GcodeError> {
    let name = path.display().to_string();
    match File::open(path) {
        Ok(file) => Ok(Parser::new(BufReader::new(file), &name, options)),
        Err(e) => Err(GcodeError { file: name, line: 0, column: 0, message: format!("cannot open: {e}") }),
    }
}

/// Streaming G-code parser: an iterator of segments over the lines of `R`.
pub struct Parser<R: BufRead> {
    reader: R,
    file: String,
    line_bytes: Vec<u8>,
    lexer: Lexer,
    block: Block,
    interpreter: Interpreter,
    queue: VecDeque<GcodeSegment>,
    error: Option<GcodeError>,
    input_done: bool,
    lines_read: usize,
}

impl<R: BufRead> Parser<R> {
    /// A parser reading `reader`; `file_name` is used in errors only.
    /// Options whose rotary mapping is invalid (see [`check_mapping`]) make the first item an
    /// error (line 0, column 0) and end the iteration.
    pub fn new(reader: R, file_name: &str, options: GcodeOptions) -> Self {
        let invalid = check_mapping(&options.rotary).err().map(|e| GcodeError {
            file: file_name.to_string(),
            line: 0,
            column: 0,
            message: format!("invalid options: rotary words: {e}"),
        });
        Parser {
            input_done: invalid.is_some(),
            error: invalid,
            reader,
            file: file_name.to_string(),
            line_bytes: Vec::with_capacity(256),
            lexer: Lexer::new(options.dialect == Dialect::Firmware),
            block: Block::default(),
            interpreter: Interpreter::new(options),
            queue: VecDeque::with_capacity(4),
            lines_read: 0,
        }
    }

    /// Codes and words not acted on (and other irregularities), once per kind with a count.
    pub fn warnings(&self) -> &[Warning] {
        &self.interpreter.warnings.entries
    }

    /// Notes on what the parser did that the program did not literally say, once per kind with a
    /// count: skipped zero-length moves (`"zero-length"`), firmware commands acted on (`"G10"`,
    /// `"M220"`, `"M203"`, `"SET_VELOCITY_LIMIT"`, ...), feeds lowered to a velocity limit
    /// (`"feed limited"`).
    pub fn notes(&self) -> &[Warning] {
        &self.interpreter.notes.entries
    }

    /// Motion settings the program requested in the lines read so far (accelerations, jerk, pressure
    /// advance, ...), for a caller to apply as min(config, program). Complete once the iterator has
    /// ended.
    pub fn program_limits(&self) -> &ProgramLimits {
        &self.interpreter.firmware.limits.recorded
    }

    /// Position (m) after the lines read so far: the end of the last segment produced, which may
    /// not have been returned yet (the parser holds one back to mark the program's last).
    pub fn position(&self) -> Vector3<f64> {
        self.interpreter.machine.position
    }

    /// Lines read so far.
    pub fn lines_read(&self) -> usize {
        self.lines_read
    }

    /// Reads and executes one line. Returns false at the end of the input.
    fn advance(&mut self) -> Result<bool, GcodeError> {
        self.line_bytes.clear();
        let limit = MAX_LINE_BYTES as u64 + 2;
        let read = (&mut self.reader).take(limit).read_until(b'\n', &mut self.line_bytes);
        let n = read.map_err(|e| self.error_at(self.lines_read + 1, 0, format!("read error: {e}")))?;
        if n == 0 {
            return Ok(false);
        }
        self.lines_read += 1;
        strip_line_end(&mut self.line_bytes);
        if self.line_bytes.len() > MAX_LINE_BYTES {
            return Err(self.error_at(self.lines_read, 0, format!("line longer than {MAX_LINE_BYTES} bytes")));
        }
        let line = self.lines_read;
        if self.interpreter.ended {
            self.interpreter.count_after_end(&self.line_bytes, line);
            return Ok(true);
        }
        let fault = match self.lexer.lex(&self.line_bytes) {
            Ok(mut lexed) => self.execute(&mut lexed, line).err(),
            Err(fault) => Some(fault),
        };
        match fault {
            Some(fault) => Err(self.error_at(line, fault.column, fault.message)),
            None => Ok(true),
        }
    }

    fn execute(&mut self, lexed: &mut Lexed, line: usize) -> Result<(), Fault> {
        let interpreter = &mut self.interpreter;
        if let Some(range) = lexed.comment.clone() {
            interpreter.read_tag_comment(&self.lexer.chars[range]);
        }
        if let Some(column) = lexed.message_comment {
            interpreter.warnings.record("(msg)", line, column, || "operator message comment not displayed".into());
        }
        if lexed.block_delete {
            interpreter.warnings.record("/", line, 1, || "block delete '/' not acted on: the line is executed".into());
        }
        match &lexed.kind {
            LineKind::Words => {}
            LineKind::Percent => {
                interpreter.percent();
                return Ok(());
            }
            LineKind::Extended(name) => {
                let malformed = lexed.malformed_param.take();
                return interpreter.extended(name, &self.lexer.params, malformed, line, lexed.first_column, &mut self.queue);
            }
        }
        if self.lexer.words.is_empty() {
            return Ok(());
        }
        let unread = match self.block.fill(&self.lexer.words) {
            Ok(()) => lexed.unread.take(),
            // A firmware reads an M-code's parameters its own way (Bambu's `M624 AQAAAAAAAAA=`,
            // packed, is A, Q, A, …): a repeated letter there sets the rest of the line aside, as
            // an unreadable word does, and matters only if the line's code is one acted on.
            Err(fault) if self.lexer.lenient && self.lexer.starts_with_m_code() => {
                let cut = self.lexer.words.iter().position(|w| w.column >= fault.column).unwrap_or(self.lexer.words.len());
                self.block.fill(&self.lexer.words[..cut])?;
                Some(fault)
            }
            Err(fault) => return Err(fault),
        };
        self.interpreter.execute(&mut self.block, line, unread, &mut self.queue)
    }

    fn error_at(&self, line: usize, column: usize, message: String) -> GcodeError {
        GcodeError { file: self.file.clone(), line, column, message }
    }

    /// The next segment to hand out, marking the program's last one.
    fn pop_ready(&mut self) -> Option<GcodeSegment> {
        let mut next = self.queue.pop_front()?;
        if self.queue.is_empty() && self.error.is_none() {
            next.segment.flags = next.segment.flags.with(SegmentFlags::LAST);
        }
        Some(next)
    }
}

impl<R: BufRead> Iterator for Parser<R> {
    type Item = Result<GcodeSegment, GcodeError>;

    fn next(&mut self) -> Option<Self::Item> {
        while !self.input_done && self.queue.len() < 2 {
            match self.advance() {
                Ok(true) => {}
                Ok(false) => self.input_done = true,
                Err(e) => {
                    self.error = Some(e);
                    self.input_done = true;
                }
            }
        }
        if self.queue.len() >= 2 {
            return self.queue.pop_front().map(Ok);
        }
        if let Some(segment) = self.pop_ready() {
            return Some(Ok(segment));
        }
        self.error.take().map(Err)
    }
}

/// Removes a trailing "\n" or "\r\n".
fn strip_line_end(bytes: &mut Vec<u8>) {
    if bytes.last() == Some(&b'\n') {
        bytes.pop();
    }
    if bytes.last() == Some(&b'\r') {
        bytes.pop();
    }
}
