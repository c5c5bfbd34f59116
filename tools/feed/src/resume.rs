//! Getting a job back onto its part: at a layer (`--resume-layer`), or where a crash or a power cut
//! stopped it, read from the run's own log (`--resume-from-log`).
//!
//! Why the log and not a segment number typed by hand: the log holds every tick's path target and
//! the segments the controller took, so it says which segment was executing and how far along it
//! the nozzle was, to the tick — a resume that starts at a segment's beginning prints that segment
//! twice (an overlap a layer thick), one that starts at the next leaves a gap. A log cut short by a
//! crash is read up to its last closed chunk (at most `[log] chunk_interval` lost, 0.1 s by default);
//! the approach over the part and the prime then bridge what the lost ticks printed.
//!
//! Both resumes share one re-entry ([`Job::reenter`]): a travel up to the clearance above
//! everything printed before the resume point, over it; straight down onto it; a prime; then the
//! rest of the program with its own segment numbers.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use strand::config::Config;
use strand::log::reader::LogFile;
use strand_cli::error::{Result, ToolError};
use strand_ipc as ipc;

use crate::{Job, layers_from_heights};

/// How a resumed job gets back onto the part.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reentry {
    /// Height above the highest point printed before the resume point at which the tool travels (m).
    pub clearance: f64,
    /// Filament pushed at the resume point before the first extruding move (m).
    pub prime: f64,
    /// Filament speed of the prime (m/s).
    pub prime_speed: f64,
    /// Travel speed (m/s).
    pub travel_feed: f64,
}

/// Where a logged run stopped: the segment executing at its last logged tick and how far along it.
#[derive(Clone, Debug, PartialEq)]
pub struct LogStop {
    /// The log read.
    pub log: PathBuf,
    /// The log was cut short (a crash or a power cut): read up to its last closed chunk.
    pub cut: bool,
    /// Ticks in the log.
    pub ticks: u64,
    /// The job's outcome at the last tick (`ipc::JobOutcome` as u32).
    pub outcome: u32,
    /// The segment executing at the last busy tick (its sequence number in the run).
    pub seq: u64,
    /// That segment as the controller took it (stamp aside, as the feeder sent it).
    pub segment: ipc::Segment,
    /// The path target at that tick (m, W): the nozzle's point on the path.
    pub position: [f64; 3],
    /// The extruder's filament position at that tick (m since the service started).
    pub filament_position: f64,
    /// The controller ended the run itself (a stop, a fault, or the file finished), so it retracted
    /// the filament by `[extruder] retract_length`; a log cut short mid-job (a crash, a power cut)
    /// retracted nothing.
    pub retracted: bool,
}

impl LogStop {
    /// What the log says, in the operator's terms: the program's line and layer, the point (W, mm),
    /// how far along its segment, and how the run ended.
    pub fn summary(&self, program: &Path, p: &ResumePoint) -> String {
        let outcome = ipc::JobOutcome::from_u32(self.outcome).map_or(format!("outcome {}", self.outcome), |o| format!("{o:?}"));
        format!(
            "strand-feed: resuming {} at line {}, layer {}, segment {} ({:.0} % along it), at [{:.3}, {:.3}, {:.3}] mm (W); \
             from {} ({}; {} ticks; the run's last state {outcome}; the extruder had pushed {:.1} mm)",
            program.display(),
            p.line,
            p.layer.map_or("-".to_string(), |l| l.to_string()),
            p.seq,
            p.fraction * 100.0,
            p.at[0] * 1e3,
            p.at[1] * 1e3,
            p.at[2] * 1e3,
            self.log.display(),
            if self.cut { "cut short: read to its last closed chunk" } else { "finished file" },
            self.ticks,
            self.filament_position * 1e3,
        )
    }

