//! Segment files: strand's job format for what G-code cannot say — a tool orientation on every
//! segment (5-axis paths on curved surfaces, tilted finishing layers, inclined beds) — read by
//! `strand-feed` like G-code and written by the `strand-plan` planners.
//!
//! A segment file is a core [`Segment`] list written down one-to-one, so nothing is lost between a
//! planner and the controller: SI units, floats written in the shortest form that reads back to the
//! same bits, and every key named as in [`Segment`].
//!
//! # Format
//!
//! [JSON Lines](https://jsonlines.org): UTF-8, one JSON object per line; blank lines are skipped.
//! The first object is the header, every other one is a segment. Coordinates are in the bed frame,
//! as G-code's are: `strand-feed` applies the config's `[bed]` transform to both (a tilted bed also
//! turns the orientations).
//!
//! Header: `{"format": "strand-segments", "version": 1, "note": "..."}` (`note` optional: who wrote
//! the file and with which parameters).
//!
//! Segment keys (unknown keys are an error, so a typo is never silently ignored):
//!
//! | key | unit | kinds | meaning |
//! |---|---|---|---|
//! | `kind` | | all | `"line"` (default), `"arc"`, `"dwell"` or `"heat"` |
//! | `end` | m | line, arc | end point of the TCP (required) |
//! | `centre` | m | arc | arc centre, in the plane of the start point (required) |
//! | `normal` | unit | arc | arc axis; counter-clockwise about it (required) |
//! | `sweep` | rad | arc | angle turned, > 0 (required) |
//! | `orientation` | unit quaternion (w, x, y, z) | all | tool orientation at the end; tool z is the nozzle direction. Default: the previous segment's; for the first, nozzle down (π about y) |
//! | `feed` | m/s | line, arc | programmed speed, > 0 (required) |
//! | `filament` | m of filament | all | to push over the segment; negative retracts (default 0) |
//! | `duration` | s | dwell | standing time, ≥ 0 (required) |
//! | `heater` | | heat | `"hot_end"` or `"bed"` (required) |
//! | `wait` | | heat | `"none"` (default), `"heating"` (M109 S), `"both"` (M109 R) or `"range"` (TEMPERATURE_WAIT) |
//! | `temperature` | °C | heat | the new target, 0–500 (absent or < 0: keep the target) |
//! | `range` | °C | heat | a `"range"` wait's low and high |
//! | `flags` | | all | any of `"extrude"`, `"travel"`, `"layer_start"`, `"last"`; default: `extrude` for a move with filament > 0, `travel` for any other move, none for a dwell |
//! | `layer` | | all | slicer layer index (optional; otherwise counted from `layer_start` flags) |
//! | `pressure_advance` | s | all | the program's pressure advance for this segment, ≥ 0 (optional; the controller clamps it to `[extruder] max_pressure_advance`; absent keeps the config's) |
//! | `axes` | rad or m | all | where the cell's external axes (a positioner under the part) are at the segment's end, in the chain order of `[positioner]`: 1 or 2 finite numbers (with 1, the second axis is 0). Over a line or arc they move in proportion to the path, over a dwell they turn in place; the points are then in the work frame at home (where they lie with every external axis at 0). Optional: absent, the axes stay where they are |
//!
//! An orientation is accepted if its norm is within 1e-6 of 1, and normalised unless it is unit to
//! rounding (1e-12). An arc's start
//! (the previous end) and end must lie at the same distance from the centre within
//! max(0.05 mm, 0.001 · radius), as the G-code parser requires; an arc cannot open a file (its start
//! would be unknown). `last` may only be on the final segment. Errors name the file, the line and
//! the key.

use std::fmt::Write as _;
use std::fs::File;
use std::io::{self, BufRead, BufReader, BufWriter, Write};
use std::path::Path;

use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use serde::Deserialize;
use thiserror::Error;

use strand_core::{HeatWait, Heater, MAX_ARC_SWEEP, Segment, SegmentFlags, SegmentKind};
use strand_wire::MAX_EXTERNAL_AXES;

/// The header's `format` value.
pub(crate) const FORMAT: &str = "strand-segments";
/// The format version this module reads and writes.
pub const VERSION: u32 = 1;

/// The `flags` names, one per flag bit.
const FLAG_NAMES: [(SegmentFlags, &str); 4] = [
    (SegmentFlags::EXTRUDE, "extrude"),
    (SegmentFlags::TRAVEL, "travel"),
    (SegmentFlags::LAYER_START, "layer_start"),
    (SegmentFlags::LAST, "last"),
];

