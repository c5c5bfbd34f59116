//! The bead: what a print is judged on. The melt the nozzle really laid per millimetre of its real
//! path (from the sim's truth, or a measurement), against what the program asked for there
//! (`ΔE·A_filament / L` of the segment executing), in 1 mm bins of actual nozzle travel, overall
//! and per feature (`;TYPE:` tags); and the melt that went where no bead was asked for: blobs
//! (laid while the nozzle stands) and strings (laid on travel moves).
//!
//! Why the truth and not the command: the command is exact by construction (`max_flow_error` 0);
//! what a hot end and an arm make of it is not. A flow figure that compares the melt with the
//! command, pressure advance included, cannot show what compensation gains.
//!
//! [`calibrate`] identifies the hot end's lag and the arm's delay from the same data.

pub mod calibrate;
pub mod plot;

use std::collections::HashMap;
use std::path::Path;

use nalgebra::Vector3;
use serde::Serialize;
use strand::log::reader::LogFile;
use strand_ipc::RunState;

use crate::truth::Truth;
use strand_cli::error::{Result, ToolError};

/// Length of a bin of actual nozzle travel (m).
pub(crate) const BIN_LENGTH: f64 = 1e-3;
/// Below this nozzle speed the nozzle stands (m/s): what it lays then is a blob.
pub(crate) const STANDING_SPEED: f64 = 1e-3;
/// Melt flow on a travel that counts it as a string by length (m³/s): 1.5 % of a typical 0.4 mm
/// nozzle's 3 mm³/s.
pub(crate) const STRING_FLOW: f64 = 0.05e-9;
/// A bin's error beyond this share is a visible flaw (Klipper's and slicers' tuning towers judge by
/// eye at about this level).
pub(crate) const FLAW: f64 = 0.10;

/// Which feature each source line prints, from the program's `;TYPE:` tags (Cura, PrusaSlicer,
/// Slic3r, Orca, Bambu) or Simplify3D's `; feature` comments.
#[derive(Clone, Debug, Default)]
pub struct Features {
    /// Feature names, indexed by [`Features::by_line`].
    pub names: Vec<String>,
    /// For each source line (1-based; index 0 unused), the index into `names`, or `u16::MAX` before
    /// the first tag.
    pub by_line: Vec<u16>,
}

impl Features {
    /// Reads the tags of a G-code file; a file without tags gives no features.
    pub fn of_gcode(path: &Path) -> Result<Features> {
        let text = std::fs::read_to_string(path).map_err(ToolError::file(path))?;
        Ok(Features::of_text(&text))
    }

    /// The tags of G-code text.
    pub(crate) fn of_text(text: &str) -> Features {
        let mut f = Features { names: Vec::new(), by_line: vec![u16::MAX] };
        let mut current = u16::MAX;
        for line in text.lines() {
            let t = line.trim();
            let tag = t.strip_prefix(";TYPE:").or_else(|| t.strip_prefix("; feature ")).map(str::trim);
            if let Some(name) = tag.filter(|n| !n.is_empty()) {
                current = match f.names.iter().position(|n| n == name) {
                    Some(i) => i as u16,
                    None => {
                        f.names.push(name.to_string());
                        (f.names.len() - 1).min(u16::MAX as usize - 1) as u16
                    }
                };
            }
            f.by_line.push(current);
        }
        f
    }

    fn of_line(&self, line: u32) -> Option<usize> {
        self.by_line.get(line as usize).copied().filter(|&i| i != u16::MAX).map(usize::from)
    }
}

/// Relative bead error of a set of bins: |deposited − asked| / asked.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct BinErrors {
    /// Bins (each [`BIN_LENGTH`] of actual nozzle travel while the program extrudes).
    pub bins: usize,
    /// Median of the relative error (1 = 100 %).
    pub p50: f64,
    /// 95th percentile.
    pub p95: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Share of bins whose error is beyond ±10 % ([`FLAW`]).
    pub beyond_10pct: f64,
    /// Mean signed error (deposited over asked, minus 1): > 0 over-extrudes.
    pub mean_signed: f64,
}