    /// Reads `path` (finished or cut short) for where its job stopped. Refused: a log with no job in
    /// it, or one whose job finished (nothing to resume).
    pub fn read(path: &Path) -> Result<LogStop> {
        let log = LogFile::open(path).map_err(|e| ToolError::Usage(format!("--resume-from-log: {e}")))?;
        let mut taken: HashMap<u64, ipc::Segment> = HashMap::new();
        let mut ticks = 0u64;
        let mut stop: Option<(u64, [f64; 3], f64)> = None;
        let mut outcome = ipc::JobOutcome::None as u32;
        for tick in log.ticks() {
            let tick = tick.map_err(|e| ToolError::Usage(format!("--resume-from-log: {e}")))?;
            ticks += 1;
            for s in tick.input.segments() {
                taken.insert(s.seq, ipc::Segment { stamp_ns: 0, ..*s });
            }
            let status = &tick.output.status;
            outcome = status.job_outcome;
            let busy = !matches!(ipc::RunState::from_u32(status.run_state), Some(ipc::RunState::Idle | ipc::RunState::Fault) | None);
            if busy && status.executing_seq != 0 {
                let d = &tick.output.diagnostics;
                stop = Some((status.executing_seq, d.tcp_target_world.into(), tick.output.extruder.filament_position));
            }
        }
        let name = path.display();
        if outcome == ipc::JobOutcome::Finished as u32 {
            return Err(ToolError::Usage(format!("--resume-from-log {name}: its job finished; there is nothing to resume")));
        }
        let Some((seq, position, filament_position)) = stop else {
            return Err(ToolError::Usage(format!(
                "--resume-from-log {name}: no segment executed in its {ticks} ticks; start the job afresh"
            )));
        };
        let segment = *taken.get(&seq).ok_or_else(|| {
            ToolError::Usage(format!(
                "--resume-from-log {name}: segment {seq} executed but the log does not hold it (a log from before it?)"
            ))
        })?;
        Ok(LogStop {
            log: path.to_path_buf(),
            cut: !log.finished,
            ticks,
            outcome,
            seq,
            segment,
            position,
            filament_position,
            retracted: log.finished || outcome != ipc::JobOutcome::InProgress as u32,
        })
    }
}

/// What `--resume-from-log` needs beside the job.
pub struct LogResume<'a> {
    /// The program (for the messages).
    pub program: &'a Path,
    /// The log of the run that stopped.
    pub log: &'a Path,
    /// The service config (the robot, for where a standing nozzle is).
    pub cfg: &'a Config,
    /// The service prefix a robot driver publishes joint states under.
    pub prefix: &'a str,
    /// The re-entry (its `prime` is what a controller-ended run retracted).
    pub reentry: Reentry,
    /// `--prime` (m), overriding the choice by how the run ended.
    pub prime: Option<f64>,
}

/// Where a job resumes from a log: the segment, how far along it (0 its start, 1 its end) and the
/// point, in the job's terms.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ResumePoint {
    /// Index in the job's segments of the segment to resume in.
    pub index: usize,
    /// Its sequence number.
    pub seq: u64,
    /// Its source line.
    pub line: u32,
    /// Its layer (the slicer's number, or by height from 0).
    pub layer: Option<i32>,
    /// How far along it the resume starts (0 to 1 of its length).
    pub fraction: f64,
    /// The point the resume starts at (m, W).
    pub at: [f64; 3],
}

impl Job {
    /// Starts the job at the first segment of layer `layer` (see [`Job::reenter`]). The controller's
    /// approach takes the arm to the first point above the part in joint space, so the tool never
    /// crosses the part lower than the clearance.
    pub fn from_layer(mut self, layer: i32, r: &Reentry) -> Result<Job> {
        if self.layers.iter().all(|l| l.is_none()) {
            self.layers = layers_from_heights(&self.segments);
        }
        let Some(k) = self.layers.iter().position(|l| *l == Some(layer)) else {
            let known: Vec<i32> = self.layers.iter().flatten().copied().collect();
            let range = match (known.iter().min(), known.iter().max()) {
                (Some(a), Some(b)) => format!("layers {a} to {b}"),
                _ => "no layers".to_string(),
            };
            return Err(ToolError::Usage(format!("--resume-layer {layer}: the program has {range}")));
        };
        if k == 0 {
            return Ok(self);
        }
        let start = self.segments[k - 1].end;
        Ok(self.reenter(k, None, start, r))
    }