/// Why a segment file cannot be read, and where.
#[derive(Clone, Debug, Error, PartialEq, Eq)]
#[error("{file}:{line}: {message}")]
pub struct SegfileError {
    /// File name as given.
    pub file: String,
    /// Line (1-based; 0 if the file could not be opened, read or written).
    pub line: usize,
    /// What is wrong, naming the key.
    pub message: String,
}

/// A segment file read back.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SegmentFile {
    /// The header's note.
    pub note: Option<String>,
    /// The segments, numbered from the first sequence number asked for, each with its layer.
    pub segments: Vec<(Segment, Option<i32>)>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Header {
    format: String,
    version: u32,
    #[serde(default)]
    note: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Record {
    #[serde(default)]
    kind: Option<String>,
    #[serde(default)]
    end: Option<[f64; 3]>,
    #[serde(default)]
    centre: Option<[f64; 3]>,
    #[serde(default)]
    normal: Option<[f64; 3]>,
    #[serde(default)]
    sweep: Option<f64>,
    #[serde(default)]
    orientation: Option<[f64; 4]>,
    #[serde(default)]
    feed: Option<f64>,
    #[serde(default)]
    filament: Option<f64>,
    #[serde(default)]
    duration: Option<f64>,
    #[serde(default)]
    flags: Option<Vec<String>>,
    #[serde(default)]
    layer: Option<i32>,
    #[serde(default)]
    pressure_advance: Option<f64>,
    #[serde(default)]
    axes: Option<Vec<f64>>,
    /// Heat records: `"hot_end"` or `"bed"`.
    #[serde(default)]
    heater: Option<String>,
    /// Heat records: `"none"`, `"heating"`, `"both"` or `"range"`.
    #[serde(default)]
    wait: Option<String>,
    /// Heat records: the target (°C; < 0 keeps it).
    #[serde(default)]
    temperature: Option<f64>,
    /// Heat records with `"range"`: low and high (°C).
    #[serde(default)]
    range: Option<[f64; 2]>,
}

const HEATERS: [(Heater, &str); 2] = [(Heater::HotEnd, "hot_end"), (Heater::Bed, "bed")];
const WAITS: [(HeatWait, &str); 4] =
    [(HeatWait::None, "none"), (HeatWait::Heating, "heating"), (HeatWait::Both, "both"), (HeatWait::Range, "range")];

/// The tool orientation that points the nozzle (tool z) along `nozzle` (any length > 0), reached
/// from the nozzle-down default by the shortest rotation, so the tool's roll stays as close to the
/// G-code default as the direction allows. Straight up (the one direction with no shortest
/// rotation from straight down) turns π about x.
pub fn tool_pointing(nozzle: &Vector3<f64>) -> UnitQuaternion<f64> {
    let down = UnitQuaternion::new_unchecked(Quaternion::new(0.0, 0.0, 1.0, 0.0));
    let turn = UnitQuaternion::rotation_between(&-Vector3::z(), nozzle)
        .unwrap_or_else(|| UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI));
    turn * down
}

/// True if the file's first non-blank line is a segment-file header (so a caller can tell a
/// segment file from G-code by content, whatever its name).
pub(crate) fn is_segment_file(path: &Path) -> bool {
    let Ok(f) = File::open(path) else { return false };
    for line in BufReader::new(f).lines() {
        let Ok(line) = line else { return false };
        let t = line.trim();
        if t.is_empty() {
            continue;
        }
        return serde_json::from_str::<Header>(t).is_ok_and(|h| h.format == FORMAT);
    }
    false
}

/// Reads a segment file; segments are numbered from `first_seq`.
pub fn read_path(path: &Path, first_seq: u64) -> Result<SegmentFile, SegfileError> {
    let name = path.display().to_string();
    let f = File::open(path).map_err(|e| SegfileError { file: name.clone(), line: 0, message: e.to_string() })?;
    read(BufReader::new(f), &name, first_seq)
}

