//! What `strand-feed` sends: a G-code program read with `strand_job::gcode` or a segment file read with
//! `strand_job::segfile`, put on the bed with the config's `[bed]` transform, numbered, flagged (the
//! last segment LAST) and converted to the wire `Segment`; and how a run ends, as an exit code. The
//! streaming itself (credit from Status, never a dropped segment, Ctrl-C as a controlled stop) is
//! [`stream`]; the job check before it, [`check`].

mod keys;
mod resume;
mod stream;

pub use keys::{Key, Keys};
pub use resume::{LogResume, LogStop, Reentry, ResumePoint};
pub use stream::{StreamOptions, check, stream};

use std::path::Path;

use strand::config::Config;
use strand_core::{Segment, SegmentFlags, SegmentKind};
use strand_ipc as ipc;
use strand_job::gcode::GcodeOptions;
pub use strand_job::load::{LayeredSegments, load_segments, load_segments_with, to_wire};

use strand_cli::error::{Result, ToolError};

/// A job ready to stream.
#[derive(Clone, Debug)]
pub struct Job {
    /// Wire segments, consecutive sequence numbers.
    pub segments: Vec<ipc::Segment>,
    /// Slicer layer of each segment (None where the program has no layer comments).
    pub layers: Vec<Option<i32>>,
    /// Path length of each segment (m), for progress and ETA.
    pub lengths: Vec<f64>,
    /// Segments of the program left out by `--resume-from`.
    pub skipped: usize,
    /// Where a resumed job starts along the program's path (m, past its leading travel): sent as
    /// `Command::ProgressOffset` before Start, so a moving base's plan by progress goes on from
    /// there (0 for a job from its start).
    pub progress_offset: f64,
    /// Parser warnings, one line each.
    pub warnings: Vec<String>,
}

/// `segments` (at most [`ipc::SEGMENT_BATCH_CAPACITY`]) as batch number `batch_seq`, all stamped now.
pub fn batch(segments: &[ipc::Segment], batch_seq: u64) -> ipc::SegmentBatch {
    let mut batch =
        ipc::SegmentBatch { seq: batch_seq, stamp_ns: strand::io::clock::monotonic_ns(), len: segments.len() as u32, ..Default::default() };
    for (k, s) in segments.iter().enumerate() {
        batch.segments[k] = ipc::Segment { stamp_ns: batch.stamp_ns, ..*s };
    }
    batch
}