impl BinErrors {
    fn of(signed: &[f64]) -> BinErrors {
        if signed.is_empty() {
            return BinErrors::default();
        }
        let mut abs: Vec<f64> = signed.iter().map(|e| e.abs()).collect();
        abs.sort_by(f64::total_cmp);
        let rank = |p: f64| abs[((p / 100.0 * abs.len() as f64).ceil() as usize).clamp(1, abs.len()) - 1];
        BinErrors {
            bins: abs.len(),
            p50: rank(50.0),
            p95: rank(95.0),
            p99: rank(99.0),
            beyond_10pct: abs.iter().filter(|&&e| e > FLAW).count() as f64 / abs.len() as f64,
            mean_signed: signed.iter().sum::<f64>() / signed.len() as f64,
        }
    }
}

/// One bin, for plots.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bin {
    /// Where the bin ends (m, W).
    pub at: Vector3<f64>,
    /// Its signed relative error.
    pub error: f64,
    /// Its feature (index into [`Bead::features`]), if the program tags them.
    pub feature: Option<usize>,
}

/// The bead figures of one run.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Bead {
    /// All bins.
    pub all: BinErrors,
    /// Per feature, in the order the program first names them.
    pub by_feature: Vec<(String, BinErrors)>,
    /// Melt laid over the job (m³).
    pub melt_m3: f64,
    /// Melt the program asked for over the actual path (m³).
    pub asked_m3: f64,
    /// Melt laid while the nozzle stood (m³): blobs.
    pub blob_m3: f64,
    /// Melt laid on travel moves (m³): strings.
    pub string_m3: f64,
    /// Travel with melt flowing (m): strings, by length.
    pub string_length_m: f64,
    /// Actual nozzle travel while extruding (m).
    pub bead_length_m: f64,
    /// The arm's delay the bins were aligned with (s): from a path target to the nozzle there.
    pub path_delay_s: f64,
    /// Feature names ([`Bin::feature`] indexes them).
    #[serde(skip)]
    pub features: Vec<String>,
    /// The bins, for plots.
    #[serde(skip)]
    pub bins: Vec<Bin>,
}

impl Bead {
    /// Blobs as a share of the melt.
    pub fn blob_share(&self) -> f64 {
        if self.melt_m3 > 0.0 { self.blob_m3 / self.melt_m3 } else { 0.0 }
    }

    /// Strings as a share of the melt.
    pub fn string_share(&self) -> f64 {
        if self.melt_m3 > 0.0 { self.string_m3 / self.melt_m3 } else { 0.0 }
    }
}

/// What one tick of the log was doing.
#[derive(Clone, Copy, Debug)]
pub struct Executing {
    /// The tick's time (ns).
    pub time_ns: u64,
    /// The segment executing.
    pub seq: u64,
    /// Its source line.
    pub line: u32,
    /// Approaching, running, pausing, stopping: not idle or in fault.
    pub busy: bool,
    /// The path target (m, W).
    pub target: Vector3<f64>,
}

impl Bead {
    /// The bins as CSV (`x_m,y_m,z_m,error,feature`): where each ends, its signed relative error.
    pub fn write_bins_csv(&self, path: &Path) -> Result<()> {
        let mut text = String::from("x_m,y_m,z_m,error,feature\n");
        for b in &self.bins {
            let feature = b.feature.and_then(|f| self.features.get(f)).map_or("", String::as_str);
            text.push_str(&format!("{:?},{:?},{:?},{:?},{}\n", b.at.x, b.at.y, b.at.z, b.error, feature.replace(',', " ")));
        }
        std::fs::write(path, text).map_err(ToolError::file(path))
    }
}

impl Executing {
    /// What the tick at `time_ns` (ns) that gave `out` was doing.
    pub fn of(time_ns: u64, out: &strand_core::TickOutput) -> Executing {
        Executing::on_part(time_ns, out, None, 0)
    }

    /// As [`of`](Self::of) in a cell with a positioner (after the `arm` joints): the target on the
    /// part ([`crate::target_on_part`]), where the sim's `tcp_part` is.
    pub fn on_part(time_ns: u64, out: &strand_core::TickOutput, positioner: Option<&strand_core::Positioner>, arm: usize) -> Executing {
        let s = &out.status;
        Executing {
            time_ns,
            seq: s.executing_seq,
            line: s.executing_line,
            busy: !matches!(RunState::from_u32(s.run_state), Some(RunState::Idle | RunState::Fault) | None),
            target: crate::target_on_part(out, positioner, arm),
        }
    }
}

