//! A cell with a positioner under the part (`cells/kr6-turntable`: a KR 6 and a rotary table),
//! driven through `Controller::step` with a robot and a table that follow their commands exactly.
//! The job is built here from its formula (a helix around the table's axis, each point paired with
//! the table angle that turns it to the same place beside the table), not read by the G-code
//! parser: what is tested is the controller's side. Every tick checks the arm's and the table's
//! limits and where the nozzle is *on the part*.

mod common;

use common::cell::{Cell, check_limits};
use nalgebra::{UnitQuaternion, Vector3};
use strand::config::Config;
use strand_core::kin::JointVector;
use strand_core::{Event, TickOutput, distance_to_segment};
use strand_ipc::{self as ipc, Command, JobOutcome, RejectReason, RunState, segment_flags};
use strand_testkit::root;

/// The table's axis in W (m) and the plate's top (cells/kr6-turntable.toml, robots/kr6-turntable.urdf).
const AXIS: [f64; 2] = [0.7, 0.0];
const PLATE_Z: f64 = 0.25;
const RADIUS: f64 = 0.03;
const LAYER: f64 = 0.3e-3;
const FEED: f64 = 0.02;
/// Filament per metre of a 0.5 × 0.3 mm bead of 1.75 mm filament (m/m).
const FLOW: f64 = 0.5e-3 * 0.3e-3 / (std::f64::consts::PI * 0.875e-3 * 0.875e-3);

fn turntable_config() -> Config {
    Config::load(&root().join("config/cells/kr6-turntable.toml")).unwrap_or_else(|e| panic!("{e}"))
}

fn cell() -> Cell {
    let cfg = turntable_config();
    let mut cell = Cell::new(&cfg, &cfg.service.initial_joints);
    assert_eq!(cell.ctl.cell_dof(), 7, "six arm joints and the table");
    cell.step();
    cell
}

/// The helix point `turned` rad past the start (at 180° of the part, beside the table facing the
/// robot), on the part as it stands with the table at 0 (m, W).
fn helix(turned: f64) -> [f64; 3] {
    let a = std::f64::consts::PI + turned;
    [AXIS[0] + RADIUS * a.cos(), AXIS[1] + RADIUS * a.sin(), PLATE_Z + LAYER + LAYER * turned / std::f64::consts::TAU]
}

fn segment(seq: u64, end: [f64; 3], table: f64, feed: f64, filament: f64) -> ipc::Segment {
    strand_testkit::line_with_axes(seq, end, [table, 0.0], feed, filament)
}

/// A travel to 5 mm above the start and down onto it, then `turns` turns of the helix in 5° lines,
/// each with the table angle that brings its end back beside the table (−turned).
fn helix_job(turns: f64) -> Vec<ipc::Segment> {
    let start = helix(0.0);
    let mut job = vec![segment(1, [start[0], start[1], start[2] + 5e-3], 0.0, 0.05, 0.0), segment(2, start, 0.0, 0.01, 0.0)];
    let steps = (turns * 72.0).round() as usize;
    let mut before = start;
    for k in 1..=steps {
        let turned = (k as f64 * 5.0).to_radians();
        let end = helix(turned);
        let length = (Vector3::from(end) - Vector3::from(before)).norm();
        job.push(segment(job.len() as u64 + 1, end, -turned, FEED, length * FLOW));
        before = end;
    }
    job.last_mut().unwrap().flags |= segment_flags::LAST;
    job
}

/// The table's limits are kept: speed 2 rad/s, acceleration 4 rad/s² (the URDF and the robot file).
fn check_table(out: &TickOutput) {
    let jc = &out.joint_command;
    assert_eq!(jc.dof, 7);
    let (q, v, a) = (jc.position[6], jc.velocity[6], jc.acceleration[6]);
    assert!(q.is_finite() && v.abs() <= 2.0 * (1.0 + 1e-9), "tick {}: table at {v} rad/s", jc.tick);
    assert!(a.abs() <= 4.0 * (1.0 + 1e-6) + 1e-6, "tick {}: table at {a} rad/s²", jc.tick);
}

/// Where the commanded joints put the nozzle on the part (m, W, the work frame at home).
fn nozzle_on_part(cell: &Cell, out: &TickOutput) -> Vector3<f64> {
    let q = JointVector::from_fn(|i, _| if i < 6 { out.joint_command.position[i] } else { 0.0 });
    let f = cell.ctl.model().forward_kinematics(&q);
    let p = cell.ctl.positioner().expect("a positioner");
    p.to_home(&f.translation.vector, &UnitQuaternion::identity(), &[out.joint_command.position[6], 0.0]).0
}

