//! The logger: a [`Logger`] on the tick side and a writer thread that owns the MCAP file.
//!
//! The tick side takes a preallocated slot from a free list, copies the tick into it (only the used
//! segments, controls and samples) and pushes it to the writer: two lock-free `ArrayQueue`
//! operations and one copy of about 2 kB, no allocation, no lock, no system call. With no free slot
//! the tick is counted as dropped and the controller goes on. The writer thread polls every
//! millisecond, encodes each tick onto its channels, closes a chunk at least every
//! `chunk_interval` (so a crash loses at most that much), rotates files by size or duration, and on
//! a write error (disk full) stops writing, marks `LogState::Failed` and counts every later tick as
//! lost; control is never touched.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crossbeam_queue::ArrayQueue;
use mcap::records::{MessageHeader, Metadata};
use mcap::{Attachment, Compression, WriteOptions};
use strand_ipc::LogState;

use super::cdr::{CdrWriter, encode, schema_text};
use super::messages::{HeatStatus, Tick, TickTiming, ros};
use super::record::{BlockEncoder, TickBlockSchema};
use super::scene::{Scene, SceneSink, SceneTopic};
use super::{LogCompression, LogConfig, ReplayRecord, build_version, names, topics, unix_now_ns, utc_stamp};
use crate::config::Config;
use crate::config::view::ViewConfig;
use crate::io::runner::TickSink;
use strand_core::kin::{JointVector, RobotModel};
use strand_core::{TickInput, TickOutput};

/// Why logging could not start or went wrong.
#[derive(Debug, thiserror::Error)]
pub enum LogError {
    /// A file or folder could not be created or written.
    #[error("{path}: {message}")]
    Io {
        /// The file or folder.
        path: String,
        /// What failed.
        message: String,
    },
}

impl LogError {
    fn io(path: &Path, e: impl std::fmt::Display) -> Self {
        LogError::Io { path: path.display().to_string(), message: e.to_string() }
    }
}

/// What the log needs to be self-contained: the configuration in force, the URDF, the chain.
#[derive(Clone)]
pub struct LogContext {
    /// [`Config::effective_toml`].
    pub effective_config: String,
    /// The URDF text the robot was built from.
    pub urdf_text: String,
    /// Where the configuration was read from.
    pub config_file: String,
    /// The chain (joint names; FK for `/tcp/actual`).
    pub model: RobotModel,
    /// Tick rate (Hz).
    pub rate_hz: f64,
    /// The scene channels' rates (`[view]`).
    pub view: ViewConfig,
    /// Every joint a command carries: the arm's, then a positioner's axes.
    pub joint_names: Vec<String>,
    /// Unix time minus tick time (ns) for the messages' log times; `None`: the wall clock's offset
    /// from `CLOCK_MONOTONIC` when the writer starts (a live run). A log rewritten from another
    /// keeps that one's.
    pub clock_offset_ns: Option<i128>,
    /// The bed's measured surface (`[bed.mesh]`), drawn on `/bed/mesh`.
    pub bed_mesh: Option<strand_core::BedMesh>,
}

impl LogContext {
    /// From the configuration in force and the model built from it.
    pub fn new(cfg: &Config, model: &RobotModel) -> Self {
        LogContext {
            effective_config: cfg.effective_toml(),
            urdf_text: cfg.robot.urdf_text.clone(),
            config_file: cfg.file.display().to_string(),
            model: model.clone(),
            rate_hz: cfg.controller.rate_hz,
            view: cfg.view.clone(),
            joint_names: model
                .joints()
                .iter()
                .chain(cfg.robot.build_positioner().ok().flatten().iter().flat_map(|p| p.model().joints().iter()))
                .map(|j| j.name.clone())
                .collect(),
            clock_offset_ns: None,
            bed_mesh: strand_job::bed::BedTransform::new(&cfg.bed).ok().and_then(|b| b.mesh().cloned()),
        }
    }
}

#[derive(Default)]
struct Shared {
    drops: AtomicU64,
    state: AtomicU32,
    stop: AtomicBool,
}

/// What the writer did, at the end.
#[derive(Clone, Debug, Default)]
pub struct LogReport {
    /// Files written, in order.
    pub files: Vec<PathBuf>,
    /// Ticks written.
    pub ticks_written: u64,
    /// Ticks not logged (queue full or after a write error).
    pub drops: u64,
    /// Bytes written (all files).
    pub bytes: u64,
    /// The write error that stopped logging, if one did.
    pub error: Option<String>,
    /// CPU time of the writer thread (s).
    pub writer_cpu_s: f64,
    /// Wall time the writer thread ran (s).
    pub writer_wall_s: f64,
    /// Messages and payload bytes handed to the live view's server (0 without one).
    pub live_sent: (u64, u64),
}

/// The tick side of the log. See the module documentation.
pub struct Logger {
    free: Arc<ArrayQueue<Box<Tick>>>,
    full: Arc<ArrayQueue<Box<Tick>>>,
    shared: Arc<Shared>,
    thread: Option<JoinHandle<LogReport>>,
    first_file: PathBuf,
    record: bool,
}

