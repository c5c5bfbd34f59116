//! G-code intake: a streaming parser that turns a G-code program (slicer output or RS274/NGC, as
//! LinuxCNC reads it) into motion [`Segment`]s in SI units.
//!
//! This module owns the reading of G-code text: the lexical rules (words, numbers, comments,
//! checksums), the modal state of the program (units, distance modes, plane, feed, extruder mode,
//! `G92` offsets), the conversion of each motion block into a line, arc or dwell segment, and the
//! bookkeeping of what it did not act on. It does not place the part on the bed (segments are in the
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
//! source line and the slicer [`Tags`] in force there (`;TYPE:` feature, layer, `;Z:` marker).
//! Sequence numbers count up from [`GcodeOptions::first_seq`]; every segment carries
//! [`GcodeOptions::orientation`]; the last segment of a program that ends normally (end of input,
//! `M2`/`M30` or a closing `%`) carries [`SegmentFlags::LAST`] (so the parser holds one segment back).
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
//! - **`G4` units.** `S` is seconds. `P` is milliseconds once the program looks like slicer output (an
//!   `E` word or `M82`/`M83` seen before the `G4`, as Marlin reads it) and seconds otherwise (LinuxCNC).
//!   `P` and `S` together are an error.
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
//! - **Numbers** have no exponent (RS274/NGC and Marlin agree): an `e`/`E` directly after a number is
//!   an error, since `X1e5` is either scientific notation or a missing space before an `E` word, and
//!   guessing wrong extrudes 5 mm. Values that overflow (`X` with 400 digits) are errors, as are `#`
//!   parameters, `[...]` expressions and `O` words.
//! - **Not acted on.** Codes and words the parser does not act on (temperatures, fans, spindle,
//!   homing `G28`, tool length `G43`, work offsets, `T`, `S`, ...) are reported once per kind with the
//!   first line and a count ([`Parser::warnings`]). The words on a line with an M-code not acted on
//!   (or `G28`, `G29`, `G10`, ...) are its parameters, not a move (Marlin's `M92 X80 E93`); with other
//!   unacted G-codes (`G43 H1 Z5`) the axis words still move. Marlin's free-text codes (`M117 text`),
//!   quoted strings (`M862.3 P "MK3S"`) and Klipper-style commands (a first word with an underscore,
//!   `EXCLUDE_OBJECT_START NAME=a`) are reported likewise. `M2`/`M30` and a closing `%` end the program
//!   and any code after them is counted, not executed. Codes that would change the path if ignored
//!   (cutter compensation, splines, canned cycles, scaling, `G52`/`G53`, inverse-time feed, rotary
//!   axes A B C U V W, ...) are errors.
//! - **Errors** stop the iterator with a [`GcodeError`] naming file, line and 1-based column.

use std::collections::VecDeque;
use std::f64::consts::{PI, TAU};
use std::fmt;
use std::fs::File;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;
use std::sync::Arc;

use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use thiserror::Error;

use crate::core::path::{Segment, SegmentFlags, SegmentKind};

/// Metres per millimetre.
const MM: f64 = 1e-3;
/// Metres per inch.
const INCH: f64 = 0.0254;
/// Displacements shorter than this (m) count as none: a zero-length move, an arc's end on its start.
pub const ZERO_LENGTH: f64 = 1e-12;
/// Longest accepted line (bytes, without the line end).
pub const MAX_LINE_BYTES: usize = 64 * 1024;
/// Most kinds the warning and note lists keep apart; further kinds are counted under `"other"`.
pub const MAX_REPORT_KINDS: usize = 64;
/// Kind under which reports beyond [`MAX_REPORT_KINDS`] kinds are counted.
pub const OTHER_KIND: &str = "other";

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
}

impl Default for GcodeOptions {
    fn default() -> Self {
        GcodeOptions { start: Vector3::zeros(), orientation: nozzle_down(), arc_radius_tolerance: 0.05e-3, rapid_feed: 0.1, first_seq: 0 }
    }
}

/// Rotation by π about y (exact: quaternion w = 0, y = 1).
fn nozzle_down() -> UnitQuaternion<f64> {
    UnitQuaternion::new_unchecked(Quaternion::new(0.0, 0.0, 1.0, 0.0))
}

/// Slicer annotations in force at a segment's source line.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Tags {
    /// Value of the last `;TYPE:` comment, e.g. `"External perimeter"` (PrusaSlicer) or `"WALL-OUTER"`
    /// (Cura). None before the first.
    pub feature: Option<Arc<str>>,
    /// Layer index (0-based): the number in Cura's `;LAYER:n` (negative for raft layers), or the count
    /// of PrusaSlicer's `;LAYER_CHANGE` markers minus one. None before the first marker (and
    /// throughout Slic3r 1.3 output, which writes no layer comments).
    pub layer: Option<i32>,
    /// Value of the last PrusaSlicer `;Z:` comment (m), the nominal top of the layer.
    pub z_marker: Option<f64>,
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
    /// Line (1-based; 0 if the file could not be opened).
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

