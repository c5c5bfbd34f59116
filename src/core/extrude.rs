//! Extrusion synchronisation: the filament rate follows the TCP's speed along the path relative to
//! the substrate, Ė = (ΔE/L)·ṡ (002 Eq. 18, 000 Eq. 5's constant flow rate), the drive motor turns at
//! ω = Ė/r_w (002 Eq. 19), pressure advance adds K·Ë, and the filament is retracted when the motion
//! stops unplanned (an underrun) and primed again when it resumes.
//!
//! What the bead needs on a real plant (the sim's truth measures it, `strand_replay::bead`):
//! - **The arm's delay.** The nozzle moves `motion_delay` after its joint command (the robot's dead
//!   time and servo lag); the extruder would not wait, so its command is delayed by as much: bead
//!   and motion meet.
//! - **The hot end's lag.** Melt flows out a time constant after the filament goes in (back
//!   pressure). Pressure advance K·Ë with K the lag cancels it: Ė is taken as a whole — the speed's
//!   changes and the program's flow steps alike, so a bead's start after a travel is primed before
//!   it (the melt its pressure needs, K·Ė, pushed at once) and its end retracted before it.
//! - **Smoothing.** Ë of a step is an impulse: the advance term is averaged over a window of
//!   `pressure_advance_smooth_time` centred on the delayed time (Klipper's symmetric window), which
//!   the delay lets us see without waiting. A window wider than twice the delay cannot be centred;
//!   it ends at the newest sample.
//!
//! The delay line is a ring of past path rates allocated with the extruder: `step` allocates nothing.
//!
//! ṡ is the path speed in W, the substrate frame (the engine plans in W), so on a moving base the
//! flow follows the nozzle's motion over the part, not the arm's motion relative to its base.

use serde::{Deserialize, Serialize};

use crate::path::{Motion, PathSample};
use crate::setting::InvalidSetting;

/// Where the hot end's and the bed's temperatures come from (`[extruder] heater`).
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum HeaterSource {
    /// No temperature source (a cell whose heaters a separate controller runs): targets are still
    /// published (`HeaterCommand`) and shown, but nothing is measured, so heat waits (`M109`,
    /// `M190`, `TEMPERATURE_WAIT`) are *skipped* — each reported (`Event::HeatWaitSkipped`, and
    /// strand-feed warns before streaming) — and cold extrusion is not checked. Today's behaviour.
    #[default]
    None,
    /// The heaters' owner publishes `HeaterState` on the wire (strand-sim's thermal model, a
    /// Klipper board's process) and consumes `HeaterCommand`: waits hold the job, cold extrusion
    /// faults `ColdExtrusion`, a silent source faults `TemperatureLost`.
    Wire,
}

