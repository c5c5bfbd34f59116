//! The simulator's own configuration file (`config/sim/*.toml`): how the plant departs from the
//! ideal robot, base, tracker and extruder. The robot itself (URDF, limits) and the base's mount
//! come from the service's config, so the two processes can never disagree about them.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use strand_core::InvalidSetting;

/// A sim config file. Every section has defaults; units are SI.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct SimConfig {
    /// Seed of every random draw (noise, dropouts, tension): the same seed gives the same plant.
    pub seed: u64,
    /// The arm's joint servo loops.
    pub joints: JointPlantConfig,
    /// The extruder motor and the melt in the hot end.
    pub extruder: ExtruderPlantConfig,
    /// Optical tracking of the base.
    pub tracker: TrackerConfig,
    /// The free-flying base; absent for a fixed-base robot.
    pub flyer: Option<FlyerConfig>,
    /// The bed's true surface, which the controller does not know (it knows `[bed.mesh]` if the
    /// cell was probed); absent: the bed is the plane of the service config's `[bed]`.
    pub bed: Option<BedSurfaceConfig>,
}

/// `[bed]`: the true bed's height (m) above the service config's bed plane, on a grid in the bed
/// frame (the layout of `[bed.mesh]`: `min`, `max`, `points`, one row per y; bicubic between
/// the heights, the edge's height past them). A warped, tilted bed for the mesh to correct.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct BedSurfaceConfig {
    /// The grid's lower corner (x, y), bed frame (m).
    pub min: [f64; 2],
    /// The grid's upper corner (x, y), bed frame (m).
    pub max: [f64; 2],
    /// Heights at the nodes (m): one row per y from `min` to `max`, one value per x.
    pub points: Vec<Vec<f64>>,
}

impl BedSurfaceConfig {
    /// As the core's mesh (bicubic, never faded), the one interpolation both sides share.
    pub fn as_mesh(&self) -> strand_core::BedMeshConfig {
        strand_core::BedMeshConfig {
            min: self.min,
            max: self.max,
            points: self.points.clone(),
            algorithm: strand_core::MeshAlgorithm::Bicubic,
            fade_start: 0.0,
            fade_end: 0.0,
            fade_target: Some(0.0),
        }
    }
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            seed: 1,
            joints: JointPlantConfig::default(),
            extruder: ExtruderPlantConfig::default(),
            tracker: TrackerConfig::default(),
            flyer: None,
            bed: None,
        }
    }
}

/// `[joints]`: each joint follows its command through a dead time and a first-order lag.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct JointPlantConfig {
    /// Robot cycles between a command's arrival and its effect (dead time of the robot's
    /// interpolator), 0 to 64.
    pub latency_ticks: usize,
    /// Time constant of each joint's position loop (s), 0 (exact) to 1.
    pub lag: f64,
    /// Standard deviation of the measured joint positions (rad or m).
    pub noise: f64,
}

impl Default for JointPlantConfig {
    fn default() -> Self {
        JointPlantConfig { latency_ticks: 1, lag: 0.002, noise: 2e-6 }
    }
}

/// `[extruder]`: the motor follows the commanded filament speed; the melt flow at the nozzle lags
/// the motor (000: back pressure in the hot end delays the extrusion rate).
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct ExtruderPlantConfig {
    /// Time constant of the motor's speed loop (s).
    pub motor_lag: f64,
    /// Time constant between the filament pushed in and the melt flowing out (s).
    pub melt_lag: f64,
}

impl Default for ExtruderPlantConfig {
    fn default() -> Self {
        ExtruderPlantConfig { motor_lag: 0.005, melt_lag: 0.08 }
    }
}

/// `[tracker]`: an optical tracker measuring the robot base's pose in W.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackerConfig {
    /// Samples per second (Hz), 1 to 1000.
    pub rate_hz: f64,
    /// From the measurement to its arrival at the controller (s). The stamp is the measurement time.
    pub latency: f64,
    /// Standard deviation of each position coordinate (m).
    pub noise: f64,
    /// Standard deviation of the yaw (rad).
    pub noise_yaw: f64,
    /// Probability that a sample is lost (markers occluded), 0 to 0.9.
    pub dropout: f64,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        TrackerConfig { rate_hz: 120.0, latency: 0.008, noise: 0.1e-3, noise_yaw: 0.3e-3, dropout: 0.01 }
    }
}

/// A bump in the table's residual acceleration: `accel · exp(−|p − centre|² / (2 radius²))`.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Bump {
    /// Centre on the table (m, W).
    pub centre: [f64; 2],
    /// Width (m).
    pub radius: f64,
    /// Peak residual acceleration (m/s², W).
    pub accel: [f64; 2],
}