#[test]
fn a_turntable_prints_a_helix_with_the_arm_nearly_still_and_the_nozzle_on_the_part() {
    let mut cell = cell();
    let turns = 3.0;
    let job = helix_job(turns);
    cell.send(&job);
    cell.control(Command::Start, 0.0);
    let (mut worst, mut worst_corner, mut worst_circle, mut on_path_ticks) = (0.0f64, 0.0f64, 0.0f64, 0u64);
    let (mut a1_min, mut a1_max) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut path_started: Option<u64> = None;
    let mut finished = None;
    for _ in 0..60_000 {
        let out = cell.step();
        check_limits(cell.ctl.model(), &out);
        check_table(&out);
        if out.status.run_state == RunState::Running as u32 && out.status.executing_seq >= 3 {
            path_started.get_or_insert(cell.tick);
            // The nozzle is on the program's 5° chords (within the corner blends' tolerance), on
            // the part, whatever the table's angle: the blends, tangent to the chords at their
            // middles, make one circle of R·cos(2.5°), 28.5 µm inside the corners. Once on the
            // helix it keeps to that circle.
            let at = nozzle_on_part(&cell, &out);
            let d = job
                .windows(2)
                .map(|w| distance_to_segment(&at, &Vector3::from(w[0].end), &Vector3::from(w[1].end)))
                .fold(f64::INFINITY, f64::min);
            let last_seq = job.len() as u64;
            if (4..last_seq).contains(&out.status.executing_seq) {
                let inscribed = RADIUS * 2.5f64.to_radians().cos();
                worst_circle = worst_circle.max(((at.x - AXIS[0]).hypot(at.y - AXIS[1]) - inscribed).abs());
                worst = worst.max(d);
            }
            worst_corner = worst_corner.max(d);
            on_path_ticks += 1;
            a1_min = a1_min.min(out.joint_command.position[0]);
            a1_max = a1_max.max(out.joint_command.position[0]);
        }
        if let Some(Event::JobEnded { outcome, .. }) = out.events().iter().find(|e| matches!(e, Event::JobEnded { .. })) {
            finished = Some((*outcome, cell.tick));
            break;
        }
    }
    let (outcome, end_tick) = finished.expect("the job ends");
    assert_eq!(outcome, JobOutcome::Finished);
    let last = cell.last.unwrap();
    // The table turned three times under the part (−3 turns: the part turns back under the nozzle).
    let table = last.joint_command.position[6];
    assert!((table + turns * std::f64::consts::TAU).abs() < 1e-9, "table at {table} rad");
    // On the part the nozzle kept within 28.6 µm of the helix's chords (their corners' cut), to
    // 1 µm on the circle the blends make (up to the last chord, which ends on its corner), and within 35 µm of the corner from the line down onto
    // the helix (its blend's `deviation_tolerance`: 0.05 mm from the corner).
    assert!(on_path_ticks > 1000);
    assert!(worst < 28.6e-6, "the nozzle left the helix on the part by {:.2} µm", worst * 1e6);
    assert!(worst_circle < 1e-6, "the nozzle left the blends' circle on the part by {:.2} µm", worst_circle * 1e6);
    assert!(worst_corner < 40e-6, "the nozzle left the path on the part by {:.1} µm", worst_corner * 1e6);
    // The arm hardly moves: the nozzle stays beside the table while the part turns under it (A1
    // turns 2·asin(sag / reach) at most: the chords' 0.03 mm sag half a metre out).
    assert!(a1_max - a1_min < 2e-3, "A1 moved {:.4} rad", a1_max - a1_min);
    // The print time is near the feed's bound: 3 turns of 188.5 mm at 20 mm/s on the part (28.3 s),
    // and the table's 4 rad/s² acceleration limits nothing at the 0.67 rad/s it turns.
    let path_s = (end_tick - path_started.unwrap()) as f64 * cell.dt_ns as f64 * 1e-9;
    let bound = turns * std::f64::consts::TAU * RADIUS / FEED;
    assert!(path_s < bound * 1.05 && path_s > bound * 0.99, "printed in {path_s:.2} s, the feed's bound is {bound:.2} s");
}