/// What the program asks for along each segment: melt cross-section (m²) by sequence number, from
/// the segments in the order they were sent (each starts where the one before it ended).
pub fn asked_sections(segments: &[strand_ipc::Segment], filament_area: f64) -> HashMap<u64, f64> {
    let mut sections = HashMap::new();
    let mut start: Option<Vector3<f64>> = None;
    for seg in segments {
        let kind = strand_ipc::SegmentKind::from_u32(seg.kind);
        let section = match (start, kind) {
            (Some(from), Some(k)) if k != strand_ipc::SegmentKind::Dwell && seg.filament > 0.0 => {
                let length = strand_core::Segment::try_from(seg).map_or(0.0, |c| strand_job::gcode::segment_length(&from, &c));
                if length > 1e-9 { seg.filament * filament_area / length } else { 0.0 }
            }
            _ => 0.0,
        };
        sections.insert(seg.seq, section);
        if kind != Some(strand_ipc::SegmentKind::Dwell) {
            start = Some(Vector3::from(seg.end));
        }
    }
    sections
}

/// The bead of a run: the log (what ran, and what the program asked) joined with the truth (where
/// the nozzle was and what melt left it), tick by tick. `features` names the bins' features.
pub fn measure(log: &LogFile, truth: &[Truth], features: Option<&Features>) -> Result<Bead> {
    let cfg = log.config()?;
    let dt_ns = (1e9 / cfg.controller.rate_hz).round() as u64;
    let filament_area = std::f64::consts::PI * 0.25 * cfg.extruder.filament_diameter.powi(2);
    let positioner = cfg.robot.build_positioner()?;
    let arm = cfg.robot.build_model()?.dof();
    let mut segments = Vec::new();
    let mut ticks = Vec::new();
    for tick in log.ticks() {
        let tick = tick?;
        segments.extend(tick.input.segments().iter().copied());
        ticks.push(Executing::on_part(tick.input.time_ns, &tick.output, positioner.as_ref(), arm));
    }
    Ok(measure_run(&ticks, &asked_sections(&segments, filament_area), truth, dt_ns, features))
}