/// Reads a job (G-code or segment file) for the cell described by `cfg`. Segment numbers start at 1 (the
/// program's first segment); `resume_from = Some(n)` drops segments before `n` and starts with a
/// travel (numbered `n − 1`) to where segment `n` starts, so a job interrupted at `n` can go on.
pub fn load_gcode(path: &Path, cfg: &Config, resume_from: Option<u64>) -> Result<Job> {
    let bed = cfg.bed_transform()?;
    let (mut all, mut warnings) = load_segments_with(path, &bed, cfg.gcode_options())?;
    warnings.extend(program_pressure_advance(all.iter().map(|(s, _)| s), cfg));
    warnings.extend(skipped_heat_waits(all.iter().map(|(s, _)| s), cfg));
    let mut start = bed.point(&GcodeOptions::default().start);
    let mut skipped = 0;
    let mut progress_offset = 0.0;
    if let Some(n) = resume_from {
        let Some(k) = all.iter().position(|(s, _)| s.seq >= n) else {
            return Err(ToolError::Usage(format!("--resume-from {n}: the program has only {} segments", all.len())));
        };
        if k > 0 {
            let (prev, layer) = all[k - 1];
            let travel = Segment {
                seq: all[k].0.seq - 1,
                kind: SegmentKind::Line,
                end: prev.end,
                orientation: prev.orientation,
                feed: GcodeOptions::default().rapid_feed,
                flags: SegmentFlags::TRAVEL,
                source_line: prev.source_line,
                ..Segment::default()
            };
            // The path the program ran before segment k, past its leading travel (which the
            // controller's progress does not count): where a moving base's plan goes on from.
            let mut at = start;
            for (i, (s, _)) in all[..k].iter().enumerate() {
                let leading = i == 0 && s.kind == SegmentKind::Line && !s.extrudes() && s.filament == 0.0;
                if !leading {
                    progress_offset += strand_job::gcode::segment_length(&at, s);
                }
                at = s.end;
            }
            // The temperatures the skipped part set, hot end and bed, as waits before the travel:
            // the resumed job heats (and waits) as the whole one would have at segment k.
            let mut heats: Vec<Segment> = Vec::new();
            for heater in [strand_core::Heater::Bed, strand_core::Heater::HotEnd] {
                let last = all[..k]
                    .iter()
                    .rev()
                    .map(|(s, _)| s)
                    .find(|s| s.kind == SegmentKind::Heat && s.heat.heater == heater && s.heat.target >= 0.0);
                if let Some(h) = last {
                    let wait = if h.heat.target > 0.0 { strand_core::HeatWait::Heating } else { strand_core::HeatWait::None };
                    heats.push(Segment { heat: strand_core::HeatRequest { wait, ..h.heat }, flags: SegmentFlags::default(), ..*h });
                }
            }
            start = if k >= 2 { all[k - 2].0.end } else { start };
            skipped = k;
            all.drain(..k);
            all.insert(0, (travel, layer));
            let first = travel.seq.saturating_sub(heats.len() as u64);
            if first >= 1 {
                for (i, h) in heats.iter().enumerate() {
                    all.insert(i, (Segment { seq: first + i as u64, ..*h }, layer));
                }
            }
        }
    }
    let last = all.len() - 1;
    all[last].0.flags = all[last].0.flags.with(SegmentFlags::LAST);
    let mut lengths = Vec::with_capacity(all.len());
    for (s, _) in &all {
        lengths.push(strand_job::gcode::segment_length(&start, s));
        start = s.end;
    }
    Ok(Job {
        segments: all.iter().map(|(s, _)| to_wire(s)).collect(),
        layers: all.iter().map(|(_, l)| *l).collect(),
        lengths,
        skipped,
        progress_offset,
        warnings,
    })
}

/// A program's heat waits (`M109`, `M190`, `TEMPERATURE_WAIT`) on a cell without a temperature
/// source (`[extruder] heater = "none"`): the service skips them; said once, before streaming,
/// with their count and the first line, so nobody believes the job waited for its heaters.
fn skipped_heat_waits<'a>(segments: impl Iterator<Item = &'a Segment>, cfg: &Config) -> Option<String> {
    if cfg.extruder.heater != strand_core::HeaterSource::None {
        return None;
    }
    let waits: Vec<u32> =
        segments.filter(|s| s.kind == SegmentKind::Heat && s.heat.wait != strand_core::HeatWait::None).map(|s| s.source_line).collect();
    let first = waits.first()?;
    Some(format!(
        "the program waits for its heaters {} times (first at line {first}); this cell has no temperature source \
         ([extruder] heater = \"none\"): the service sets the targets but skips the waits",
        waits.len()
    ))
}

/// What becomes of the pressure advance a program sets (`M900 K`, `M572 S`, `SET_PRESSURE_ADVANCE`):
/// a slicer's K was tuned for somebody's desktop hot end, not for this cell's, so a calibrated cell
/// ships `[extruder] max_pressure_advance = 0` and keeps its own K. Says so once, naming the first line
/// that set it, so nobody wonders why the program's K did nothing (or was cut to the cell's limit).
fn program_pressure_advance<'a>(segments: impl Iterator<Item = &'a Segment>, cfg: &Config) -> Option<String> {
    let (first, k) = segments.filter_map(|s| s.pressure_advance.map(|k| (s.source_line, k))).fold(None, |acc, (line, k)| {
        let (first, most) = acc.unwrap_or((line, k));
        Some((first, f64::max(most, k)))
    })?;
    let (own, max) = (cfg.extruder.pressure_advance, cfg.extruder.max_pressure_advance);
    if max == 0.0 {
        Some(format!(
            "the program sets pressure advance (up to {k} s, from line {first}); ignored: this cell keeps its calibrated \
             [extruder] pressure_advance = {own} s (max_pressure_advance = 0)"
        ))
    } else if k > max {
        Some(format!("the program sets pressure advance up to {k} s (from line {first}); cut to [extruder] max_pressure_advance = {max} s"))
    } else {
        None
    }
}

