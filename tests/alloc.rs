//! The per-tick kinematics path does not touch the heap: a counting global allocator sees zero
//! allocations over 10,000 CLIK steps (FK, Jacobian, SVD, gradient, limits) on the 7-axis iiwa and on
//! the 6-axis VP6242 in the 5-D task, none in FK or the gradient alone, and none on the rare paths:
//! joints saturating at their limits (re-solves), NaN targets (braking) and repaired joint input;
//! and none in a whole controller tick with its log record queued, with and without the live view
//! streaming to a connected Foxglove client; and none in whole runner ticks, iceoryx2 ports included.

mod common;
#[path = "common/paths.rs"]
mod paths;

use nalgebra::UnitQuaternion;
use strand_core::kin::{ChainState, Clik, ClikConfig, Task, TaskJacobian, TcpTarget, manipulability_gradient};

#[path = "common/counting.rs"]
mod counting;
use counting::allocations;

#[global_allocator]
static GLOBAL: counting::Counting = counting::Counting;

#[test]
fn ten_thousand_clik_steps_allocate_nothing() {
    let probe = allocations();
    std::hint::black_box(vec![1u8; 16]);
    assert!(allocations() > probe, "the counting allocator must see a Vec");
    for (name, task) in [("iiwa7", Task::Pose6), ("iiwa7", Task::Print5), ("vp6242", Task::Print5)] {
        let model = common::robot(name);
        let q0 = model.middle_configuration() + nalgebra::SVector::<f64, 8>::from_fn(|i, _| if i < model.dof() { 0.3 } else { 0.0 });
        let start = model.forward_kinematics(&q0);
        let orient = UnitQuaternion::from_rotation_matrix(&start.rotation);
        let shape = paths::Shape::Circle { a: nalgebra::Vector3::x(), b: nalgebra::Vector3::y(), radius: 0.02 };
        // Targets computed before counting.
        let targets: Vec<TcpTarget> = (0..10_000)
            .map(|k| {
                let (p, v) = paths::sample(shape, start.translation.vector, (k + 1) as f64 * 1e-3, 10.0);
                TcpTarget { position: p, orientation: orient, linear_velocity: v, angular_velocity: nalgebra::Vector3::zeros() }
            })
            .collect();
        let mut solver = Clik::new(ClikConfig { task, ..ClikConfig::default() }).unwrap();
        let mut q = q0;
        let before = allocations();
        for target in &targets {
            let step = solver.step(&model, &q, target, 1e-3);
            q = step.q;
        }
        let during = allocations() - before;
        assert_eq!(during, 0, "{name} {task:?}: {during} allocations in 10,000 CLIK steps");
        assert!(q.iter().all(|x| x.is_finite()));

        let before = allocations();
        let mut state = ChainState::new(model.dof());
        for _ in 0..1000 {
            model.kinematics(&q, &mut state);
            let tj = TaskJacobian::new(&state, task);
            let svd = tj.svd();
            std::hint::black_box(manipulability_gradient(&state, &tj, &svd));
        }
        assert_eq!(allocations() - before, 0, "{name}: FK/Jacobian/gradient allocated");
    }
}

#[test]
fn the_rare_paths_allocate_nothing_either() {
    let model = common::robot("vp6242");
    let upper = model.limits(0).upper;
    let q0 = common::jv(&[upper - 0.2, 0.3, 1.7, 0.3, 0.9, 0.2]);
    let mut qt = q0;
    qt[0] = upper + 0.3;
    let past = model.forward_kinematics(&qt);
    let past_limit = TcpTarget::at_rest(past.translation.vector, UnitQuaternion::from_rotation_matrix(&past.rotation));
    let mut nan = past_limit;
    nan.position.x = f64::NAN;
    let mut solver = Clik::new(ClikConfig { task: Task::Pose6, ..ClikConfig::default() }).unwrap();
    let mut q = q0;
    let (mut saturations, mut invalid) = (0, 0);
    let before = allocations();
    for k in 0..4000 {
        let target = if (3000..3500).contains(&k) { &nan } else { &past_limit };
        let mut input = q;
        if k == 3600 {
            input[2] = f64::NAN;
        }
        let step = solver.step(&model, &input, target, 1e-3);
        saturations += usize::from(step.saturated != 0);
        invalid += usize::from(step.status.invalid_input);
        q = step.q;
    }
    assert_eq!(allocations() - before, 0, "allocations on the saturation / invalid-input paths");
    assert!(saturations > 100 && invalid == 501, "paths not reached: {saturations} saturated, {invalid} invalid");
}

