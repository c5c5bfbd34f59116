//! TOML configuration: the service config and the per-robot files it points to, validated at load,
//! with errors that name the file and the key (and, for syntax errors, the line and column).
//!
//! Layout: `config/default.toml` names a robot file (`robot = "robots/iiwa7.toml"`, relative to the
//! config file) and holds the controller sections; a robot file names its URDF (relative to itself),
//! the chain's root and tip links, the tool transform and the limits URDF does not carry.
//!
//! Which file a tool reads when none (or only a name) is given: [`locate`] (the search order, and
//! the copy of `config/` built into the binary).

pub mod board;
pub mod check;
pub mod driver;
pub mod locate;
pub mod log;
pub mod tracker;
pub mod view;

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::io::rt::RealtimeConfig;
use crate::io::runner::ServiceConfig;
use board::BoardConfig;
use check::CheckConfig;
use driver::DriverConfig;
use log::LogConfig;
use strand_core::BaseConfig;
pub use strand_core::ControllerConfig;
use strand_core::ControllerSettings;
use strand_core::ExtruderConfig;
use strand_core::PathConfig;
use strand_core::ThermalConfig;
use strand_core::kin::{ClikConfig, Frame, ModelError, RobotModel, geom};
use strand_core::{Carries, Controller, Positioner};
use strand_job::bed::BedConfig;
use strand_job::bed::BedTransform;
use strand_job::gcode::GcodeOptions;
use tracker::TrackerConfig;
use view::ViewConfig;

/// A configuration problem, naming the file and what in it is wrong.
#[derive(Clone, Debug, Error)]
#[error("{file}: {message}")]
pub struct ConfigError {
    /// The file (config, robot file or URDF).
    pub file: String,
    /// What is wrong, naming the key.
    pub message: String,
}

impl ConfigError {
    fn new(file: &Path, message: impl Into<String>) -> Self {
        ConfigError { file: file.display().to_string(), message: message.into() }
    }
}

/// Reads a text file; text that is not UTF-8 is an error naming the line.
pub fn read_text(path: &Path) -> Result<String, ConfigError> {
    let bytes = std::fs::read(path).map_err(|e| ConfigError::new(path, format!("cannot read: {e}")))?;
    String::from_utf8(bytes).map_err(|e| {
        let valid = e.utf8_error().valid_up_to();
        let line = e.as_bytes()[..valid].iter().filter(|b| **b == b'\n').count() + 1;
        ConfigError::new(path, format!("line {line}: not UTF-8 text"))
    })
}

/// Reads the URDF at `path` and builds the chain `root_link` → `tip_link` (the core parses the
/// text; the shell reads the file). A file that cannot be read is a [`ModelError::Read`] naming it.
pub fn robot_model_from_urdf_file(path: &Path, root_link: &str, tip_link: &str) -> Result<RobotModel, ModelError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| ModelError::Read { file: file.clone(), reason: e.to_string() })?;
    RobotModel::from_urdf_str(&text, &file, root_link, tip_link)
}

fn read_toml<T: for<'de> Deserialize<'de>>(path: &Path) -> Result<T, ConfigError> {
    let text = read_text(path)?;
    toml::from_str(&text).map_err(|e| ConfigError::new(path, e.to_string().trim_end().to_string()))
}

/// Sets `section.key` (or a top-level `key`) in a parsed config to `value`, parsed as TOML.
fn apply_override(table: &mut toml::Table, assignment: &str) -> Result<(), String> {
    let (key, value) = assignment.split_once('=').ok_or("expected KEY=VALUE, e.g. base.estimator=moving-average")?;
    let value = value.trim();
    let value = match toml::from_str::<toml::Table>(&format!("v = {value}")) {
        Ok(mut t) => t.remove("v").expect("parsed above"),
        Err(_) => toml::Value::String(value.to_string()),
    };
    let parts: Vec<&str> = key.trim().split('.').collect();
    if parts.iter().any(|p| p.is_empty()) || parts.len() > 2 {
        return Err(format!("key {key:?}: expected `key` or `section.key`"));
    }
    let slot = match parts.as_slice() {
        [_] => table,
        [section, _] => table
            .entry(section.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()))
            .as_table_mut()
            .ok_or_else(|| format!("{section} is not a section"))?,
        _ => unreachable!("checked above"),
    };
    slot.insert(parts[parts.len() - 1].to_string(), value);
    Ok(())
}