#[test]
fn a_move_of_the_table_alone_is_a_smooth_turn_with_the_nozzle_on_its_point_of_the_part() {
    let mut cell = cell();
    let start = helix(0.0);
    let quarter = std::f64::consts::FRAC_PI_2;
    // Down onto the point, then the table a quarter turn with the nozzle on the same point of the
    // part (a zero-length line that moves only the table: a dwell as long as the table needs).
    let mut job = vec![segment(1, [start[0], start[1], start[2] + 5e-3], 0.0, 0.05, 0.0), segment(2, start, 0.0, 0.01, 0.0)];
    job.push(segment(3, start, quarter, FEED, 0.0));
    job.last_mut().unwrap().flags |= segment_flags::LAST;
    cell.send(&job);
    cell.control(Command::Start, 0.0);
    let (mut worst, mut turning_ticks, mut peak_speed) = (0.0f64, 0u64, 0.0f64);
    let mut outcome = None;
    for _ in 0..20_000 {
        let out = cell.step();
        check_limits(cell.ctl.model(), &out);
        check_table(&out);
        if out.joint_command.position[6] > 1e-12 && out.status.run_state == RunState::Running as u32 {
            turning_ticks += 1;
            peak_speed = peak_speed.max(out.joint_command.velocity[6]);
            worst = worst.max((nozzle_on_part(&cell, &out) - Vector3::from(start)).norm());
        }
        if let Some(Event::JobEnded { outcome: o, .. }) = out.events().iter().find(|e| matches!(e, Event::JobEnded { .. })) {
            outcome = Some(*o);
            break;
        }
    }
    assert_eq!(outcome, Some(JobOutcome::Finished));
    assert!((cell.last.unwrap().joint_command.position[6] - quarter).abs() < 1e-9);
    assert!(worst < 20e-6, "the nozzle left its point of the part by {:.1} µm", worst * 1e6);
    // The smooth step within 2 rad/s and 4 rad/s²: peak speed 1.875·Δ/T, so T ≥ 1.47 s for π/2
    // by the speed and ≥ 1.09 s by the acceleration: about 370 ticks of 4 ms.
    assert!(peak_speed <= 2.0 && peak_speed > 0.9, "peak {peak_speed} rad/s");
    assert!(turning_ticks >= 360, "{turning_ticks} ticks");
}

#[test]
fn a_segment_that_turns_external_axes_is_refused_by_a_cell_without_them() {
    let mut cell = Cell::iiwa();
    cell.step();
    let mut s = common::cell::line(1, [0.5, 0.0, 0.3], 0.05, 0.0);
    s.flags |= segment_flags::AXES;
    s.axes = [0.3, 0.0];
    cell.send(&[s]);
    let out = cell.step();
    assert!(
        out.events().iter().any(|e| matches!(e, Event::SegmentRejected { seq: 1, reason: RejectReason::BadGeometry, field: "axes" })),
        "{:?}",
        out.events()
    );
}

#[test]
fn a_joint_state_without_the_table_is_refused_as_the_wrong_dof() {
    let cfg = turntable_config();
    let mut cell = Cell::new(&cfg, &cfg.service.initial_joints);
    cell.driver = false;
    let mut input = cell.input();
    input.joint_state = Some(ipc::JointState { seq: 1, dof: 6, ..Default::default() });
    let out = cell.ctl.step(&input);
    assert!(out.events().iter().any(|e| matches!(e, Event::JointStateRejected { reason: RejectReason::WrongDof, .. })));
}