/// Reads a segment file from any reader; `name` is used in errors.
pub fn read<R: BufRead>(input: R, name: &str, first_seq: u64) -> Result<SegmentFile, SegfileError> {
    let err = |line: usize, message: String| SegfileError { file: name.to_string(), line, message };
    let mut out = SegmentFile::default();
    let mut header_seen = false;
    let mut orientation = UnitQuaternion::new_unchecked(Quaternion::new(0.0, 0.0, 1.0, 0.0));
    let mut position: Option<Vector3<f64>> = None;
    let mut layer: Option<i32> = None;
    let mut last_line = 0;
    for (k, line) in input.lines().enumerate() {
        let n = k + 1;
        let line = line.map_err(|e| err(n, e.to_string()))?;
        let text = line.trim();
        if text.is_empty() {
            continue;
        }
        if !header_seen {
            let h: Header = serde_json::from_str(text).map_err(|e| {
                err(n, format!("not a segment-file header ({e}); expected {{\"format\": \"{FORMAT}\", \"version\": {VERSION}}}"))
            })?;
            if h.format != FORMAT {
                return Err(err(n, format!("format: \"{}\" is not \"{FORMAT}\"", h.format)));
            }
            if h.version != VERSION {
                return Err(err(n, format!("version: {} is not supported (this strand reads version {VERSION})", h.version)));
            }
            out.note = h.note;
            header_seen = true;
            continue;
        }
        if let Some((prev, _)) = out.segments.last()
            && prev.flags.contains(SegmentFlags::LAST)
        {
            return Err(err(last_line, "flags: \"last\" on a segment that is not the final one".into()));
        }
        let r: Record = serde_json::from_str(text).map_err(|e| err(n, e.to_string()))?;
        let seq = first_seq + out.segments.len() as u64;
        let (segment, seg_layer) = segment(&r, seq, n, &mut orientation, &mut position, &mut layer).map_err(|m| err(n, m))?;
        out.segments.push((segment, seg_layer));
        last_line = n;
    }
    if !header_seen {
        return Err(err(0, "empty: no header line".into()));
    }
    Ok(out)
}

fn finite3(key: &str, v: Option<[f64; 3]>) -> Result<Option<Vector3<f64>>, String> {
    match v {
        Some(a) if a.iter().all(|x| x.is_finite()) => Ok(Some(Vector3::from(a))),
        Some(a) => Err(format!("{key}: {a:?} is not finite")),
        None => Ok(None),
    }
}

/// The `axes` key: 1 or [`MAX_EXTERNAL_AXES`] finite numbers (rad or m), missing entries 0.
fn external_axes(values: &[f64]) -> Result<[f64; MAX_EXTERNAL_AXES], String> {
    if values.is_empty() || values.len() > MAX_EXTERNAL_AXES {
        return Err(format!("axes: {} entries, give 1 to {MAX_EXTERNAL_AXES} (one per external axis)", values.len()));
    }
    if let Some(bad) = values.iter().find(|v| !v.is_finite()) {
        return Err(format!("axes: {bad} is not finite"));
    }
    let mut axes = [0.0; MAX_EXTERNAL_AXES];
    axes[..values.len()].copy_from_slice(values);
    Ok(axes)
}

fn required<T>(key: &str, kind: &str, v: Option<T>) -> Result<T, String> {
    v.ok_or_else(|| format!("{key}: required for a {kind}"))
}

fn absent<T>(key: &str, kind: &str, v: &Option<T>) -> Result<(), String> {
    if v.is_some() { Err(format!("{key}: not allowed on a {kind}")) } else { Ok(()) }
}

