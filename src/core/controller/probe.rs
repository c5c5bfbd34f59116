//! The stages of a tick, by name, and the probe [`Controller::step_probed`](super::Controller::step_probed)
//! calls as each one ends: what `strand-bench tick` times, so that every piece of a tick's work is
//! a named stage and nothing hides in the rest.
//!
//! The core reads no clock: the probe is the caller's (the bench's reads one). `step` calls
//! `step_probed` with a probe that does nothing, which the compiler removes, so the tick that runs
//! a cell is the one the bench measures, without the probe.

/// One stage of [`Controller::step`](super::Controller::step), in the order the tick runs them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TickStage {
    /// The joint state, the heaters' state, the tracking samples, the segments and the controls
    /// taken in (sequence, refusals, the path's intake: blending and the backward pass).
    Intake,
    /// The timeouts and the joint-space following error.
    Supervise,
    /// The base pose estimated for the command's time.
    BaseEstimate,
    /// The path engine's step: the target of this tick.
    PathSample,
    /// The target and the path's velocity mapped from W into the base frame (and onto the part
    /// by a positioner's axes).
    BaseCorrection,
    /// The CLIK step (or, off the path, the approach's joint-space move or the brake).
    Clik,
    /// The final command stage: every joint's limits, non-finite commands.
    CommandLimits,
    /// Heat waits, targets, the cold-extrusion guard.
    Heat,
    /// The progress watchdog and the state changes that follow from the motion.
    RunState,
    /// The moving base's setpoint.
    BaseSetpoint,
    /// FK and Jacobian of the new command: its TCP for the diagnostics and the watchdog, and the
    /// next tick's CLIK starts from them.
    CommandKinematics,
    /// The Cartesian following-error watchdog: the TCP of the measured joints (shared with the
    /// CLIK's when they are the command) and its distance to the recent path.
    FollowingWatch,
    /// The extruder's command (filament rate, pressure advance).
    Extrusion,
    /// The joint command, the status, the heaters' and the base's commands, the events.
    Outputs,
}

impl TickStage {
    /// Every stage, in the tick's order.
    pub const ALL: [TickStage; 14] = [
        TickStage::Intake,
        TickStage::Supervise,
        TickStage::BaseEstimate,
        TickStage::PathSample,
        TickStage::BaseCorrection,
        TickStage::Clik,
        TickStage::CommandLimits,
        TickStage::Heat,
        TickStage::RunState,
        TickStage::BaseSetpoint,
        TickStage::CommandKinematics,
        TickStage::FollowingWatch,
        TickStage::Extrusion,
        TickStage::Outputs,
    ];

    /// Its place in [`TickStage::ALL`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// A short name for a table.
    pub fn name(self) -> &'static str {
        match self {
            TickStage::Intake => "intake (state, segments, controls)",
            TickStage::Supervise => "supervision (timeouts, joint error)",
            TickStage::BaseEstimate => "base estimate",
            TickStage::PathSample => "path sample",
            TickStage::BaseCorrection => "base correction",
            TickStage::Clik => "CLIK (SVD, null space, limits)",
            TickStage::CommandLimits => "command limits",
            TickStage::Heat => "heat",
            TickStage::RunState => "progress watchdog, run state",
            TickStage::BaseSetpoint => "base setpoint",
            TickStage::CommandKinematics => "FK + Jacobian of the command",
            TickStage::FollowingWatch => "following-error watchdog",
            TickStage::Extrusion => "extrusion",
            TickStage::Outputs => "outputs (command, status, events)",
        }
    }
}

/// Told as each stage of a tick ends. A stage may end more than once in a tick (its work comes in
/// pieces): the caller adds them up.
pub trait TickProbe {
    /// `stage` has just ended.
    fn stage_done(&mut self, stage: TickStage);
}

/// The probe of [`Controller::step`](super::Controller::step): nothing.
pub(crate) struct NoProbe;

impl TickProbe for NoProbe {
    #[inline(always)]
    fn stage_done(&mut self, _: TickStage) {}
}