/// A KR 6 on a 2 m linear track (`[track]`: a prismatic joint from the rail to the arm's base
/// link, along W's y) printing a 1.2 m line along the track, each segment carrying where the
/// track is: the track carries the arm along, the arm stands nearly still, the nozzle on the line in W.
#[test]
fn a_track_carries_the_arm_along_a_line_longer_than_its_reach() {
    let dir = strand_testkit::temp_dir("positioner", "track");
    let arm = std::fs::read_to_string(root().join("config/robots/kr6r900.urdf")).unwrap();
    let urdf = arm.replace(
        "<link name=\"base_link\"/>",
        "<link name=\"rail\"/><link name=\"base_link\"/>\n  <joint name=\"track_y\" type=\"prismatic\"><parent link=\"rail\"/><child link=\"base_link\"/>\n    <axis xyz=\"0 1 0\"/><limit effort=\"0\" lower=\"-0.1\" upper=\"2.0\" velocity=\"0.5\"/></joint>",
    );
    std::fs::write(dir.join("kr6-track.urdf"), urdf).unwrap();
    let robot = std::fs::read_to_string(root().join("config/robots/kr6r900.toml")).unwrap().replace("kr6r900.urdf", "kr6-track.urdf")
        + "\n[track]\nroot_link = \"rail\"\nlimits = { acceleration = [1.0], jerk = [10.0] }\n";
    std::fs::write(dir.join("kr6-track.toml"), robot).unwrap();
    let service = std::fs::read_to_string(root().join("config/kr6r900.toml"))
        .unwrap()
        .replace("robot = \"robots/kr6r900.toml\"", &format!("robot = \"{}\"", dir.join("kr6-track.toml").display()));
    std::fs::write(dir.join("service.toml"), service).unwrap();
    let cfg = Config::load(&dir.join("service.toml")).unwrap_or_else(|e| panic!("{e}"));
    let mut cell = Cell::new(&cfg, &cfg.service.initial_joints);
    assert_eq!(cell.ctl.cell_dof(), 7);
    assert_eq!(cell.ctl.positioner().unwrap().carries(), strand_core::Carries::Robot);
    cell.step();
    // From (0.5, 0) to (0.5, 1.2) m in W at 0.25 m up, the track keeping the arm's base level with
    // the nozzle (y), in 24 lines of 50 mm.
    let (x, z) = (0.5, 0.26);
    let mut job = vec![segment(1, [x, 0.0, z + 5e-3], 0.0, 0.05, 0.0), segment(2, [x, 0.0, z], 0.0, 0.01, 0.0)];
    for k in 1..=24 {
        let y = k as f64 * 0.05;
        job.push(segment(job.len() as u64 + 1, [x, y, z], y, FEED, 0.05 * FLOW));
    }
    job.last_mut().unwrap().flags |= segment_flags::LAST;
    cell.send(&job);
    cell.control(Command::Start, 0.0);
    let (mut worst, mut a1_min, mut a1_max, mut ticks) = (0.0f64, f64::INFINITY, f64::NEG_INFINITY, 0);
    let mut outcome = None;
    for _ in 0..40_000 {
        let out = cell.step();
        check_limits(cell.ctl.model(), &out);
        let (track, speed) = (out.joint_command.position[6], out.joint_command.velocity[6]);
        assert!(speed.abs() <= 0.5 * (1.0 + 1e-9) && (-0.1..=2.0).contains(&track), "track at {track} m, {speed} m/s");
        // From the second line on (the first begins with the blend of the corner from the line down).
        if out.status.run_state == RunState::Running as u32 && out.status.executing_seq >= 4 {
            // The nozzle in W: the arm's TCP where the track has carried the base.
            let at = nozzle_on_part(&cell, &out);
            worst = worst.max((at.x - x).hypot(at.z - z));
            a1_min = a1_min.min(out.joint_command.position[0]);
            a1_max = a1_max.max(out.joint_command.position[0]);
            ticks += 1;
        }
        if let Some(Event::JobEnded { outcome: o, .. }) = out.events().iter().find(|e| matches!(e, Event::JobEnded { .. })) {
            outcome = Some(*o);
            break;
        }
    }
    assert_eq!(outcome, Some(JobOutcome::Finished));
    let last = cell.last.unwrap();
    assert!((last.joint_command.position[6] - 1.2).abs() < 1e-9, "the track ended at {} m", last.joint_command.position[6]);
    assert!(ticks > 10_000, "{ticks} ticks on the line");
    // On the line to a micrometre, and the arm's A1 all but still (the track did the 1.2 m).
    assert!(worst < 1e-6, "the nozzle left the line by {:.2} µm", worst * 1e6);
    assert!(a1_max - a1_min < 1e-3, "A1 moved {:.4} rad", a1_max - a1_min);
}

/// The Cartesian following-error watchdog looks at the nozzle on the part: a table that stands
/// 0.1 rad behind its command (within `following_error_limit`, 0.2 rad), the arm exactly where it
/// was told, puts the nozzle 3 mm off the helix on the part, and `TcpErrorLimit` latches — in W
/// nothing is wrong, the arm being where its target is.
#[test]
fn a_table_that_lags_its_command_trips_the_tcp_error_watchdog_on_the_part() {
    let mut cell = cell();
    cell.send(&helix_job(1.0));
    cell.control(Command::Start, 0.0);
    let mut fault_tick = None;
    let mut lag_from = None;
    for _ in 0..20_000 {
        let on_helix = cell.last.is_some_and(|o| o.status.run_state == RunState::Running as u32 && o.status.executing_seq >= 10);
        if on_helix {
            lag_from.get_or_insert(cell.tick);
            cell.q_robot[6] -= 0.1;
        }
        let out = cell.step();
        if let Some(Event::Fault { code, value, .. }) = out.events().iter().find(|e| matches!(e, Event::Fault { .. })) {
            fault_tick = Some((cell.tick, *code, *value));
            break;
        }
    }
    let (tick, code, value) = fault_tick.expect("a fault");
    assert_eq!(code, ipc::FaultCode::TcpErrorLimit);
    assert!((2e-3..3.1e-3).contains(&value), "tripped at {:.2} mm", value * 1e3);
    // Within the lag allowance (0.1 s) and the time above the limit (0.05 s), plus a few ticks.
    let after = (tick - lag_from.unwrap()) as f64 * cell.dt_ns as f64 * 1e-9;
    assert!(after < 0.2, "tripped {after} s after the table fell behind");
}