/// One record → a segment; `orientation`, `position` and `layer` carry the state between lines.
fn segment(
    r: &Record,
    seq: u64,
    line: usize,
    orientation: &mut UnitQuaternion<f64>,
    position: &mut Option<Vector3<f64>>,
    layer: &mut Option<i32>,
) -> Result<(Segment, Option<i32>), String> {
    let kind_name = r.kind.as_deref().unwrap_or("line");
    let kind = match kind_name {
        "line" => SegmentKind::Line,
        "arc" => SegmentKind::Arc,
        "dwell" => SegmentKind::Dwell,
        "heat" => SegmentKind::Heat,
        other => return Err(format!("kind: \"{other}\" is not one of \"line\", \"arc\", \"dwell\", \"heat\"")),
    };
    if kind != SegmentKind::Heat {
        for (key, present) in [
            ("heater", r.heater.is_some()),
            ("wait", r.wait.is_some()),
            ("temperature", r.temperature.is_some()),
            ("range", r.range.is_some()),
        ] {
            if present {
                return Err(format!("{key}: not allowed on a {kind_name}"));
            }
        }
    }
    let mut s = Segment { seq, kind, source_line: u32::try_from(line).unwrap_or(u32::MAX), ..Segment::default() };
    if let Some(q) = r.orientation {
        if !q.iter().all(|x| x.is_finite()) {
            return Err(format!("orientation: {q:?} is not finite"));
        }
        let quat = Quaternion::new(q[0], q[1], q[2], q[3]);
        if (quat.norm() - 1.0).abs() > 1e-6 {
            return Err(format!("orientation: {q:?} has norm {:.9}, not 1 (w, x, y, z)", quat.norm()));
        }
        // Kept as written when already unit to rounding, so a written file reads back bit for bit.
        *orientation =
            if (quat.norm() - 1.0).abs() < 1e-12 { UnitQuaternion::new_unchecked(quat) } else { UnitQuaternion::from_quaternion(quat) };
    }
    s.orientation = *orientation;
    let filament = r.filament.unwrap_or(0.0);
    if !filament.is_finite() {
        return Err(format!("filament: {filament} is not finite"));
    }
    s.filament = filament;
    if let Some(k) = r.pressure_advance
        && !(k.is_finite() && k >= 0.0)
    {
        return Err(format!("pressure_advance: {k} s must be finite and ≥ 0"));
    }
    s.pressure_advance = r.pressure_advance;
    s.axes = r.axes.as_deref().map(external_axes).transpose()?;
    match kind {
        SegmentKind::Heat => {
            absent("end", kind_name, &r.end)?;
            absent("feed", kind_name, &r.feed)?;
            absent("duration", kind_name, &r.duration)?;
            if filament != 0.0 {
                return Err("filament: not allowed on a heat record".into());
            }
            let heater = required("heater", kind_name, r.heater.as_deref())?;
            s.heat.heater = HEATERS
                .iter()
                .find(|(_, n)| *n == heater)
                .map(|(h, _)| *h)
                .ok_or_else(|| format!("heater: \"{heater}\" is not \"hot_end\" or \"bed\""))?;
            let wait = r.wait.as_deref().unwrap_or("none");
            s.heat.wait = WAITS
                .iter()
                .find(|(_, n)| *n == wait)
                .map(|(w, _)| *w)
                .ok_or_else(|| format!("wait: \"{wait}\" is not one of \"none\", \"heating\", \"both\", \"range\""))?;
            s.heat.target = r.temperature.unwrap_or(-1.0);
            s.heat.band = r.range.unwrap_or(strand_core::OPEN_BAND);
            s.end = position.unwrap_or_else(Vector3::zeros);
            s.check().map_err(|e| e.to_string())?;
        }
        SegmentKind::Dwell => {
            absent("end", kind_name, &r.end)?;
            absent("feed", kind_name, &r.feed)?;
            let d = required("duration", kind_name, r.duration)?;
            if !(d.is_finite() && d >= 0.0) {
                return Err(format!("duration: {d} s must be finite and ≥ 0"));
            }
            s.duration = d;
            s.end = position.unwrap_or_else(Vector3::zeros);
        }
        SegmentKind::Line | SegmentKind::Arc => {
            absent("duration", kind_name, &r.duration)?;
            let end = required("end", kind_name, finite3("end", r.end)?)?;
            let feed = required("feed", kind_name, r.feed)?;
            if !(feed.is_finite() && feed > 0.0) {
                return Err(format!("feed: {feed} m/s must be finite and > 0"));
            }
            s.end = end;
            s.feed = feed;
        }
    }
    if kind == SegmentKind::Arc {
        let centre = required("centre", "arc", finite3("centre", r.centre)?)?;
        let normal = required("normal", "arc", finite3("normal", r.normal)?)?;
        let sweep = required("sweep", "arc", r.sweep)?;
        if (normal.norm() - 1.0).abs() > 1e-6 {
            return Err(format!("normal: norm {:.9} is not 1", normal.norm()));
        }
        if !(sweep.is_finite() && sweep > 0.0 && sweep <= MAX_ARC_SWEEP) {
            return Err(format!("sweep: {sweep} rad must be finite, > 0 and at most 1000 turns (2000π)"));
        }
        let start = position.ok_or("kind: an arc cannot be the first segment (its start point is not in the file)")?;
        let radius_at = |p: &Vector3<f64>| {
            let d = p - centre;
            (d - normal * d.dot(&normal)).norm()
        };
        let (r0, r1) = (radius_at(&start), radius_at(&s.end));
        if (r0 - r1).abs() > (0.05e-3f64).max(1e-3 * r0.max(r1)) {
            return Err(format!("centre: start radius {:.6} mm and end radius {:.6} mm differ", r0 * 1e3, r1 * 1e3));
        }
        s.centre = centre;
        s.normal = normal.normalize();
        s.sweep = sweep;
    } else {
        absent("centre", kind_name, &r.centre)?;
        absent("normal", kind_name, &r.normal)?;
        absent("sweep", kind_name, &r.sweep)?;
    }
    let moves = !matches!(kind, SegmentKind::Dwell | SegmentKind::Heat);
    s.flags = match &r.flags {
        None if moves && filament > 0.0 => SegmentFlags::EXTRUDE,
        None if moves => SegmentFlags::TRAVEL,
        None => SegmentFlags::default(),
        Some(names) => {
            let mut f = SegmentFlags::default();
            for name in names {
                let Some((bit, _)) = FLAG_NAMES.iter().find(|(_, n)| n == name) else {
                    return Err(format!("flags: \"{name}\" is not one of \"extrude\", \"travel\", \"layer_start\", \"last\""));
                };
                f = f.with(*bit);
            }
            if f.contains(SegmentFlags::EXTRUDE) && f.contains(SegmentFlags::TRAVEL) {
                return Err("flags: \"extrude\" and \"travel\" together".into());
            }
            if f.contains(SegmentFlags::EXTRUDE) && !(moves && filament > 0.0) {
                return Err("flags: \"extrude\" needs a line or arc with filament > 0".into());
            }
            f
        }
    };
    if let Some(l) = r.layer {
        *layer = Some(l);
    } else if s.flags.contains(SegmentFlags::LAYER_START) {
        *layer = Some(layer.map_or(0, |l| l + 1));
    }
    if moves {
        *position = Some(s.end);
    }
    Ok((s, *layer))
}