    /// Where `stop` lies in this job: the segment the log says was executing (checked to be this
    /// program's: the same kind, end point, filament and source line) and the logged point's
    /// projection onto it. A straight line resumes at that point; an arc or a dwell at its start.
    pub fn resume_point(&self, stop: &LogStop) -> Result<ResumePoint> {
        let name = stop.log.display();
        let Some(k) = self.segments.iter().position(|s| s.seq == stop.seq) else {
            return Err(ToolError::Usage(format!(
                "--resume-from-log {name}: segment {} executed there, and this program has segments {} to {}: not the program it ran",
                stop.seq,
                self.segments.first().map_or(0, |s| s.seq),
                self.segments.last().map_or(0, |s| s.seq)
            )));
        };
        let (ours, theirs) = (&self.segments[k], &stop.segment);
        let same = ours.kind == theirs.kind
            && ours.source_line == theirs.source_line
            && (Vector3::from(ours.end) - Vector3::from(theirs.end)).norm() < 1e-9
            && (ours.filament - theirs.filament).abs() < 1e-12;
        if !same {
            return Err(ToolError::Usage(format!(
                "--resume-from-log {name}: its segment {} (line {}, to {:?} m) is not this program's (line {}, to {:?} m): \
                 resume with the program and the config (its [bed]) the log ran",
                stop.seq, theirs.source_line, theirs.end, ours.source_line, ours.end
            )));
        }
        let layers = if self.layers.iter().all(Option::is_none) { layers_from_heights(&self.segments) } else { self.layers.clone() };
        let start = if k > 0 { Vector3::from(self.segments[k - 1].end) } else { Vector3::from(stop.position) };
        let end = Vector3::from(ours.end);
        let (fraction, at) = if ours.kind == ipc::SegmentKind::Line as u32 && (end - start).norm() > 1e-9 {
            let d = end - start;
            let f = ((Vector3::from(stop.position) - start).dot(&d) / d.norm_squared()).clamp(0.0, 1.0);
            (f, start + d * f)
        } else {
            (0.0, start)
        };
        Ok(ResumePoint { index: k, seq: ours.seq, line: ours.source_line, layer: layers[k], fraction, at: at.into() })
    }

    /// The job resumed where `r.log`'s run stopped: the point the log says ([`Job::resume_point`]),
    /// moved forward to where a robot that held its position stands ([`Job::advance_to`], the
    /// nozzle within 1 mm of the path at most 50 mm on), primed with what the controller retracted
    /// when it ended the run (nothing after a crash) unless `r.prime` says. Each finding is told to
    /// `say`, in the operator's terms, before anything is sent.
    pub fn from_log(self, r: &LogResume, say: &mut dyn FnMut(String)) -> Result<Job> {
        let stop = LogStop::read(r.log)?;
        let mut point = self.resume_point(&stop)?;
        say(stop.summary(r.program, &point));
        if let Some((tcp, advanced)) =
            standing_nozzle(r.cfg, r.prefix).and_then(|tcp| Some((tcp, self.advance_to(&point, tcp, 1e-3, 0.05)?)))
        {
            let moved = (Vector3::from(advanced.at) - Vector3::from(point.at)).norm();
            say(format!(
                "strand-feed: the nozzle stands {:.2} mm further along the path than the log's last tick (at [{:.3}, {:.3}, {:.3}] mm): \
                 resuming there, line {}, segment {} ({:.0} % along it)",
                moved * 1e3,
                tcp[0] * 1e3,
                tcp[1] * 1e3,
                tcp[2] * 1e3,
                advanced.line,
                advanced.seq,
                advanced.fraction * 100.0
            ));
            point = advanced;
        }
        let prime = r.prime.unwrap_or(if stop.retracted { r.reentry.prime } else { 0.0 });
        say(format!(
            "strand-feed: resume point at [{:.3}, {:.3}, {:.3}] mm (W); prime {:.2} mm of filament",
            point.at[0] * 1e3,
            point.at[1] * 1e3,
            point.at[2] * 1e3,
            prime * 1e3
        ));
        Ok(self.from_point(&point, &Reentry { prime, ..r.reentry }))
    }