impl Logger {
    /// Creates the first file (so a bad folder is an error now, not later), allocates the queue and
    /// starts the writer thread.
    pub fn start(cfg: &LogConfig, ctx: LogContext) -> Result<Logger, LogError> {
        Self::start_at(cfg, ctx, &Self::new_file_path(cfg)?)
    }

    /// Where [`start`](Logger::start) writes: `[log] dir` (created if missing) / `name` or
    /// `strand-<UTC start time>`, `.mcap`.
    pub fn new_file_path(cfg: &LogConfig) -> Result<PathBuf, LogError> {
        let dir = PathBuf::from(&cfg.dir);
        std::fs::create_dir_all(&dir).map_err(|e| LogError::io(&dir, e))?;
        let stem = if cfg.name.is_empty() { format!("strand-{}", utc_stamp(unix_now_ns())) } else { cfg.name.clone() };
        Ok(dir.join(format!("{stem}.mcap")))
    }

    /// As [`start`](Logger::start), writing to `path` (rotated parts go beside it as `STEM-001.mcap`...).
    pub fn start_at(cfg: &LogConfig, ctx: LogContext, path: &Path) -> Result<Logger, LogError> {
        Self::start_with(cfg, ctx, Some(path), None)
    }

    /// The general start: a file at `path` (`None`: no file, the writer only feeds the live view)
    /// and a live view the writer thread feeds every message it encodes (decimated by the view).
    pub fn start_with(
        cfg: &LogConfig,
        ctx: LogContext,
        path: Option<&Path>,
        live: Option<strand_view::LiveView>,
    ) -> Result<Logger, LogError> {
        let record = path.is_some();
        let path = path.unwrap_or(Path::new("(no log file)"));
        let free = Arc::new(ArrayQueue::new(cfg.queue_ticks));
        for _ in 0..cfg.queue_ticks {
            let _ = free.push(Box::default());
        }
        let full = Arc::new(ArrayQueue::new(cfg.queue_ticks));
        let shared = Arc::new(Shared::default());
        shared.state.store(if record { LogState::Recording } else { LogState::Off } as u32, Ordering::Relaxed);
        let mut writer = WriterThread::new(cfg.clone(), ctx, path.to_path_buf(), shared.clone());
        if let Some(view) = live {
            writer.live = Some(LiveTap::new(view, &writer.ctx.view)?);
            writer.publish_description();
        }
        if record {
            writer.open(0)?;
        }
        let (f, q) = (free.clone(), full.clone());
        let thread =
            std::thread::Builder::new().name("strand-log".into()).spawn(move || writer.run(&f, &q)).map_err(|e| LogError::io(path, e))?;
        Ok(Logger { free, full, shared, thread: Some(thread), first_file: path.to_path_buf(), record })
    }

    /// True when it writes a file (else it only feeds the live view).
    pub fn records(&self) -> bool {
        self.record
    }

    /// The first file.
    pub fn path(&self) -> &Path {
        &self.first_file
    }

