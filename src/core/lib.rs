//! The deterministic controller core: no I/O, no clock, no threads, no allocation after start-up.
//! Everything that may influence a tick arrives as an argument, so the same inputs give the same
//! outputs to the bit, and a logged run replays exactly.
//!
//! This crate is closed: its modules are private and this list is its whole interface (the model
//! is quinn-proto's `lib.rs`). The rule "the core does no I/O and imports nothing of the shell" is
//! kept by the build: the core is its own crate, its dependencies are nalgebra, rsruckig, urdf-rs
//! (URDF *text*; the shell reads the file), serde (config derives), thiserror and the wire contract
//! `strand-wire` (the wire types, no transport), and it cannot name the shell's `io`, `log` or `config`.
//!
//! - The controller: [`Controller::step`]`(&`[`TickInput`]`) -> `[`TickOutput`], built from
//!   [`ControllerSettings`] (the `[controller]`, `[clik]`, `[path]`, `[extruder]` and `[base]`
//!   configs) and a [`kin::RobotModel`]; [`Controller::step_probed`] is the same tick telling a
//!   [`TickProbe`] as each [`TickStage`] ends (the bench's stage timing).
//! - The path engine on its own ([`PathEngine`]), for the offline tools that time a job with the
//!   controller's own per-tick code, and the [`Segment`] it takes.
//! - Kinematics ([`kin`]): the chain, FK, Jacobians, manipulability and the CLIK, for the tools and
//!   benches that check a job or a robot.
//! - The positioner ([`Positioner`]): the external axes that carry the part, and the work's motion.
//! - The base estimator and the extruder model, for the simulator and the tools that predict them.
//! - The heaters' thermal model ([`ThermalModel`], `[thermal]`), for the simulator's plant and the
//!   job check's prediction of heat-up waits.

mod base;
mod base_setpoint;
mod controller;
mod extrude;
mod following;
pub mod kin;
mod path;
mod positioner;
mod setting;
mod thermal;

pub use base::{BaseConfig, BaseEstimator, BaseMode, BaseState, EstimatorKind, MAX_WINDOW, MountPose, PoseRejection};
pub use controller::{
    Controller, ControllerConfig, ControllerError, ControllerSettings, CycleCounters, Event, MAX_BASE_POSES_PER_TICK,
    MAX_CONTROLS_PER_TICK, MAX_EVENTS, MAX_SEGMENTS_PER_TICK, TickDiagnostics, TickInput, TickOutput, TickProbe, TickStage,
};
pub use extrude::{Extruder, ExtruderCommand, ExtruderConfig, HeaterSource};
pub use path::{
    AxisLimits, BedMesh, BedMeshConfig, Geometry, HeatRequest, HeatWait, Heater, InvalidPathConfig, InvalidSegment, MAX_ARC_SWEEP,
    MAX_TEMPERATURE, MESH_COUNT, MeshAlgorithm, Motion, OPEN_BAND, PathConfig, PathEngine, PathPoint, PathSample, PathStats, PlanningMode,
    Segment, SegmentError, SegmentFlags, SegmentKind, arc_geometry, distance_to_arc, distance_to_segment,
};
pub use positioner::{Carries, Positioner, PositionerError};
pub use setting::InvalidSetting;
pub use thermal::{HeaterModel, HeaterModelConfig, ThermalConfig, ThermalModel};