#[test]
fn path_engine_and_extruder_ticks_allocate_nothing() {
    use nalgebra::Vector3;
    use strand_core::{Extruder, ExtruderConfig};
    use strand_core::{PathConfig, PathEngine, PlanningMode};
    use strand_job::gcode::{GcodeOptions, parse_file};
    let file = strand_testkit::root().join("tests/data/gcode/slic3r/vase_cyl_spiral.gcode");
    // The first 3,000 segments, read before counting; fed under back-pressure while counting.
    let segments: Vec<_> = parse_file(&file, GcodeOptions::for_path(&file)).unwrap().take(3000).map(|s| s.unwrap().segment).collect();
    for mode in [PlanningMode::Lookahead, PlanningMode::KnowledgeRules, PlanningMode::StopAndGo] {
        let config = PathConfig { mode, queue_capacity: 256, ..PathConfig::default() };
        let mut engine = PathEngine::new(&config, 1e-3, Vector3::zeros(), segments[0].orientation).unwrap();
        let mut extruder = Extruder::new(&ExtruderConfig::default(), 1e-3).unwrap();
        let mut next = 0;
        let before = allocations();
        for tick in 0..60_000 {
            while next < segments.len() && engine.free_space() > 0 {
                engine.push(&segments[next]).unwrap();
                next += 1;
            }
            if tick == 20_000 {
                engine.set_feed_override(0.6);
            }
            // The program's M190/M109 are heat waits: no heaters here, released at once.
            engine.release_wait();
            let sample = engine.step(if (30_000..30_200).contains(&tick) { 0.7 } else { 1.0 });
            std::hint::black_box(extruder.step(&sample));
        }
        let during = allocations() - before;
        assert_eq!(during, 0, "{mode:?}: {during} allocations in 60,000 path ticks");
        assert!(engine.stats().replans > 100, "{mode:?}: the planner did not run");
    }
}