    /// Queues one tick. Tick-path safe: no allocation, lock or system call.
    pub fn push(&self, input: &TickInput, output: &TickOutput, timing: &TickTiming) {
        let Some(mut slot) = self.free.pop() else {
            self.shared.drops.fetch_add(1, Ordering::Relaxed);
            return;
        };
        copy_tick(&mut slot, input, output, timing);
        if let Err(slot) = self.full.push(slot) {
            // Cannot happen (both queues hold at most every slot); keep the slot anyway.
            let _ = self.free.push(slot);
            self.shared.drops.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Ticks not logged so far.
    pub fn dropped(&self) -> u64 {
        self.shared.drops.load(Ordering::Relaxed)
    }

    /// [`LogState`] as u32.
    pub fn state(&self) -> u32 {
        self.shared.state.load(Ordering::Relaxed)
    }

    /// Writes what is queued, closes the file and reports.
    pub fn finish(mut self) -> LogReport {
        self.shared.stop.store(true, Ordering::Release);
        self.thread.take().and_then(|t| t.join().ok()).unwrap_or_default()
    }
}

impl Drop for Logger {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl TickSink for Logger {
    fn record(&mut self, input: &TickInput, output: &TickOutput, timing: &TickTiming) {
        self.push(input, output, timing);
    }
    fn drops(&self) -> u64 {
        self.dropped()
    }
    fn log_state(&self) -> u32 {
        self.state()
    }
    fn wait_for_room(&self) {
        let recording = |s: u32| s == LogState::Recording as u32 || s == LogState::RecordOnly as u32;
        while self.free.is_empty() && recording(self.state()) {
            std::thread::sleep(std::time::Duration::from_micros(200));
        }
    }
}

/// Copies what a tick used (not the empty tails of its fixed arrays).
fn copy_tick(slot: &mut Tick, input: &TickInput, output: &TickOutput, timing: &TickTiming) {
    let d = &mut slot.input;
    d.tick = input.tick;
    d.time_ns = input.time_ns;
    let n = input.segment_count as usize;
    d.segments[..n].copy_from_slice(&input.segments[..n]);
    d.segment_count = input.segment_count;
    let n = input.control_count as usize;
    d.controls[..n].copy_from_slice(&input.controls[..n]);
    d.control_count = input.control_count;
    d.joint_state = input.joint_state;
    d.heater_state = input.heater_state;
    let n = input.base_pose_count as usize;
    d.base_poses[..n].copy_from_slice(&input.base_poses[..n]);
    d.base_pose_count = input.base_pose_count;
    d.feeder_lost = input.feeder_lost;
    d.cycle = input.cycle;
    slot.output = *output;
    slot.timing = *timing;
}

/// The file under the MCAP writer: buffered, counting the bytes on their way (for rotation and the
/// report), and with `fsync` set, syncing on every flush (mcap flushes when it closes a chunk).
struct LogSink {
    inner: BufWriter<File>,
    bytes: Arc<AtomicU64>,
    sync: Option<File>,
}

impl Write for LogSink {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.bytes.fetch_add(n as u64, Ordering::Relaxed);
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()?;
        match &self.sync {
            Some(f) => f.sync_data(),
            None => Ok(()),
        }
    }
}

impl Seek for LogSink {
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        self.inner.seek(pos)
    }
}

type McapWriter = mcap::Writer<LogSink>;

/// The log's channels in a fixed order: the file's channel ids and the live view's channels are
/// indexed by it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Channel {
    Tick,
    JointStates,
    JointCommand,
    TcpTarget,
    TcpActual,
    BaseMeasured,
    BaseEstimated,
    Extruder,
    Status,
    Segments,
    BaseCommand,
    Heaters,
    TickBlock,
    Scene(SceneTopic),
}

const TICK_CHANNELS: usize = 13;
const CHANNELS: usize = TICK_CHANNELS + SceneTopic::ALL.len();

impl Channel {
    fn index(self) -> usize {
        match self {
            Channel::Tick => 0,
            Channel::JointStates => 1,
            Channel::JointCommand => 2,
            Channel::TcpTarget => 3,
            Channel::TcpActual => 4,
            Channel::BaseMeasured => 5,
            Channel::BaseEstimated => 6,
            Channel::Extruder => 7,
            Channel::Status => 8,
            Channel::Segments => 9,
            Channel::BaseCommand => 10,
            Channel::Heaters => 11,
            Channel::TickBlock => 12,
            Channel::Scene(t) => TICK_CHANNELS + t.index(),
        }
    }
}

/// Every channel: topic, schema name and schema text (in [`Channel::index`] order).
fn channel_list() -> Vec<(&'static str, String, String)> {
    let js = ros::joint_state_schema();
    let pose = ros::pose_stamped_schema();
    let mut list = vec![
        (topics::TICK, "strand_msgs/msg/Tick".to_string(), schema_text::<Tick>()),
        (topics::JOINT_STATES, ros::JOINT_STATE.to_string(), js.clone()),
        (topics::JOINT_COMMAND, ros::JOINT_STATE.to_string(), js),
        (topics::TCP_TARGET, ros::POSE_STAMPED.to_string(), pose.clone()),
        (topics::TCP_ACTUAL, ros::POSE_STAMPED.to_string(), pose.clone()),
        (topics::BASE_MEASURED, ros::POSE_STAMPED.to_string(), pose.clone()),
        (topics::BASE_ESTIMATED, ros::POSE_STAMPED.to_string(), pose),
        (topics::EXTRUDER, "strand_msgs/msg/ExtruderCommand".to_string(), schema_text::<strand_ipc::ExtruderCommand>()),
        (topics::STATUS, "strand_msgs/msg/Status".to_string(), schema_text::<strand_ipc::Status>()),
        (topics::SEGMENTS, "strand_msgs/msg/Segment".to_string(), schema_text::<strand_ipc::Segment>()),
        (topics::BASE_COMMAND, ros::POSE_STAMPED.to_string(), ros::pose_stamped_schema()),
        (topics::HEATERS, "strand_msgs/msg/HeatStatus".to_string(), schema_text::<HeatStatus>()),
        (topics::TICKS, "strand_msgs/msg/TickBlock".to_string(), schema_text::<TickBlockSchema>()),
    ];
    for t in SceneTopic::ALL {
        let (name, text) = t.schema();
        list.push((t.topic(), name.to_string(), text));
    }
    list
}

/// The live view and its channels, in [`Channel::index`] order.
struct LiveTap {
    view: strand_view::LiveView,
    channels: Vec<strand_view::ChannelIndex>,
}