/// The tool: tip link (flange) → TCP at the nozzle tip. The TCP's z axis points along the nozzle, out
/// of the tool towards the substrate.
#[derive(Clone, Debug, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ToolConfig {
    /// Translation (m), in the tip link's frame.
    #[serde(default)]
    pub xyz: [f64; 3],
    /// Rotation as URDF roll, pitch, yaw (rad), fixed axes x then y then z.
    #[serde(default)]
    pub rpy: [f64; 3],
}

impl ToolConfig {
    /// The transform tip → TCP.
    pub fn frame(&self) -> Frame {
        let [x, y, z] = self.xyz;
        let [r, p, w] = self.rpy;
        Frame::from_parts(nalgebra::Translation3::new(x, y, z), geom::rpy(r, p, w))
    }
}

/// Joint limits that URDF does not carry, one value per joint in chain order.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DynamicLimits {
    /// Acceleration limits (rad/s² or m/s²).
    pub acceleration: Vec<f64>,
    /// Jerk limits (rad/s³ or m/s³).
    pub jerk: Vec<f64>,
}

/// `[positioner]` in a robot file: the cell's external axes that carry the part (a turntable, a
/// tilt-and-turn table), as a chain of the same URDF from the arm's root link (the base frame B)
/// to the plate the part is fixed to. Or `[track]`: the axes that carry the robot (a linear
/// track), as a chain from the rail to the arm's root link. Its joints follow the arm's in every
/// joint array; the URDF gives their position and speed limits, this section the rest, and how
/// G-code names them (rotary words only: a track's axes come from segment files, else stay still).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PositionerConfig {
    /// The chain's root link: `[positioner]` default the arm's `root_link` (the plate's pose is in
    /// B); `[track]` the rail (required).
    #[serde(default)]
    pub root_link: String,
    /// The chain's tip link: `[positioner]` the plate the part is fixed to (required); `[track]`
    /// default the arm's `root_link`.
    #[serde(default)]
    pub tip_link: String,
    /// Acceleration (rad/s² or m/s²) and jerk (rad/s³ or m/s³) limits, one per axis in chain order.
    pub limits: DynamicLimits,
    /// The G-code word of each axis in chain order (`"A"`, `"B"` or `"C"`); empty: G-code cannot move them.
    #[serde(default)]
    pub gcode_words: Vec<String>,
    /// Each axis = sign × word (degrees, turned into rad) + offset: the signs (+1 or −1; default +1).
    #[serde(default)]
    pub gcode_signs: Vec<f64>,
    /// … and the offsets (rad; default 0).
    #[serde(default)]
    pub gcode_offsets: Vec<f64>,
}

/// A robot file.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RobotConfig {
    /// Path of the URDF, relative to the robot file.
    pub urdf: PathBuf,
    /// Root link of the chain: the robot base frame B.
    pub root_link: String,
    /// Tip link of the chain: the flange.
    pub tip_link: String,
    /// Flange → TCP.
    #[serde(default)]
    pub tool: ToolConfig,
    /// Acceleration and jerk limits.
    pub limits: DynamicLimits,
    /// The cell's positioner under the part, if it has one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub positioner: Option<PositionerConfig>,
    /// The cell's track under the robot, if it has one (a cell has one chain of external axes).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub track: Option<PositionerConfig>,
    /// Where the robot file was read from (set by [`RobotConfig::load`]).
    #[serde(skip)]
    pub file: PathBuf,
    /// The URDF's text, read once at load (so a log can carry exactly what was used).
    #[serde(skip)]
    pub urdf_text: String,
}

