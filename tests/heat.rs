//! Temperatures through `Controller::step` (CELL item 2): a heat wait holds the job — no segment
//! after it executes — until the measured temperature has stayed within the tolerance for the
//! settle time; targets take effect where the job sets them; a cold hot end never extrudes
//! (`ColdExtrusion`); a silent heater is `TemperatureLost`; without a temperature source waits are
//! skipped and reported. The heaters are strand-core's thermal model, ticked beside the controller
//! as strand-sim ticks it.

mod common;

use common::cell::{Cell, IIWA_START, check_limits, config, square_job};
use strand_core::{Event, HeaterSource, ThermalConfig, ThermalModel, TickOutput};
use strand_ipc::{self as ipc, Command, FaultCode, HeatHold, JobOutcome, RunState, heater_flags};

const ORIGIN: [f64; 3] = [0.45, -0.02, 0.2];

/// A heat segment (°C).
fn heat(seq: u64, bed: bool, wait: ipc::HeatWait, target: f64) -> ipc::Segment {
    ipc::Segment {
        seq,
        kind: ipc::SegmentKind::Heat as u32,
        orientation: common::cell::DOWN,
        heater: if bed { ipc::Heater::Bed } else { ipc::Heater::HotEnd } as u32,
        heat_wait: wait as u32,
        temperature: target,
        temperature_range: [-273.15, 10_000.0],
        ..Default::default()
    }
}

/// A job: `before` heat segments, then the 4 cm square (travel + 4 extruding sides).
fn job_after(before: &[ipc::Segment]) -> Vec<ipc::Segment> {
    let mut job = before.to_vec();
    job.extend(square_job(before.len() as u64 + 1, ORIGIN, 0.04, 1, 0.03));
    job
}

/// A fast plant (τ 2 s toward 300 °C, sensor lag 0.2 s): 210 °C in about 2.4 s from 25 °C.
fn fast_thermal() -> ThermalConfig {
    let mut t = ThermalConfig::default();
    t.hot_end.time_constant = 2.0;
    t.hot_end.max_temperature = 300.0;
    t.hot_end.sensor_lag = 0.2;
    t.bed.time_constant = 3.0;
    t.bed.max_temperature = 120.0;
    t.bed.sensor_lag = 0.2;
    t
}

fn wire_cell(settle: f64) -> Cell {
    let cfg = config(|c| {
        c.extruder.heater = HeaterSource::Wire;
        c.extruder.temperature_settle_time = settle;
        c.extruder.temperature_tolerance = 3.0;
    });
    Cell::new(&cfg, &IIWA_START)
}

/// One tick with the plant: it measures, the controller steps, the plant follows the targets.
fn tick(cell: &mut Cell, plant: &mut ThermalModel) -> TickOutput {
    let seq = cell.tick + 1;
    cell.heater_state = Some(plant.state(seq, cell.now_ns()));
    let out = cell.step();
    check_limits(cell.ctl.model(), &out);
    plant.step(out.heater.hot_end_target, out.heater.bed_target, cell.dt_ns as f64 * 1e-9);
    out
}

#[test]
fn m109_holds_the_job_until_the_hot_end_has_settled() {
    let settle = 2.0;
    let mut cell = wire_cell(settle);
    let mut plant = ThermalModel::new(&fast_thermal());
    let job = job_after(&[heat(1, false, ipc::HeatWait::Heating, 210.0)]);
    cell.send(&job);
    cell.control(Command::Start, 0.0);
    let dt = cell.dt_ns as f64 * 1e-9;
    let settle_ticks = (settle / dt).round() as u64;
    // The tick from which the measured value stays within 210 ± 3 °C (reset on leaving).
    let mut in_band_from: Option<u64> = None;
    let mut first_after_wait: Option<u64> = None;
    let mut first_extruding: Option<u64> = None;
    let mut held_ticks = 0u64;
    let mut finished = false;
    for t in 0..60_000u64 {
        let measured = plant.hot_end.sensor;
        let out = tick(&mut cell, &mut plant);
        if (measured - 210.0).abs() <= 3.0 {
            in_band_from.get_or_insert(t);
        } else if first_after_wait.is_none() {
            in_band_from = None;
        }
        if out.status.heat_hold == HeatHold::HotEnd as u32 {
            held_ticks += 1;
            assert_eq!(out.status.heat_hold_band, [207.0, 213.0]);
            assert_eq!(out.status.hot_end_target, 210.0);
            assert_eq!(out.status.run_state, RunState::Running as u32);
            assert!(out.status.heat_hold_left >= 0.0 && out.status.heat_hold_left <= settle);
            assert_eq!(out.extruder.filament_rate, 0.0, "nothing extrudes during the wait");
        }
        if first_after_wait.is_none() && out.status.executing_seq > 1 {
            first_after_wait = Some(t);
        }
        if first_extruding.is_none() && out.extruder.filament_rate > 0.0 {
            first_extruding = Some(t);
        }
        if out.status.job_outcome == JobOutcome::Finished as u32 {
            finished = true;
            break;
        }
    }
    assert!(finished, "the job finishes after the wait");
    let (band, after, extruding) = (in_band_from.unwrap(), first_after_wait.unwrap(), first_extruding.unwrap());
    // The first segment after the wait starts only once the hot end has been in its band for the
    // settle time (the release is decided on the tick the settle completes, the path moves on the
    // next), and the first extrusion comes after that.
    assert!(after >= band + settle_ticks, "segment 2 began at tick {after}, in band from {band}, settle {settle_ticks}");
    assert!(after <= band + settle_ticks + 2, "and no later than the tick after the settle: {after} vs {band} + {settle_ticks}");
    assert!(extruding > after);
    eprintln!("in band from tick {band}, segment 2 at {after}, first extrusion at {extruding}, held {held_ticks} ticks");
    // Heat-up of the fast plant from 25 °C: about 2.4 s to the band, then 2 s settle.
    assert!(held_ticks as f64 * dt > 2.0 + settle * 0.9, "held {held_ticks} ticks");
    assert!(plant.hot_end.sensor > 205.0);
}