impl LiveTap {
    /// Advertises every channel, each at its `[view]` rate (`/robot_description` latched, the bead
    /// and the executed path replayed whole to a client that subscribes late).
    fn new(mut view: strand_view::LiveView, cfg: &ViewConfig) -> Result<LiveTap, LogError> {
        let mut channels = Vec::with_capacity(CHANNELS);
        for (topic, name, text) in channel_list() {
            let replay = match topic {
                t if t == SceneTopic::RobotDescription.topic() || t == SceneTopic::BedMesh.topic() => strand_view::Replay::Last,
                t if t == SceneTopic::Bead.topic() || t == SceneTopic::PathExecuted.topic() => strand_view::Replay::History,
                _ => strand_view::Replay::None,
            };
            // The trails send only what is new: never thinned, whatever `rates` says.
            let rate = if replay == strand_view::Replay::None { cfg.rate_for(topic) } else { 0.0 };
            let index = view
                .add_channel(topic, &name, &text, rate, replay)
                .map_err(|e| LogError::Io { path: view.address().to_string(), message: e.to_string() })?;
            channels.push(index);
        }
        Ok(LiveTap { view, channels })
    }
}

struct OpenFile {
    mcap: McapWriter,
    channels: [u16; CHANNELS],
    path: PathBuf,
    bytes: Arc<AtomicU64>,
    first_time_ns: Option<u64>,
    sequence: u32,
}

struct WriterThread {
    cfg: LogConfig,
    ctx: LogContext,
    first_path: PathBuf,
    shared: Arc<Shared>,
    file: Option<OpenFile>,
    part: u32,
    report: LogReport,
    joint_names: Vec<String>,
    /// Unix time − monotonic time at start (ns): log times are Unix times, as viewers expect.
    clock_offset_ns: i128,
    cdr: CdrWriter,
    last_measured: Option<JointVector>,
    bytes_closed: u64,
    scene: Scene,
    live: Option<LiveTap>,
    /// The next log time (Unix ns) at which a trail's history may be built for late viewers.
    next_history_ns: u64,
    /// The next tick time (ns) at which the derived channels go to the file (`[log] derived_rate_hz`).
    next_derived_ns: u64,
    /// What the last `/status` written to the file said: run state, fault, job outcome, layer.
    last_status_written: Option<(u32, u32, u32, u32)>,
    /// The next log time (Unix ns) at which `/tf`, `/joints/normalized` and `/path/ahead` may go to
    /// the file again (their snapshots follow `derived_rate_hz` there; the live view keeps `[view]`'s).
    next_snapshot_ns: [u64; 3],
    /// Free space fell below `[log] min_free_bytes`: the replay record and the segments only.
    record_only: bool,
    /// When the free space was last checked.
    disk_checked: Option<Instant>,
    /// The last tick's log time (Unix ns): the time of what a file's end writes.
    last_log_time: u64,
    /// The open block of the compact replay record (`[log] record = "compact"`).
    block: BlockEncoder,
    block_cdr: CdrWriter,
}

impl WriterThread {
    fn new(cfg: LogConfig, ctx: LogContext, first_path: PathBuf, shared: Arc<Shared>) -> Self {
        let joint_names = ctx.joint_names.clone();
        let clock_offset_ns = ctx.clock_offset_ns.unwrap_or_else(|| unix_now_ns() as i128 - crate::io::clock::monotonic_ns() as i128);
        let mut scene = Scene::new(&ctx.urdf_text, &ctx.model, &ctx.view, ctx.bed_mesh.as_ref());
        // Thinned derived channels: the trails go to the file a finished chunk at a time; with
        // everything at every tick, as the live view gets them.
        scene.set_file_chunks(cfg.derived_rate_hz > 0.0);
        WriterThread {
            cfg,
            first_path,
            shared,
            file: None,
            part: 0,
            report: LogReport::default(),
            joint_names,
            clock_offset_ns,
            cdr: CdrWriter::new(),
            last_measured: None,
            bytes_closed: 0,
            scene,
            live: None,
            next_history_ns: 0,
            next_derived_ns: 0,
            last_status_written: None,
            next_snapshot_ns: [0; 3],
            last_log_time: 0,
            record_only: false,
            disk_checked: None,
            block: BlockEncoder::new(),
            block_cdr: CdrWriter::new(),
            ctx,
        }
    }

    fn part_path(&self, part: u32) -> PathBuf {
        if part == 0 {
            return self.first_path.clone();
        }
        let stem = self.first_path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        self.first_path.with_file_name(format!("{stem}-{part:03}.mcap"))
    }