impl RobotConfig {
    /// Reads a robot file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let mut cfg: RobotConfig = read_toml(path)?;
        cfg.file = path.to_path_buf();
        let urdf = cfg.urdf_path();
        cfg.urdf_text =
            std::fs::read_to_string(&urdf).map_err(|e| ConfigError::new(path, format!("urdf: cannot read {}: {e}", urdf.display())))?;
        cfg.check()?;
        Ok(cfg)
    }

    fn check(&self) -> Result<(), ConfigError> {
        let path = &self.file;
        let cfg = self;
        for (key, v) in [("tool.xyz", cfg.tool.xyz), ("tool.rpy", cfg.tool.rpy)] {
            if v.iter().any(|x| !x.is_finite()) {
                return Err(ConfigError::new(path, format!("{key}: values must be finite")));
            }
        }
        if self.positioner.is_some() && self.track.is_some() {
            return Err(ConfigError::new(path, "[positioner] and [track]: a cell has one chain of external axes".to_string()));
        }
        if let Some((section, p)) = self.external_axes() {
            GcodeOptions::default()
                .with_rotary(&p.gcode_words, &p.gcode_signs, &p.gcode_offsets)
                .map_err(|e| ConfigError::new(path, format!("[{section}] {}: {}", e.key, e.message)))?;
            if section == "positioner" && p.tip_link.is_empty() {
                return Err(ConfigError::new(path, "[positioner] tip_link: name the plate the part is fixed to".to_string()));
            }
            if section == "track" && p.root_link.is_empty() {
                return Err(ConfigError::new(path, "[track] root_link: name the rail the robot rides on".to_string()));
            }
        }
        Ok(())
    }

    /// The URDF path, resolved against the robot file's folder.
    pub fn urdf_path(&self) -> PathBuf {
        self.file.parent().unwrap_or(Path::new(".")).join(&self.urdf)
    }

    /// The section of the external axes (`"positioner"` or `"track"`) and its settings, if any.
    pub fn external_axes(&self) -> Option<(&'static str, &PositionerConfig)> {
        self.positioner.as_ref().map(|p| ("positioner", p)).or(self.track.as_ref().map(|t| ("track", t)))
    }

    /// Builds the external axes' chain from the same URDF (None without a `[positioner]` or `[track]`).
    pub fn build_positioner(&self) -> Result<Option<Positioner>, ConfigError> {
        let Some((section, p)) = self.external_axes() else {
            return Ok(None);
        };
        let urdf = self.urdf_path();
        let carries = if section == "track" { Carries::Robot } else { Carries::Work };
        let (root, tip) = match carries {
            Carries::Work => (if p.root_link.is_empty() { &self.root_link } else { &p.root_link }, &p.tip_link),
            Carries::Robot => (&p.root_link, if p.tip_link.is_empty() { &self.root_link } else { &p.tip_link }),
        };
        let in_file = |message: String| ConfigError::new(&self.file, format!("[{section}] {message}"));
        let model = RobotModel::from_urdf_str(&self.urdf_text, &urdf.display().to_string(), root, tip)
            .map_err(|e| in_file(format!("urdf: {e}")))?
            .with_dynamic_limits(&p.limits.acceleration, &p.limits.jerk, ("limits.acceleration", "limits.jerk"))
            .map_err(|e| in_file(e.to_string()))?;
        if p.gcode_words.len() > model.dof() {
            return Err(in_file(format!(
                "gcode_words: {} words for {} axes (\"{}\" → \"{}\")",
                p.gcode_words.len(),
                model.dof(),
                root,
                tip
            )));
        }
        if let Some(k) = (0..p.gcode_words.len()).find(|&k| !model.joints()[k].kind.rotates()) {
            return Err(in_file(format!(
                "gcode_words: axis {} (\"{}\") is linear, and A, B and C are rotary words (degrees)",
                k + 1,
                model.joints()[k].name
            )));
        }
        Positioner::new(model, carries).map(Some).map_err(|e| in_file(e.to_string()))
    }

    /// The controller for this robot (and its positioner) with `settings`.
    pub fn build_controller(&self, settings: &ControllerSettings) -> Result<Controller, ConfigError> {
        let model = self.build_model()?;
        let controller = Controller::new(settings, model).map_err(|e| ConfigError::new(&self.file, e.to_string()))?;
        match self.build_positioner()? {
            Some(p) => controller.with_positioner(p).map_err(|e| ConfigError::new(&self.file, format!("[positioner] {e}"))),
            None => Ok(controller),
        }
    }

    /// Builds the chain from the URDF read at load, with the tool and all limits.
    pub fn build_model(&self) -> Result<RobotModel, ConfigError> {
        let urdf = self.urdf_path();
        let model = RobotModel::from_urdf_str(&self.urdf_text, &urdf.display().to_string(), &self.root_link, &self.tip_link)
            .map_err(|e| ConfigError { file: self.file.display().to_string(), message: format!("urdf: {e}") })?;
        let in_file = |e: strand_core::kin::ModelError| ConfigError::new(&self.file, e.to_string());
        model
            .with_tool(self.tool.frame())
            .map_err(in_file)?
            .with_dynamic_limits(&self.limits.acceleration, &self.limits.jerk, ("limits.acceleration", "limits.jerk"))
            .map_err(in_file)
    }
}

