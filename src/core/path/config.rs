//! Path engine settings (`[path]` in the service config), validated once at start-up.

use serde::{Deserialize, Serialize};

/// How the engine decides the speed at segment junctions.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum PlanningMode {
    /// Every segment on its own trapezoid from rest to rest (004's "normal planning").
    StopAndGo,
    /// 004's knowledge-based planning: Table I decides from ζ and cos φ which junctions are passed at
    /// speed; trapezoidal time scaling (Eqs. 3-6), acceleration-limited only, as in the paper.
    /// Config value `rules-004` (the paper's number stays in the config, not in the type).
    #[serde(rename = "rules-004", alias = "rules004")]
    KnowledgeRules,
    /// Corners blended within a deviation tolerance, junction speeds from the centripetal limit, a
    /// backward pass over the lookahead window, jerk-limited speed along the path (rsruckig).
    #[default]
    Lookahead,
}

impl PlanningMode {
    /// The config spelling of the mode.
    pub fn name(self) -> &'static str {
        match self {
            PlanningMode::StopAndGo => "stop-and-go",
            PlanningMode::KnowledgeRules => "rules-004",
            PlanningMode::Lookahead => "lookahead",
        }
    }
}

/// `[path]`: limits along the path and the lookahead window.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct PathConfig {
    /// Junction planning mode.
    pub mode: PlanningMode,
    /// Segments the intake queue holds (the back-pressure window); the lookahead holds up to twice
    /// as many path pieces (lines, arcs and the blends between them).
    pub queue_capacity: usize,
    /// Planning work allowed per tick, in junction updates of the backward pass. Segments that do
    /// not fit wait in the intake queue for the next tick.
    pub plan_budget: usize,
    /// Speed cap along the path (m/s), whatever the feed.
    pub max_speed: f64,
    /// Acceleration limit along the path (m/s²); 004's user-specified `a` in `rules-004`.
    pub max_acceleration: f64,
    /// Jerk limit along the path (m/s³), `lookahead` only.
    pub max_jerk: f64,
    /// Centripetal acceleration limit on arcs and corner blends (m/s²).
    pub centripetal_acceleration: f64,
    /// Largest distance a corner blend may leave the programmed corner (m).
    pub deviation_tolerance: f64,
    /// 004's threshold ε on cos φ between consecutive segment directions (`rules-004`).
    pub corner_cosine: f64,
    /// Largest kink (rad) passed without slowing to a stop where no blend is possible (arc
    /// junctions); larger kinks are passed at `centripetal_acceleration · dt / angle`.
    pub max_kink: f64,
    /// The controller's progress watchdog (s): with segments left to execute, no hold requested,
    /// and neither the path position nor a dwell's clock advancing for this long, the job faults
    /// with `PathStalled`. 0 disables.
    pub stall_timeout: f64,
}

impl Default for PathConfig {
    fn default() -> Self {
        PathConfig {
            mode: PlanningMode::Lookahead,
            queue_capacity: 1024,
            plan_budget: 8192,
            max_speed: 0.25,
            max_acceleration: 3.0,
            max_jerk: 100.0,
            centripetal_acceleration: 3.0,
            deviation_tolerance: 0.05e-3,
            corner_cosine: 0.5,
            max_kink: 0.01,
            stall_timeout: 0.5,
        }
    }
}

/// A `[path]` value out of range, naming the key.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("[path] {key}: {message}")]
pub struct InvalidPathConfig {
    /// The key.
    pub key: &'static str,
    /// What is wrong.
    pub message: &'static str,
}

impl PathConfig {
    /// Checks every value.
    pub fn validate(&self) -> Result<(), InvalidPathConfig> {
        let positive = |key, v: f64| {
            if v.is_finite() && v > 0.0 { Ok(()) } else { Err(InvalidPathConfig { key, message: "must be finite and > 0" }) }
        };
        if self.queue_capacity < 2 || self.queue_capacity > 1 << 20 {
            return Err(InvalidPathConfig { key: "queue_capacity", message: "must be between 2 and 1048576" });
        }
        if self.plan_budget < 16 {
            return Err(InvalidPathConfig { key: "plan_budget", message: "must be at least 16" });
        }
        positive("max_speed", self.max_speed)?;
        positive("max_acceleration", self.max_acceleration)?;
        positive("max_jerk", self.max_jerk)?;
        positive("centripetal_acceleration", self.centripetal_acceleration)?;
        positive("deviation_tolerance", self.deviation_tolerance)?;
        // Physical ranges: beyond them the planner's arithmetic (w(v), braking distances, rsruckig)
        // leaves floating point, and a job could never end.
        let within =
            |key, v: f64, lo: f64, hi: f64, message| if (lo..=hi).contains(&v) { Ok(()) } else { Err(InvalidPathConfig { key, message }) };
        within("max_speed", self.max_speed, 1e-4, 10.0, "must be in [1e-4, 10] m/s")?;
        within("max_acceleration", self.max_acceleration, 1e-3, 1e3, "must be in [1e-3, 1000] m/s²")?;
        within("max_jerk", self.max_jerk, 1e-2, 1e6, "must be in [0.01, 1e6] m/s³")?;
        within("centripetal_acceleration", self.centripetal_acceleration, 1e-3, 1e3, "must be in [1e-3, 1000] m/s²")?;
        within("deviation_tolerance", self.deviation_tolerance, 1e-9, 0.1, "must be in [1e-9, 0.1] m")?;
        positive("max_kink", self.max_kink)?;
        if !(self.corner_cosine.is_finite() && (-1.0..=1.0).contains(&self.corner_cosine)) {
            return Err(InvalidPathConfig { key: "corner_cosine", message: "must be in [-1, 1]" });
        }
        if !(self.stall_timeout.is_finite() && (0.0..=3600.0).contains(&self.stall_timeout)) {
            return Err(InvalidPathConfig { key: "stall_timeout", message: "must be in [0, 3600] s (0 disables)" });
        }
        Ok(())
    }
}