/// `[flyer]`: a planar rigid body on an air-bearing table (000 Section 2.1), eight thrusters, three
/// PID loops on the tracked pose, and the table's and the arm's disturbances.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct FlyerConfig {
    /// Mass (kg). 000 gives the thrust limit as 30 mm/s²: 8 N of x thrust over 267 kg.
    pub mass: f64,
    /// Moment of inertia about the vertical axis through the centre of mass (kg m²).
    pub inertia: f64,
    /// Largest force of each of the eight thrusters (N), either direction.
    pub thruster_force: f64,
    /// Thrusters sit in pairs (one along x, one along y) at the corners (±a, ±a) (m).
    pub thruster_arm: f64,
    /// The robot base relative to the centre of mass, in the flyer's frame (m): 000's d_base.
    pub base_offset: [f64; 2],
    /// PID gains (P N/m, I N/(m s), D N s/m) for x and y (000 footnote 2: 60, 1.5, 150).
    pub pid_xy: [f64; 3],
    /// PID gains (P N m/rad, I N m/(rad s), D N m s/rad) for θ (000 footnote 2: 2, 0.05, 6).
    pub pid_theta: [f64; 3],
    /// PID update period (s; 000: position updates every 60 ms).
    pub pid_period: f64,
    /// Time constant of the derivative's low-pass filter (s).
    pub derivative_filter: f64,
    /// A planned trajectory of the robot base followed by the *clock*: a CSV with a header and the
    /// columns `t` (s from the start), `base_x`, `base_y` (m, W) and optionally `base_theta` (rad),
    /// linearly interpolated (relative to this file) — 000's open-loop way, which a pause or a feed
    /// override breaks (kept to show it). Empty: the flyer follows the service's `BaseCommand`,
    /// read from its `[base] plan` at the print's progress, and holds the mount pose without one.
    pub trajectory: PathBuf,
    /// Residual acceleration everywhere on the table (m/s², W): its slope.
    pub residual: [f64; 2],
    /// Places where the residual acceleration changes (000 saw the error peak at fixed spots).
    pub bumps: Vec<Bump>,
    /// Standard deviation of the residual acceleration's slow drift in time (m/s²): the air
    /// film and the table are not steady.
    pub residual_variation: f64,
    /// Correlation time of that drift (s).
    pub residual_time: f64,
    /// Arm mass that reacts on the base when the nozzle accelerates (kg; 000: arm 4.5 kg,
    /// extruder 0.26 kg; about half the arm moves with the nozzle).
    pub arm_reaction_mass: f64,
    /// Mean filament tension (N), whose torque on the flyer is 000 Eq. 6.
    pub tension: f64,
    /// Standard deviation of the tension's slow variation (N).
    pub tension_variation: f64,
    /// Correlation time of that variation (s).
    pub tension_time: f64,
}

impl Default for FlyerConfig {
    fn default() -> Self {
        FlyerConfig {
            mass: 266.7,
            inertia: 28.4,
            thruster_force: 2.0,
            thruster_arm: 0.35,
            base_offset: [0.15, 0.0],
            pid_xy: [60.0, 1.5, 150.0],
            pid_theta: [2.0, 0.05, 6.0],
            pid_period: 0.06,
            derivative_filter: 0.2,
            trajectory: PathBuf::new(),
            residual: [0.0, 0.0],
            bumps: Vec::new(),
            residual_variation: 0.0,
            residual_time: 20.0,
            arm_reaction_mass: 2.5,
            tension: 1.0,
            tension_variation: 0.3,
            tension_time: 5.0,
        }
    }
}

/// A sim config problem, naming the file and the key.
#[derive(Debug, thiserror::Error)]
#[error("{file}: {message}")]
pub struct SimConfigError {
    /// The file.
    pub file: String,
    /// What is wrong.
    pub message: String,
}

impl SimConfig {
    /// The plant that goes with a service config: `sim/free-flyer.toml` for a tracked base, else
    /// `sim/default.toml`, in the service config's folder if it is there, else by the search order
    /// of [`strand::config::locate`]. The error names the files tried.
    pub fn default_path(service: &strand::config::Config) -> Result<PathBuf, strand::config::ConfigError> {
        let tracked = service.base.mode == strand_core::BaseMode::Tracked;
        let name = if tracked { "sim/free-flyer.toml" } else { "sim/default.toml" };
        strand::config::locate::beside_or_find(&service.file, name)
    }