/// [`measure`] on records: what each tick executed, the program's melt cross-section by segment
/// (m², [`asked_sections`]), and the truth rows; `dt_ns` is the tick.
pub fn measure_run(ticks: &[Executing], sections: &HashMap<u64, f64>, truth: &[Truth], dt_ns: u64, features: Option<&Features>) -> Bead {
    let dt = dt_ns as f64 * 1e-9;
    // The program at the point where the nozzle really is: the tick whose target the nozzle is at,
    // the arm's delay after it (measured here, the delay that brings the two paths together).
    let lag = calibrate::path_delay_ticks(ticks, truth, dt_ns);
    let executing: HashMap<u64, &Executing> = ticks.iter().map(|e| (e.time_ns + lag * dt_ns, e)).collect();
    let mut bead = Bead { features: features.map_or(Vec::new(), |f| f.names.clone()), path_delay_s: lag as f64 * dt, ..Default::default() };
    let mut signed = Vec::new();
    let mut by_feature: Vec<Vec<f64>> = vec![Vec::new(); bead.features.len()];
    // The open bin: travel (m), melt laid and asked (m³), its feature.
    let (mut length, mut laid, mut asked, mut feature) = (0.0, 0.0, 0.0, None::<usize>);
    let mut close = |length: &mut f64, laid: &mut f64, asked: &mut f64, feature: Option<usize>, at: Vector3<f64>, bead: &mut Bead| {
        // A bin cut short at the end of a run still counts if it is half a bin or more.
        if *length >= 0.5 * BIN_LENGTH && *asked > 0.0 {
            let e = *laid / *asked - 1.0;
            signed.push(e);
            if let Some(f) = feature {
                by_feature[f].push(e);
            }
            bead.bins.push(Bin { at, error: e, feature });
        }
        (*length, *laid, *asked) = (0.0, 0.0, 0.0);
    };
    // The nozzle's travel per tick along the path: its displacement projected on the direction the
    // path target moved in at that time. A bead is laid along its centreline; the nozzle's wiggle
    // across it (0.05 mm at 10 Hz on the free flyer's base, a measured position's noise) widens
    // nothing, while its surges along it thin or thicken the bead, and are kept. Projections
    // telescope: noise along the path cancels within a bin instead of adding up.
    let target_at = |time_ns: u64| executing.get(&time_ns).map(|e| e.target);
    let mut previous: Option<Vector3<f64>> = None;
    let mut last_at = Vector3::zeros();
    for row in truth {
        let at = Vector3::from(row.tcp_part);
        let moved = previous.map_or(Vector3::zeros(), |p| at - p);
        previous = Some(at);
        let direction = match (target_at(row.time_ns), target_at(row.time_ns.wrapping_sub(dt_ns))) {
            (Some(a), Some(b)) if (a - b).norm() > 1e-9 => (a - b).normalize(),
            _ => moved.try_normalize(1e-12).unwrap_or_else(Vector3::zeros),
        };
        let step = moved.dot(&direction).max(0.0);
        let Some(&&Executing { seq, line, busy, .. }) = executing.get(&row.time_ns) else { continue };
        if !busy {
            continue;
        }
        let melt = row.flow_actual.max(0.0) * dt;
        bead.melt_m3 += melt;
        let section = sections.get(&seq).copied().unwrap_or(0.0);
        let row_feature = features.and_then(|f| f.of_line(line));
        // Standing: the path stands (a stop, a dwell), whatever the nozzle's wiggle.
        let path_step = match (target_at(row.time_ns), target_at(row.time_ns.wrapping_sub(dt_ns))) {
            (Some(a), Some(b)) => (a - b).norm(),
            _ => moved.norm(),
        };
        if path_step < STANDING_SPEED * dt {
            bead.blob_m3 += melt;
            continue;
        }
        if section <= 0.0 {
            // A travel: whatever flows now is a string; the bead's run ended.
            close(&mut length, &mut laid, &mut asked, feature, last_at, &mut bead);
            bead.string_m3 += melt;
            if row.flow_actual > STRING_FLOW {
                bead.string_length_m += step;
            }
            continue;
        }
        if row_feature != feature {
            close(&mut length, &mut laid, &mut asked, feature, last_at, &mut bead);
            feature = row_feature;
        }
        length += step;
        laid += melt;
        asked += section * step;
        bead.asked_m3 += section * step;
        bead.bead_length_m += step;
        last_at = at;
        if length >= BIN_LENGTH {
            close(&mut length, &mut laid, &mut asked, feature, at, &mut bead);
        }
    }
    close(&mut length, &mut laid, &mut asked, feature, last_at, &mut bead);
    bead.all = BinErrors::of(&signed);
    bead.by_feature = bead.features.iter().cloned().zip(by_feature.iter().map(|v| BinErrors::of(v))).filter(|(_, e)| e.bins > 0).collect();
    bead
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn features_follow_the_type_tags_of_each_slicer() {
        let f = Features::of_text("G1 X1\n;TYPE:WALL-OUTER\nG1 X2\n; feature inner perimeter\nG1 X3\n;TYPE:WALL-OUTER\nG1 X4\n");
        assert_eq!(f.names, vec!["WALL-OUTER", "inner perimeter"]);
        assert_eq!(f.of_line(1), None);
        assert_eq!(f.of_line(3), Some(0));
        assert_eq!(f.of_line(5), Some(1));
        assert_eq!(f.of_line(7), Some(0));
        assert_eq!(f.of_line(99), None);
    }

    #[test]
    fn bin_errors_are_nearest_rank_of_the_magnitude() {
        let signed: Vec<f64> = (0..100).map(|i| if i % 2 == 0 { i as f64 / 1000.0 } else { -(i as f64) / 1000.0 }).collect();
        let e = BinErrors::of(&signed);
        assert_eq!(e.bins, 100);
        assert_eq!(e.p50, 0.049);
        assert_eq!(e.p95, 0.094);
        assert_eq!(e.beyond_10pct, 0.0);
        let e = BinErrors::of(&[0.2, -0.05, 0.0, 0.01]);
        assert_eq!(e.beyond_10pct, 0.25);
        assert!((e.mean_signed - 0.04).abs() < 1e-12);
    }
}