/// Writes `segments` as a segment file (header with `note`, then one line per segment). Every key
/// a segment needs is written, orientation included, so each line stands on its own.
pub fn write<W: Write>(out: W, segments: &[Segment], note: &str) -> io::Result<()> {
    let mut out = BufWriter::new(out);
    let header = serde_json::json!({ "format": FORMAT, "version": VERSION, "note": note });
    writeln!(out, "{header}")?;
    let mut line = String::new();
    for s in segments {
        line.clear();
        record(&mut line, s);
        writeln!(out, "{line}")?;
    }
    out.flush()
}

/// [`write()`] to a file; the error names it (line 0: the file as a whole).
pub fn write_path(path: &Path, segments: &[Segment], note: &str) -> Result<(), SegfileError> {
    let failed = |e: std::io::Error| SegfileError { file: path.display().to_string(), line: 0, message: format!("cannot write: {e}") };
    let f = File::create(path).map_err(failed)?;
    write(f, segments, note).map_err(failed)
}

/// One segment as a JSON object. Floats use Rust's shortest round-trip form (valid JSON for finite
/// values), so a file reads back to the same bits.
fn record(out: &mut String, s: &Segment) {
    let v3 = |v: &Vector3<f64>| format!("[{:?},{:?},{:?}]", v.x, v.y, v.z);
    let q = s.orientation.quaternion();
    let kind = match s.kind {
        SegmentKind::Line => "line",
        SegmentKind::Arc => "arc",
        SegmentKind::Dwell => "dwell",
        SegmentKind::Heat => "heat",
    };
    let _ = write!(out, "{{\"kind\":\"{kind}\"");
    match s.kind {
        SegmentKind::Heat => {
            let heater = HEATERS.iter().find(|(h, _)| *h == s.heat.heater).map_or("hot_end", |(_, n)| n);
            let wait = WAITS.iter().find(|(w, _)| *w == s.heat.wait).map_or("none", |(_, n)| n);
            let _ = write!(out, ",\"heater\":\"{heater}\",\"wait\":\"{wait}\",\"temperature\":{:?}", s.heat.target);
            if s.heat.wait == HeatWait::Range {
                let _ = write!(out, ",\"range\":[{:?},{:?}]", s.heat.band[0], s.heat.band[1]);
            }
        }
        SegmentKind::Dwell => {
            let _ = write!(out, ",\"duration\":{:?}", s.duration);
        }
        SegmentKind::Line | SegmentKind::Arc => {
            let _ = write!(out, ",\"end\":{}", v3(&s.end));
            if s.kind == SegmentKind::Arc {
                let _ = write!(out, ",\"centre\":{},\"normal\":{},\"sweep\":{:?}", v3(&s.centre), v3(&s.normal), s.sweep);
            }
            let _ = write!(out, ",\"feed\":{:?}", s.feed);
        }
    }
    let _ = write!(out, ",\"orientation\":[{:?},{:?},{:?},{:?}]", q.w, q.i, q.j, q.k);
    let _ = write!(out, ",\"filament\":{:?}", s.filament);
    if let Some(k) = s.pressure_advance {
        let _ = write!(out, ",\"pressure_advance\":{k:?}");
    }
    if let Some(axes) = s.axes {
        let values: Vec<String> = axes.iter().map(|a| format!("{a:?}")).collect();
        let _ = write!(out, ",\"axes\":[{}]", values.join(","));
    }
    let flags: Vec<String> = FLAG_NAMES.iter().filter(|(f, _)| s.flags.contains(*f)).map(|(_, n)| format!("\"{n}\"")).collect();
    let _ = write!(out, ",\"flags\":[{}]}}", flags.join(","));
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<SegmentFile, SegfileError> {
        read(text.as_bytes(), "job.jsonl", 1)
    }

    const HEADER: &str = "{\"format\":\"strand-segments\",\"version\":1}\n";

    #[test]
    fn segments_round_trip_to_the_bit() {
        let tilt = UnitQuaternion::from_euler_angles(0.1, -0.7, 0.3);
        let segments = vec![
            Segment {
                seq: 1,
                end: Vector3::new(0.1, 0.2 / 3.0, 1e-17),
                feed: 0.05,
                flags: SegmentFlags::TRAVEL,
                orientation: tool_pointing(&Vector3::new(0.0, 0.0, -1.0)),
                ..Segment::default()
            },
            Segment {
                seq: 2,
                end: Vector3::new(0.12, 0.2 / 3.0, 0.0),
                feed: 0.01,
                filament: 3.3e-4,
                flags: SegmentFlags::EXTRUDE.with(SegmentFlags::LAYER_START),
                orientation: tilt,
                pressure_advance: Some(0.045),
                ..Segment::default()
            },
            Segment {
                seq: 3,
                kind: SegmentKind::Arc,
                end: Vector3::new(0.1, 0.2 / 3.0 + 0.02, 0.0),
                centre: Vector3::new(0.1, 0.2 / 3.0, 0.0),
                normal: Vector3::z(),
                sweep: std::f64::consts::FRAC_PI_2,
                feed: 0.01,
                filament: 1e-3,
                flags: SegmentFlags::EXTRUDE,
                orientation: tilt,
                ..Segment::default()
            },
            Segment { seq: 4, kind: SegmentKind::Dwell, duration: 0.25, filament: -1e-3, orientation: tilt, ..Segment::default() },
            Segment {
                seq: 5,
                end: Vector3::new(0.1, 0.07, 0.0),
                feed: 0.01,
                flags: SegmentFlags::TRAVEL,
                orientation: tilt,
                axes: Some([0.1 / 3.0, -std::f64::consts::PI]),
                ..Segment::default()
            },
            Segment { seq: 6, kind: SegmentKind::Dwell, duration: 0.5, orientation: tilt, axes: Some([1.0, 0.0]), ..Segment::default() },
        ];
        let mut bytes = Vec::new();
        write(&mut bytes, &segments, "test").unwrap();
        let back = read(bytes.as_slice(), "mem", 1).unwrap();
        assert_eq!(back.note.as_deref(), Some("test"));
        assert_eq!(back.segments.len(), 6);
        for ((got, layer), want) in back.segments.iter().zip(&segments) {
            let mut want = *want;
            if want.kind == SegmentKind::Dwell {
                want.end = segments[if want.seq < 5 { 2 } else { 4 }].end;
            }
            assert_eq!(got.source_line, want.seq as u32 + 1, "one line per segment after the header");
            let got = Segment { source_line: 0, ..*got };
            assert_eq!(got, want);
            assert_eq!(*layer, if want.seq >= 2 { Some(0) } else { None });
        }
    }

    #[test]
    fn defaults_follow_the_previous_segment_and_the_filament() {
        let text = format!(
            "{HEADER}\n{{\"end\":[0,0,0.01],\"feed\":0.1}}\n{{\"end\":[0.01,0,0.01],\"feed\":0.01,\"filament\":1e-4,\"orientation\":[1,0,0,0],\"layer\":3}}\n{{\"end\":[0.02,0,0.01],\"feed\":0.01}}\n"
        );
        let f = parse(&text).unwrap();
        let s: Vec<_> = f.segments.iter().map(|(s, _)| *s).collect();
        assert_eq!(s[0].orientation, tool_pointing(&-Vector3::z()));
        assert_eq!(s[0].flags, SegmentFlags::TRAVEL);
        assert_eq!(s[1].flags, SegmentFlags::EXTRUDE);
        assert_eq!(s[2].orientation, UnitQuaternion::identity());
        assert_eq!(s[2].flags, SegmentFlags::TRAVEL);
        assert_eq!([s[0].seq, s[1].seq, s[2].seq], [1, 2, 3]);
        assert_eq!([s[0].source_line, s[1].source_line, s[2].source_line], [3, 4, 5]);
        assert_eq!(f.segments[2].1, Some(3));
    }

    #[test]
    fn errors_name_the_line_and_the_key() {
        let cases = [
            ("{\"end\":[0,0,0]}", "5: feed: required for a line"),
            ("{\"end\":[0,0,0],\"feed\":-1}", "5: feed: -1 m/s must be finite and > 0"),
            ("{\"end\":[0,0],\"feed\":1}", "5: invalid length 2"),
            ("{\"end\":[0,0,0],\"fed\":1}", "5: unknown field `fed`"),
            ("{\"end\":[0,0,0],\"feed\":1,\"orientation\":[1,1,0,0]}", "5: orientation: [1.0, 1.0, 0.0, 0.0] has norm 1.414213562, not 1"),
            ("{\"kind\":\"spline\"}", "5: kind: \"spline\" is not one of"),
            ("{\"kind\":\"dwell\",\"duration\":1,\"feed\":1}", "5: feed: not allowed on a dwell"),
            ("{\"end\":[0,0,0],\"feed\":1,\"flags\":[\"extrude\"]}", "5: flags: \"extrude\" needs a line or arc with filament > 0"),
            (
                "{\"kind\":\"arc\",\"end\":[0.03,0,0],\"centre\":[0,0,0],\"normal\":[0,0,1],\"sweep\":1,\"feed\":1}",
                "5: centre: start radius 14.142136 mm and end radius 30.000000 mm differ",
            ),
            (
                "{\"end\":[0,0,0],\"feed\":1,\"flags\":[\"last\"]}\n{\"end\":[0,0,0],\"feed\":1}",
                "5: flags: \"last\" on a segment that is not",
            ),
            ("{\"end\":[0,0,0],\"feed\":1,\"axes\":[1,2,3]}", "5: axes: 3 entries, give 1 to 2"),
            ("{\"end\":[0,0,0],\"feed\":1,\"axes\":[]}", "5: axes: 0 entries, give 1 to 2"),
            ("{\"end\":[0,0,0],\"feed\":1,\"axes\":[1e999]}", "5: number out of range"),
            ("{\"end\":[0,0,0],\"feed\":1,\"axes\":[\"a\"]}", "5: invalid type"),
            ("{\"end\":[0,0,0],\"feed\":1,\"axes\":0.5}", "5: invalid type"),
        ];
        for (bad, want) in cases {
            let text = format!("{HEADER}{{\"end\":[0.01,0,0],\"feed\":1}}\n\n{{\"end\":[0.01,0.01,0],\"feed\":1}}\n{bad}\n");
            let e = parse(&text).expect_err(bad).to_string();
            assert!(e.starts_with(&format!("job.jsonl:{want}")), "{bad}: got {e}, want job.jsonl:{want}");
        }
        assert_eq!(parse("").unwrap_err().to_string(), "job.jsonl:0: empty: no header line");
        let e = parse("{\"format\":\"strand-segments\",\"version\":2}").unwrap_err().to_string();
        assert_eq!(e, "job.jsonl:1: version: 2 is not supported (this strand reads version 1)");
        assert!(parse("G1 X1\n").unwrap_err().to_string().starts_with("job.jsonl:1: not a segment-file header"));
        let e =
            parse(&format!("{HEADER}{{\"kind\":\"arc\",\"end\":[0,0,0],\"centre\":[0,0,0],\"normal\":[0,0,1],\"sweep\":1,\"feed\":1}}"));
        assert!(e.unwrap_err().to_string().contains("2: kind: an arc cannot be the first segment"));
    }

    #[test]
    fn axes_take_one_or_two_numbers_and_absent_keeps_them() {
        let text = format!(
            "{HEADER}{{\"end\":[0.01,0,0],\"feed\":1,\"axes\":[0.5]}}\n{{\"kind\":\"dwell\",\"duration\":1,\"axes\":[0.5,-0.25]}}\n{{\"end\":[0.02,0,0],\"feed\":1}}\n"
        );
        let f = parse(&text).unwrap();
        let axes: Vec<_> = f.segments.iter().map(|(s, _)| s.axes).collect();
        assert_eq!(axes, [Some([0.5, 0.0]), Some([0.5, -0.25]), None]);
        let mut bytes = Vec::new();
        let segments: Vec<Segment> = f.segments.iter().map(|(s, _)| *s).collect();
        write(&mut bytes, &segments, "").unwrap();
        let text = String::from_utf8(bytes).unwrap();
        assert!(text.contains(",\"axes\":[0.5,0.0],") && text.contains(",\"axes\":[0.5,-0.25],"), "{text}");
        assert_eq!(text.matches("\"axes\"").count(), 2, "written only when set: {text}");
    }

    #[test]
    fn tool_pointing_turns_the_nozzle_along_the_direction() {
        for dir in [Vector3::new(0.0, 0.0, -1.0), Vector3::new(0.3, -0.2, -0.9), Vector3::new(1.0, 0.0, 0.0), Vector3::new(0.0, 0.0, 2.0)] {
            let q = tool_pointing(&dir);
            let z = q * Vector3::z();
            assert!((z - dir.normalize()).norm() < 1e-12, "{dir:?} → {z:?}");
        }
        let down = tool_pointing(&-Vector3::z());
        assert!(down.angle_to(&UnitQuaternion::from_axis_angle(&Vector3::y_axis(), std::f64::consts::PI)) < 1e-12);
    }
}