/// Path length (m) of `segment` when it starts at `start` (m): the chord of a line, 0 for a dwell,
/// and for an arc ∫ |p'(θ)| dθ along the helical spiral whose radius goes linearly from r₀ (at the
/// start) to r₁ (at the end, in its plane) while the height along `normal` goes linearly from 0 to h.
/// With r₀ = r₁ this is √((r·θ)² + h²); otherwise it is the closed form of ∫ √(a + r²) dr / k
/// (k = (r₁ − r₀)/θ, a = k² + (h/θ)²), written without cancellation.
pub fn segment_length(start: &Vector3<f64>, segment: &Segment) -> f64 {
    match segment.kind {
        SegmentKind::Line => (segment.end - start).norm(),
        SegmentKind::Dwell => 0.0,
        SegmentKind::Arc => {
            let n = segment.normal;
            let from_centre = segment.end - segment.centre;
            let h = from_centre.dot(&n);
            let r0 = (start - segment.centre).norm();
            let r1 = (from_centre - n * h).norm();
            spiral_length(r0, r1, segment.sweep, h)
        }
    }
}

/// Length of the spiral r(φ) = r₀ + (r₁ − r₀)·φ/θ, height h·φ/θ, φ ∈ [0, θ].
fn spiral_length(r0: f64, r1: f64, theta: f64, h: f64) -> f64 {
    let dr = r1 - r0;
    if dr == 0.0 || theta <= 0.0 {
        return libm::hypot(r0 * theta, h);
    }
    let a = (dr / theta).powi(2) + (h / theta).powi(2);
    let (s0, s1) = (libm::sqrt(a + r0 * r0), libm::sqrt(a + r1 * r1));
    // [r·√(a+r²)] from r₀ to r₁, divided by Δr.
    let algebraic = (r1 + r0) * (a + r0 * r0 + r1 * r1) / (r1 * s1 + r0 * s0);
    // [a·asinh(r/√a)] from r₀ to r₁, divided by Δr, via asinh x − asinh y = asinh(x√(1+y²) − y√(1+x²)).
    let z = dr * (r1 + r0) / (r1 * s0 + r0 * s1);
    let asinh_ratio = if z.abs() < 1e-4 { 1.0 - z * z / 6.0 } else { libm::asinh(z) / z };
    let logarithmic = a * (r1 + r0) / (r1 * s0 + r0 * s1) * asinh_ratio;
    0.5 * theta * (algebraic + logarithmic)
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
    pub fn new(reader: R, file_name: &str, options: GcodeOptions) -> Self {
        Parser {
            reader,
            file: file_name.to_string(),
            line_bytes: Vec::with_capacity(256),
            lexer: Lexer::default(),
            block: Block::default(),
            interpreter: Interpreter::new(options),
            queue: VecDeque::with_capacity(4),
            error: None,
            input_done: false,
            lines_read: 0,
        }
    }

    /// Codes and words not acted on (and other irregularities), once per kind with a count.
    pub fn warnings(&self) -> &[Warning] {
        &self.interpreter.warnings.entries
    }

    /// Notes on what the parser did that the program did not literally say: skipped zero-length
    /// moves (kind `"zero-length"`), once per kind with a count.
    pub fn notes(&self) -> &[Warning] {
        &self.interpreter.notes.entries
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
            Ok(lexed) => self.execute(&lexed, line).err(),
            Err(fault) => Some(fault),
        };
        match fault {
            Some(fault) => Err(self.error_at(line, fault.column, fault.message)),
            None => Ok(true),
        }
    }

    fn execute(&mut self, lexed: &Lexed, line: usize) -> Result<(), Fault> {
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
                interpreter.warnings.record(name, line, lexed.first_column, || format!("extended command {name} not acted on"));
                return Ok(());
            }
        }
        if self.lexer.words.is_empty() {
            return Ok(());
        }
        self.block.fill(&self.lexer.words)?;
        self.interpreter.execute(&mut self.block, line, &mut self.queue)
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

// ---------------------------------------------------------------------------------------------
// Lexing: one line of text → words.
// ---------------------------------------------------------------------------------------------

/// An error at a column of the current line.
#[derive(Debug)]
struct Fault {
    column: usize,
    message: String,
}

impl Fault {
    fn new(column: usize, message: impl Into<String>) -> Self {
        Fault { column, message: message.into() }
    }
}

/// A letter and its value.
#[derive(Clone, Copy, Debug)]
struct Word {
    /// Upper-case ASCII letter.
    letter: u8,
    /// The number, or None for a quoted string (`M862.3 P "MK3S"`).
    value: Option<f64>,
    /// 1-based column of the letter.
    column: usize,
}

#[derive(Clone, Debug)]
enum LineKind {
    /// Words (possibly none).
    Words,
    /// A `%` program delimiter.
    Percent,
    /// A Klipper-style extended command (`EXCLUDE_OBJECT_START NAME=..`).
    Extended(String),
}

/// What a line holds besides its words.
#[derive(Clone, Debug)]
struct Lexed {
    kind: LineKind,
    /// Character range of the `;` comment's text (after the `;`).
    comment: Option<std::ops::Range<usize>>,
    /// Column of a `(msg, ...)` comment.
    message_comment: Option<usize>,
    /// The line starts with `/` (block delete).
    block_delete: bool,
    /// Column of the first non-blank character.
    first_column: usize,
}

/// M-codes whose argument is free text up to the end of the line (Marlin).
const TEXT_M_CODES: [u32; 7] = [230, 280, 320, 330, 1170, 1180, 9280];

