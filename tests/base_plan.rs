//! A moving base commanded by the print's progress (`[base] plan`, `BaseCommand`), driven through
//! `Controller::step` with a base that is where its setpoint puts it: the base moves with the
//! nozzle, stands with it through a pause, slows with it under a feed override, and a second job
//! waits on the path's first point until the base is back at the plan's start. Every tick checks the
//! joint limits and the base's own.

mod common;

use common::cell::{Cell, IIWA_START, check_limits, config, square_job};
use strand_core::BaseMode;
use strand_ipc::{BaseCommand, Command, JobOutcome, RunState};

const ORIGIN: [f64; 3] = [0.45, -0.02, 0.2];
/// The plan: 20 mm along x over the 0.16 m square (0.125 m of base a metre of path).
const BASE_PER_PATH: f64 = 0.125;

fn planned_cell() -> (Cell, [f64; 2]) {
    let cfg = config(|c| {
        c.base.mode = BaseMode::Tracked;
        let [x, y, _] = c.base.mount_xyz;
        let yaw = c.base.mount_rpy[2];
        c.base.plan = vec![[0.0, x, y, yaw], [0.16, x + 0.16 * BASE_PER_PATH, y, yaw]];
    });
    let mount = [cfg.base.mount_xyz[0], cfg.base.mount_xyz[1]];
    let mut cell = Cell::new(&cfg, &IIWA_START);
    cell.base_follows_command = true;
    // The tracker's first samples before anything starts (a tracked base without one faults
    // TrackingLost on Start).
    for _ in 0..10 {
        cell.step();
    }
    (cell, mount)
}

/// One tick, its limits checked (the base's: 0.1 m/s, 0.02 m/s², the defaults).
fn step(cell: &mut Cell) -> BaseCommand {
    let before = cell.last.map(|o| o.base_command);
    let out = cell.step();
    check_limits(cell.ctl.model(), &out);
    let b = out.base_command;
    assert_eq!(b.valid, 1);
    let speed = b.velocity[0].hypot(b.velocity[1]);
    assert!(speed <= 0.1 + 1e-12, "tick {}: base at {speed} m/s", b.tick);
    if let Some(a) = before {
        let accel = (b.velocity[0] - a.velocity[0]).hypot(b.velocity[1] - a.velocity[1]) / (cell.dt_ns as f64 * 1e-9);
        assert!(accel <= 0.02 * (1.0 + 1e-6), "tick {}: base at {accel} m/s²", b.tick);
    }
    b
}

fn run_until(cell: &mut Cell, max: u64, mut until: impl FnMut(&Cell, &BaseCommand) -> bool) -> BaseCommand {
    for _ in 0..max {
        let b = step(cell);
        if until(cell, &b) {
            return b;
        }
    }
    panic!(
        "not reached in {max} ticks (state {:?}, fault {:?})",
        cell.state(),
        strand_ipc::FaultCode::from_u32(cell.last.unwrap().status.fault)
    );
}

#[test]
fn the_base_moves_with_the_print_stands_with_a_pause_and_slows_with_the_feed() {
    let (mut cell, mount) = planned_cell();
    cell.send(&square_job(1, ORIGIN, 0.04, 1, 0.03));
    cell.control(Command::Start, 0.0);
    // On the path, a quarter of the way: the base is where the plan has it at this progress, and
    // moves at the plan's slope times the path's speed (30 mm/s → 3.75 mm/s).
    let b = run_until(&mut cell, 60_000, |_, b| b.progress >= 0.06);
    let planned = mount[0] + BASE_PER_PATH * b.progress;
    assert!((b.position[0] - planned).abs() < 0.2e-3 && b.lag < 0.2e-3, "base at {} for {planned}, lag {}", b.position[0], b.lag);
    assert!((b.velocity[0] - BASE_PER_PATH * 0.03).abs() < 0.05e-3, "base at {} m/s", b.velocity[0]);
    // A pause: the base stops with the nozzle, and stays, however long the pause.
    cell.control(Command::Pause, 0.0);
    run_until(&mut cell, 10_000, |c, _| c.state() == RunState::Paused);
    let held = run_until(&mut cell, 10_000, |_, b| b.velocity[0] == 0.0 && b.velocity[1] == 0.0);
    for _ in 0..20_000 {
        let b = step(&mut cell);
        assert_eq!((b.position, b.progress), (held.position, held.progress), "the base moved in a pause");
    }
    assert!(held.lag < 0.5e-3, "stopped {} mm off the plan", held.lag * 1e3);
    // Resumed at half the feed: half the base's speed.
    cell.control(Command::FeedOverride, 0.5);
    cell.control(Command::Resume, 0.0);
    let from = held.progress + 0.03;
    let b = run_until(&mut cell, 20_000, |_, b| b.progress >= from);
    assert!((b.velocity[0] - BASE_PER_PATH * 0.015).abs() < 0.05e-3, "base at {} m/s at half the feed", b.velocity[0]);
    // The job ends with the base at the plan's end.
    run_until(&mut cell, 60_000, |c, _| c.state() == RunState::Idle);
    assert_eq!(cell.last.unwrap().status.job_outcome, JobOutcome::Finished as u32);
    let end = run_until(&mut cell, 10_000, |_, b| b.lag < 1e-6 && b.velocity[0] == 0.0);
    // (The blended corners make the path a little shorter than the programmed 0.16 m.)
    assert!(end.progress > 0.159 && end.progress <= 0.16, "the path ended at {} m", end.progress);
    assert!((end.position[0] - (mount[0] + BASE_PER_PATH * end.progress)).abs() < 2e-6, "base ends at {}", end.position[0]);
}