/// The service configuration (grows with the controller).
#[derive(Clone, Debug, PartialEq)]
pub struct Config {
    /// Where it was read from.
    pub file: PathBuf,
    /// The robot.
    pub robot: RobotConfig,
    /// CLIK tuning.
    pub clik: ClikConfig,
    /// The control loop.
    pub controller: ControllerConfig,
    /// Path engine limits and lookahead.
    pub path: PathConfig,
    /// Extrusion synchronisation.
    pub extruder: ExtruderConfig,
    /// `[extruder.board]`: the Klipper board that drives the extruder and the hot end (`strand-mcu`),
    /// if the cell has one.
    pub extruder_board: Option<BoardConfig>,
    /// Print bed pose and tilt.
    pub bed: BedConfig,
    /// Robot base: fixed mount or tracked.
    pub base: BaseConfig,
    /// Service names, clock, joint feedback.
    pub service: ServiceConfig,
    /// Real-time scheduling, affinity, memory locking.
    pub realtime: RealtimeConfig,
    /// The MCAP log.
    pub log: LogConfig,
    /// `strand check-job` thresholds.
    pub check: CheckConfig,
    /// The robot driver bridge (`strand-egm`, `strand-rsi`), if the robot has one.
    pub driver: Option<DriverConfig>,
    /// The OptiTrack NatNet client (`strand-natnet`), if the base is tracked by Motive.
    pub tracker: Option<TrackerConfig>,
    /// The live view and the log's scene channels.
    pub view: ViewConfig,
    /// The heaters as a plant: strand-sim runs it, `strand check-job` predicts heat-up waits with it.
    pub thermal: ThermalConfig,
}

#[derive(Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct ConfigFile<R> {
    robot: R,
    #[serde(default)]
    clik: ClikConfig,
    #[serde(default)]
    controller: ControllerConfig,
    #[serde(default)]
    path: PathConfig,
    #[serde(default)]
    extruder: ExtruderConfig,
    #[serde(default)]
    bed: BedConfig,
    #[serde(default)]
    base: BaseConfig,
    #[serde(default)]
    service: ServiceConfig,
    #[serde(default)]
    realtime: RealtimeConfig,
    #[serde(default)]
    log: LogConfig,
    #[serde(default)]
    check: CheckConfig,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    driver: Option<DriverConfig>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    tracker: Option<TrackerConfig>,
    #[serde(default)]
    view: ViewConfig,
    #[serde(default)]
    thermal: ThermalConfig,
}