impl Job {
    /// Keeps the segments up to the end of the program's first `n` layers, then the program's end
    /// code (see inside), renumbered to follow on (by the slicer's layer
    /// comments; moves before the first layer stay) and flags the new last one LAST. A program
    /// without layer comments, or with at most `n` layers, is kept whole.
    pub fn first_layers(mut self, n: usize) -> Job {
        if self.layers.iter().all(|l| l.is_none()) {
            self.layers = layers_from_heights(&self.segments);
        }
        let mut seen: Vec<i32> = Vec::new();
        let mut keep = self.segments.len();
        for (k, layer) in self.layers.iter().enumerate() {
            if let Some(l) = layer
                && !seen.contains(l)
            {
                if seen.len() == n {
                    keep = k;
                    break;
                }
                seen.push(*l);
            }
        }
        if keep == 0 || keep == self.segments.len() {
            return self;
        }
        // The program's end code — everything after its last extrusion (retract, lift, park) — still
        // runs, so a job cut to its first layers ends the way the whole one would. It starts from
        // where the cut leaves the tool (one travel there), so it is kept only without arcs, whose
        // geometry depends on their start.
        let end_code =
            self.segments.iter().rposition(|s| s.flags & ipc::segment_flags::EXTRUDE != 0).map_or(self.segments.len(), |k| k + 1);
        let tail: Vec<(ipc::Segment, Option<i32>)> =
            if end_code > keep && self.segments[end_code..].iter().all(|s| s.kind != ipc::SegmentKind::Arc as u32) {
                self.segments[end_code..].iter().copied().zip(self.layers[end_code..].iter().copied()).collect()
            } else {
                Vec::new()
            };
        self.segments.truncate(keep);
        self.layers.truncate(keep);
        self.lengths.truncate(keep);
        for (mut segment, layer) in tail {
            let previous = self.segments.last().expect("kept at least one");
            let start = nalgebra::Vector3::from(previous.end);
            segment.seq = previous.seq + 1;
            segment.flags &= !ipc::segment_flags::LAST;
            let length =
                if segment.kind == ipc::SegmentKind::Line as u32 { (nalgebra::Vector3::from(segment.end) - start).norm() } else { 0.0 };
            if segment.kind == ipc::SegmentKind::Dwell as u32 {
                segment.end = previous.end;
            }
            self.segments.push(segment);
            self.layers.push(layer);
            self.lengths.push(length);
        }
        let last = self.segments.last_mut().expect("kept at least one");
        last.flags |= ipc::segment_flags::LAST;
        self
    }
}

impl Job {
    /// The job opens with a leading travel (a line that moves no filament): the controller's
    /// approach replaces it, and its progress starts at its end.
    fn leads_with_travel(&self) -> bool {
        self.segments
            .first()
            .is_some_and(|s| s.kind == ipc::SegmentKind::Line as u32 && s.flags & ipc::segment_flags::EXTRUDE == 0 && s.filament == 0.0)
    }
}

/// Layers of a program without layer comments (Slic3r 1.3): a layer starts with the first
/// extruding segment above every earlier one (by more than 1 µm); moves before any extrusion have
/// none.
fn layers_from_heights(segments: &[ipc::Segment]) -> Vec<Option<i32>> {
    let mut top = f64::NEG_INFINITY;
    let mut layer: Option<i32> = None;
    segments
        .iter()
        .map(|s| {
            if s.flags & ipc::segment_flags::EXTRUDE != 0 && s.end[2] > top + 1e-6 {
                top = s.end[2];
                layer = Some(layer.map_or(0, |l| l + 1));
            }
            layer
        })
        .collect()
}