/// `[extruder]`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct ExtruderConfig {
    /// Radius of the drive (friction) wheel r_w (m), 002 Eq. 19.
    pub drive_wheel_radius: f64,
    /// Filament diameter (m), for the volumetric rate.
    pub filament_diameter: f64,
    /// Pressure-advance constant K (s): Ė_cmd = Ė + K·Ë. 0 disables it. The hot end's melt lag plus
    /// the extruder motor's lag (`strand-replay calibrate` measures them).
    pub pressure_advance: f64,
    /// Width of the window the advance term is averaged over (s): a flow step becomes a push spread
    /// over this time instead of a one-tick spike. 0: no smoothing.
    pub pressure_advance_smooth_time: f64,
    /// Time constant of the extruder drive (s): its speed follows the command through this lag.
    /// With the melt lag that pressure advance cancels, a second lag: the command gets the second
    /// derivative term `(K − motor_lag)·motor_lag·E⃛` as well, which the first-order advance leaves
    /// as a delay of about `motor_lag` on every change of flow. 0: none.
    pub motor_lag: f64,
    /// The arm's command-to-motion delay (s): the robot's dead time and servo lag. The extruder
    /// command is delayed by it (rounded to ticks) so that the bead meets the motion. 0: none.
    pub motion_delay: f64,
    /// The most pressure advance a program may set (s): `SET_PRESSURE_ADVANCE ADVANCE`, `M900 K` and
    /// `M572 S` replace `pressure_advance` from their segment on, clamped to [0, this]. 0 ignores
    /// the program's setting.
    pub max_pressure_advance: f64,
    /// Filament pulled back when the motion stops unplanned (m); 0 disables retraction.
    pub retract_length: f64,
    /// Filament speed of a retraction and of the prime that undoes it (m/s).
    pub retract_speed: f64,
    /// Where temperatures come from: `"none"` (default: waits skipped and reported, no cold
    /// check) or `"wire"` (`HeaterState` from strand-sim or a board; see [`HeaterSource`]).
    pub heater: HeaterSource,
    /// No extruding segment starts, and the extruder pushes nothing, with the hot end measured
    /// below this (°C; Marlin's `EXTRUDE_MINTEMP`, Klipper's `min_extrude_temp`): `ColdExtrusion`.
    pub min_extrude_temp: f64,
    /// A hot-end wait ends once |T − target| ≤ this (°C) for `temperature_settle_time`.
    pub temperature_tolerance: f64,
    /// The same for the bed (°C).
    pub bed_temperature_tolerance: f64,
    /// How long (s) the temperature must stay in its band before a wait ends (Marlin's
    /// `TEMP_RESIDENCY_TIME` is 10 s, `TEMP_BED_RESIDENCY_TIME` 10 s; Klipper's M109 none).
    pub temperature_settle_time: f64,
    /// A temperature older than this (s) is stale: `TemperatureLost` when a wait or an extruding
    /// move needs it.
    pub temperature_timeout: f64,
}

impl Default for ExtruderConfig {
    fn default() -> Self {
        ExtruderConfig {
            drive_wheel_radius: 5.5e-3,
            filament_diameter: 1.75e-3,
            pressure_advance: 0.0,
            pressure_advance_smooth_time: 0.0,
            motor_lag: 0.0,
            motion_delay: 0.0,
            max_pressure_advance: 0.2,
            retract_length: 1.0e-3,
            retract_speed: 0.035,
            heater: HeaterSource::None,
            min_extrude_temp: 170.0,
            temperature_tolerance: 3.0,
            bed_temperature_tolerance: 3.0,
            temperature_settle_time: 5.0,
            temperature_timeout: 1.0,
        }
    }
}