    fn open(&mut self, first_tick: u64) -> Result<(), LogError> {
        let path = self.part_path(self.part);
        let file = File::create(&path).map_err(|e| LogError::io(&path, e))?;
        let sync = if self.cfg.fsync { Some(file.try_clone().map_err(|e| LogError::io(&path, e))?) } else { None };
        let bytes = Arc::new(AtomicU64::new(0));
        let compression = match self.cfg.compression {
            LogCompression::Zstd => Some(Compression::Zstd),
            LogCompression::Lz4 => Some(Compression::Lz4),
            LogCompression::None => None,
        };
        let io = |e: mcap::McapError| LogError::io(&path, e);
        let mut w = WriteOptions::new()
            .compression(compression)
            .compression_threads(0)
            .chunk_size(Some(self.cfg.chunk_bytes))
            .profile("ros2")
            .library(format!("strand {}", build_version()))
            .create(LogSink { inner: BufWriter::with_capacity(1 << 20, file), bytes: bytes.clone(), sync })
            .map_err(io)?;
        let mut meta = BTreeMap::new();
        meta.insert("version".to_string(), build_version());
        meta.insert("contract_version".to_string(), strand_ipc::CONTRACT_VERSION.to_string());
        meta.insert("config_file".to_string(), self.ctx.config_file.clone());
        meta.insert("robot".to_string(), self.ctx.model.name().to_string());
        meta.insert("urdf".to_string(), self.ctx.model.source().to_string());
        meta.insert("rate_hz".to_string(), format!("{}", self.ctx.rate_hz));
        meta.insert("dof".to_string(), self.joint_names.len().to_string());
        meta.insert("joint_names".to_string(), self.joint_names.join(","));
        meta.insert("clock_offset_ns".to_string(), self.clock_offset_ns.to_string());
        meta.insert("part".to_string(), self.part.to_string());
        meta.insert("first_tick".to_string(), first_tick.to_string());
        meta.insert("started_utc".to_string(), utc_stamp(unix_now_ns()));
        w.write_metadata(&Metadata { name: names::METADATA.to_string(), metadata: meta }).map_err(io)?;
        let now = unix_now_ns();
        for (name, media, data) in [
            (names::EFFECTIVE_CONFIG, "application/toml", self.ctx.effective_config.as_bytes()),
            (names::URDF, "application/xml", self.ctx.urdf_text.as_bytes()),
        ] {
            w.attach(&Attachment {
                log_time: now,
                create_time: now,
                name: name.to_string(),
                media_type: media.to_string(),
                data: std::borrow::Cow::Borrowed(data),
            })
            .map_err(io)?;
        }
        let mut channels = [0u16; CHANNELS];
        // One replay record per file: the compact blocks or the whole ticks (`[log] record`).
        let unused = if self.cfg.record == ReplayRecord::Compact { topics::TICK } else { topics::TICKS };
        for (id, (topic, name, text)) in channels.iter_mut().zip(channel_list()).filter(|(_, (t, _, _))| *t != unused) {
            let sid = w.add_schema(&name, "ros2msg", text.as_bytes()).map_err(io)?;
            *id = w.add_channel(sid, topic, "cdr", &BTreeMap::new()).map_err(io)?;
        }
        // Make the header, metadata and attachments durable at once: a crash in the first
        // chunk still leaves a file that names its config.
        w.flush().map_err(io)?;
        self.report.files.push(path.clone());
        self.file = Some(OpenFile { mcap: w, channels, path, bytes, first_time_ns: None, sequence: 1 });
        Ok(())
    }

    fn close(&mut self) -> Result<(), LogError> {
        self.write_block()?;
        // The trails' last chunks, which the file takes only when they are finished.
        let (scene, file, time) = (&mut self.scene, &mut self.file, self.last_log_time);
        if let Some(f) = file.as_mut() {
            scene.flush_trails(time, &mut |topic, bytes| {
                f.sequence = f.sequence.wrapping_add(1);
                let channel_id = f.channels[Channel::Scene(topic).index()];
                let header = MessageHeader { channel_id, sequence: f.sequence, log_time: time, publish_time: time };
                f.mcap.write_to_known_channel(&header, bytes).map_err(|e| LogError::io(&f.path, e))
            })?;
        }
        if let Some(mut f) = self.file.take() {
            f.mcap.finish().map_err(|e| LogError::io(&f.path, e))?;
            let mut inner = f.mcap.into_inner();
            inner.flush().map_err(|e| LogError::io(&f.path, e))?;
            self.bytes_closed += f.bytes.load(Ordering::Relaxed);
        }
        Ok(())
    }

