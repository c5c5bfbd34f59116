//! Calibration: the arm's command-to-motion delay and the hot end's lag, identified from a run.
//!
//! - **The arm's delay** is the time shift that brings the nozzle's path onto the controller's
//!   path targets ([`path_delay_ticks`], with the sim's truth or any measurement of the nozzle), or
//!   the joint positions the driver reports onto the joint commands ([`joint_delay_ticks`], from
//!   the log alone: what a cell owner has on real hardware).
//! - **The hot end's lag** is the time constant of the first-order lag that best maps the filament
//!   commanded onto the melt measured at the nozzle ([`melt_lag`]): least squares over a grid, then
//!   refined. On hardware the melt comes from a measurement (a filament or nozzle-pressure sensor,
//!   the extruder motor's current as a pressure proxy), logged at the control rate.

use nalgebra::Vector3;

use super::Executing;
use crate::truth::Truth;

/// The most delay looked for (ticks).
pub(crate) const MAX_DELAY_TICKS: u64 = 200;

/// The shift (ticks) that best lays the nozzle's actual path (`truth`) onto the ticks' path targets,
/// in mean distance over the ticks on the path; 0 if nothing ran.
pub fn path_delay_ticks(ticks: &[Executing], truth: &[Truth], dt_ns: u64) -> u64 {
    let by_time: std::collections::HashMap<u64, Vector3<f64>> = truth.iter().map(|t| (t.time_ns, Vector3::from(t.tcp_part))).collect();
    let running: Vec<&Executing> = ticks.iter().filter(|e| e.busy && e.seq > 0).collect();
    if running.is_empty() {
        return 0;
    }
    // Every few ticks is plenty for a mean over a job.
    let step = (running.len() / 20_000).max(1);
    let mut best = (f64::INFINITY, 0);
    for lag in 0..=MAX_DELAY_TICKS {
        let (mut sum, mut n) = (0.0, 0usize);
        for e in running.iter().step_by(step) {
            if let Some(p) = by_time.get(&(e.time_ns + lag * dt_ns)) {
                sum += (p - e.target).norm();
                n += 1;
            }
        }
        if n > 0 && sum / (n as f64) < best.0 {
            best = (sum / n as f64, lag);
        }
    }
    best.1
}

/// The hot end as identified: the melt's and the drive's time constants.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct HotEnd {
    /// Melt lag: filament in to melt out (s).
    pub melt_lag_s: f64,
    /// The drive's lag: commanded to actual filament speed (s).
    pub motor_lag_s: f64,
    /// Root-mean-square misfit of the model to the measured flow (m³/s).
    pub rms_m3s: f64,
    /// The same over the mean measured flow while it flows.
    pub rms_relative: f64,
}

/// The hot-end model strand-sim runs and a real one approximates: the drive follows its command
/// through a first-order lag; melt pushed in is stored in the hot end's compliance and flows out
/// in proportion (`flow = stored / melt_lag`); a retraction leaves a void the prime refills.
/// Returns the flow (m³/s) for each commanded filament rate (m/s).
pub(crate) fn hot_end_response(commanded: &[f64], filament_area: f64, dt: f64, melt_lag: f64, motor_lag: f64) -> Vec<f64> {
    let gain = |tau: f64| if tau > 0.0 { 1.0 - (-dt / tau).exp() } else { 1.0 };
    let (gm, g) = (gain(motor_lag), gain(melt_lag));
    let (mut motor, mut pressure) = (0.0, 0.0);
    commanded
        .iter()
        .map(|&u| {
            motor += gm * (u - motor);
            let pushed = motor * filament_area;
            if pressure > 0.0 || (pressure == 0.0 && pushed >= 0.0) || melt_lag <= 0.0 {
                pressure += g * (pushed - pressure);
            } else {
                pressure += pushed * dt / melt_lag;
            }
            pressure.max(0.0)
        })
        .collect()
}