#[derive(Default)]
struct Lexer {
    chars: Vec<char>,
    words: Vec<Word>,
    number: String,
}

impl Lexer {
    /// Splits one line (without its line end) into words; comments, checksum and delimiters aside.
    fn lex(&mut self, bytes: &[u8]) -> Result<Lexed, Fault> {
        self.chars.clear();
        self.words.clear();
        self.chars.extend(String::from_utf8_lossy(bytes).chars());
        let mut lexed = Lexed { kind: LineKind::Words, comment: None, message_comment: None, block_delete: false, first_column: 1 };
        let mut i = self.skip_blank(0);
        lexed.first_column = i + 1;
        if self.chars.get(i) == Some(&'/') {
            lexed.block_delete = true;
            i = self.skip_blank(i + 1);
        }
        if self.chars.get(i) == Some(&'%') {
            lexed.kind = LineKind::Percent;
            return Ok(lexed);
        }
        if let Some(name) = self.extended_command(i) {
            lexed.kind = LineKind::Extended(name);
            return Ok(lexed);
        }
        self.words_from(i, bytes, &mut lexed)?;
        Ok(lexed)
    }

    fn skip_blank(&self, mut i: usize) -> usize {
        while i < self.chars.len() && is_blank(self.chars[i]) {
            i += 1;
        }
        i
    }

    /// A first token like `SET_PRESSURE_ADVANCE`: a letter, then letters, digits and at least one
    /// underscore, then a blank, a `;` or the end of the line.
    fn extended_command(&self, i: usize) -> Option<String> {
        let token = &self.chars[i.min(self.chars.len())..];
        let length = token.iter().take_while(|c| c.is_ascii_alphanumeric() || **c == '_').count();
        let token = &token[..length];
        let starts_with_letter = token.first().is_some_and(|c| c.is_ascii_alphabetic());
        let ends_token = self.chars.get(i + length).is_none_or(|c| is_blank(*c) || *c == ';');
        (starts_with_letter && token.contains(&'_') && ends_token).then(|| token.iter().collect::<String>().to_ascii_uppercase())
    }

    fn words_from(&mut self, mut i: usize, bytes: &[u8], lexed: &mut Lexed) -> Result<(), Fault> {
        loop {
            i = self.skip_blank(i);
            let Some(&c) = self.chars.get(i) else { return Ok(()) };
            match c {
                ';' => {
                    lexed.comment = Some(i + 1..self.chars.len());
                    return Ok(());
                }
                '(' => i = self.paren_comment(i, lexed)?,
                '*' => return self.checksum(i, bytes),
                'O' | 'o' => return Err(Fault::new(i + 1, "O words (subroutines, loops) are not supported")),
                'A'..='Z' | 'a'..='z' => {
                    i = self.word(i)?;
                    if self.starts_text_argument() {
                        return Ok(());
                    }
                }
                '#' => return Err(Fault::new(i + 1, "parameters (#) are not supported")),
                '[' => return Err(Fault::new(i + 1, "expressions ([...]) are not supported")),
                _ => return Err(Fault::new(i + 1, format!("unexpected character {c:?} where a word letter should be"))),
            }
        }
    }

    /// Skips a `( ... )` comment starting at `i`; returns the index after it.
    fn paren_comment(&self, i: usize, lexed: &mut Lexed) -> Result<usize, Fault> {
        let close = self.chars[i + 1..].iter().position(|c| *c == ')').map(|p| i + 1 + p);
        let close = close.ok_or_else(|| Fault::new(i + 1, "unclosed '(' comment"))?;
        let body = &self.chars[self.skip_blank(i + 1).min(close)..close];
        if body.len() >= 4 && body[..4].iter().zip("msg,".chars()).all(|(c, m)| c.to_ascii_lowercase() == m) {
            lexed.message_comment = Some(i + 1);
        }
        Ok(close + 1)
    }

    /// Checks a `*NN` checksum at `i`: the XOR of the line's bytes before the `*` (Marlin/RepRap).
    fn checksum(&self, i: usize, bytes: &[u8]) -> Result<(), Fault> {
        let digits: String = self.chars[i + 1..].iter().take_while(|c| c.is_ascii_digit()).collect();
        let rest = self.skip_blank(i + 1 + digits.len());
        if digits.is_empty() || (rest < self.chars.len() && self.chars[rest] != ';') {
            return Err(Fault::new(i + 1, "malformed checksum: '*' must be followed by digits at the end of the line"));
        }
        let prefix_bytes: usize = self.chars[..i].iter().map(|c| c.len_utf8()).sum();
        let expected = bytes.get(..prefix_bytes).unwrap_or(bytes).iter().fold(0u8, |x, b| x ^ b);
        match digits.parse::<u32>() {
            Ok(given) if given == u32::from(expected) => Ok(()),
            _ => Err(Fault::new(i + 1, format!("checksum mismatch: line says *{digits}, its bytes give *{expected}"))),
        }
    }