#[test]
fn a_second_job_waits_on_its_first_point_for_the_base_to_return() {
    let (mut cell, mount) = planned_cell();
    cell.send(&square_job(1, ORIGIN, 0.04, 1, 0.03));
    cell.control(Command::Start, 0.0);
    run_until(&mut cell, 60_000, |c, b| c.state() == RunState::Idle && b.lag < 1e-6);
    // The same square again, at once: the tool is on its first point already, but the base is
    // 20 mm down the plan. The path starts only once the setpoint is back at the plan's start.
    cell.send(&square_job(100, ORIGIN, 0.04, 1, 0.03));
    cell.control(Command::Start, 0.0);
    let started = run_until(&mut cell, 60_000, |c, _| c.last.unwrap().status.path_speed > 0.0);
    let tolerance = config(|_| {}).controller.approach_position_tolerance;
    assert!(started.lag <= tolerance, "the path started with the base {} mm from the plan's start", started.lag * 1e3);
    assert!((started.position[0] - mount[0]).abs() <= tolerance + 1e-9, "{}", started.position[0]);
    run_until(&mut cell, 60_000, |c, _| c.state() == RunState::Idle);
    assert_eq!(cell.last.unwrap().status.job_outcome, JobOutcome::Finished as u32);
}

#[test]
fn a_job_resumed_after_a_fault_goes_on_along_the_base_plan_from_where_it_resumes() {
    let (mut cell, mount) = planned_cell();
    let job = square_job(1, ORIGIN, 0.04, 1, 0.03);
    cell.send(&job);
    cell.control(Command::Start, 0.0);
    // Halfway round, an emergency stop: the base brakes with the arm, then the fault is cleared.
    run_until(&mut cell, 60_000, |_, b| b.progress >= 0.07);
    cell.control(Command::EmergencyStop, 0.0);
    run_until(&mut cell, 20_000, |c, b| c.state() == RunState::Fault && b.velocity[0] == 0.0);
    cell.control(Command::ClearFault, 0.0);
    run_until(&mut cell, 10, |c, _| c.state() == RunState::Idle);
    // Resumed at segment 4 (the third side) as strand-feed --resume-from 4 sends it: a travel
    // (numbered 3) to where segment 4 starts, then 4 and 5, and the path before segment 4 past the
    // leading travel (two sides, 0.08 m) as the progress offset.
    let mut resumed = vec![common::cell::line(3, job[2].end, 0.1, 0.0)];
    resumed.extend_from_slice(&job[3..]);
    cell.send(&resumed);
    cell.control(Command::ProgressOffset, 0.08);
    cell.control(Command::Start, 0.0);
    // The path starts only once the base's setpoint is where the plan has it at 0.08 m, not back
    // at its start.
    let started = run_until(&mut cell, 60_000, |c, _| c.last.unwrap().status.path_speed > 0.0);
    let tolerance = config(|_| {}).controller.approach_position_tolerance;
    let planned = mount[0] + BASE_PER_PATH * 0.08;
    assert!((started.progress - 0.08).abs() < 1e-9, "resumed at {} m of the plan", started.progress);
    assert!((started.position[0] - planned).abs() <= tolerance + 1e-9, "base at {} for {planned}", started.position[0]);
    run_until(&mut cell, 60_000, |c, _| c.state() == RunState::Idle);
    assert_eq!(cell.last.unwrap().status.job_outcome, JobOutcome::Finished as u32);
    let end = run_until(&mut cell, 10_000, |_, b| b.lag < 1e-6 && b.velocity[0] == 0.0);
    assert!(end.progress > 0.159 && end.progress <= 0.16, "the plan ended at {} m", end.progress);
    // The offset held for that job only: a ProgressOffset is refused while a job runs, and the
    // next job starts at the plan's start again.
    cell.send(&square_job(200, ORIGIN, 0.04, 1, 0.03));
    cell.control(Command::Start, 0.0);
    let b = run_until(&mut cell, 60_000, |c, _| c.last.unwrap().status.path_speed > 0.0);
    assert!(b.progress < 1e-3, "a new job at {} m of the plan", b.progress);
    cell.control(Command::ProgressOffset, 0.05);
    let out = cell.step();
    assert!(
        out.events().iter().any(|e| matches!(e, strand_core::Event::ControlRejected { reason: strand_ipc::RejectReason::NotAllowed, .. }))
    );
}