#[test]
fn pause_and_stop_work_during_a_wait() {
    let mut cell = wire_cell(1.0);
    let mut plant = ThermalModel::new(&fast_thermal());
    cell.send(&job_after(&[heat(1, true, ipc::HeatWait::Both, 60.0)]));
    cell.control(Command::Start, 0.0);
    let mut t = 0;
    while tick(&mut cell, &mut plant).status.heat_hold != HeatHold::Bed as u32 {
        t += 1;
        assert!(t < 20_000, "the bed wait begins");
    }
    cell.control(Command::Pause, 0.0);
    for _ in 0..200 {
        tick(&mut cell, &mut plant);
    }
    assert_eq!(cell.state(), RunState::Paused);
    assert!(plant.bed.duty > 0.0, "the bed heats while paused");
    cell.control(Command::Resume, 0.0);
    tick(&mut cell, &mut plant);
    assert_eq!(cell.state(), RunState::Running);
    cell.control(Command::Stop, 0.0);
    for _ in 0..500 {
        let out = tick(&mut cell, &mut plant);
        assert!(out.status.executing_seq <= 1, "nothing after the wait ran");
        if cell.state() == RunState::Idle {
            assert_eq!(out.status.job_outcome, JobOutcome::Stopped as u32);
            // A controlled stop keeps the heaters on (a resumed job continues hot).
            assert_eq!(out.heater.bed_target, 60.0);
            return;
        }
    }
    panic!("the stop ended the job");
}

#[test]
fn an_extruding_move_never_starts_below_min_extrude_temp() {
    let mut cell = wire_cell(1.0);
    // The hot end stays at 150 °C (below the default 170 °C); no wait in the job.
    cell.heater_state = Some(ipc::HeaterState {
        seq: 1,
        hot_end: 150.0,
        bed: 25.0,
        flags: heater_flags::HOT_END | heater_flags::BED,
        ..Default::default()
    });
    let job = job_after(&[heat(1, false, ipc::HeatWait::None, 210.0)]);
    cell.send(&job);
    cell.control(Command::Start, 0.0);
    let mut fault = None;
    for _ in 0..60_000 {
        let out = cell.step();
        check_limits(cell.ctl.model(), &out);
        assert!(out.extruder.filament_rate <= 0.0, "no extruder command > 0: {}", out.extruder.filament_rate);
        for e in out.events() {
            if let Event::Fault { code, seq, .. } = *e {
                fault = Some((code, seq));
            }
        }
        if cell.state() == RunState::Fault {
            break;
        }
    }
    let (code, seq) = fault.expect("a fault");
    assert_eq!(code, FaultCode::ColdExtrusion);
    assert_eq!(seq, 3, "at the first extruding segment (after the heat segment and the travel)");
    let out = cell.last.unwrap();
    assert_eq!(out.status.fault, FaultCode::ColdExtrusion as u32);
    assert_eq!(out.status.job_outcome, JobOutcome::Faulted as u32);
    assert_eq!(out.heater.hot_end_target, 0.0, "a fault turns the heaters off");
    // The arm stands.
    assert!(out.joint_command.velocity.iter().all(|v| *v == 0.0));
}

#[test]
fn a_silent_heater_at_a_wait_is_temperature_lost() {
    let mut cell = wire_cell(1.0);
    cell.send(&job_after(&[heat(1, false, ipc::HeatWait::Heating, 210.0)]));
    cell.control(Command::Start, 0.0);
    let out = cell.run_until(30_000, |o| o.status.fault != 0).expect("a fault");
    assert_eq!(out.status.fault, FaultCode::TemperatureLost as u32);
    assert!(out.status.executing_seq <= 1);
}