/// Identifies the hot end from the filament rate commanded each tick (m/s) and the melt flow
/// measured after it (m³/s, `flow[i]` the flow at the end of the tick that ran `commanded[i]`):
/// the time constants whose [`hot_end_response`] fits best in least squares, on a coarse grid and
/// then refined by golden-section search in each.
pub fn melt_lag(commanded: &[f64], flow: &[f64], filament_area: f64, dt: f64) -> HotEnd {
    let n = commanded.len().min(flow.len());
    let (commanded, flow) = (&commanded[..n], &flow[..n]);
    let misfit = |melt: f64, motor: f64| -> f64 {
        let model = hot_end_response(commanded, filament_area, dt, melt, motor);
        model.iter().zip(flow).map(|(m, f)| (m - f) * (m - f)).sum::<f64>()
    };
    // Coarse: melt lag 5 ms to 1 s (log-spaced), motor lag 0 to 30 ms.
    let melts: Vec<f64> = (0..40).map(|k| 0.005 * (200f64).powf(k as f64 / 39.0)).collect();
    let motors: Vec<f64> = (0..13).map(|k| k as f64 * 0.0025).collect();
    let mut best = (f64::INFINITY, 0.08, 0.0);
    for &m in &melts {
        for &d in &motors {
            let e = misfit(m, d);
            if e < best.0 {
                best = (e, m, d);
            }
        }
    }
    // Refine each in turn within a grid step of the coarse optimum.
    let golden = |lo: f64, hi: f64, f: &dyn Fn(f64) -> f64| -> f64 {
        let r = 0.5 * (5f64.sqrt() - 1.0);
        let (mut a, mut b) = (lo, hi);
        for _ in 0..40 {
            let (c, d) = (b - r * (b - a), a + r * (b - a));
            if f(c) < f(d) {
                b = d;
            } else {
                a = c;
            }
        }
        0.5 * (a + b)
    };
    let (_, mut melt, mut motor) = best;
    for _ in 0..3 {
        melt = golden(melt / 1.2, melt * 1.2, &|m| misfit(m, motor));
        motor = golden((motor - 0.003).max(0.0), motor + 0.003, &|d| misfit(melt, d));
    }
    let rms = (misfit(melt, motor) / n.max(1) as f64).sqrt();
    let flowing: Vec<f64> = flow.iter().copied().filter(|f| *f > 0.0).collect();
    let mean = if flowing.is_empty() { 0.0 } else { flowing.iter().sum::<f64>() / flowing.len() as f64 };
    HotEnd { melt_lag_s: melt, motor_lag_s: motor, rms_m3s: rms, rms_relative: if mean > 0.0 { rms / mean } else { 0.0 } }
}

/// What a run says to set in `[extruder]`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Calibration {
    /// The hot end.
    pub hot_end: HotEnd,
    /// From a path target to the nozzle there (s).
    pub arm_delay_s: f64,
    /// `[extruder] pressure_advance` (s): melt lag + motor lag.
    pub pressure_advance: f64,
    /// `[extruder] motor_lag` (s).
    pub motor_lag: f64,
    /// `[extruder] motion_delay` (s): the arm's delay less the extruder's own (one tick: the
    /// extruder command acts in the cycle it arrives in, the joint command a cycle later and
    /// through the servo lag).
    pub motion_delay: f64,
}

impl Calibration {
    /// From the identified hot end and the arm's delay (s) at tick `dt` (s).
    pub fn new(hot_end: HotEnd, arm_delay_s: f64, dt: f64) -> Calibration {
        Calibration {
            hot_end,
            arm_delay_s,
            pressure_advance: hot_end.melt_lag_s + hot_end.motor_lag_s,
            motor_lag: hot_end.motor_lag_s,
            motion_delay: (arm_delay_s - dt).max(0.0),
        }
    }

    /// The `[extruder]` lines to paste into a config.
    pub fn toml(&self) -> String {
        format!(
            "[extruder]\npressure_advance = {:.3}  # s: melt lag {:.1} ms + motor lag {:.1} ms\nmotor_lag = {:.4}\nmotion_delay = {:.3}  # s: arm {:.1} ms behind its target, less the extruder's own tick\n",
            self.pressure_advance,
            self.hot_end.melt_lag_s * 1e3,
            self.hot_end.motor_lag_s * 1e3,
            self.motor_lag,
            self.motion_delay,
            self.arm_delay_s * 1e3
        )
    }
}

/// Calibrates from a log and the truth (or a measurement) of the same run: the extruder's commanded
/// filament rate each tick against the melt flow a cycle later, and the ticks' path targets
/// against the nozzle.
pub fn calibrate_log(log: &strand::log::reader::LogFile, truth: &[Truth]) -> strand_cli::error::Result<Calibration> {
    let cfg = log.config()?;
    let dt_ns = (1e9 / cfg.controller.rate_hz).round() as u64;
    let dt = dt_ns as f64 * 1e-9;
    let flow_at: std::collections::HashMap<u64, f64> = truth.iter().map(|t| (t.time_ns, t.flow_actual)).collect();
    let (mut commanded, mut flow, mut ticks) = (Vec::new(), Vec::new(), Vec::new());
    let positioner = cfg.robot.build_positioner()?;
    let arm = cfg.robot.build_model()?.dof();
    for tick in log.ticks() {
        let tick = tick?;
        ticks.push(Executing::on_part(tick.input.time_ns, &tick.output, positioner.as_ref(), arm));
        if let Some(f) = flow_at.get(&(tick.input.time_ns + dt_ns)) {
            commanded.push(tick.output.extruder.filament_rate);
            flow.push(*f);
        }
    }
    if commanded.len() < 100 || flow.iter().all(|f| *f <= 0.0) {
        return Err(strand_cli::error::ToolError::Measurement(
            "the truth and the log share too few ticks with melt flowing to calibrate".into(),
        ));
    }
    let area = std::f64::consts::PI * 0.25 * cfg.extruder.filament_diameter.powi(2);
    let hot = melt_lag(&commanded, &flow, area, dt);
    Ok(Calibration::new(hot, path_delay_ticks(&ticks, truth, dt_ns) as f64 * dt, dt))
}