#[test]
fn controller_steps_allocate_nothing() {
    let dir = std::env::temp_dir().join(format!("strand-alloc-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let total = counted_cell_ticks(Some(&dir.join("a.mcap")), None);
    assert_eq!(total, 0, "allocations inside Controller::step and Logger::push");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The same ticks with the live view on and a Foxglove client (tungstenite, `foxglove.sdk.v1`)
/// subscribed to every channel: the view is fed by the writer thread, so the tick side still
/// allocates nothing — and the client did receive the stream while the ticks were counted.
#[test]
fn controller_steps_allocate_nothing_with_a_live_viewer() {
    use std::sync::Arc;
    use std::sync::atomic::{AtomicU64, Ordering};
    let options = strand_view::ViewOptions { address: "127.0.0.1:0".parse().unwrap(), name: "alloc test".into(), control: None };
    let view = strand_view::LiveView::start(&options).unwrap();
    let url = format!("ws://{}", view.address());
    let received = Arc::new(AtomicU64::new(0));
    let counter = received.clone();
    let client = std::thread::spawn(move || {
        use tungstenite::client::IntoClientRequest;
        let mut request = url.into_client_request().unwrap();
        request.headers_mut().insert("Sec-WebSocket-Protocol", "foxglove.sdk.v1".parse().unwrap());
        let (mut ws, _) = tungstenite::connect(request).unwrap();
        let mut next_sub = 1;
        loop {
            match ws.read() {
                Ok(tungstenite::Message::Text(t)) => {
                    let v: serde_json::Value = serde_json::from_str(t.as_str()).unwrap();
                    if v["op"] == "advertise" {
                        let subs: Vec<_> = v["channels"]
                            .as_array()
                            .unwrap()
                            .iter()
                            .map(|c| {
                                next_sub += 1;
                                serde_json::json!({"id": next_sub, "channelId": c["id"]})
                            })
                            .collect();
                        let msg = serde_json::json!({"op": "subscribe", "subscriptions": subs}).to_string();
                        ws.send(tungstenite::Message::Text(msg.into())).unwrap();
                    }
                }
                Ok(tungstenite::Message::Binary(b)) if b.first() == Some(&1) => {
                    counter.fetch_add(1, Ordering::Relaxed);
                }
                Ok(_) => {}
                Err(_) => return,
            }
        }
    });
    let total = counted_cell_ticks(None, Some(view));
    assert_eq!(total, 0, "allocations inside Controller::step and Logger::push with the live view on");
    let _ = client.join();
    assert!(received.load(Ordering::Relaxed) > 1000, "the viewer received {} messages", received.load(Ordering::Relaxed));
}

/// `Controller::step` allocates nothing in a cell with a rotary table (`cells/kr6-turntable`):
/// segments that turn the table (a quarter circle around its axis, each point paired with its
/// angle), a move of the table alone (a dwell), the approach moving arm and table together, the
/// path with the work carried, pause, resume, feed override, stop and an emergency stop.
#[test]
fn controller_steps_with_a_turning_table_allocate_nothing() {
    use common::cell::Cell;
    use strand_ipc::{Command, segment_flags};
    let cfg = strand::config::Config::load(&strand_testkit::root().join("config/cells/kr6-turntable.toml")).unwrap();
    let mut cell = Cell::new(&cfg, &cfg.service.initial_joints);
    let point = |a: f64| [0.7 - 0.03 * a.cos(), -0.03 * a.sin(), 0.2503];
    let segment =
        |seq: u64, end: [f64; 3], table: f64, filament: f64| strand_testkit::line_with_axes(seq, end, [table, 0.0], 0.02, filament);
    let mut job = vec![segment(1, [0.67, 0.0, 0.2553], 0.3, 0.0), segment(2, point(0.0), 0.3, 0.0)];
    for k in 1..=18 {
        let a = (k as f64 * 5.0).to_radians();
        job.push(segment(job.len() as u64 + 1, point(a), 0.3 - a, 1e-4));
    }
    // The table alone, a quarter turn back, the nozzle on its point of the part.
    job.push(segment(job.len() as u64 + 1, point(std::f64::consts::FRAC_PI_2), 0.3, 0.0));
    job.last_mut().unwrap().flags |= segment_flags::LAST;
    let mut total = 0usize;
    let mut states = std::collections::BTreeSet::new();
    for k in 0..20_000u64 {
        match k {
            0 => cell.send(&job),
            10 => cell.control(Command::Start, 0.0),
            1500 => cell.control(Command::Pause, 0.0),
            1800 => cell.control(Command::Resume, 0.0),
            1900 => cell.control(Command::FeedOverride, 0.5),
            9000 => {
                let mut again = job.clone();
                for (i, s) in again.iter_mut().enumerate() {
                    s.seq = 100 + i as u64;
                }
                cell.send(&again);
                cell.control(Command::Start, 0.0);
            }
            11_000 => cell.control(Command::Stop, 0.0),
            14_000 => cell.control(Command::EmergencyStop, 0.0),
            _ => {}
        }
        let input = cell.input();
        let before = allocations();
        let out = cell.ctl.step(&input);
        total += allocations() - before;
        cell.q_robot = out.joint_command.position;
        cell.tick += 1;
        states.insert(cell.state() as u32);
    }
    assert_eq!(total, 0, "allocations inside Controller::step with a turning table");
    for s in [strand_ipc::RunState::Approaching, strand_ipc::RunState::Running, strand_ipc::RunState::Paused, strand_ipc::RunState::Fault] {
        assert!(states.contains(&(s as u32)), "never in {s:?}: {states:?}");
    }
    assert!(cell.last.is_none_or(|o| o.joint_command.dof == 7));
}

/// `Controller::step` allocates nothing over a whole job on a tracked base: intake, approach (IK and
/// the joint-space trajectory), running with base correction, pause, resume, feed override, stop, a
/// second job, emergency stop, fault and clear.
fn counted_cell_ticks(file: Option<&std::path::Path>, view: Option<strand_view::LiveView>) -> usize {
    use common::cell::{Cell, IIWA_START, config, square_job};
    use strand_ipc::{BasePose, Command, RunState};
    // A tracked base with a plan by progress: its setpoint and `BaseCommand` are counted too. And
    // the heaters: measured every tick, the job opening with an `M109 S210` wait (the hot end at
    // 209 °C: 0.5 s of settling) and switching the bed on.
    let cfg = config(|c| {
        c.base.mode = strand_core::BaseMode::Tracked;
        let [x, y, _] = c.base.mount_xyz;
        c.base.plan = vec![[0.0, x, y, 0.0], [0.2, x + 0.01, y, 0.0]];
        c.extruder.heater = strand_core::HeaterSource::Wire;
        c.extruder.temperature_settle_time = 0.5;
    });
    let mut cell = Cell::new(&cfg, &IIWA_START);
    let mut plant = strand_core::ThermalModel::new(&cfg.thermal);
    (plant.hot_end.block, plant.hot_end.sensor) = (209.0, 209.0);
    let heat = |seq: u64, bed: bool, wait: strand_ipc::HeatWait, target: f64| strand_ipc::Segment {
        seq,
        kind: strand_ipc::SegmentKind::Heat as u32,
        orientation: common::cell::DOWN,
        heater: bed as u32,
        heat_wait: wait as u32,
        temperature: target,
        ..Default::default()
    };
    let mut job = vec![heat(1, false, strand_ipc::HeatWait::Heating, 210.0), heat(2, true, strand_ipc::HeatWait::None, 60.0)];
    job.extend(square_job(3, [0.45, -0.02, 0.2], 0.03, 3, 0.04));
    let second = square_job(100, [0.45, -0.02, 0.2], 0.02, 1, 0.04);
    // The log's tick side runs in the same ticks (its writer thread allocates as it likes).
    let model = cfg.robot.build_model().unwrap();
    let log_cfg = strand::log::LogConfig { queue_ticks: 65536, ..Default::default() };
    let logger = strand::log::writer::Logger::start_with(&log_cfg, strand::log::writer::LogContext::new(&cfg, &model), file, view).unwrap();
    let timing = strand::log::messages::TickTiming::default();
    let mut total = 0usize;
    let mut states = std::collections::BTreeSet::new();
    let mut heat_held = false;
    for k in 0..30_000u64 {
        match k {
            0 => cell.send(&job),
            10 => cell.control(Command::Start, 0.0),
            4000 => cell.control(Command::Pause, 0.0),
            4500 => cell.control(Command::Resume, 0.0),
            5000 => cell.control(Command::FeedOverride, 0.5),
            7000 => cell.control(Command::Stop, 0.0),
            9000 => {
                cell.send(&second);
                cell.control(Command::Start, 0.0);
            }
            12_000 => cell.control(Command::EmergencyStop, 0.0),
            14_000 => cell.control(Command::ClearFault, 0.0),
            _ => {}
        }
        if k % 5 == 0 {
            let t = cell.now_ns();
            cell.poses.push(BasePose { seq: k + 1, stamp_ns: t, position: [1e-7 * k as f64, 0.0, 0.0], orientation: [1.0, 0.0, 0.0, 0.0] });
        }
        cell.heater_state = Some(plant.state(k + 1, cell.now_ns()));
        let input = cell.input();
        let before = allocations();
        let out = cell.ctl.step(&input);
        logger.push(&input, &out, &timing);
        total += allocations() - before;
        plant.step(out.heater.hot_end_target, out.heater.bed_target, 1e-3);
        heat_held |= out.status.heat_hold != 0;
        cell.q_robot = out.joint_command.position;
        cell.tick += 1;
        states.insert(cell.state() as u32);
    }
    for s in [
        RunState::Approaching,
        RunState::Running,
        RunState::Pausing,
        RunState::Paused,
        RunState::Stopping,
        RunState::EmergencyStopping,
        RunState::Fault,
        RunState::Idle,
    ] {
        assert!(states.contains(&(s as u32)), "never in {s:?}: {states:?}");
    }
    assert!(heat_held, "the job held at its heat wait");
    let recorded = file.is_some();
    let report = logger.finish();
    if recorded {
        assert_eq!(report.ticks_written + report.drops, 30_000);
    } else {
        assert_eq!((report.ticks_written, report.drops), (0, 0), "a view-only writer writes no file and loses nothing");
    }
    total
}

/// Whole runner ticks allocate nothing: `Runner::run` on the timer clock at 1 kHz, its iceoryx2 ports
/// live, a feeder thread streaming a job within its credit and starting it, joint states echoed.
/// Each tick's count spans one record to the next: the wait, the drain of every subscriber, the
/// step, the three publishes, the status notify, the sink and the event logging. Only a peer's
/// arrival costs allocations (iceoryx2 connects to its ports at the next receive or publish after
/// they appear): so the feeder opens its ports before the run, and the count starts at the end of the
/// first tick.
#[test]
fn whole_runner_ticks_allocate_nothing() {
    use common::cell::{IIWA_START, config, square_job};
    use std::sync::atomic::{AtomicBool, Ordering};
    use strand::io::clock::ClockMode;
    use strand::io::rt::RealtimeConfig;
    use strand::io::runner::{JointFeedback, Runner, StopWhen, TickSink, TickTiming};
    use strand_core::{TickInput, TickOutput};
    use strand_ipc::ports::{ClientPorts, ClientRoles};
    use strand_ipc::{Command, Control, JobOutcome, SegmentBatch, ServiceNames};

    /// Allocations between consecutive records, in room reserved up front.
    struct PerTick {
        last: Option<usize>,
        counts: Vec<usize>,
    }
    impl TickSink for PerTick {
        fn record(&mut self, _: &TickInput, _: &TickOutput, _: &TickTiming) {
            let now = allocations();
            if let Some(last) = self.last
                && self.counts.len() < self.counts.capacity()
            {
                self.counts.push(now - last);
            }
            self.last = Some(allocations());
        }
    }

    let prefix = format!("strand/test-alloc-runner-{}", std::process::id());
    let cfg = config(|c| {
        c.service.prefix = prefix.clone();
        c.service.clock = ClockMode::Timer;
        c.service.joint_feedback = JointFeedback::Echo;
        c.service.initial_joints = IIWA_START.to_vec();
        c.controller.rate_hz = 1000.0;
    });
    let job = square_job(1, [0.45, -0.02, 0.2], 0.02, 1, 0.04);
    let (first, last) = (job[0].seq, job[job.len() - 1].seq);
    let model = cfg.robot.build_model().unwrap();
    let controller = strand_core::Controller::new(&cfg.controller_settings(), model).unwrap();
    let mut runner = Runner::new(controller, &cfg.service, cfg.controller.joint_state_timeout, cfg.controller.rate_hz).unwrap();
    let mut sink = PerTick { last: None, counts: Vec::with_capacity(20_000) };
    let stop = AtomicBool::new(false);
    let feeder_done = AtomicBool::new(false);
    let feeder_open = std::sync::Barrier::new(2);
    let summary = std::thread::scope(|scope| {
        scope.spawn(|| {
            let roles = ClientRoles { feeder: true, control: true, monitor: true, ..Default::default() };
            let client = ClientPorts::open(&ServiceNames::new(&prefix), "test-feeder", roles).unwrap();
            feeder_open.wait();
            let (mut sent, mut started, mut batch_seq) = (0usize, false, 0u64);
            while !feeder_done.load(Ordering::Relaxed) {
                let status = client.latest_status().unwrap_or_default();
                let ours = started && (first..=last).contains(&status.last_received_seq);
                let allowed = (if ours { status.last_received_seq - first + 1 } else { 0 } + status.queue_free as u64) as usize;
                while sent < allowed.min(job.len()) {
                    let k = (allowed.min(job.len()) - sent).min(strand_ipc::SEGMENT_BATCH_CAPACITY);
                    batch_seq += 1;
                    let mut batch = SegmentBatch { seq: batch_seq, len: k as u32, ..Default::default() };
                    batch.segments[..k].copy_from_slice(&job[sent..sent + k]);
                    client.send_segments(&batch).unwrap();
                    sent += k;
                }
                if !started && sent > 0 {
                    client.send_control(&Control { seq: 1, command: Command::Start as u32, ..Default::default() }).unwrap();
                    started = true;
                }
                std::thread::sleep(std::time::Duration::from_millis(2));
            }
        });
        feeder_open.wait();
        let when = StopWhen { max_ticks: Some(20_000), job_done: true };
        let summary = runner.run(&RealtimeConfig::default(), &stop, when, &mut sink);
        feeder_done.store(true, Ordering::Relaxed);
        summary.unwrap()
    });
    assert_eq!(summary.status.job_outcome, JobOutcome::Finished as u32, "the job did not finish: {:?}", summary.status);
    let counts = &sink.counts;
    let allocating: Vec<(usize, usize)> = counts.iter().copied().enumerate().filter(|(_, n)| *n > 0).collect();
    let total: usize = counts.iter().sum();
    eprintln!("{} ticks counted, {total} allocations, in ticks {allocating:?}", counts.len());
    assert!(counts.len() > 1000, "{} ticks", counts.len());
    assert_eq!(total, 0, "{} of {} runner ticks allocated: {allocating:?}", allocating.len(), counts.len());
}