#[test]
fn without_a_heater_waits_are_skipped_and_reported_and_targets_follow_the_path() {
    let mut cell = Cell::iiwa();
    assert_eq!(config(|_| {}).extruder.heater, HeaterSource::None);
    let mut job = job_after(&[heat(1, false, ipc::HeatWait::Heating, 210.0), heat(2, true, ipc::HeatWait::None, 60.0)]);
    // The job's end switches the hot end off: it must not act before the last side has run.
    let last = job.len() as u64;
    job.last_mut().unwrap().flags &= !ipc::segment_flags::LAST;
    let mut off = heat(last + 1, false, ipc::HeatWait::None, 0.0);
    off.flags = ipc::segment_flags::LAST;
    job.push(off);
    cell.send(&job);
    cell.control(Command::Start, 0.0);
    let mut skipped = Vec::new();
    let mut finished = None;
    for _ in 0..60_000 {
        let out = cell.step();
        for e in out.events() {
            if let Event::HeatWaitSkipped { seq } = *e {
                skipped.push(seq);
            }
        }
        if out.status.executing_seq > 2 && out.status.executing_seq <= last && cell.state() == RunState::Running {
            assert_eq!((out.heater.hot_end_target, out.heater.bed_target), (210.0, 60.0), "at segment {}", out.status.executing_seq);
        }
        assert_eq!(out.status.heater_flags, 0, "nothing measured, not acting");
        if out.status.job_outcome == JobOutcome::Finished as u32 {
            finished = Some(out);
            break;
        }
    }
    assert_eq!(skipped, [1]);
    let l = cell.last.unwrap();
    let out = finished.unwrap_or_else(|| {
        panic!(
            "not finished: {:?} seq {} outcome {} {:?}",
            cell.state(),
            l.status.executing_seq,
            l.status.job_outcome,
            cell.ctl.engine().debug_plan()
        )
    });
    assert_eq!((out.heater.hot_end_target, out.heater.bed_target), (0.0, 60.0), "M104 S0 took effect at the job's end");
}

#[test]
fn an_implausible_measurement_is_refused_and_goes_stale() {
    let mut cell = wire_cell(1.0);
    // A shorted thermistor reads 1500 °C: refused (an event), never taken for a hot hot end.
    cell.heater_state = Some(ipc::HeaterState {
        seq: 7,
        hot_end: 1500.0,
        bed: 25.0,
        flags: heater_flags::HOT_END | heater_flags::BED,
        ..Default::default()
    });
    cell.send(&job_after(&[heat(1, false, ipc::HeatWait::None, 210.0)]));
    cell.control(Command::Start, 0.0);
    let out = cell.step();
    assert!(out.events().contains(&Event::HeaterStateRejected { seq: 7 }), "{:?}", out.events());
    assert_eq!(out.status.heater_flags & heater_flags::HOT_END, 0, "no hot-end measurement");
    let out = cell.run_until(60_000, |o| o.status.fault != 0).expect("a fault");
    assert_eq!(out.status.fault, FaultCode::TemperatureLost as u32, "at the first extruding segment");
    assert_eq!(out.status.executing_seq, 3);
}

/// The heaters' owner switched the hot end off for a fault (a board's verify_heater): mid-print the
/// service faults `HeaterFault` with the heaters off and nothing pushed after it; idle, the same;
/// after ClearFault a board that still says so faults again.
#[test]
fn a_heater_fault_reported_by_its_owner_stops_the_job_and_keeps_the_heaters_off() {
    let mut cell = wire_cell(0.2);
    let mut plant = ThermalModel::new(&fast_thermal());
    cell.send(&job_after(&[heat(1, false, ipc::HeatWait::Heating, 210.0)]));
    cell.control(Command::Start, 0.0);
    // Heat up and print until the square's second side.
    let mut printing = false;
    for _ in 0..30_000 {
        let out = tick(&mut cell, &mut plant);
        if out.status.executing_seq >= 4 && out.extruder.filament_rate > 0.0 {
            printing = true;
            break;
        }
    }
    assert!(printing, "the job printed before the fault");
    let faulty = |cell: &Cell, plant: &ThermalModel| {
        let mut s = plant.state(cell.tick + 1, cell.now_ns());
        s.flags |= heater_flags::FAULT;
        s
    };
    cell.heater_state = Some(faulty(&cell, &plant));
    let out = cell.step();
    assert_eq!(out.status.fault, FaultCode::HeaterFault as u32);
    assert_eq!((out.heater.hot_end_target, out.heater.bed_target), (0.0, 0.0));
    assert_eq!(out.status.job_outcome, JobOutcome::Faulted as u32);
    cell.heater_state = None;
    let out = cell.run_until(5_000, |o| o.status.run_state == RunState::Fault as u32).expect("braked to a halt");
    assert_eq!(out.extruder.filament_rate.max(0.0), 0.0, "nothing pushed after the fault");
    // Cleared while the board still reports the fault: faulted again, idle or not.
    cell.control(Command::ClearFault, 0.0);
    cell.heater_state = Some(faulty(&cell, &plant));
    let out = cell.step();
    assert_eq!(out.status.fault, FaultCode::HeaterFault as u32);
    // With no temperature source the flag means nothing to the service.
    let mut none = Cell::iiwa();
    none.heater_state = Some(faulty(&none, &plant));
    assert_eq!(none.step().status.fault, 0);
}
