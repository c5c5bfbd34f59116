//! What `strand-replay` tells about a log besides the bit-exact replay: a summary (`info`), one CSV
//! per channel (`export`) and plots (`plot`). Everything is computed from the logged ticks and the
//! logged configuration, so a log is read the same way on any machine.
//!
//! - [`bead`] — the deposited bead against the program (1 mm bins, blobs, strings) from a log and the
//!   sim's [`truth`], and the calibration of the hot end's lag and the arm's delay (`bead`,
//!   `calibrate`).
//! - [`truth`] — the sim's ground-truth rows, as strand-sim writes them.
//! - [`plot`] — the log's plots.

pub mod bead;
pub mod plot;
pub mod truth;

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use nalgebra::{UnitQuaternion, Vector3};
use strand::io::histogram::Histogram;
use strand::log::dynamic::Schema;
use strand::log::reader::LogFile;
use strand_core::BaseState;
use strand_core::kin::{JointVector, RobotModel};
use strand_core::{Event, TickOutput};
use strand_ipc::{FaultCode, JobOutcome, LogState, RunState};

use strand_cli::error::{Result, ToolError};

/// Which ticks count for the TCP error: on the path for the whole tick (running before it and after
/// it: the tick that leaves the approach has no path target yet), once the path has begun (a segment
/// is executing: the settling on the first point, where a moving base is caught up with before the
/// extruder starts, is not printing).
#[derive(Clone, Copy, Debug, Default)]
pub struct PathTicks {
    was_on_path: bool,
}

impl PathTicks {
    /// Feeds the next tick's output; true if that tick counts.
    pub fn update(&mut self, o: &TickOutput) -> bool {
        let on_path = matches!(RunState::from_u32(o.status.run_state), Some(RunState::Running | RunState::Pausing | RunState::Stopping));
        let counts = on_path && self.was_on_path && o.status.executing_seq != 0;
        self.was_on_path = on_path;
        counts
    }
}

/// Where a tick's path target is on the part (m, W, the work frame at home, where the job's points
/// are): with a positioner, its target brought back from where the tick's commanded axes (after the
/// `arm` joints) put the part; without one, the target itself.
pub fn target_on_part(out: &TickOutput, positioner: Option<&strand_core::Positioner>, arm: usize) -> Vector3<f64> {
    let target = out.diagnostics.tcp_target_world;
    let Some(p) = positioner else {
        return target;
    };
    let base = &out.diagnostics.base;
    let in_base = base.orientation.inverse() * (target - base.position);
    let axes = std::array::from_fn(|k| out.joint_command.position.get(arm + k).copied().unwrap_or(0.0));
    base.position + base.orientation * p.to_home(&in_base, &UnitQuaternion::identity(), &axes).0
}

/// The TCP in W from joint positions `q` (rad or m) through the base pose the tick used.
pub fn tcp_world(model: &RobotModel, q: &JointVector, base: &BaseState) -> Vector3<f64> {
    let tcp = model.forward_kinematics(q);
    let r = UnitQuaternion::from_rotation_matrix(&tcp.rotation);
    base.base_to_world(&tcp.translation.vector, &r).0
}

/// Per-tick series of a log, in SI units.
#[derive(Default)]
pub struct Series {
    /// Time since the first tick (s).
    pub t: Vec<f64>,
    /// Run state per tick.
    pub run_state: Vec<u32>,
    /// Path target (m, W), while a job runs (NaN otherwise).
    pub target: Vec<[f64; 3]>,
    /// TCP from the measured joints through the estimated base (m, W), NaN without a measurement.
    pub actual: Vec<[f64; 3]>,
    /// |target − actual| while running (m), NaN otherwise.
    pub tcp_error: Vec<f64>,
    /// Path speed (m/s).
    pub path_speed: Vec<f64>,
    /// Filament feed rate (m/s).
    pub filament_rate: Vec<f64>,
    /// Commanded joint positions (rad or m), one Vec per joint.
    pub q: Vec<Vec<f64>>,
    /// Commanded joint velocities.
    pub qd: Vec<Vec<f64>>,
    /// Wake-up lateness (ns; timer clock only).
    pub lateness_ns: Vec<u64>,
    /// Step cost (ns).
    pub step_ns: Vec<u64>,
}