    /// Reads the word whose letter is at `i`; returns the index after it.
    fn word(&mut self, i: usize) -> Result<usize, Fault> {
        let letter = self.chars[i].to_ascii_uppercase() as u8;
        let column = i + 1;
        let j = self.skip_blank(i + 1);
        match self.chars.get(j) {
            Some('[') => return Err(Fault::new(column, "expressions ([...]) are not supported")),
            Some('#') => return Err(Fault::new(column, "parameters (#) are not supported")),
            _ => {}
        }
        if self.chars.get(j) == Some(&'"') {
            let end = self.quoted_string(j, column)?;
            self.words.push(Word { letter, value: None, column });
            return Ok(end);
        }
        let (value, end) = self.number(j, letter as char, column)?;
        self.words.push(Word { letter, value: Some(value), column });
        Ok(end)
    }

    /// Skips a `"..."` string (`""` is a quote inside it); returns the index after it.
    fn quoted_string(&self, mut j: usize, column: usize) -> Result<usize, Fault> {
        j += 1;
        loop {
            match self.chars.get(j) {
                None => return Err(Fault::new(column, "unclosed quoted string")),
                Some('"') if self.chars.get(j + 1) == Some(&'"') => j += 2,
                Some('"') => return Ok(j + 1),
                Some(_) => j += 1,
            }
        }
    }

    /// Reads `[+-]digits[.digits]` at `j` for the word `letter` at `column`.
    fn number(&mut self, mut j: usize, letter: char, column: usize) -> Result<(f64, usize), Fault> {
        self.number.clear();
        if let Some(&sign @ ('+' | '-')) = self.chars.get(j) {
            self.number.push(sign);
            j += 1;
        }
        let mut digits = 0;
        let mut seen_point = false;
        while let Some(&c) = self.chars.get(j) {
            if c.is_ascii_digit() {
                digits += 1;
            } else if c == '.' && !seen_point {
                seen_point = true;
            } else {
                break;
            }
            self.number.push(c);
            j += 1;
        }
        if digits == 0 || self.chars.get(j) == Some(&'.') {
            return Err(self.malformed(letter, column));
        }
        if let Some(e @ ('e' | 'E')) = self.chars.get(j) {
            let token = self.rest_of_token(column);
            let message =
                format!("{letter}{token}: '{e}' right after a number: exponents are not G-code, and an E word needs a space before it");
            return Err(Fault::new(column, message));
        }
        let value: f64 = self.number.parse().map_err(|_| self.malformed(letter, column))?;
        if !value.is_finite() {
            return Err(Fault::new(column, format!("number out of range after {letter}")));
        }
        Ok((value, j))
    }

    fn malformed(&self, letter: char, column: usize) -> Fault {
        match self.rest_of_token(column) {
            token if token.is_empty() => Fault::new(column, format!("{letter} without a number")),
            token => Fault::new(column, format!("malformed number after {letter}: {token:?}")),
        }
    }

    /// The characters after a word letter up to the next blank or comment, for messages.
    fn rest_of_token(&self, column: usize) -> String {
        self.chars[column.min(self.chars.len())..].iter().take_while(|c| !is_blank(**c) && !matches!(c, ';' | '(')).take(20).collect()
    }

    /// True if the last word is an M-code whose argument is free text (`M117 Printing...`).
    fn starts_text_argument(&self) -> bool {
        let only_codes = self.words.iter().all(|w| matches!(w.letter, b'M' | b'N'));
        match self.words.last() {
            Some(Word { letter: b'M', value: Some(v), .. }) => only_codes && code_tenths(*v).is_some_and(|c| TEXT_M_CODES.contains(&c)),
            _ => false,
        }
    }
}

fn is_blank(c: char) -> bool {
    matches!(c, ' ' | '\t' | '\r' | '\x0b' | '\x0c')
}

/// A code number in tenths (`G92.1` → 921), if it is a non-negative number with at most one decimal.
fn code_tenths(value: f64) -> Option<u32> {
    let tenths = value * 10.0;
    let rounded = tenths.round();
    ((tenths - rounded).abs() < 1e-6 && (0.0..=1e7).contains(&rounded)).then_some(rounded as u32)
}

/// `G92.1`, `M104`.
fn code_name(letter: char, tenths: u32) -> String {
    if tenths.is_multiple_of(10) { format!("{letter}{}", tenths / 10) } else { format!("{letter}{}.{}", tenths / 10, tenths % 10) }
}

// ---------------------------------------------------------------------------------------------
// Blocks: the words of one line, grouped.
// ---------------------------------------------------------------------------------------------

/// A G- or M-code on a line.
#[derive(Clone, Copy, Debug)]
struct Code {
    tenths: u32,
    column: usize,
}

/// A parameter word (any letter but G, M, N).
#[derive(Clone, Copy, Debug)]
struct Param {
    value: Option<f64>,
    column: usize,
}

/// The words of one line: its codes, and at most one parameter per letter.
#[derive(Default)]
struct Block {
    g: Vec<Code>,
    m: Vec<Code>,
    params: [Option<Param>; 26],
    /// Letters consumed by what the line does (bit i = letter 'A' + i).
    used: u32,
}

fn letter_index(letter: u8) -> usize {
    usize::from(letter.wrapping_sub(b'A')).min(25)
}

impl Block {
    fn fill(&mut self, words: &[Word]) -> Result<(), Fault> {
        self.g.clear();
        self.m.clear();
        self.params = [None; 26];
        self.used = 0;
        for word in words {
            self.add(word)?;
        }
        Ok(())
    }