    fn run(mut self, free: &ArrayQueue<Box<Tick>>, full: &ArrayQueue<Box<Tick>>) -> LogReport {
        let started = Instant::now();
        let cpu0 = thread_cpu_s();
        let interval = Duration::from_secs_f64(self.cfg.chunk_interval);
        let mut last_close = Instant::now();
        let mut dirty = false;
        loop {
            let stopping = self.shared.stop.load(Ordering::Acquire);
            let mut any = false;
            while let Some(tick) = full.pop() {
                any = true;
                if self.file.is_some() || self.live.is_some() {
                    // The live view goes on after a write error: the operator needs it most then.
                    let recording = self.file.is_some();
                    match self.write_tick(&tick) {
                        Ok(()) if recording => {
                            dirty = true;
                            self.report.ticks_written += 1;
                        }
                        Ok(()) if self.report.error.is_some() => {
                            self.shared.drops.fetch_add(1, Ordering::Relaxed);
                        }
                        Ok(()) => {}
                        Err(e) => self.fail(e),
                    }
                } else {
                    self.shared.drops.fetch_add(1, Ordering::Relaxed);
                }
                let _ = free.push(tick);
                if dirty && last_close.elapsed() >= interval {
                    break;
                }
            }
            if dirty && last_close.elapsed() >= interval {
                if let Err(e) = self.close_chunk() {
                    self.fail(e);
                }
                dirty = false;
                last_close = Instant::now();
            }
            if stopping && full.is_empty() {
                break;
            }
            if !any {
                std::thread::sleep(Duration::from_millis(1));
            }
        }
        if self.file.is_some()
            && let Err(e) = self.close()
        {
            self.fail(e);
        }
        self.report.bytes = self.bytes_closed;
        self.report.drops = self.shared.drops.load(Ordering::Relaxed);
        self.report.writer_cpu_s = thread_cpu_s() - cpu0;
        if let Some(live) = self.live.take() {
            self.report.live_sent = live.view.sent();
            live.view.stop();
        }
        self.report.writer_wall_s = started.elapsed().as_secs_f64();
        self.report
    }

    fn fail(&mut self, e: LogError) {
        tracing::error!("log: {e}; logging stopped, control goes on");
        self.report.error = Some(e.to_string());
        self.shared.state.store(LogState::Failed as u32, Ordering::Relaxed);
        // Dropping the writer would try to finish the file (and fail again): forget the open file,
        // keeping what its closed chunks hold, which `strand-replay recover` can read.
        if let Some(f) = self.file.take() {
            std::mem::forget(f);
        }
    }

    fn close_chunk(&mut self) -> Result<(), LogError> {
        // The open block goes into the chunk it belongs to: a crash loses at most the open chunk.
        self.write_block()?;
        self.check_disk();
        if let Some(f) = self.file.as_mut() {
            f.mcap.flush().map_err(|e| LogError::io(&f.path, e))?;
        }
        Ok(())
    }

    /// At most once a second: below `[log] min_free_bytes` of free space the file gets the replay
    /// record and the segments only (`LogState::RecordOnly`); at 1.1 × that it gets everything again.
    fn check_disk(&mut self) {
        if self.cfg.min_free_bytes == 0 || self.disk_checked.is_some_and(|t| t.elapsed() < Duration::from_secs(1)) {
            return;
        }
        self.disk_checked = Some(Instant::now());
        let Some(free) = self.file.as_ref().and_then(|f| free_bytes(&f.path)) else { return };
        let floor = self.cfg.min_free_bytes;
        let was = self.record_only;
        if !was && free < floor {
            self.record_only = true;
            tracing::warn!(
                "log: {free} bytes free on the log's disk, under [log] min_free_bytes = {floor}: the replay record only until there is room"
            );
            self.shared.state.store(LogState::RecordOnly as u32, Ordering::Relaxed);
        } else if was && free as f64 >= 1.1 * floor as f64 {
            self.record_only = false;
            tracing::info!("log: {free} bytes free again: every channel is written");
            self.shared.state.store(LogState::Recording as u32, Ordering::Relaxed);
        }
    }

    /// Writes the open block of the compact replay record, if any, as one `/strand/ticks` message
    /// at its first tick's log time.
    fn write_block(&mut self) -> Result<(), LogError> {
        let time = (self.block.first_time_ns() as i128 + self.clock_offset_ns).max(0) as u64;
        if self.block.finish(&mut self.block_cdr).is_none() {
            return Ok(());
        }
        if let Some(f) = self.file.as_mut() {
            f.sequence = f.sequence.wrapping_add(1);
            let channel_id = f.channels[Channel::TickBlock.index()];
            let header = MessageHeader { channel_id, sequence: f.sequence, log_time: time, publish_time: time };
            f.mcap.write_to_known_channel(&header, self.block_cdr.bytes()).map_err(|e| LogError::io(&f.path, e))?;
        }
        Ok(())
    }

    /// Offers `/robot_description` to the live view (latched there for every client).
    fn publish_description(&mut self) {
        if let Some(live) = self.live.as_mut() {
            let now = unix_now_ns();
            let index = live.channels[Channel::Scene(SceneTopic::RobotDescription).index()];
            live.view.publish(index, now, self.scene.robot_description());
            let index = live.channels[Channel::Scene(SceneTopic::BedMesh).index()];
            if let Some(mesh) = self.scene.bed_mesh(now) {
                live.view.publish(index, now, mesh);
            }
        }
    }