    /// `p` moved forward along the job to where the nozzle stands at `tcp` (m, W), if the nozzle is
    /// within `tolerance` (m) of the path between `p` and `reach` (m of path) after it: the log
    /// lags the nozzle by up to its last open chunk, which a robot that stood still where the
    /// service died (its brakes on, or its driver holding) tells exactly. `None`: the nozzle is
    /// not on that stretch (the arm was moved, or the robot restarted elsewhere).
    pub fn advance_to(&self, p: &ResumePoint, tcp: [f64; 3], tolerance: f64, reach: f64) -> Option<ResumePoint> {
        let tcp = Vector3::from(tcp);
        let mut travelled = 0.0;
        let mut best: Option<(f64, ResumePoint)> = None;
        for k in p.index..self.segments.len() {
            let s = &self.segments[k];
            if s.kind != ipc::SegmentKind::Line as u32 || k == 0 {
                break;
            }
            let (a, b) = (Vector3::from(self.segments[k - 1].end), Vector3::from(s.end));
            let d = b - a;
            let from = if k == p.index { p.fraction } else { 0.0 };
            let f = if d.norm() > 1e-9 { ((tcp - a).dot(&d) / d.norm_squared()).clamp(from, 1.0) } else { from };
            let off = (a + d * f - tcp).norm();
            if off <= tolerance && best.as_ref().is_none_or(|(o, _)| off < *o) {
                let layer = self.layers.get(k).copied().flatten().or(p.layer);
                best = Some((off, ResumePoint { index: k, seq: s.seq, line: s.source_line, layer, fraction: f, at: (a + d * f).into() }));
            }
            travelled += d.norm() * (1.0 - from);
            if travelled > reach {
                break;
            }
        }
        best.map(|(_, p)| p)
    }

    /// Starts the job at `p` (from [`Job::resume_point`]): the rest of its segment (its filament
    /// in proportion), then the rest of the program, after the re-entry.
    pub fn from_point(self, p: &ResumePoint, r: &Reentry) -> Job {
        let k = p.index;
        let first = (p.fraction > 0.0).then(|| {
            let s = &self.segments[k];
            (ipc::Segment { filament: s.filament * (1.0 - p.fraction), ..*s }, self.lengths[k] * (1.0 - p.fraction))
        });
        self.reenter(k, first, p.at, r)
    }

    /// The job from segment `k` on, `first` replacing segment `k` (with its length), the tool
    /// brought to `start` (where segment `k` or its replacement starts): a travel up to
    /// `r.clearance` above everything printed before (over `start`), a travel straight down onto
    /// it, a prime, then the rest. Segment numbers stay the program's (the new ones take the
    /// numbers just below segment `k`'s, or the program is renumbered when there are none).
    pub(crate) fn reenter(mut self, k: usize, first: Option<(ipc::Segment, f64)>, start: [f64; 3], r: &Reentry) -> Job {
        if self.layers.iter().all(|l| l.is_none()) {
            self.layers = layers_from_heights(&self.segments);
        }
        let printed = &self.segments[..k];
        let top = printed.iter().filter(|s| s.flags & ipc::segment_flags::EXTRUDE != 0).map(|s| s.end[2]).fold(start[2], f64::max);
        let safe = [start[0], start[1], top + r.clearance];
        let orientation = self.segments[k].orientation;
        let travel = |end: [f64; 3]| ipc::Segment {
            kind: ipc::SegmentKind::Line as u32,
            flags: ipc::segment_flags::TRAVEL,
            end,
            orientation,
            feed: r.travel_feed,
            source_line: self.segments[k].source_line,
            ..ipc::Segment::default()
        };
        // Re-heat first: the last target each heater had before the resume point (bed, then hot
        // end, as slicers order them), as a wait when it heats — the job resumes as hot as it was.
        let mut lead: Vec<ipc::Segment> = Vec::new();
        for heater in [ipc::Heater::Bed, ipc::Heater::HotEnd] {
            let last =
                printed.iter().rev().find(|s| s.kind == ipc::SegmentKind::Heat as u32 && s.heater == heater as u32 && s.temperature >= 0.0);
            if let Some(h) = last {
                let wait = if h.temperature > 0.0 { ipc::HeatWait::Heating } else { ipc::HeatWait::None };
                lead.push(ipc::Segment { heat_wait: wait as u32, flags: 0, ..*h });
            }
        }
        lead.extend([travel(safe), travel(start)]);
        if r.prime > 0.0 && r.prime_speed > 0.0 {
            lead.push(ipc::Segment {
                kind: ipc::SegmentKind::Dwell as u32,
                flags: ipc::segment_flags::EXTRUDE,
                end: start,
                orientation,
                filament: r.prime,
                duration: r.prime / r.prime_speed,
                source_line: self.segments[k].source_line,
                ..ipc::Segment::default()
            });
        }
        let layer = self.layers[k];
        let first_seq = self.segments[k].seq;
        let shift = (lead.len() as u64 + 1).saturating_sub(first_seq);
        let mut segments: Vec<ipc::Segment> = lead.to_vec();
        let (first_length, skipped_of_k) = match &first {
            Some((_, length)) => (*length, self.lengths[k] - length),
            None => (self.lengths[k], 0.0),
        };
        if let Some((s, _)) = first {
            self.segments[k] = s;
        }
        segments.extend(self.segments[k..].iter().map(|s| ipc::Segment { seq: s.seq + shift, ..*s }));
        let base = first_seq + shift - lead.len() as u64;
        for (i, s) in segments.iter_mut().take(lead.len()).enumerate() {
            s.seq = base + i as u64;
        }
        // The lead's lengths: the heats none, the travel up from wherever the approach leaves the
        // tool none, the travel down its height, the prime none.
        let heats = lead.len() - 2 - usize::from(r.prime > 0.0 && r.prime_speed > 0.0);
        let mut lengths = vec![0.0; lead.len()];
        lengths[heats + 1] = r.clearance.max(safe[2] - start[2]);
        lengths.push(first_length);
        lengths.extend_from_slice(&self.lengths[k + 1..]);
        let mut layers = vec![layer; lead.len()];
        layers.extend_from_slice(&self.layers[k..]);
        // Where a moving base's plan goes on from: the path before the resume point (past the
        // leading travel), less the travel down onto it (which the controller's progress counts).
        let before: f64 = self.lengths[..k].iter().skip(usize::from(self.leads_with_travel())).sum::<f64>() + skipped_of_k;
        let progress_offset = (self.progress_offset + before - lengths[heats + 1]).max(0.0);
        self.skipped += k;
        Job { segments, layers, lengths, skipped: self.skipped, progress_offset, warnings: self.warnings }
    }
}