/// A summary of a log.
pub struct Summary {
    /// The files read.
    pub files: Vec<(PathBuf, bool)>,
    /// Robot name.
    pub robot: String,
    /// Configured rate (Hz).
    pub rate_hz: f64,
    /// Ticks.
    pub ticks: u64,
    /// First to last tick (s).
    pub duration_s: f64,
    /// Segments received.
    pub segments: u64,
    /// Faults latched, in order.
    pub faults: Vec<(u64, FaultCode)>,
    /// Jobs ended (tick, outcome).
    pub jobs: Vec<(u64, JobOutcome)>,
    /// Per-topic message counts.
    pub topics: BTreeMap<String, u64>,
    /// The last Status.
    pub last_status: strand_ipc::Status,
    /// Wake-up lateness (ns).
    pub lateness: Histogram,
    /// Step cost (ns).
    pub step: Histogram,
    /// TCP error while running (m): mean, p99, max; samples.
    pub tcp_error: (f64, f64, f64, usize),
    /// Ticks missing between logged ticks.
    pub gaps: u64,
}

/// Reads a log (or its rotated parts) into series and a summary.
pub fn analyse(files: &[LogFile]) -> Result<(Series, Summary, RobotModel)> {
    let first = files.first().ok_or_else(|| ToolError::Usage("no log file given".to_string()))?;
    let cfg = first.config()?;
    let model = cfg.robot.build_model()?;
    let dof = model.dof();
    let mut s = Series { q: vec![Vec::new(); dof], qd: vec![Vec::new(); dof], ..Default::default() };
    let mut sum = Summary {
        files: files.iter().map(|f| (f.path.clone(), f.finished)).collect(),
        robot: model.name().to_string(),
        rate_hz: cfg.controller.rate_hz,
        ticks: 0,
        duration_s: 0.0,
        segments: 0,
        faults: Vec::new(),
        jobs: Vec::new(),
        topics: BTreeMap::new(),
        last_status: Default::default(),
        lateness: Histogram::new(),
        step: Histogram::new(),
        tcp_error: (0.0, 0.0, 0.0, 0),
        gaps: 0,
    };
    let mut t0 = None;
    let mut path_ticks = PathTicks::default();
    let mut last_tick: Option<u64> = None;
    let mut measured: Option<JointVector> = None;
    let mut errors = Histogram::new();
    let mut err_sum = 0.0;
    let mut err_max: f64 = 0.0;
    for f in files {
        for m in f.messages() {
            *sum.topics.entry(m.channel.topic.clone()).or_default() += 1;
        }
    }
    // The parts together: a compact log's outputs are recomputed across them.
    {
        for tick in strand::log::reader::ticks_of(files) {
            let tick = tick?;
            let (i, o) = (&tick.input, &tick.output);
            if let Some(l) = last_tick {
                sum.gaps += i.tick.saturating_sub(l + 1);
            }
            last_tick = Some(i.tick);
            let t0 = *t0.get_or_insert(i.time_ns);
            s.t.push((i.time_ns - t0) as f64 * 1e-9);
            s.run_state.push(o.status.run_state);
            let running = path_ticks.update(o);
            let d = &o.diagnostics;
            let target: [f64; 3] = d.tcp_target_world.into();
            s.target.push(if running { target } else { [f64::NAN; 3] });
            if let Some(js) = &i.joint_state
                && js.dof as usize == dof
            {
                let mut q = JointVector::zeros();
                q.as_mut_slice()[..dof].copy_from_slice(&js.position[..dof]);
                measured = Some(q);
            }
            let actual = measured.map(|q| tcp_world(&model, &q, &d.base).into());
            s.actual.push(actual.unwrap_or([f64::NAN; 3]));
            let err = match actual {
                Some(a) if running => ((a[0] - target[0]).powi(2) + (a[1] - target[1]).powi(2) + (a[2] - target[2]).powi(2)).sqrt(),
                _ => f64::NAN,
            };
            if err.is_finite() {
                errors.record((err * 1e9) as u64);
                err_sum += err;
                err_max = err_max.max(err);
            }
            s.tcp_error.push(err);
            s.path_speed.push(d.path_speed);
            s.filament_rate.push(o.extruder.filament_rate);
            for j in 0..dof {
                s.q[j].push(o.joint_command.position[j]);
                s.qd[j].push(o.joint_command.velocity[j]);
            }
            s.lateness_ns.push(tick.timing.wake_lateness_ns);
            s.step_ns.push(tick.timing.step_ns);
            sum.lateness.record(tick.timing.wake_lateness_ns);
            sum.step.record(tick.timing.step_ns);
            sum.segments += i.segment_count as u64;
            for e in o.events() {
                match *e {
                    Event::Fault { code, .. } => sum.faults.push((i.tick, code)),
                    Event::JobEnded { outcome, .. } => sum.jobs.push((i.tick, outcome)),
                    _ => {}
                }
            }
            sum.last_status = o.status;
            sum.ticks += 1;
        }
    }
    sum.duration_s = s.t.last().copied().unwrap_or(0.0);
    let n = errors.count() as usize;
    if n > 0 {
        sum.tcp_error = (err_sum / n as f64, errors.percentile(99.0) as f64 * 1e-9, err_max, n);
    }
    Ok((s, sum, model))
}

