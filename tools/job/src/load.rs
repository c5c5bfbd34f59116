//! A job as the controller receives it: a G-code program or a segment file, read and put on the
//! bed with the config's `[bed]` transform (W), and the one conversion of a core segment to the
//! wire. strand-feed streams what this reads, and `strand check-job` runs the same segments through
//! the controller, so the check and the print can never read a file differently.

use std::path::Path;

use nalgebra::{UnitQuaternion, Vector3};

use strand_wire as ipc;

use crate::bed::BedTransform;
use crate::gcode::GcodeError;
use crate::gcode::{GcodeOptions, parse_file};
use crate::segfile::{self, SegfileError};
use strand_core::{Segment, SegmentKind};

/// Why a job, or a planned base trajectory, cannot be read (or a segment file written). Every
/// variant names the file, and the line where there is one.
#[derive(Debug, thiserror::Error)]
pub enum JobError {
    /// The G-code program is not valid (file, line and column in the message).
    #[error(transparent)]
    Gcode(#[from] GcodeError),
    /// The segment file is not valid (file and line in the message).
    #[error(transparent)]
    Segments(#[from] SegfileError),
    /// The file cannot be opened, read or written, or holds nothing usable.
    #[error("{file}: {message}")]
    File {
        /// The file as given.
        file: String,
        /// What went wrong (the system's error, or what is missing).
        message: String,
    },
    /// A line of a CSV file is not valid.
    #[error("{file}: line {line}: {message}")]
    Line {
        /// The file as given.
        file: String,
        /// Line (1-based).
        line: usize,
        /// What is wrong, naming the column.
        message: String,
    },
}

/// Core segment (W) → wire segment.
pub fn to_wire(s: &Segment) -> ipc::Segment {
    let q = s.orientation;
    ipc::Segment {
        seq: s.seq,
        stamp_ns: 0,
        kind: s.kind as u32,
        flags: s.flags.0
            | if s.pressure_advance.is_some() { ipc::segment_flags::PRESSURE_ADVANCE } else { 0 }
            | if s.axes.is_some() { ipc::segment_flags::AXES } else { 0 },
        end: s.end.into(),
        centre: s.centre.into(),
        normal: s.normal.into(),
        sweep: s.sweep,
        orientation: [q.w, q.i, q.j, q.k],
        feed: s.feed,
        filament: s.filament,
        duration: s.duration,
        source_line: s.source_line,
        _reserved: 0,
        pressure_advance: s.pressure_advance.unwrap_or(0.0),
        axes: s.axes.unwrap_or_default(),
        heater: if s.kind == SegmentKind::Heat { s.heat.heater as u32 } else { 0 },
        heat_wait: if s.kind == SegmentKind::Heat { s.heat.wait as u32 } else { 0 },
        temperature: if s.kind == SegmentKind::Heat { s.heat.target } else { 0.0 },
        temperature_range: if s.kind == SegmentKind::Heat { s.heat.band } else { [0.0; 2] },
    }
}

/// The wire segments of a job as strand-feed sends them — numbered as read, the last flagged
/// LAST — and each one's slicer layer.
pub fn wire_job(all: &LayeredSegments) -> (Vec<ipc::Segment>, Vec<Option<i32>>) {
    let mut segments: Vec<ipc::Segment> = all.iter().map(|(s, _)| to_wire(s)).collect();
    if let Some(last) = segments.last_mut() {
        last.flags |= ipc::segment_flags::LAST;
    }
    (segments, all.iter().map(|(_, l)| *l).collect())
}

/// A job's segments, each with its slicer layer (None where the job has none).
pub type LayeredSegments = Vec<(Segment, Option<i32>)>;

/// The job's segments in W (`bed` applied: the config's `[bed]`), numbered from 1, each with its
/// slicer layer, and the reader's warnings (one line each, naming the file). The job is a G-code
/// program or a segment file ([`crate::segfile`], told apart by its header line, whatever the file
/// is called); both are in bed coordinates. An error if it has no motion.
pub fn load_segments(path: &Path, bed: &BedTransform) -> Result<(LayeredSegments, Vec<String>), JobError> {
    load_segments_with(path, bed, GcodeOptions::default())
}

/// As [`load_segments`], a G-code program read with `options` (a cell's rotary words: the
/// service config's `Config::gcode_options`); its dialect is still the file's, its first
/// segment still 1.
pub fn load_segments_with(path: &Path, bed: &BedTransform, options: GcodeOptions) -> Result<(LayeredSegments, Vec<String>), JobError> {
    let (all, warnings) = if segfile::is_segment_file(path) {
        let file = segfile::read_path(path, 1)?;
        (file.segments.iter().map(|(s, layer)| (bed.segment(s), *layer)).collect(), Vec::new())
    } else {
        let options = GcodeOptions { first_seq: 1, dialect: GcodeOptions::for_path(path).dialect, ..options };
        let mut parser = parse_file(path, options)?;
        let mut all = Vec::new();
        for item in parser.by_ref() {
            let g = item?;
            all.push((bed.segment(&g.segment), g.tags.layer));
        }
        (all, parser.warnings().iter().map(|w| format!("{}: {w}", path.display())).collect())
    };
    if all.is_empty() {
        return Err(JobError::File { file: path.display().to_string(), message: "no motion in the program".into() });
    }
    Ok((all, warnings))
}

/// The planned robot-base trajectory: (t s, x m, y m, θ rad) samples, linearly interpolated and
/// held at both ends.
#[derive(Clone, Debug, PartialEq)]
pub struct BaseTrajectory {
    samples: Vec<[f64; 4]>,
}

impl BaseTrajectory {
    /// From (t s, x m, y m, θ rad) samples; None unless t strictly increases and every value is
    /// finite.
    pub fn from_samples(samples: Vec<[f64; 4]>) -> Option<Self> {
        let ok =
            !samples.is_empty() && samples.iter().all(|s| s.iter().all(|v| v.is_finite())) && samples.windows(2).all(|w| w[0][0] < w[1][0]);
        ok.then_some(BaseTrajectory { samples })
    }

    /// Holds `pose` (x, y, θ) for ever.
    pub fn stationary(pose: [f64; 3]) -> Self {
        BaseTrajectory { samples: vec![[0.0, pose[0], pose[1], pose[2]]] }
    }

    /// Reads a CSV with a header naming `t`, `base_x`, `base_y` and optionally `base_theta`;
    /// `theta` (rad) is used where the file has no angle. Errors name the file and the line.
    pub fn load(path: &Path, theta: f64) -> Result<Self, JobError> {
        Self::load_keyed(path, "t", theta)
    }

    /// The samples: (key, x m, y m, θ rad) — the key is t (s) or, for a plan by progress, s (m).
    pub fn samples(&self) -> &[[f64; 4]] {
        &self.samples
    }

    /// As [`load`](Self::load), keyed by the column `key` instead of `t`: `s` for a base plan by
    /// the print's progress (`strand-plan base --plan`, the service's `[base] plan_file`).
    pub fn load_keyed(path: &Path, key: &str, theta: f64) -> Result<Self, JobError> {
        let file = path.display().to_string();
        let whole = |e: &dyn std::fmt::Display| JobError::File { file: file.clone(), message: e.to_string() };
        let at = |line: usize, message: String| JobError::Line { file: file.clone(), line, message };
        let mut rd = csv::Reader::from_path(path).map_err(|e| whole(&e))?;
        let header = rd.headers().map_err(|e| whole(&e))?.clone();
        let col = |name: &str| header.iter().position(|h| h.trim() == name);
        let (Some(ct), Some(cx), Some(cy)) = (col(key), col("base_x"), col("base_y")) else {
            return Err(at(1, format!("the header must name {key}, base_x and base_y (and optionally base_theta)")));
        };
        let cth = col("base_theta");
        let mut samples: Vec<[f64; 4]> = Vec::new();
        for (i, rec) in rd.records().enumerate() {
            let line = i + 2;
            let rec = rec.map_err(|e| at(line, e.to_string()))?;
            let num = |c: usize, name: &str| -> Result<f64, JobError> {
                let v: f64 = rec.get(c).unwrap_or("").trim().parse().map_err(|_| at(line, format!("{name} is not a number")))?;
                if v.is_finite() { Ok(v) } else { Err(at(line, format!("{name} is not finite"))) }
            };
            let s = [
                num(ct, key)?,
                num(cx, "base_x")?,
                num(cy, "base_y")?,
                match cth {
                    Some(c) => num(c, "base_theta")?,
                    None => theta,
                },
            ];
            if samples.last().is_some_and(|p| s[0] <= p[0]) {
                return Err(at(line, format!("{key} = {} does not increase", s[0])));
            }
            samples.push(s);
        }
        if samples.is_empty() {
            return Err(whole(&"no samples"));
        }
        Ok(BaseTrajectory { samples })
    }

    /// The planned (x, y, θ) at `t` seconds.
    pub fn at(&self, t: f64) -> [f64; 3] {
        let s = &self.samples;
        let k = s.partition_point(|p| p[0] <= t);
        if k == 0 {
            return [s[0][1], s[0][2], s[0][3]];
        }
        if k == s.len() {
            let l = s[k - 1];
            return [l[1], l[2], l[3]];
        }
        let (a, b) = (s[k - 1], s[k]);
        let f = (t - a[0]) / (b[0] - a[0]);
        [a[1] + f * (b[1] - a[1]), a[2] + f * (b[2] - a[2]), a[3] + f * (b[3] - a[3])]
    }

    /// The planned base pose at `t` (s) as a position (m, W) and orientation: the trajectory's x, y
    /// and yaw θ on the mount's height, roll and pitch (`mount_yaw` is the mount's own yaw, which θ
    /// replaces).
    pub fn pose_at(
        &self,
        t: f64,
        mount_position: &Vector3<f64>,
        mount_orientation: &UnitQuaternion<f64>,
        mount_yaw: f64,
    ) -> (Vector3<f64>, UnitQuaternion<f64>) {
        let [x, y, theta] = self.at(t);
        let yaw = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), theta - mount_yaw);
        (Vector3::new(x, y, mount_position.z), yaw * mount_orientation)
    }
}