impl ExtruderConfig {
    /// Checks every value; the error names the key.
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        if !(self.drive_wheel_radius.is_finite() && self.drive_wheel_radius > 0.0) {
            return Err(InvalidSetting::new("extruder", "[extruder] drive_wheel_radius: must be finite and > 0".to_string()));
        }
        if !(self.filament_diameter.is_finite() && self.filament_diameter > 0.0) {
            return Err(InvalidSetting::new("extruder", "[extruder] filament_diameter: must be finite and > 0".to_string()));
        }
        if !(self.pressure_advance.is_finite() && (0.0..1.0).contains(&self.pressure_advance)) {
            return Err(InvalidSetting::new("extruder", "[extruder] pressure_advance: must be in [0, 1) s".to_string()));
        }
        if !(self.pressure_advance_smooth_time.is_finite() && (0.0..=0.2).contains(&self.pressure_advance_smooth_time)) {
            return Err(InvalidSetting::new("extruder", "[extruder] pressure_advance_smooth_time: must be in [0, 0.2] s".to_string()));
        }
        if !(self.motor_lag.is_finite() && (0.0..=0.1).contains(&self.motor_lag)) {
            return Err(InvalidSetting::new("extruder", "[extruder] motor_lag: must be in [0, 0.1] s".to_string()));
        }
        if !(self.motion_delay.is_finite() && (0.0..=0.5).contains(&self.motion_delay)) {
            return Err(InvalidSetting::new("extruder", "[extruder] motion_delay: must be in [0, 0.5] s".to_string()));
        }
        if !(self.max_pressure_advance.is_finite() && (0.0..1.0).contains(&self.max_pressure_advance)) {
            return Err(InvalidSetting::new("extruder", "[extruder] max_pressure_advance: must be in [0, 1) s".to_string()));
        }
        if !(self.retract_length.is_finite() && (0.0..0.05).contains(&self.retract_length)) {
            return Err(InvalidSetting::new("extruder", "[extruder] retract_length: must be in [0, 0.05) m".to_string()));
        }
        if !(self.retract_speed.is_finite() && self.retract_speed > 0.0) {
            return Err(InvalidSetting::new("extruder", "[extruder] retract_speed: must be finite and > 0".to_string()));
        }
        for (key, v, lo, hi, unit) in [
            ("min_extrude_temp", self.min_extrude_temp, 0.0, 500.0, "degC"),
            ("temperature_tolerance", self.temperature_tolerance, 0.1, 50.0, "degC"),
            ("bed_temperature_tolerance", self.bed_temperature_tolerance, 0.1, 50.0, "degC"),
            ("temperature_settle_time", self.temperature_settle_time, 0.0, 600.0, "s"),
            ("temperature_timeout", self.temperature_timeout, 0.05, 60.0, "s"),
        ] {
            if !(v.is_finite() && (lo..=hi).contains(&v)) {
                return Err(InvalidSetting::new("extruder", format!("[extruder] {key} = {v}: must lie in [{lo}, {hi}] {unit}")));
            }
        }
        Ok(())
    }
}

/// The extruder command for one tick.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ExtruderCommand {
    /// Filament rate Ė that the path asks for this tick (m/s of filament), 002 Eq. 18; the
    /// command carries it `motion_delay` later.
    pub path_rate: f64,
    /// Commanded filament rate (m/s): path rate plus pressure advance, or a retraction/prime.
    pub filament_rate: f64,
    /// Drive motor speed ω = filament_rate / r_w (rad/s), 002 Eq. 19.
    pub motor_speed: f64,
    /// Volumetric rate of the commanded filament (m³/s).
    pub volumetric_rate: f64,
    /// Filament pushed since the start (m; retractions subtract).
    pub position: f64,
    /// True while the filament is pulled back.
    pub retracted: bool,
}

/// One tick of the delay line.
#[derive(Clone, Copy, Debug, Default)]
struct Past {
    motion_rate: f64,
    standstill_rate: f64,
    advance: f64,
}

/// Extruder state: the delay line of path rates, retraction and the integrated filament position.
#[derive(Clone, Debug)]
pub struct Extruder {
    config: ExtruderConfig,
    dt: f64,
    area: f64,
    /// Filament still to pull back (> 0) or to prime (< 0) (m).
    pending: f64,
    retracted: bool,
    position: f64,
    /// The last `history.len()` ticks' filament rates (m/s): of the motion (`flow · ṡ`, what pressure
    /// advance acts on) and of standstills (a slicer's or firmware retraction and its prime, which
    /// act on the hot end's pressure as they are), and the advance K (s) in effect; `head` is the
    /// newest.
    history: Vec<Past>,
    head: usize,
    /// The delay (ticks).
    delay: usize,
    /// The advance term's window: from `newer` to `older` ticks ago.
    newer: usize,
    older: usize,
}