impl<R> ConfigFile<R> {
    fn validate(&self, path: &Path) -> Result<(), ConfigError> {
        self.clik.validate().map_err(|m| ConfigError::new(path, m.to_string()))?;
        self.controller.validate().map_err(|m| ConfigError::new(path, m.to_string()))?;
        self.base.validate().map_err(|m| ConfigError::new(path, m.to_string()))?;
        self.service.validate().map_err(|m| ConfigError::new(path, m.to_string()))?;
        self.realtime.validate().map_err(|m| ConfigError::new(path, m.to_string()))?;
        self.path.validate().map_err(|m| ConfigError::new(path, m.to_string()))?;
        self.extruder.validate().map_err(|m| ConfigError::new(path, m.message))?;
        self.log.validate().map_err(|m| ConfigError::new(path, m.to_string()))?;
        self.check.validate().map_err(|m| ConfigError::new(path, m.to_string()))?;
        self.view.validate().map_err(|m| ConfigError::new(path, m.to_string()))?;
        self.thermal.validate().map_err(|m| ConfigError::new(path, m.message))?;
        if let Some(d) = &self.driver {
            // The per-joint lists are checked against the robot by the driver, which loads it.
            d.validate(d.axis_sign.len().max(d.axis_offset.len())).map_err(|m| ConfigError::new(path, m.to_string()))?;
        }
        if let Some(t) = &self.tracker {
            t.validate().map_err(|m| ConfigError::new(path, m.to_string()))?;
        }
        BedTransform::new(&self.bed).map_err(|m| ConfigError::new(path, m.message))?;
        Ok(())
    }

    fn into_config(self, file: &Path, robot: RobotConfig, extruder_board: Option<BoardConfig>) -> Config {
        Config {
            file: file.to_path_buf(),
            robot,
            extruder_board,
            clik: self.clik,
            controller: self.controller,
            path: self.path,
            extruder: self.extruder,
            bed: self.bed,
            base: self.base,
            service: self.service,
            realtime: self.realtime,
            log: self.log,
            check: self.check,
            driver: self.driver,
            tracker: self.tracker,
            view: self.view,
            thermal: self.thermal,
        }
    }
}

/// `[base] plan`, read from `plan_file` when the config gives a file and no inline rows (a path
/// relative to the config file's folder, as `robot`; an effective config in a log has the rows).
fn read_base_plan(config: &Path, base: &BaseConfig) -> Result<Vec<[f64; 4]>, ConfigError> {
    if !base.plan.is_empty() || base.plan_file.is_empty() {
        return Ok(base.plan.clone());
    }
    let file = config.parent().unwrap_or(Path::new(".")).join(&base.plan_file);
    let plan = strand_job::load::BaseTrajectory::load_keyed(&file, "s", base.mount_rpy[2])
        .map_err(|e| ConfigError::new(config, format!("[base] plan_file: {e}")))?;
    Ok(plan.samples().to_vec())
}

impl Config {
    /// How this cell reads G-code: the robot file's `[positioner]` rotary words (checked at load),
    /// else the defaults.
    pub fn gcode_options(&self) -> GcodeOptions {
        match self.robot.external_axes() {
            Some((_, p)) => GcodeOptions::default()
                .with_rotary(&p.gcode_words, &p.gcode_signs, &p.gcode_offsets)
                .unwrap_or_else(|_| GcodeOptions::default()),
            None => GcodeOptions::default(),
        }
    }

    /// The `[bed]` transform (checked at load, so an error here names the file and the section).
    pub fn bed_transform(&self) -> Result<BedTransform, ConfigError> {
        BedTransform::new(&self.bed).map_err(|e| ConfigError::new(&self.file, e.message))
    }