#[cfg(test)]
mod heat_tests {
    use super::*;
    use strand_core::HeatRequest;

    /// Heat records round trip (targets, waits, a band), stand where the previous move ended, and
    /// bad ones are refused naming the key.
    #[test]
    fn heat_records_round_trip_and_bad_ones_name_the_key() {
        let down = tool_pointing(&Vector3::new(0.0, 0.0, -1.0));
        let travel = Segment {
            seq: 1,
            end: Vector3::new(0.1, 0.0, 0.2),
            feed: 0.05,
            flags: SegmentFlags::TRAVEL,
            orientation: down,
            ..Segment::default()
        };
        let heat = |seq, heater, wait, target, band| Segment {
            seq,
            kind: SegmentKind::Heat,
            end: travel.end,
            orientation: down,
            heat: HeatRequest { heater, wait, target, band },
            ..Segment::default()
        };
        let segments = vec![
            travel,
            heat(2, Heater::Bed, HeatWait::None, 60.0, strand_core::OPEN_BAND),
            heat(3, Heater::HotEnd, HeatWait::Heating, 210.0, strand_core::OPEN_BAND),
            heat(4, Heater::HotEnd, HeatWait::Range, -1.0, [200.0, 215.0]),
        ];
        let mut bytes = Vec::new();
        write(&mut bytes, &segments, "heat").unwrap();
        let back = read(bytes.as_slice(), "heat.jsonl", 1).unwrap();
        // (The reader numbers each segment's source line: its line in the file.)
        let got: Vec<Segment> = back.segments.iter().map(|(s, _)| Segment { source_line: 0, ..*s }).collect();
        assert_eq!(got, segments);
        let header = "{\"format\":\"strand-segments\",\"version\":1}\n";
        for (record, words) in [
            ("{\"kind\":\"heat\",\"wait\":\"heating\",\"temperature\":210}", "heater: required"),
            ("{\"kind\":\"heat\",\"heater\":\"chamber\"}", "heater: \"chamber\""),
            ("{\"kind\":\"heat\",\"heater\":\"bed\",\"temperature\":900}", "temperature"),
            ("{\"kind\":\"line\",\"end\":[0,0,0],\"feed\":0.01,\"heater\":\"bed\"}", "heater: not allowed on a line"),
        ] {
            let e = read(format!("{header}{record}\n").as_bytes(), "bad.jsonl", 1).unwrap_err();
            assert!(e.to_string().contains(words), "{e}");
            assert_eq!(e.line, 2, "{e}");
        }
    }
}