    fn add(&mut self, word: &Word) -> Result<(), Fault> {
        let letter = word.letter as char;
        let number = |w: &Word| w.value.ok_or_else(|| Fault::new(w.column, format!("{letter} needs a number, not a string")));
        match word.letter {
            b'G' | b'M' => {
                let value = number(word)?;
                let tenths = code_tenths(value).ok_or_else(|| Fault::new(word.column, format!("invalid code number {letter}{value}")))?;
                let code = Code { tenths, column: word.column };
                if word.letter == b'G' { self.g.push(code) } else { self.m.push(code) }
            }
            b'N' => {
                number(word)?;
            }
            _ => {
                let slot = &mut self.params[letter_index(word.letter)];
                if slot.is_some() {
                    return Err(Fault::new(word.column, format!("word {letter} given twice on one line")));
                }
                *slot = Some(Param { value: word.value, column: word.column });
            }
        }
        Ok(())
    }

    fn has(&self, letter: u8) -> bool {
        self.params[letter_index(letter)].is_some()
    }

    fn has_any(&self, letters: &[u8]) -> bool {
        letters.iter().any(|l| self.has(*l))
    }

    /// Column of `letter`'s word (0 if absent).
    fn column(&self, letter: u8) -> usize {
        self.params[letter_index(letter)].map_or(0, |p| p.column)
    }

    /// The number of `letter`'s word, marking it used; an error if it is a string.
    fn take(&mut self, letter: u8) -> Result<Option<f64>, Fault> {
        let Some(param) = self.params[letter_index(letter)] else { return Ok(None) };
        self.used |= 1 << letter_index(letter);
        let message = || format!("{} needs a number, not a string", letter as char);
        param.value.map(Some).ok_or_else(|| Fault::new(param.column, message()))
    }

    /// Parameters present but not consumed, in letter order.
    fn unused(&self) -> impl Iterator<Item = (u8, Param)> + '_ {
        (0..26u8).filter(|i| self.used & (1 << i) == 0).filter_map(|i| self.params[usize::from(i)].map(|p| (b'A' + i, p)))
    }

    fn mark_all_used(&mut self) {
        self.used = u32::MAX;
    }
}

// ---------------------------------------------------------------------------------------------
// Code tables.
// ---------------------------------------------------------------------------------------------

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Motion {
    Rapid,
    Linear,
    Clockwise,
    CounterClockwise,
}