fn name_of<T: std::fmt::Debug>(v: Option<T>, raw: u32) -> String {
    v.map_or(format!("unknown({raw})"), |v| format!("{v:?}"))
}

/// The `info` text.
pub fn info_text(sum: &Summary) -> String {
    let st = &sum.last_status;
    let us = |ns: u64| ns as f64 / 1e3;
    let mut out = String::new();
    for (p, finished) in &sum.files {
        let _ = writeln!(
            out,
            "file        {}{}",
            p.display(),
            if *finished { "" } else { "  (cut short: no summary; run `strand-replay recover`)" }
        );
    }
    let measured_rate = if sum.duration_s > 0.0 { (sum.ticks.saturating_sub(1)) as f64 / sum.duration_s } else { 0.0 };
    let _ = writeln!(out, "robot       {}", sum.robot);
    let _ = writeln!(out, "duration    {:.3} s", sum.duration_s);
    let _ =
        writeln!(out, "ticks       {} at {} Hz configured, {:.1} Hz measured; {} missing", sum.ticks, sum.rate_hz, measured_rate, sum.gaps);
    let _ = writeln!(out, "log         {} dropped, state {}", st.log_drops, name_of(LogState::from_u32(st.log_state), st.log_state));
    let _ = writeln!(
        out,
        "timing      overruns {}, late wake-ups {}, worst lateness {:.1} µs; lateness p50 {:.1} p99 {:.1} max {:.1} µs; step p50 {:.1} p99 {:.1} max {:.1} µs",
        st.overruns,
        st.late_wakeups,
        us(st.worst_lateness_ns),
        us(sum.lateness.percentile(50.0)),
        us(sum.lateness.percentile(99.0)),
        us(sum.lateness.max()),
        us(sum.step.percentile(50.0)),
        us(sum.step.percentile(99.0)),
        us(sum.step.max())
    );
    let _ = writeln!(
        out,
        "segments    {} received, {} accepted, {} rejected, {} underruns, {} clamped ticks",
        sum.segments, st.segments_accepted, st.rejected, st.underruns, st.clamps
    );
    let faults: Vec<String> = sum.faults.iter().map(|(t, c)| format!("{c:?} at tick {t}")).collect();
    let _ = writeln!(out, "faults      {}", if faults.is_empty() { "none".to_string() } else { faults.join(", ") });
    let jobs: Vec<String> = sum.jobs.iter().map(|(t, o)| format!("{o:?} at tick {t}")).collect();
    let _ = writeln!(
        out,
        "job         {} (ended: {})",
        name_of(JobOutcome::from_u32(st.job_outcome), st.job_outcome),
        if jobs.is_empty() { "none".to_string() } else { jobs.join(", ") }
    );
    let _ = writeln!(out, "final state {}", name_of(RunState::from_u32(st.run_state), st.run_state));
    let (mean, p99, max, n) = sum.tcp_error;
    if n > 0 {
        let _ = writeln!(
            out,
            "TCP error   mean {:.3} mm, p99 {:.3} mm, max {:.3} mm over {n} running ticks (target vs measured joints)",
            mean * 1e3,
            p99 * 1e3,
            max * 1e3
        );
    }
    let topics: Vec<String> = sum.topics.iter().map(|(t, n)| format!("{t} {n}")).collect();
    let _ = writeln!(out, "channels    {}", topics.join(", "));
    out
}