    /// Reads and validates a config file and the robot file it names.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        Self::load_with(path, &[])
    }

    /// Reads a config file with `section.key=value` overrides applied before validation (the
    /// value is TOML — `0.5`, `true`, `[1, 2]`, `"text"` — or else taken as a string), as `strand
    /// run --set` and the demo use them. Errors name the override.
    pub fn load_with(path: &Path, overrides: &[String]) -> Result<Self, ConfigError> {
        let mut table: toml::Table = read_toml(path)?;
        let board = board::take(&mut table).map_err(|m| ConfigError::new(path, m.message))?;
        let raw: ConfigFile<PathBuf> = if overrides.is_empty() && board.is_none() {
            // From the text, so that an error names its line.
            read_toml(path)?
        } else {
            for o in overrides {
                apply_override(&mut table, o).map_err(|m| ConfigError::new(path, format!("--set {o:?}: {m}")))?;
            }
            let with = if overrides.is_empty() { "" } else { "with --set: " };
            toml::Value::Table(table)
                .try_into()
                .map_err(|e: toml::de::Error| ConfigError::new(path, format!("{with}{}", e.to_string().trim_end())))?
        };
        let mut raw = raw;
        raw.base.fold_mount().map_err(|m| ConfigError::new(path, m.to_string()))?;
        raw.base.plan = read_base_plan(path, &raw.base)?;
        raw.validate(path)?;
        let robot_path = path.parent().unwrap_or(Path::new(".")).join(&raw.robot);
        if !robot_path.is_file() {
            return Err(ConfigError::new(path, format!("robot: no robot file at {}", robot_path.display())));
        }
        let robot = RobotConfig::load(&robot_path)?;
        Ok(raw.into_config(path, robot, board))
    }

    /// The configuration in force, as one self-contained TOML text: every section with its values
    /// after command-line overrides, and the robot file inline under `[robot]` (its URDF travels
    /// separately). A log stores this; [`Config::from_effective`] reads it back to the same values.
    pub fn effective_toml(&self) -> String {
        let file = ConfigFile {
            robot: self.robot.clone(),
            clik: self.clik,
            controller: self.controller.clone(),
            path: self.path.clone(),
            extruder: self.extruder.clone(),
            bed: self.bed.clone(),
            base: self.base.clone(),
            service: self.service.clone(),
            realtime: self.realtime.clone(),
            log: self.log.clone(),
            check: self.check.clone(),
            driver: self.driver.clone(),
            tracker: self.tracker.clone(),
            view: self.view.clone(),
            thermal: self.thermal.clone(),
        };
        let mut table = toml::Table::try_from(&file).expect("every config value is representable in TOML");
        if let Some(b) = &self.extruder_board {
            board::put(&mut table, b);
        }
        toml::to_string(&table).expect("every config value is representable in TOML")
    }

    /// Reads an [`effective_toml`](Config::effective_toml) text with the URDF it used. `origin`
    /// names where the text came from (the log file) in errors.
    pub fn from_effective(origin: &Path, text: &str, urdf_text: &str) -> Result<Self, ConfigError> {
        let effective = |e: String| ConfigError::new(origin, format!("effective config: {}", e.trim_end()));
        let mut table: toml::Table = toml::from_str(text).map_err(|e: toml::de::Error| effective(e.to_string()))?;
        let board = board::take(&mut table).map_err(|m| effective(m.message))?;
        let mut raw: ConfigFile<RobotConfig> =
            toml::Value::Table(table).try_into().map_err(|e: toml::de::Error| effective(e.to_string()))?;
        raw.base.fold_mount().map_err(|m| ConfigError::new(origin, m.to_string()))?;
        raw.validate(origin)?;
        let mut robot = raw.robot.clone();
        robot.file = origin.join("robot");
        robot.urdf_text = urdf_text.to_string();
        robot.check()?;
        Ok(raw.into_config(origin, robot, board))
    }

    /// The sections the controller core uses.
    pub fn controller_settings(&self) -> ControllerSettings {
        ControllerSettings {
            controller: self.controller.clone(),
            clik: self.clik,
            path: self.path.clone(),
            extruder: self.extruder.clone(),
            base: self.base.clone(),
            // Checked when the config was read: a config that loaded has a valid bed.
            bed_mesh: BedTransform::new(&self.bed).ok().and_then(|b| b.mesh().cloned()),
        }
    }
}