impl Extruder {
    /// An extruder ticking every `dt` seconds.
    pub fn new(config: &ExtruderConfig, dt: f64) -> Result<Self, InvalidSetting> {
        config.validate()?;
        let r = 0.5 * config.filament_diameter;
        let delay = (config.motion_delay / dt).round() as usize;
        let half = (0.5 * config.pressure_advance_smooth_time / dt).round() as usize;
        // Centred on the delayed time when the delay lets us see that far ahead; else the newest
        // window of the same width. At least a tick each side: the second difference needs three
        // points (without smoothing the derivatives are those of a tick ago, with no delay).
        let half = half.max(1);
        let (newer, older) = if half <= delay { (delay - half, delay + half) } else { (0, 2 * half) };
        Ok(Extruder {
            config: config.clone(),
            dt,
            area: std::f64::consts::PI * r * r,
            pending: 0.0,
            retracted: false,
            position: 0.0,
            history: vec![Past::default(); older + 1],
            head: 0,
            delay,
            newer,
            older,
        })
    }

    /// Filament pushed since the start (m; retractions subtract).
    pub fn position(&self) -> f64 {
        self.position
    }

    /// The extruder stopped dead (an emergency stop, a fault): what was on its way is forgotten.
    pub fn halt(&mut self) {
        self.history.fill(Past::default());
        self.pending = 0.0;
    }

    /// The tick `ago` ticks back.
    fn past(&self, ago: usize) -> Past {
        let n = self.history.len();
        self.history[(self.head + n - ago % n) % n]
    }

    /// The command for the path sample of this tick.
    pub fn step(&mut self, sample: &PathSample) -> ExtruderCommand {
        let advance = match sample.pressure_advance {
            Some(k) if self.config.max_pressure_advance > 0.0 => k.clamp(0.0, self.config.max_pressure_advance),
            _ => self.config.pressure_advance,
        };
        let finite = |x: f64| if x.is_finite() { x } else { 0.0 };
        self.head = (self.head + 1) % self.history.len();
        self.history[self.head] =
            Past { motion_rate: finite(sample.flow * sample.speed), standstill_rate: finite(sample.dwell_filament_rate), advance };
        let now = self.past(self.delay);
        let delayed_rate = now.motion_rate + now.standstill_rate;
        // K·Ë over the window: the difference of the motion's Ė across it, over its width. Not on
        // a retraction or its prime: they are meant to move the pressure, and an advance on them
        // would turn the prime into melt laid where the nozzle stands.
        let (newer, older) = (self.past(self.newer).motion_rate, self.past(self.older).motion_rate);
        let middle = self.past((self.newer + self.older) / 2).motion_rate;
        let h = (self.older - self.newer) as f64 * 0.5 * self.dt;
        let slope = (newer - older) / (2.0 * h);
        let curvature = (newer - 2.0 * middle + older) / (h * h);
        let motor_lag = self.config.motor_lag.min(now.advance);
        let mut rate = delayed_rate + now.advance * slope + (now.advance - motor_lag) * motor_lag * curvature;
        let stopped_unplanned = matches!(sample.motion, Motion::Starved | Motion::Held);
        if stopped_unplanned && !self.retracted && self.config.retract_length > 0.0 {
            self.retracted = true;
            self.pending = self.config.retract_length;
        } else if sample.motion == Motion::Moving && self.retracted {
            self.retracted = false;
            self.pending = -self.config.retract_length;
        }
        if self.pending != 0.0 {
            // A retraction (pending > 0) or prime (pending < 0) at retract_speed, on top of the path.
            let step = self.config.retract_speed * self.dt;
            let moved = self.pending.abs().min(step);
            let direction = if self.pending > 0.0 { -1.0 } else { 1.0 };
            rate += direction * moved / self.dt;
            self.pending -= -direction * moved;
            if self.pending.abs() < 1e-15 {
                self.pending = 0.0;
            }
        }
        if !rate.is_finite() {
            rate = 0.0;
        }
        self.position += rate * self.dt;
        ExtruderCommand {
            path_rate: finite(sample.flow * sample.speed + sample.dwell_filament_rate),
            filament_rate: rate,
            motor_speed: rate / self.config.drive_wheel_radius,
            volumetric_rate: rate * self.area,
            position: self.position,
            retracted: self.retracted,
        }
    }
}