/// Writes one CSV per channel into `dir`, decoding each with its own schema. Columns: `log_time_ns`
/// and every field path (`position[0]`, `header.stamp.sec`...); a channel whose messages vary in
/// shape (sequences of different lengths) gets the union of the columns, empty where absent.
///
/// Two passes over the log, streaming: the first finds each channel's columns, the second writes the
/// rows, so memory does not grow with the log (an hour at 1 kHz is millions of records).
pub fn export_csv(files: &[LogFile], dir: &Path) -> Result<Vec<(PathBuf, u64)>> {
    std::fs::create_dir_all(dir).map_err(ToolError::file(dir))?;
    struct Channel {
        schema: Schema,
        columns: Vec<String>,
        index: BTreeMap<String, usize>,
        path: PathBuf,
        writer: Option<csv::Writer<std::fs::File>>,
        rows: u64,
    }
    let mut channels: BTreeMap<String, Channel> = BTreeMap::new();
    // The compact replay record holds blocks of encoded ticks: its CSV is the replayed ticks,
    // one row each, as `/strand/tick` would have been (below).
    let compact = strand::log::topics::TICKS;
    for f in files {
        for m in f.messages().filter(|m| m.channel.topic != compact) {
            let topic = &m.channel.topic;
            if !channels.contains_key(topic) {
                let schema =
                    m.channel.schema.as_ref().ok_or_else(|| ToolError::Content(format!("{}: {topic}: no schema", f.path.display())))?;
                let text = String::from_utf8_lossy(&schema.data);
                let schema =
                    Schema::parse(&schema.name, &text).map_err(|e| ToolError::Content(format!("{}: {topic}: {e}", f.path.display())))?;
                let name = topic.trim_start_matches('/').replace('/', "_");
                let path = dir.join(format!("{name}.csv"));
                channels
                    .insert(topic.clone(), Channel { schema, columns: Vec::new(), index: BTreeMap::new(), path, writer: None, rows: 0 });
            }
            let c = channels.get_mut(topic).expect("inserted above");
            for (k, _) in c.schema.decode(&m.data).map_err(|e| ToolError::Content(format!("{}: {topic}: {e}", f.path.display())))? {
                if !c.index.contains_key(&k) {
                    c.index.insert(k.clone(), c.columns.len());
                    c.columns.push(k);
                }
            }
        }
    }
    for c in channels.values_mut() {
        let mut w = csv::Writer::from_path(&c.path).map_err(|e| csv_error(&c.path, e))?;
        let mut header = vec!["log_time_ns".to_string()];
        header.extend(c.columns.iter().cloned());
        w.write_record(&header).map_err(|e| csv_error(&c.path, e))?;
        c.writer = Some(w);
    }
    let mut record: Vec<String> = Vec::new();
    for f in files {
        for m in f.messages().filter(|m| m.channel.topic != compact) {
            let c = channels.get_mut(&m.channel.topic).expect("seen in the first pass");
            record.resize(c.columns.len() + 1, String::new());
            record.truncate(c.columns.len() + 1);
            record.iter_mut().for_each(String::clear);
            record[0] = m.log_time.to_string();
            for (k, v) in
                c.schema.decode(&m.data).map_err(|e| ToolError::Content(format!("{}: {}: {e}", f.path.display(), m.channel.topic)))?
            {
                record[c.index[&k] + 1] = v.to_string();
            }
            c.writer.as_mut().expect("opened above").write_record(&record).map_err(|e| csv_error(&c.path, e))?;
            c.rows += 1;
        }
    }
    let mut written = Vec::new();
    for c in channels.into_values() {
        c.writer.expect("opened above").flush().map_err(ToolError::file(&c.path))?;
        written.push((c.path, c.rows));
    }
    if files.iter().any(|f| f.channel(compact).next().is_some()) {
        written.push(export_replayed_ticks(files, dir)?);
    }
    Ok(written)
}