impl Motion {
    fn name(self) -> &'static str {
        match self {
            Motion::Rapid => "G0",
            Motion::Linear => "G1",
            Motion::Clockwise => "G2",
            Motion::CounterClockwise => "G3",
        }
    }

    fn is_arc(self) -> bool {
        matches!(self, Motion::Clockwise | Motion::CounterClockwise)
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Plane {
    Xy,
    Zx,
    Yz,
}

/// An arc plane as LinuxCNC orders it: (first, second, normal) form a right-handed frame, and G3
/// turns from first towards second.
struct PlaneAxes {
    first: usize,
    second: usize,
    normal: usize,
    /// Centre-offset letters along first, second and normal.
    offsets: [u8; 3],
    name: &'static str,
}

impl Plane {
    fn axes(self) -> PlaneAxes {
        match self {
            Plane::Xy => PlaneAxes { first: 0, second: 1, normal: 2, offsets: [b'I', b'J', b'K'], name: "XY plane (G17)" },
            Plane::Zx => PlaneAxes { first: 2, second: 0, normal: 1, offsets: [b'K', b'I', b'J'], name: "ZX plane (G18)" },
            Plane::Yz => PlaneAxes { first: 1, second: 2, normal: 0, offsets: [b'J', b'K', b'I'], name: "YZ plane (G19)" },
        }
    }
}

/// What a G-code does here.
#[derive(Clone, Copy, Debug, PartialEq)]
enum GAction {
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

fn classify_g(tenths: u32) -> GAction {
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
fn ignored_g_message(tenths: u32) -> &'static str {
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

fn ignored_m_message(tenths: u32) -> &'static str {
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

// ---------------------------------------------------------------------------------------------
// Warnings and notes, once per kind.
// ---------------------------------------------------------------------------------------------

#[derive(Default)]
struct Reports {
    entries: Vec<Warning>,
}

impl Reports {
    /// Counts one occurrence of `kind`; the first one keeps its line, column and message.
    fn record(&mut self, kind: &str, line: usize, column: usize, message: impl FnOnce() -> String) {
        if self.count(kind) {
            return;
        }
        if self.entries.len() < MAX_REPORT_KINDS {
            self.entries.push(Warning { line, column, kind: kind.to_string(), message: message(), count: 1 });
        } else if !self.count(OTHER_KIND) {
            let message = format!("more kinds than are listed apart; the first: {kind}: {}", message());
            self.entries.push(Warning { line, column, kind: OTHER_KIND.to_string(), message, count: 1 });
        }
    }

    /// Counts one more of `kind` if it is listed.
    fn count(&mut self, kind: &str) -> bool {
        let entry = self.entries.iter_mut().find(|e| e.kind == kind);
        entry.map(|e| e.count = e.count.saturating_add(1)).is_some()
    }
}

// ---------------------------------------------------------------------------------------------
// Interpretation: modal state and the segments a block makes.
// ---------------------------------------------------------------------------------------------

/// Modes that persist from line to line.
struct Modal {
    motion: Option<Motion>,
    plane: Plane,
    /// Metres per program length unit.
    unit: f64,
    absolute: bool,
    absolute_e: bool,
    absolute_arc_centres: bool,
    /// Modal feed (m/s).
    feed: Option<f64>,
    /// Last feed given on a line executing G0 (m/s).
    rapid_feed: Option<f64>,
    /// An E word or M82/M83 has been seen: G4 P is in milliseconds.
    slicer_dialect: bool,
}

/// Where the machine is.
struct Machine {
    /// Physical position (m).
    position: Vector3<f64>,
    /// physical = program · unit + offset (m), set by G92.
    offset: Vector3<f64>,
    /// Extruder position (m of filament), as G92 E sets it.
    extruder: f64,
}

/// The codes of one line, sorted by what they do.
#[derive(Default)]
struct Plan {
    motion: Option<(Motion, usize)>,
    cancel_motion: bool,
    dwell: Option<usize>,
    plane: Option<Plane>,
    unit: Option<f64>,
    absolute: Option<bool>,
    absolute_arc_centres: Option<bool>,
    set_position: Option<usize>,
    reset_offsets: bool,
    absolute_e: Option<bool>,
    program_end: bool,
    /// An unacted code that owns the line's leftover parameters (all of them if it takes axes).
    owner: Option<(usize, bool)>,
}

/// Which modal group a code is in, for the one-per-line check.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Group {
    Motion,
    Plane,
    Units,
    Distance,
    ArcDistance,
    Extruder,
}

struct Interpreter {
    options: GcodeOptions,
    modal: Modal,
    machine: Machine,
    tags: Tags,
    layer_marker_pending: bool,
    next_seq: u64,
    warnings: Reports,
    notes: Reports,
    /// A `%` or code was seen: a later `%` ends the program.
    started: bool,
    /// M2, M30 or a closing `%` was executed.
    ended: bool,
    groups_seen: Vec<(Group, usize)>,
}

const AXES: [u8; 3] = [b'X', b'Y', b'Z'];
const POSITION_WORDS: [u8; 4] = [b'X', b'Y', b'Z', b'E'];
const ARC_WORDS: [u8; 4] = [b'I', b'J', b'K', b'R'];
const UNSUPPORTED_AXES: [u8; 6] = [b'A', b'B', b'C', b'U', b'V', b'W'];

impl Interpreter {
    fn new(options: GcodeOptions) -> Self {
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
    fn percent(&mut self) {
        if self.started {
            self.ended = true;
        }
        self.started = true;
    }

    /// After the program's end: count lines that still hold code.
    fn count_after_end(&mut self, bytes: &[u8], line: usize) {
        let text = String::from_utf8_lossy(bytes);
        let code = text.trim_start();
        if !code.is_empty() && !code.starts_with([';', '(', '%']) {
            self.warnings.record("after end", line, 1, || "code after the program's end (M2, M30 or %) not executed".into());
        }
    }

    /// Slicer tags in a `;` comment (the characters after the `;`).
    fn read_tag_comment(&mut self, comment: &[char]) {
        if !comment.first().is_some_and(|c| c.is_ascii_uppercase()) {
            return;
        }
        let text: String = comment.iter().collect();
        let text = text.trim();
        if let Some(feature) = text.strip_prefix("TYPE:") {
            let feature = feature.trim();
            if self.tags.feature.as_deref() != Some(feature) {
                self.tags.feature = Some(Arc::from(feature));
            }
        } else if text == "LAYER_CHANGE" {
            self.tags.layer = Some(self.tags.layer.map_or(0, |l| l.saturating_add(1)));
            self.layer_marker_pending = true;
        } else if let Some(layer) = text.strip_prefix("LAYER:") {
            if let Ok(layer) = layer.trim().parse::<i32>() {
                self.tags.layer = Some(layer);
                self.layer_marker_pending = true;
            }
        } else if let Some(Ok(z)) = text.strip_prefix("Z:").map(|z| z.trim().parse::<f64>()) {
            self.tags.z_marker = Some(z * self.modal.unit).filter(|z| z.is_finite());
        }
    }

    /// Executes one block in RS274/NGC order: feed, unacted codes, extruder mode, dwell, modes,
    /// G92, motion, words left over, program end.
    fn execute(&mut self, block: &mut Block, line: usize, out: &mut VecDeque<GcodeSegment>) -> Result<(), Fault> {
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
    fn plan(&mut self, block: &Block, line: usize) -> Result<Plan, Fault> {
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

    fn claim_group(&mut self, group: Group, code: Code, letter: char) -> Result<(), Fault> {
        if let Some((_, first)) = self.groups_seen.iter().find(|(g, _)| *g == group) {
            let message = format!("{} conflicts with another code of its group at column {first}", code_name(letter, code.tenths));
            return Err(Fault::new(code.column, message));
        }
        self.groups_seen.push((group, code.column));
        Ok(())
    }

    fn plan_g(&mut self, code: Code, plan: &mut Plan, line: usize) -> Result<(), Fault> {
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

    fn plan_m(&mut self, code: Code, plan: &mut Plan, line: usize) -> Result<(), Fault> {
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
    fn motion_to_execute(&mut self, plan: &Plan, block: &Block) -> Result<Option<(Motion, usize)>, Fault> {
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
    fn set_feed(&mut self, block: &mut Block, motion: Option<Motion>, plan: &Plan) -> Result<(), Fault> {
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

    fn apply_modes(&mut self, plan: &Plan) {
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
    fn dwell(&mut self, block: &mut Block, line: usize, column: usize, out: &mut VecDeque<GcodeSegment>) -> Result<(), Fault> {
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
    fn set_position(&mut self, block: &mut Block) -> Result<(), Fault> {
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
    fn target(&self, block: &mut Block) -> Result<Vector3<f64>, Fault> {
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
    fn extrusion(&mut self, block: &mut Block) -> Result<f64, Fault> {
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
    fn feed_for(&self, motion: Motion, column: usize) -> Result<f64, Fault> {
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

    fn move_to(
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
    fn emit_move(&mut self, mut segment: Segment, feed: f64, filament: f64, line: usize, out: &mut VecDeque<GcodeSegment>) {
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

    fn emit(&mut self, mut segment: Segment, line: usize, out: &mut VecDeque<GcodeSegment>) {
        segment.seq = self.next_seq;
        self.next_seq = self.next_seq.wrapping_add(1);
        segment.orientation = self.options.orientation;
        segment.source_line = u32::try_from(line).unwrap_or(u32::MAX);
        out.push_back(GcodeSegment { segment, line, tags: self.tags.clone() });
    }

    /// Words no code acted on: parameters of an unacted code, or warned once per kind; unsupported
    /// axes are an error.
    fn report_leftovers(&mut self, block: &mut Block, plan: &Plan, line: usize) -> Result<(), Fault> {
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
fn merge_owner(owner: Option<(usize, bool)>, column: usize, takes_axes: bool) -> (usize, bool) {
    match owner {
        Some((first, takes)) => (first, takes || takes_axes),
        None => (column, takes_axes),
    }
}

/// True if an explicit `motion` code on this block moves: position words, or centre words for an
/// arc (`G2 I.5 J.5` is a full circle where it stands).
fn moves(block: &Block, motion: Motion) -> bool {
    block.has_any(&POSITION_WORDS) || (motion.is_arc() && block.has_any(&ARC_WORDS))
}

/// Column of the first of `letters` present (0 if none).
fn first_column(block: &Block, letters: &[u8]) -> usize {
    letters.iter().map(|l| block.column(*l)).filter(|c| *c > 0).min().unwrap_or(0)
}

fn finite(value: f64, column: usize) -> Result<f64, Fault> {
    if value.is_finite() { Ok(value) } else { Err(Fault::new(column, "value out of range (not finite)")) }
}

// ---------------------------------------------------------------------------------------------
// Arcs.
// ---------------------------------------------------------------------------------------------

/// An arc's geometry, as the segment carries it.
struct ArcGeometry {
    centre: Vector3<f64>,
    normal: Vector3<f64>,
    sweep: f64,
}

/// An arc's start and end in plane coordinates (first, second), metres.
struct PlaneArc {
    start: (f64, f64),
    end: (f64, f64),
}

impl PlaneArc {
    fn chord(&self) -> f64 {
        libm::hypot(self.end.0 - self.start.0, self.end.1 - self.start.1)
    }
}

impl Interpreter {
    fn arc(&self, block: &mut Block, motion: Motion, column: usize, target: Vector3<f64>) -> Result<ArcGeometry, Fault> {
        let axes = self.modal.plane.axes();
        let start = self.machine.position;
        let plane = PlaneArc { start: (start[axes.first], start[axes.second]), end: (target[axes.first], target[axes.second]) };
        let clockwise = motion == Motion::Clockwise;
        let centre = if block.has(b'R') {
            self.radius_form_centre(block, &axes, &plane, clockwise, column)?
        } else {
            self.offset_form_centre(block, &axes, column)?
        };
        let full_circle = plane.chord() < ZERO_LENGTH;
        self.check_radii(&plane, centre, column)?;
        let turns = arc_turns(block)?;
        let sweep = finite(arc_sweep(&plane, centre, clockwise, full_circle) + TAU * (turns - 1.0), column)?;
        let mut centre3 = start;
        centre3[axes.first] = centre.0;
        centre3[axes.second] = centre.1;
        let mut normal = Vector3::zeros();
        normal[axes.normal] = if clockwise { -1.0 } else { 1.0 };
        Ok(ArcGeometry { centre: centre3, normal, sweep })
    }

    /// Centre from I/J/K: offsets from the start (absolute under G90.1). The normal's offset is an error.
    fn offset_form_centre(&self, block: &mut Block, axes: &PlaneAxes, column: usize) -> Result<(f64, f64), Fault> {
        let [first, second, normal] = axes.offsets;
        if block.has(normal) {
            let message = format!("{} word given for an arc in the {}", normal as char, axes.name);
            return Err(Fault::new(block.column(normal), message));
        }
        if !block.has(first) && !block.has(second) {
            return Err(Fault::new(column, format!("arc without a centre: give {} / {} or R", first as char, second as char)));
        }
        let unit = self.modal.unit;
        let (i, j) = (block.take(first)?.unwrap_or(0.0) * unit, block.take(second)?.unwrap_or(0.0) * unit);
        let position = self.machine.position;
        let centre = if self.modal.absolute_arc_centres {
            (i + self.machine.offset[axes.first], j + self.machine.offset[axes.second])
        } else {
            (position[axes.first] + i, position[axes.second] + j)
        };
        Ok((finite(centre.0, block.column(first))?, finite(centre.1, block.column(second))?))
    }

    /// Centre from R (LinuxCNC's construction): on the chord's perpendicular bisector, on the side
    /// that makes the arc at most a half circle for R > 0 and at least one for R < 0.
    fn radius_form_centre(
        &self,
        block: &mut Block,
        axes: &PlaneAxes,
        arc: &PlaneArc,
        clockwise: bool,
        column: usize,
    ) -> Result<(f64, f64), Fault> {
        let r_column = block.column(b'R');
        let [first, second, normal] = axes.offsets;
        if let Some(letter) = [first, second, normal].into_iter().find(|l| block.has(*l)) {
            return Err(Fault::new(block.column(letter), format!("both R and {} given for one arc", letter as char)));
        }
        let radius = block.take(b'R')?.unwrap_or(0.0) * self.modal.unit;
        let abs_radius = radius.abs();
        if abs_radius < self.zero_radius() {
            return Err(Fault::new(r_column, "zero radius arc"));
        }
        if arc.chord() < ZERO_LENGTH {
            return Err(Fault::new(column, "R-form arc with its end on its start: the circle is undefined (use I/J/K for a full circle)"));
        }
        let mut half = arc.chord() / 2.0;
        if half - abs_radius > self.tolerance(abs_radius) {
            let message =
                format!("arc radius too small to reach the end point: |R| = {} mm, half chord = {} mm", abs_radius / MM, half / MM);
            return Err(Fault::new(r_column, message));
        }
        half = half.min(abs_radius);
        let mid = ((arc.start.0 + arc.end.0) / 2.0, (arc.start.1 + arc.end.1) / 2.0);
        let chord_angle = libm::atan2(arc.end.1 - arc.start.1, arc.end.0 - arc.start.0);
        let right_side = clockwise == (radius > 0.0);
        let direction = if right_side { chord_angle - PI / 2.0 } else { chord_angle + PI / 2.0 };
        let offset = libm::sqrt((abs_radius - half) * (abs_radius + half));
        Ok((mid.0 + offset * libm::cos(direction), mid.1 + offset * libm::sin(direction)))
    }

    /// Radius tolerance (m) for an arc of radius `radius`.
    fn tolerance(&self, radius: f64) -> f64 {
        self.options.arc_radius_tolerance.max(0.001 * radius)
    }

    /// Radii below this (m) are zero: a tenth of the absolute tolerance, as LinuxCNC.
    fn zero_radius(&self) -> f64 {
        (0.1 * self.options.arc_radius_tolerance).max(ZERO_LENGTH)
    }

    /// Rejects zero radii and start/end radii further apart than the tolerance.
    fn check_radii(&self, arc: &PlaneArc, centre: (f64, f64), column: usize) -> Result<(), Fault> {
        let r0 = libm::hypot(arc.start.0 - centre.0, arc.start.1 - centre.1);
        let r1 = libm::hypot(arc.end.0 - centre.0, arc.end.1 - centre.1);
        if r0 < self.zero_radius() || r1 < self.zero_radius() {
            return Err(Fault::new(column, format!("zero radius arc: start radius {} mm, end radius {} mm", r0 / MM, r1 / MM)));
        }
        let tolerance = self.tolerance(r0.max(r1));
        if (r0 - r1).abs() > tolerance {
            let message = format!(
                "radius to end of arc differs from radius to start: r0 = {:.6} mm, r1 = {:.6} mm, tolerance {:.6} mm",
                r0 / MM,
                r1 / MM,
                tolerance / MM
            );
            return Err(Fault::new(column, message));
        }
        Ok(())
    }
}

/// Turns from the P word: a whole number ≥ 1 (default 1).
fn arc_turns(block: &mut Block) -> Result<f64, Fault> {
    let column = block.column(b'P');
    match block.take(b'P')? {
        None => Ok(1.0),
        Some(p) if p >= 1.0 && p.fract() == 0.0 => Ok(p),
        Some(p) => Err(Fault::new(column, format!("P{p}: the number of turns must be a whole number ≥ 1"))),
    }
}

/// Angle (rad, in (0, 2π]) swept from start to end about the centre, clockwise or not.
fn arc_sweep(arc: &PlaneArc, centre: (f64, f64), clockwise: bool, full_circle: bool) -> f64 {
    if full_circle {
        return TAU;
    }
    let a0 = libm::atan2(arc.start.1 - centre.1, arc.start.0 - centre.0);
    let a1 = libm::atan2(arc.end.1 - centre.1, arc.end.0 - centre.0);
    let mut sweep = if clockwise { a0 - a1 } else { a1 - a0 };
    if sweep <= 0.0 {
        sweep += TAU;
    }
    if sweep > TAU { sweep - TAU } else { sweep }
}