    fn write_tick(&mut self, t: &Tick) -> Result<(), LogError> {
        // Rotation, between ticks.
        let rotate = self.file.as_ref().is_some_and(|f| {
            (self.cfg.rotate_bytes > 0 && f.mcap_bytes() >= self.cfg.rotate_bytes)
                || (self.cfg.rotate_seconds > 0.0
                    && f.first_time_ns.is_some_and(|t0| t.input.time_ns.saturating_sub(t0) as f64 >= self.cfg.rotate_seconds * 1e9))
        });
        if rotate {
            self.close()?;
            self.part += 1;
            self.open(t.input.tick)?;
        }
        let log_time = (t.input.time_ns as i128 + self.clock_offset_ns).max(0) as u64;
        self.last_log_time = log_time;
        let stamp = |ns: u64| (ns as i128 + self.clock_offset_ns).max(0) as u64;
        let dof = self.joint_names.len();
        if let Some(f) = self.file.as_mut()
            && f.first_time_ns.is_none()
        {
            f.first_time_ns = Some(t.input.time_ns);
            // The URDF once per file, as its first message (for a viewer's 3D panel), at the first
            // tick's time: on the robot clock a tick's time is the robot's, which may be behind
            // the wall clock the file was opened by, and a log's times must not go back.
            let description = Channel::Scene(SceneTopic::RobotDescription).index();
            let header = MessageHeader { channel_id: f.channels[description], sequence: 0, log_time, publish_time: log_time };
            f.mcap.write_to_known_channel(&header, self.scene.robot_description()).map_err(|e| LogError::io(&f.path, e))?;
            let mesh = Channel::Scene(SceneTopic::BedMesh).index();
            let header = MessageHeader { channel_id: f.channels[mesh], ..header };
            if let Some(bytes) = self.scene.bed_mesh(log_time) {
                f.mcap.write_to_known_channel(&header, bytes).map_err(|e| LogError::io(&f.path, e))?;
            }
        }
        // The derived channels go to the file at `derived_rate_hz` (on the tick's own time, so a
        // replay of the log decimates the same way); `/status` also whenever its state changes.
        let derived = self.cfg.derived_rate_hz == 0.0 || t.input.time_ns >= self.next_derived_ns;
        if derived && self.cfg.derived_rate_hz > 0.0 {
            let period = (1e9 / self.cfg.derived_rate_hz) as u64;
            self.next_derived_ns =
                if t.input.time_ns >= self.next_derived_ns + period { t.input.time_ns } else { self.next_derived_ns } + period;
        }
        let st = &t.output.status;
        let state = (st.run_state, st.fault, st.job_outcome, st.executing_layer);
        let status_due = derived || self.last_status_written != Some(state);
        if status_due {
            self.last_status_written = Some(state);
        }
        // Nothing to encode a derived channel for: not due in the file, no live view.
        let encode_derived = derived || self.live.is_some();
        let compact = self.cfg.record == ReplayRecord::Compact;
        let record_only = self.record_only;
        let has_live = self.live.is_some();
        let derived_period_ns = if self.cfg.derived_rate_hz > 0.0 { (1e9 / self.cfg.derived_rate_hz) as u64 } else { 0 };
        let (file, live, cdr, next_snapshot) = (&mut self.file, &mut self.live, &mut self.cdr, &mut self.next_snapshot_ns);
        // Every message is offered to the live view (which decimates); the file gets the replay
        // record and the segments always, the derived channels when due.
        let mut put_to = |channel: Channel, sink: SceneSink, time: u64, bytes: &[u8]| -> Result<(), LogError> {
            let c = channel.index();
            let due = match channel {
                Channel::Tick => !compact,
                Channel::TickBlock => false,
                Channel::Segments => true,
                // The scene's snapshots are derived too: at most the derived rate in the file (the
                // path preview at most every 5 s). The trails and the robot are never thinned.
                Channel::Scene(topic @ (SceneTopic::Tf | SceneTopic::JointsNormalized | SceneTopic::PathAhead)) => {
                    let (k, period) = match topic {
                        SceneTopic::Tf => (0, derived_period_ns),
                        SceneTopic::JointsNormalized => (1, derived_period_ns),
                        // Every message when everything goes to the file (`derived_rate_hz = 0`).
                        _ if derived_period_ns == 0 => (2, 0),
                        // The preview of the path ahead, whose segments `/segments` holds anyway.
                        _ => (2, derived_period_ns.max(5_000_000_000)),
                    };
                    let due = time >= next_snapshot[k];
                    if due {
                        next_snapshot[k] = time + period;
                    }
                    due
                }
                Channel::Scene(_) => true,
                Channel::Status => status_due,
                _ => derived,
            };
            let replay_record = matches!(channel, Channel::Tick | Channel::TickBlock | Channel::Segments);
            if let Some(f) = file.as_mut().filter(|_| due && sink != SceneSink::Live && (replay_record || !record_only)) {
                f.sequence = f.sequence.wrapping_add(1);
                let header = MessageHeader { channel_id: f.channels[c], sequence: f.sequence, log_time: time, publish_time: time };
                f.mcap.write_to_known_channel(&header, bytes).map_err(|e| LogError::io(&f.path, e))?;
            }
            if let Some(l) = live.as_mut().filter(|_| sink != SceneSink::File) {
                l.view.publish(l.channels[c], time, bytes);
            }
            Ok(())
        };
        let mut put = |channel: Channel, time: u64, bytes: &[u8]| put_to(channel, SceneSink::Both, time, bytes);
        if !compact || has_live {
            encode(cdr, t);
            put(Channel::Tick, log_time, cdr.bytes())?;
        }
        for s in t.input.segments() {
            encode(cdr, s);
            put(Channel::Segments, log_time, cdr.bytes())?;
        }
        if let Some(js) = &t.input.joint_state {
            let n = (js.dof as usize).min(dof);
            if encode_derived {
                ros::joint_state(cdr, stamp(js.stamp_ns), &self.joint_names, &js.position[..n], &js.velocity[..n], &js.effort[..n]);
                put(Channel::JointStates, log_time, cdr.bytes())?;
            }
            if n == dof && js.position[..n].iter().all(|v| v.is_finite()) {
                let mut q = JointVector::zeros();
                q.as_mut_slice()[..n].copy_from_slice(&js.position[..n]);
                self.last_measured = Some(q);
            }
        }
        let o = &t.output;
        if encode_derived {
            if o.joint_command.valid == 1 {
                let c = &o.joint_command;
                ros::joint_state(cdr, log_time, &self.joint_names, &c.position[..dof], &c.velocity[..dof], &[]);
                put(Channel::JointCommand, log_time, cdr.bytes())?;
            }
            let d = &o.diagnostics;
            let quat = |q: &nalgebra::UnitQuaternion<f64>| [q.w, q.i, q.j, q.k];
            ros::pose_stamped(cdr, log_time, "world", d.tcp_target_world.into(), quat(&d.tcp_target_orientation));
            put(Channel::TcpTarget, log_time, cdr.bytes())?;
            if let Some(q) = &self.last_measured {
                let tcp_b = self.ctx.model.forward_kinematics(q);
                let rot_b = nalgebra::UnitQuaternion::from_rotation_matrix(&tcp_b.rotation);
                let (p_w, r_w) = d.base.base_to_world(&tcp_b.translation.vector, &rot_b);
                ros::pose_stamped(cdr, log_time, "world", p_w.into(), quat(&r_w));
                put(Channel::TcpActual, log_time, cdr.bytes())?;
            }
            for p in t.input.base_poses() {
                ros::pose_stamped(cdr, stamp(p.stamp_ns), "world", p.position, p.orientation);
                put(Channel::BaseMeasured, log_time, cdr.bytes())?;
            }
            ros::pose_stamped(cdr, log_time, "world", d.base.position.into(), quat(&d.base.orientation));
            put(Channel::BaseEstimated, log_time, cdr.bytes())?;
            if o.base_command.valid == 1 {
                let b = &o.base_command;
                ros::pose_stamped(cdr, log_time, "world", b.position, b.orientation);
                put(Channel::BaseCommand, log_time, cdr.bytes())?;
            }
            encode(cdr, &o.extruder);
            put(Channel::Extruder, log_time, cdr.bytes())?;
            encode(cdr, &HeatStatus::of(&o.status));
            put(Channel::Heaters, log_time, cdr.bytes())?;
        }
        if encode_derived || status_due {
            encode(cdr, &o.status);
            put(Channel::Status, log_time, cdr.bytes())?;
        }
        self.scene.tick(t, log_time, self.last_measured.as_ref(), &mut |topic, sink, bytes| {
            put_to(Channel::Scene(topic), sink, log_time, bytes)
        })?;
        // Viewers that subscribed to a trail since the last time get the whole of it, built at most
        // once a second (requests in between are served together), in a buffer freed after.
        if let Some(l) = self.live.as_mut()
            && log_time >= self.next_history_ns
        {
            for topic in [SceneTopic::Bead, SceneTopic::PathExecuted] {
                let c = l.channels[Channel::Scene(topic).index()];
                if l.view.history_wanted(c) {
                    self.next_history_ns = log_time + 1_000_000_000;
                    l.view.send_history(c, log_time, &self.scene.history(topic, log_time).unwrap_or_default());
                }
            }
        }
        if compact && self.file.is_some() {
            if !self.block.takes(t) {
                self.write_block()?;
            }
            self.block.push(t);
        }
        Ok(())
    }
}

impl OpenFile {
    /// Bytes handed to the file so far (an open chunk counts once it closes).
    fn mcap_bytes(&self) -> u64 {
        self.bytes.load(Ordering::Relaxed)
    }
}

/// Free bytes for an unprivileged writer on the file system holding `path`.
fn free_bytes(path: &Path) -> Option<u64> {
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let c = std::ffi::CString::new(dir.as_os_str().as_encoded_bytes()).ok()?;
    let mut s: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: a NUL-terminated path and a valid statvfs to fill.
    (unsafe { libc::statvfs(c.as_ptr(), &mut s) } == 0).then(|| s.f_bavail as u64 * s.f_frsize as u64)
}

/// CPU time of the calling thread (s).
pub fn thread_cpu_s() -> f64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: valid pointer to a timespec.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}