/// Where the nozzle stands now (m, W), from the robot's newest JointState on `prefix` (within 0.5 s):
/// after the service died, a robot that held its position says where the print really stopped.
/// `None` without a driver, for a cell with a positioner (the part moved with it) or a tracked
/// base (the pose the service estimated is gone).
fn standing_nozzle(cfg: &Config, prefix: &str) -> Option<[f64; 3]> {
    use strand_ipc::ports::{ClientPorts, ClientRoles};
    if cfg.robot.external_axes().is_some() || cfg.base.mode != strand_core::BaseMode::Fixed {
        return None;
    }
    let model = cfg.robot.build_model().ok()?;
    let roles = ClientRoles { measurements: true, ..Default::default() };
    let ports = ClientPorts::open(&ipc::ServiceNames::new(prefix), &format!("strand-feed-resume-{}", std::process::id()), roles).ok()?;
    let deadline = std::time::Instant::now() + std::time::Duration::from_millis(500);
    let state = loop {
        if let Some(s) = ports.latest_joint_state() {
            break s;
        }
        if std::time::Instant::now() >= deadline {
            return None;
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    };
    let dof = model.dof();
    if (state.dof as usize) < dof || !state.position[..dof].iter().all(|v| v.is_finite()) {
        return None;
    }
    let mut q = strand_core::kin::JointVector::zeros();
    q.as_mut_slice()[..dof].copy_from_slice(&state.position[..dof]);
    let tcp = cfg.base.mount() * model.forward_kinematics(&q);
    Some(tcp.translation.vector.into())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::load_gcode;

    fn job() -> Job {
        let cfg = Config::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../config/default.toml"))).unwrap();
        let path = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/data/gcode/slic3r/box35.gcode"));
        load_gcode(path, &cfg, None).unwrap()
    }

    /// A stop logged `fraction` along the job's `k`-th segment.
    fn stop_at(job: &Job, k: usize, fraction: f64) -> LogStop {
        let (a, b) = (Vector3::from(job.segments[k - 1].end), Vector3::from(job.segments[k].end));
        LogStop {
            log: PathBuf::from("run.mcap"),
            cut: true,
            ticks: 1000,
            outcome: ipc::JobOutcome::InProgress as u32,
            seq: job.segments[k].seq,
            segment: job.segments[k],
            position: (a + (b - a) * fraction).into(),
            filament_position: 0.01,
            retracted: false,
        }
    }

    /// The longest extruding line after the first layer.
    fn long_line(job: &Job) -> usize {
        (job.segments.len() / 3..job.segments.len())
            .filter(|&k| job.segments[k].kind == ipc::SegmentKind::Line as u32 && job.segments[k].flags & ipc::segment_flags::EXTRUDE != 0)
            .max_by(|&a, &b| job.lengths[a].total_cmp(&job.lengths[b]))
            .unwrap()
    }

    #[test]
    fn a_logged_stop_resumes_at_its_point_with_the_rest_of_the_segment() {
        let job = job();
        let k = long_line(&job);
        let p = job.resume_point(&stop_at(&job, k, 0.4)).unwrap();
        assert_eq!((p.index, p.seq, p.line), (k, job.segments[k].seq, job.segments[k].source_line));
        assert!((p.fraction - 0.4).abs() < 1e-9, "{p:?}");
        let r = Reentry { clearance: 0.01, prime: 0.0, prime_speed: 0.02, travel_feed: 0.1 };
        let resumed = job.clone().from_point(&p, &r);
        // Up over the point, down onto it (no prime after a crash), then the rest of the segment:
        // its end, 60 % of its filament and of its length.
        let heats = resumed.segments.iter().take_while(|s| s.kind == ipc::SegmentKind::Heat as u32).count();
        assert_eq!(heats, 2, "re-heated first: the bed's and the hot end's last targets");
        let (up, down, rest) = (&resumed.segments[heats], &resumed.segments[heats + 1], &resumed.segments[heats + 2]);
        assert_eq!((up.end[0], up.end[1]), (p.at[0], p.at[1]));
        assert!(up.end[2] >= p.at[2] + 0.01 - 1e-12);
        assert_eq!(down.end, p.at);
        assert_eq!((rest.seq, rest.end), (job.segments[k].seq, job.segments[k].end));
        assert!((rest.filament - 0.6 * job.segments[k].filament).abs() < 1e-15);
        assert!((resumed.lengths[heats + 2] - 0.6 * job.lengths[k]).abs() < 1e-12);
        assert_eq!(resumed.segments.len(), job.segments.len() - k + heats + 2);
        assert!(resumed.segments.windows(2).all(|w| w[1].seq == w[0].seq + 1));
        // A robot standing further along moves the point forward; one elsewhere does not.
        let a = Vector3::from(job.segments[k - 1].end);
        let d = Vector3::from(job.segments[k].end) - a;
        let further = job.advance_to(&p, (a + d * 0.55 + Vector3::new(0.0, 0.0, 2e-4)).into(), 1e-3, 0.05).unwrap();
        assert!((further.fraction - 0.55).abs() < 1e-9 && further.index == k, "{further:?}");
        assert!(job.advance_to(&p, (a + d * 0.55 + Vector3::new(0.0, 0.0, 0.05)).into(), 1e-3, 0.05).is_none());
        // A little behind the logged point counts as at it (the log never runs ahead of the
        // nozzle); far behind is not on the stretch.
        let behind = job.advance_to(&p, (a + d * 0.39).into(), 1e-3, 0.05).unwrap();
        assert!((behind.fraction - 0.4).abs() < 1e-9, "{behind:?}");
        assert!(job.advance_to(&p, (a + d * 0.2).into(), 1e-3, 0.05).is_none());
    }

    #[test]
    fn a_log_of_another_program_is_refused_naming_the_segment() {
        let job = job();
        let k = long_line(&job);
        let mut stop = stop_at(&job, k, 0.5);
        stop.segment.end[0] += 0.01;
        let e = job.resume_point(&stop).unwrap_err().to_string();
        assert!(e.contains(&format!("segment {}", stop.seq)) && e.contains("is not this program's"), "{e}");
        stop.seq = 1_000_000;
        let e = job.resume_point(&stop).unwrap_err().to_string();
        assert!(e.contains("not the program it ran"), "{e}");
    }
}
