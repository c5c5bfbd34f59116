//! What the demo reports about a run: the service's log joined with the sim's truth. The log says
//! where the controller wanted the nozzle (the path target of each tick, for the time its command
//! takes effect); the truth says where the nozzle really was at that time (the sim's actual joints
//! through its actual base). Their distance is the TCP error a ruler on the part would see — not
//! the controller's own estimate, which trusts the encoders and the base estimate.

use std::collections::HashMap;
use std::path::Path;

use serde::Serialize;
use strand::io::histogram::Histogram;
use strand::log::reader::LogFile;
use strand::log::replay::{Verdict, verify};
use strand_ipc::RunState;

use strand_cli::error::Result;
use strand_replay::bead::{Bead, Features};
use strand_replay::truth::Truth;
use strand_replay::{PathTicks, target_on_part, tcp_world};

/// Distribution of a quantity (SI unit as named by the field that holds it).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Spread {
    /// Samples.
    pub samples: usize,
    /// Mean.
    pub mean: f64,
    /// 50th percentile.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Largest.
    pub max: f64,
}

impl Spread {
    /// From raw values (sorted here; NaN left out).
    pub fn of(mut v: Vec<f64>) -> Spread {
        v.retain(|x| x.is_finite());
        if v.is_empty() {
            return Spread::default();
        }
        v.sort_by(f64::total_cmp);
        let rank = |p: f64| v[((p / 100.0 * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1];
        Spread { samples: v.len(), mean: v.iter().sum::<f64>() / v.len() as f64, p50: rank(50.0), p99: rank(99.0), max: v[v.len() - 1] }
    }

    fn of_histogram(h: &Histogram) -> Spread {
        Spread {
            samples: h.count() as usize,
            mean: h.mean() * 1e-9,
            p50: h.percentile(50.0) as f64 * 1e-9,
            p99: h.percentile(99.0) as f64 * 1e-9,
            max: h.max() as f64 * 1e-9,
        }
    }
}

/// The demo's summary of one run.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Report {
    /// Robot name.
    pub robot: String,
    /// Control rate (Hz).
    pub rate_hz: f64,
    /// Ticks logged.
    pub ticks: u64,
    /// From the first tick that left Idle to the job's end (s, the sim's time).
    pub job_time_s: f64,
    /// How the job ended ("Finished", "Stopped", "Faulted", or "none").
    pub job_outcome: String,
    /// Segments the controller accepted and rejected, and its queue underruns.
    pub segments_accepted: u64,
    /// Segments rejected.
    pub segments_rejected: u64,
    /// Queue underruns.
    pub underruns: u64,
    /// Nozzle position error against the path target, from the sim's truth (m), ticks on the path.
    pub tcp_error_m: Spread,
    /// The controller's own view: target against FK of the measured joints through its base
    /// estimate (m).
    pub tcp_error_estimated_m: Spread,
    /// The largest Cartesian following error the controller's `TcpErrorLimit` watchdog saw (m):
    /// the target against the commanded and the measured TCP, on the path.
    pub tcp_error_fault_m: f64,
    /// `[controller] tcp_error_limit` of the run (m).
    pub tcp_error_limit_m: f64,
    /// The bead: melt laid per millimetre of actual nozzle path against the program's, blobs and
    /// strings ([`strand_replay::bead`]).
    pub bead: Bead,
    /// Melt flow error |actual − commanded| while extruding (m³/s).
    pub flow_error_m3s: Spread,
    /// Mean commanded melt flow while extruding (m³/s).
    pub flow_mean_m3s: f64,
    /// Melt deposited over the net melt commanded (retractions subtracted), whole job.
    pub volume_ratio: f64,
    /// Robot base against its plan (m), if the base moves: against the setpoint the service
    /// commanded (`[base] plan`), or the trajectory's pose by the clock.
    pub base_error_m: Option<Spread>,
    /// The base setpoint's lag behind its plan at the print's progress (m; `BaseCommand::lag`),
    /// if the service has a `[base] plan`: what the base's limits cost.
    pub base_lag_m: Option<Spread>,
    /// The arm's reach on the path (m): horizontal distance from the robot base to the nozzle
    /// (truth), if the base moves.
    pub reach_m: Option<Spread>,
    /// Controller step (s).
    pub step_s: Spread,
    /// Wake-up to last publish (s).
    pub tick_s: Spread,
    /// Wake-up lateness (s; timer clock only, zero on the robot clock).
    pub lateness_s: Spread,
    /// Overruns and late wake-ups (Status counters at the end).
    pub overruns: u64,
    /// Late wake-ups.
    pub late_wakeups: u64,
    /// Final-stage clamps.
    pub clamps: u64,
    /// Log records dropped.
    pub log_drops: u64,
    /// Faults raised: (tick, code).
    pub faults: Vec<(u64, String)>,
    /// Ticks whose target found no truth row (should be 0 in lockstep).
    pub unmatched: u64,
    /// The heaters, when the service acted on their temperatures: the time held at heat waits
    /// (s, robot time) for the bed and the hot end, and the hot end's measured range while
    /// extruding (°C).
    pub heat: Option<HeatSummary>,
    /// `strand-replay verify` on the log: "identical (N ticks)" or what diverged.
    pub verify: String,
    /// True when verify found the replay identical.
    pub identical: bool,
}

/// The heat-up a run held for (see [`Report::heat`]).
#[derive(Clone, Debug, Default, Serialize)]
pub struct HeatSummary {
    /// Held at bed waits (s).
    pub bed_wait_s: f64,
    /// Held at hot-end waits (s).
    pub hot_end_wait_s: f64,
    /// The hot end's lowest and highest measurement while extruding (°C).
    pub extruding_c: [f64; 2],
}

/// Joins the log with the truth and replays the log. `flyer`: report the base's error;
/// `features`: the program's feature tags, for the bead per feature.
pub fn report(log: &Path, truth: &[Truth], flyer: bool, features: Option<&Features>) -> Result<Report> {
    let file = LogFile::open(log)?;
    let cfg = file.config()?;
    let dt_ns = (1e9 / cfg.controller.rate_hz).round() as u64;
    let model = cfg.robot.build_model()?;
    // With a positioner the error is measured on the part: the target brought back from where the
    // commanded axes put it, the nozzle from where the actual axes put the part (`tcp_part`).
    let positioner = cfg.robot.build_positioner()?;
    let by_time: HashMap<u64, &Truth> = truth.iter().map(|t| (t.time_ns, t)).collect();
    let mut r = Report {
        robot: model.name().to_string(),
        rate_hz: cfg.controller.rate_hz,
        job_outcome: "none".into(),
        tcp_error_limit_m: cfg.controller.tcp_error_limit,
        ..Default::default()
    };
    let (mut errors, mut estimated, mut lags, mut reach) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let (mut step, mut tick_cost, mut lateness) = (Histogram::new(), Histogram::new(), Histogram::new());
    let mut path_ticks = PathTicks::default();
    let mut started: Option<u64> = None;
    let mut ended: Option<u64> = None;
    let mut measured: Option<strand_core::kin::JointVector> = None;
    let dof = model.dof();
    for tick in file.ticks() {
        let tick = tick?;
        let (i, o) = (&tick.input, &tick.output);
        r.ticks += 1;
        step.record(tick.timing.step_ns);
        tick_cost.record(tick.timing.tick_ns);
        lateness.record(tick.timing.wake_lateness_ns);
        let state = RunState::from_u32(o.status.run_state);
        if started.is_none() && !matches!(state, Some(RunState::Idle)) {
            started = Some(i.time_ns);
        }
        if let Some(js) = &i.joint_state
            && js.dof as usize >= dof
        {
            let mut q = strand_core::kin::JointVector::zeros();
            q.as_mut_slice()[..dof].copy_from_slice(&js.position[..dof]);
            measured = Some(q);
        }
        r.tcp_error_fault_m = r.tcp_error_fault_m.max(o.diagnostics.tcp_error);
        if o.status.heater_flags & strand_ipc::heater_flags::ACTING != 0 {
            let h = r.heat.get_or_insert(HeatSummary { extruding_c: [f64::INFINITY, f64::NEG_INFINITY], ..HeatSummary::default() });
            match strand_ipc::HeatHold::from_u32(o.status.heat_hold) {
                Some(strand_ipc::HeatHold::Bed) => h.bed_wait_s += dt_ns as f64 * 1e-9,
                Some(strand_ipc::HeatHold::HotEnd) => h.hot_end_wait_s += dt_ns as f64 * 1e-9,
                _ => {}
            }
            if o.extruder.filament_rate > 0.0 && o.status.heater_flags & strand_ipc::heater_flags::HOT_END != 0 {
                let t = o.status.hot_end_temperature;
                h.extruding_c = [h.extruding_c[0].min(t), h.extruding_c[1].max(t)];
            }
        }
        if path_ticks.update(o) {
            let target = o.diagnostics.tcp_target_world;
            let target_on_part = target_on_part(o, positioner.as_ref(), dof);
            match by_time.get(&(i.time_ns + dt_ns)) {
                Some(t) => {
                    let on_part = t.tcp_part;
                    errors.push(
                        ((on_part[0] - target_on_part.x).powi(2)
                            + (on_part[1] - target_on_part.y).powi(2)
                            + (on_part[2] - target_on_part.z).powi(2))
                        .sqrt(),
                    );
                    if flyer {
                        reach.push((t.tcp[0] - t.base[0]).hypot(t.tcp[1] - t.base[1]));
                    }
                }
                None => r.unmatched += 1,
            }
            if o.base_command.valid == 1 {
                lags.push(o.base_command.lag);
            }
            if let Some(q) = measured {
                estimated.push((tcp_world(&model, &q, &o.diagnostics.base) - target).norm());
            }
        }
        for e in o.events() {
            match *e {
                strand_core::Event::Fault { code, seq, line, value } => {
                    let figure = if code == strand_ipc::FaultCode::TcpErrorLimit {
                        format!(" (TCP error {:.3} mm)", value * 1e3)
                    } else {
                        String::new()
                    };
                    r.faults.push((
                        i.tick,
                        if seq > 0 { format!("{code:?} at segment {seq}, line {line}{figure}") } else { format!("{code:?}{figure}") },
                    ))
                }
                strand_core::Event::JobEnded { outcome, .. } => {
                    r.job_outcome = format!("{outcome:?}");
                    ended = Some(i.time_ns);
                }
                _ => {}
            }
        }
        let s = &o.status;
        r.segments_accepted = s.segments_accepted;
        r.segments_rejected = s.rejected;
        r.underruns = s.underruns;
        r.overruns = s.overruns;
        r.late_wakeups = s.late_wakeups;
        r.clamps = s.clamps;
        r.log_drops = s.log_drops;
    }
    if let (Some(a), Some(b)) = (started, ended) {
        r.job_time_s = b.saturating_sub(a) as f64 * 1e-9;
    }
    r.tcp_error_m = Spread::of(errors);
    r.tcp_error_estimated_m = Spread::of(estimated);
    r.step_s = Spread::of_histogram(&step);
    r.tick_s = Spread::of_histogram(&tick_cost);
    r.lateness_s = Spread::of_histogram(&lateness);
    // Flow: while either the command or the nozzle flows.
    let dt = dt_ns as f64 * 1e-9;
    let extruding: Vec<&Truth> = truth.iter().filter(|t| t.flow_commanded > 0.0).collect();
    r.flow_error_m3s = Spread::of(extruding.iter().map(|t| (t.flow_actual - t.flow_commanded).abs()).collect());
    r.flow_mean_m3s =
        if extruding.is_empty() { 0.0 } else { extruding.iter().map(|t| t.flow_commanded).sum::<f64>() / extruding.len() as f64 };
    // Net of retractions and pressure advance's pull-backs: what the motor pushed in, in all.
    let commanded: f64 = truth.iter().map(|t| t.flow_commanded * dt).sum();
    let deposited: f64 = truth.iter().map(|t| t.flow_actual * dt).sum();
    r.volume_ratio = if commanded > 0.0 { deposited / commanded } else { 0.0 };
    if !lags.is_empty() {
        r.base_lag_m = Some(Spread::of(lags));
    }
    if flyer {
        r.reach_m = Some(Spread::of(reach));
        r.base_error_m = Some(Spread::of(
            truth.iter().map(|t| ((t.base[0] - t.base_planned[0]).powi(2) + (t.base[1] - t.base_planned[1]).powi(2)).sqrt()).collect(),
        ));
    }
    r.bead = strand_replay::bead::measure(&file, truth, features)?;
    match verify(&[file]) {
        Ok(Verdict::Identical { ticks }) => {
            r.verify = format!("identical ({ticks} ticks)");
            r.identical = true;
        }
        Ok(Verdict::Diverged { tick, field, logged, replayed }) => {
            r.verify = format!("diverged at tick {tick}: {field}: logged {logged}, replayed {replayed}")
        }
        Err(e) => r.verify = format!("cannot replay: {e}"),
    }
    Ok(r)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spreads_use_nearest_rank() {
        let s = Spread::of((1..=100).map(f64::from).collect());
        assert_eq!((s.samples, s.p50, s.p99, s.max), (100, 50.0, 99.0, 100.0));
        assert!((s.mean - 50.5).abs() < 1e-12);
        assert_eq!(Spread::of(vec![f64::NAN]).samples, 0);
    }
}