    /// Reads and checks a sim config; the flyer's trajectory path is resolved against the file.
    pub fn load(path: &Path) -> Result<Self, SimConfigError> {
        let err = |message: String| SimConfigError { file: path.display().to_string(), message };
        let text = strand::config::read_text(path).map_err(|e| err(e.message))?;
        let mut cfg: SimConfig = toml::from_str(&text).map_err(|e| err(e.to_string().trim_end().to_string()))?;
        if let Some(f) = cfg.flyer.as_mut()
            && !f.trajectory.as_os_str().is_empty()
        {
            f.trajectory = path.parent().unwrap_or(Path::new(".")).join(&f.trajectory);
        }
        cfg.validate().map_err(|e| err(e.message))?;
        Ok(cfg)
    }

    /// Checks every key; the message names it and its range.
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        let invalid = |message: String| InvalidSetting::new("sim", message);
        let range = |key: &str, v: f64, lo: f64, hi: f64| {
            if v.is_finite() && v >= lo && v <= hi { Ok(()) } else { Err(invalid(format!("{key} = {v}: must lie in [{lo}, {hi}]"))) }
        };
        if let Some(bed) = &self.bed {
            strand_core::BedMesh::new(&bed.as_mesh(), nalgebra::Vector3::zeros(), nalgebra::Rotation3::identity())
                .map_err(|e| invalid(e.message.replace("[bed.mesh]", "[bed]")))?;
        }
        let j = &self.joints;
        if j.latency_ticks > 64 {
            return Err(invalid(format!("joints.latency_ticks = {}: must lie in [0, 64]", j.latency_ticks)));
        }
        range("joints.lag", j.lag, 0.0, 1.0)?;
        range("joints.noise", j.noise, 0.0, 0.01)?;
        range("extruder.motor_lag", self.extruder.motor_lag, 0.0, 5.0)?;
        range("extruder.melt_lag", self.extruder.melt_lag, 0.0, 10.0)?;
        let t = &self.tracker;
        range("tracker.rate_hz", t.rate_hz, 1.0, 1000.0)?;
        range("tracker.latency", t.latency, 0.0, 1.0)?;
        range("tracker.noise", t.noise, 0.0, 0.1)?;
        range("tracker.noise_yaw", t.noise_yaw, 0.0, 0.1)?;
        range("tracker.dropout", t.dropout, 0.0, 0.9)?;
        if let Some(f) = &self.flyer {
            range("flyer.mass", f.mass, 1.0, 1e4)?;
            range("flyer.inertia", f.inertia, 0.01, 1e4)?;
            range("flyer.thruster_force", f.thruster_force, 0.0, 1e3)?;
            range("flyer.thruster_arm", f.thruster_arm, 0.01, 10.0)?;
            range("flyer.pid_period", f.pid_period, 0.001, 1.0)?;
            range("flyer.derivative_filter", f.derivative_filter, 0.0, 10.0)?;
            range("flyer.arm_reaction_mass", f.arm_reaction_mass, 0.0, 100.0)?;
            range("flyer.tension", f.tension, 0.0, 100.0)?;
            range("flyer.tension_variation", f.tension_variation, 0.0, 100.0)?;
            range("flyer.tension_time", f.tension_time, 0.001, 1e4)?;
            range("flyer.residual_variation", f.residual_variation, 0.0, 1.0)?;
            range("flyer.residual_time", f.residual_time, 0.001, 1e4)?;
            for (key, v) in [("flyer.pid_xy", f.pid_xy), ("flyer.pid_theta", f.pid_theta)] {
                if v.iter().any(|g| !(g.is_finite() && *g >= 0.0)) {
                    return Err(invalid(format!("{key} = {v:?}: gains must be finite and ≥ 0")));
                }
            }
            for (key, v) in [("flyer.base_offset", f.base_offset), ("flyer.residual", f.residual)] {
                if v.iter().any(|x| !x.is_finite()) {
                    return Err(invalid(format!("{key}: values must be finite")));
                }
            }
            for (i, b) in f.bumps.iter().enumerate() {
                if !(b.radius.is_finite() && b.radius > 0.0) || b.centre.iter().chain(&b.accel).any(|x| !x.is_finite()) {
                    return Err(invalid(format!("flyer.bumps[{i}]: radius must be > 0 and every value finite")));
                }
            }
        }
        Ok(())
    }
}

impl From<SimConfigError> for strand_cli::error::ToolError {
    fn from(e: SimConfigError) -> Self {
        strand_cli::error::ToolError::SimConfig(Box::new(e))
    }
}