/// How a streamed job ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ending {
    /// Every segment executed.
    Finished,
    /// A controlled stop (Ctrl-C, or a stop from elsewhere).
    Stopped,
    /// The controller faulted.
    Faulted {
        /// `ipc::FaultCode` as u32.
        code: u32,
        /// The segment executing then.
        seq: u64,
        /// Its source line.
        line: u32,
    },
    /// The controller refused one of our segments.
    Rejected {
        /// Its sequence number.
        seq: u64,
        /// `ipc::RejectReason` as u32.
        reason: u32,
    },
}

impl Ending {
    /// The process exit code: 0 finished, 4 faulted, 5 a segment rejected, 6 stopped. (1 is a
    /// service or transport error, 2 a bad program or config, 3 a job the check refused.)
    pub fn exit_code(self) -> u8 {
        match self {
            Ending::Finished => 0,
            Ending::Faulted { .. } => 4,
            Ending::Rejected { .. } => 5,
            Ending::Stopped => 6,
        }
    }
}

/// How many of a job's segments the controller can hold now: its credit. Before it has taken any
/// of ours (`last_received_seq` outside our range), the free queue space; after, what it took plus
/// the free space (the Status contract: a feeder may send up to `last_received_seq + queue_free`).
pub fn credit(status: &ipc::Status, first_seq: u64, last_seq: u64, started: bool) -> u64 {
    let ours = started && status.last_received_seq >= first_seq && status.last_received_seq <= last_seq;
    let taken = if ours { status.last_received_seq - first_seq + 1 } else { 0 };
    taken + status.queue_free as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_layers_cut_at_a_layer_change() {
        let cfg = Config::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../config/default.toml"))).unwrap();
        let path = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/data/gcode/slic3r/box35.gcode"));
        let whole = load_gcode(path, &cfg, None).unwrap();
        let two = whole.clone().first_layers(2);
        assert!(two.segments.len() < whole.segments.len());
        // Two layers of extrusion…
        let mut distinct: Vec<i32> = two
            .segments
            .iter()
            .zip(&two.layers)
            .filter(|(s, _)| s.flags & ipc::segment_flags::EXTRUDE != 0)
            .filter_map(|(_, l)| *l)
            .collect();
        distinct.dedup();
        assert_eq!(distinct.len(), 2, "{distinct:?}");
        // …then the program's end code, renumbered to follow on, ending where the program ends.
        let (last, whole_last) = (two.segments.last().unwrap(), whole.segments.last().unwrap());
        assert_eq!((last.kind, last.source_line, last.filament), (whole_last.kind, whole_last.source_line, whole_last.filament));
        assert!(two.segments.windows(2).all(|w| w[1].seq == w[0].seq + 1));
        assert_eq!(two.segments.iter().filter(|s| s.flags & ipc::segment_flags::LAST != 0).count(), 1);
        assert!(two.segments.last().unwrap().flags & ipc::segment_flags::LAST != 0);
        assert_eq!(two.lengths.len(), two.segments.len());
        assert_eq!(whole.clone().first_layers(10_000).segments.len(), whole.segments.len());
    }

    #[test]
    fn a_programs_pressure_advance_is_ignored_by_a_calibrated_cell_and_said_so() {
        let mut cfg = Config::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../config/default.toml"))).unwrap();
        let path = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/data/gcode/prusaslicer25/mk3s_box20.gcode"));
        let note = |cfg: &Config| load_gcode(path, cfg, None).unwrap().warnings.into_iter().find(|w| w.contains("pressure advance"));
        // The shipped configs are calibrated: PrusaSlicer's `M900 K0.05` is named and ignored.
        assert_eq!(cfg.extruder.max_pressure_advance, 0.0);
        let ignored = note(&cfg).expect("a note");
        assert!(ignored.contains("0.05 s") && ignored.contains("ignored") && ignored.contains("from line "), "{ignored}");
        // A cell that follows the program says nothing, unless it cuts the program's K.
        cfg.extruder.max_pressure_advance = 0.2;
        assert_eq!(note(&cfg), None);
        cfg.extruder.max_pressure_advance = 0.02;
        assert!(note(&cfg).is_some_and(|w| w.contains("cut to")));
    }

    #[test]
    fn resume_at_a_layer_lifts_over_the_part_and_primes() {
        let cfg = Config::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../config/default.toml"))).unwrap();
        let path = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/data/gcode/slic3r/box35.gcode"));
        let whole = load_gcode(path, &cfg, None).unwrap();
        // Slic3r 1.3 writes no layer comments: layers by height, as `from_layer` numbers them.
        let layer_of = if whole.layers.iter().all(Option::is_none) { layers_from_heights(&whole.segments) } else { whole.layers.clone() };
        let mut distinct: Vec<i32> = layer_of.iter().flatten().copied().collect();
        distinct.dedup();
        let third = distinct[2];
        let r = Reentry { clearance: 0.01, prime: 0.001, prime_speed: 0.02, travel_feed: 0.1 };
        let resumed = whole.clone().from_layer(third, &r).unwrap();
        let k = layer_of.iter().position(|l| *l == Some(third)).unwrap();
        let top =
            whole.segments[..k].iter().filter(|s| s.flags & ipc::segment_flags::EXTRUDE != 0).map(|s| s.end[2]).fold(f64::MIN, f64::max);
        let start = whole.segments[k - 1].end;
        // Re-heat (the program's last targets before the layer, as waits), then up to the
        // clearance above the part, over the layer's start; straight down; a prime.
        let heats = resumed.segments.iter().take_while(|s| s.kind == ipc::SegmentKind::Heat as u32).count();
        assert_eq!(heats, 2, "the bed's and the hot end's targets");
        assert!(resumed.segments[..heats].iter().all(|s| s.heat_wait == ipc::HeatWait::Heating as u32 && s.temperature > 0.0));
        let (up, down, prime) = (&resumed.segments[heats], &resumed.segments[heats + 1], &resumed.segments[heats + 2]);
        assert!((up.end[2] - (top.max(start[2]) + 0.01)).abs() < 1e-12, "{:?} vs top {top}", up.end);
        assert_eq!((up.end[0], up.end[1]), (start[0], start[1]));
        assert_eq!(down.end, start);
        assert!(up.flags & ipc::segment_flags::TRAVEL != 0 && down.flags & ipc::segment_flags::TRAVEL != 0);
        assert_eq!((prime.kind, prime.filament), (ipc::SegmentKind::Dwell as u32, 0.001));
        // Then the layer, with the program's numbers, consecutive throughout.
        assert_eq!(resumed.segments[heats + 3].seq, whole.segments[k].seq);
        assert_eq!(resumed.segments[heats + 3].end, whole.segments[k].end);
        assert!(resumed.segments.windows(2).all(|w| w[1].seq == w[0].seq + 1));
        assert_eq!(resumed.segments.len(), whole.segments.len() - k + heats + 3);
        assert_eq!((resumed.layers.len(), resumed.lengths.len()), (resumed.segments.len(), resumed.segments.len()));
        // A layer the program does not have is an error naming the range.
        let e = whole.from_layer(100_000, &r).unwrap_err().to_string();
        assert!(e.contains("--resume-layer 100000") && e.contains("layers"), "{e}");
    }

    #[test]
    fn credit_follows_the_status_contract() {
        let st = |last, free| ipc::Status { last_received_seq: last, queue_free: free, ..Default::default() };
        // A previous job's numbers do not count.
        assert_eq!(credit(&st(900, 1024), 1, 500, false), 1024);
        assert_eq!(credit(&st(900, 1024), 1, 500, true), 1024);
        // Ours: taken plus free.
        assert_eq!(credit(&st(40, 1000), 1, 500, true), 1040);
        assert_eq!(credit(&st(40, 1000), 11, 500, true), 1030);
    }
}