/// `strand_tick.csv` from a compact log: every tick replayed (its output recomputed and checked
/// against the logged digest), in `strand_msgs/msg/Tick`'s columns. Two passes (the columns vary
/// with what a tick received).
fn export_replayed_ticks(files: &[LogFile], dir: &Path) -> Result<(PathBuf, u64)> {
    use strand::log::cdr::{CdrWriter, encode, schema_text};
    use strand::log::messages::Tick;
    let schema =
        Schema::parse("strand_msgs/msg/Tick", &schema_text::<Tick>()).map_err(|e| ToolError::Content(format!("the Tick schema: {e}")))?;
    let offset: i128 = files.first().and_then(|f| f.meta("clock_offset_ns")).and_then(|s| s.parse().ok()).unwrap_or(0);
    let mut cdr = CdrWriter::new();
    let (mut columns, mut index) = (Vec::<String>::new(), BTreeMap::<String, usize>::new());
    let decode = |cdr: &CdrWriter| schema.decode(cdr.bytes()).map_err(|e| ToolError::Content(format!("a replayed tick: {e}")));
    for tick in strand::log::reader::ticks_of(files) {
        encode(&mut cdr, &tick?);
        for (k, _) in decode(&cdr)? {
            if !index.contains_key(&k) {
                index.insert(k.clone(), columns.len());
                columns.push(k);
            }
        }
    }
    let path = dir.join("strand_tick.csv");
    let mut w = csv::Writer::from_path(&path).map_err(|e| csv_error(&path, e))?;
    w.write_record(std::iter::once("log_time_ns").chain(columns.iter().map(String::as_str))).map_err(|e| csv_error(&path, e))?;
    let mut rows = 0;
    let mut record = vec![String::new(); columns.len() + 1];
    for tick in strand::log::reader::ticks_of(files) {
        let tick = tick?;
        record.iter_mut().for_each(String::clear);
        record[0] = (tick.input.time_ns as i128 + offset).max(0).to_string();
        encode(&mut cdr, &tick);
        for (k, v) in decode(&cdr)? {
            record[index[&k] + 1] = v.to_string();
        }
        w.write_record(&record).map_err(|e| csv_error(&path, e))?;
        rows += 1;
    }
    w.flush().map_err(ToolError::file(&path))?;
    Ok((path, rows))
}

/// Opens the logs; an error for one without a tick (cut short before its first chunk was closed,
/// or not a strand log), a note on stderr for one cut short (only its closed chunks are read).
pub fn open_all(files: &[PathBuf]) -> Result<Vec<LogFile>> {
    let logs: Vec<LogFile> = files.iter().map(|f| LogFile::open(f)).collect::<Result<_, _>>()?;
    for l in &logs {
        if l.records().next().is_none() {
            return Err(ToolError::Content(format!(
                "{}: no ticks in the log ({})",
                l.path.display(),
                if l.finished { "not a strand log, or a run of no tick" } else { "cut short before its first chunk was closed?" }
            )));
        }
        if !l.finished {
            eprintln!(
                "strand-replay: note: {}: cut short (no footer): only its closed chunks are read; `strand-replay recover` rewrites it",
                l.path.display()
            );
        }
    }
    Ok(logs)
}

/// A CSV file that could not be written.
fn csv_error(path: &Path, e: csv::Error) -> ToolError {
    match e.into_kind() {
        csv::ErrorKind::Io(source) => ToolError::File { path: path.to_path_buf(), source },
        other => ToolError::Content(format!("{}: {other:?}", path.display())),
    }
}
