//! The path engine: segments in, one TCP sample per tick out.
//!
//! Segments wait in a bounded intake queue; each tick the planner turns as many as the planning
//! budget allows into *pieces* (lines, arcs, corner blends, standstills) in a fixed ring — the
//! lookahead window — and updates the speed limits at their boundaries. The executor then advances
//! one tick along the pieces and samples position, velocity and acceleration.
//!
//! Speed limits (lookahead mode). Every boundary k between pieces has a cap `vcap_k` (the corner's
//! centripetal limit, the feeds on both sides, zero before a dwell), a speed `vb_k ≤ vcap_k` and a
//! *potential* `g_k = S_k + vb_k²/(2a)`; the end of what has arrived is a boundary with speed 0.
//! With `G_k = min_{m>k} g_m` attained at M, the speed `w⁻¹(G_k − S_k)` at boundary k lets one
//! continuous jerk-limited brake (see [`Braking`]) arrive at M at `vb_M` with zero acceleration, and
//! every profile that does so stays under `vb_m` at every boundary m in between (their potentials
//! are higher), hence under the caps of the pieces in between; `vb_k` is that or, if higher, the
//! speed that slows to `vb_{k+1}` within piece k exactly (with a hair of length in hand, see
//! [`hop_margin`]), at most `vcap_k`. So from boundary k at `vb_k` a plan to the next binding
//! boundary at its `vb` always exists. (The potential used to be `S_k + vcap_k²/(2a)`: that bounds
//! arrivals at M's *cap*, and where `vb_M < vcap_M` — the `v·a/j` term of `w` — the executor
//! arrived at M too fast to meet what follows M, failed to plan, braked blindly and entered small
//! blends over their centripetal cap.) The backward pass keeps `G_k` and the boundary that attains
//! it; a new segment changes only the boundaries within one braking distance of the old end, so the
//! pass stops there.
//!
//! Execution (lookahead mode) is one jerk-limited rsruckig trajectory on the path parameter at a
//! time, from the current state to the next *binding* boundary (the first whose `vb` is below the
//! current piece's cap), or, when that boundary lies on the braking curve of a later one, straight
//! to the later one, so braking across many short pieces is one continuous S-curve. When the
//! trajectory ends exactly on its target, the next one starts from that state inside the same tick,
//! so ticks sample one continuous, jerk-limited motion. New segments, a feed override, a speed
//! scale from the CLIK, or entering a piece with a higher cap start a new trajectory from the
//! current state. Nothing here allocates after [`PathEngine::new`].
//!
//! Progress (why every valid stream ends). The executor is one loop over *plans* — a rsruckig
//! trajectory, a trapezoid, or a dwell on a hold — that spends the tick's time: each pass either
//! returns inside the current plan (its clock advanced by what was left of the tick) or uses the
//! plan up and starts the next one from where it ended, in the same tick. A dwell is a plan like
//! the others, so one that ends mid-tick hands over to whatever follows — another dwell, an E-only
//! retraction, a move — exactly as a trajectory does. (Before, the dwell lived outside that loop
//! and a second hold entered from the end of a first one was taken for the end of the path: the
//! engine reported `Starved` with work left and stood still forever — issue 17's hang.) So:
//!
//! > every tick either advances the path state (s, ṡ or s̈ changes), advances a dwell's clock, or
//! > leaves the engine at rest with nothing left to execute (idle, starved, finished) or held by
//! > request.
//!
//! [`PathEngine::step`] asserts this in debug builds, [`PathEngine::progress`] exposes the
//! measure, and the controller's stall watchdog (`[path] stall_timeout`) faults if it ever stops
//! growing while [`PathEngine::has_work`].
//!
//! One file per step: this one holds the types, the public interface and the tick ([`PathEngine::step`]);
//! `ring.rs` the fixed-capacity ring, `lookahead.rs` the intake and the backward pass, `blend.rs`
//! segments into pieces and corner blends, `executor.rs` the plans, the forced brake and the sample.

use nalgebra::{UnitQuaternion, Vector3};
use rsruckig::prelude::*;

use super::bed_mesh::BedMesh;
use super::config::{InvalidPathConfig, PathConfig, PlanningMode};
use super::geometry::{Geometry, PathPoint, arc_geometry};
use super::profile::{Braking, PathState, Trapezoid};
use super::segment::{HeatWait, Segment, SegmentFlags, SegmentKind};
use crate::kin::geom;
use strand_wire::MAX_EXTERNAL_AXES;

mod blend;
mod executor;
mod lookahead;
mod ring;

use lookahead::{hop_speed, piece_cap};
use ring::Ring;

/// How many boundaries the executor looks past for a binding one before it settles for a
/// non-binding intermediate target (it re-targets from there).
const TARGET_WALK: usize = 256;
/// Lines shorter than this (m) carry no direction; a move this short is skipped.
const MIN_LENGTH: f64 = 1e-9;
/// Turns smaller than this (rad) are straight: no blend, no limit.
const STRAIGHT: f64 = 1e-7;
/// The share of the centripetal limit that curves are planned at. The time-optimal trajectory
/// meets a boundary speed to about 1e-9 m/s, absolutely; on the nanometre-radius blends between
/// sub-micrometre moves, where speeds are a few 1e-5 m/s, that is a 1e-4 share of v²/r (a
/// property run found 3.000367 m/s² against 3). Planning at 0.999 keeps the limit itself.
const CENTRIPETAL_PLANNING_SHARE: f64 = 0.999;

/// The speed and acceleration limits of one external axis ([`PathEngine::set_external_axes`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisLimits {
    /// Largest speed (rad/s or m/s).
    pub velocity: f64,
    /// Largest acceleration (rad/s² or m/s²).
    pub acceleration: f64,
    /// Largest jerk (rad/s³ or m/s³).
    pub jerk: f64,
}

/// The share of an external axis's speed limit a segment is planned at (the rest is the CLIK's and
/// the final stage's room).
const AXIS_SPEED_SHARE: f64 = 0.95;

/// Why a segment was refused. Nothing already accepted is affected. `seq` is the segment's sequence
/// number, `field` the wire field at fault.
#[allow(missing_docs)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum SegmentError {
    /// The intake queue is full; retry after the queue reports space.
    #[error("segment {seq}: intake queue full")]
    QueueFull { seq: u64 },
    /// A field is NaN, infinite or out of range.
    #[error("segment {seq}: field `{field}` {reason}")]
    Invalid { seq: u64, field: &'static str, reason: &'static str },
}

/// What the engine is doing.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Motion {
    /// At rest with nothing to do.
    #[default]
    Idle,
    /// Moving along the path.
    Moving,
    /// Standing still for a dwell.
    Dwelling,
    /// Came to a stop at the end of what has arrived, but the job is not finished (no segment
    /// flagged `LAST` has run): an underrun.
    Starved,
    /// Ran the segment flagged `LAST` to its end.
    Finished,
    /// Brought to rest on the path by [`PathEngine::set_hold`] (a pause or a controlled stop).
    Held,
    /// Standing at a heat wait (a [`SegmentKind::Heat`] segment with a hold) until the caller
    /// releases it ([`PathEngine::release_wait`]): nothing after it executes meanwhile.
    Waiting,
}

/// One tick of the path: the TCP's motion in W and the progress along the job.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathSample {
    /// TCP position (m, W).
    pub position: Vector3<f64>,
    /// TCP velocity (m/s, W).
    pub velocity: Vector3<f64>,
    /// TCP acceleration (m/s², W).
    pub acceleration: Vector3<f64>,
    /// Tool orientation (W).
    pub orientation: UnitQuaternion<f64>,
    /// Tool angular velocity (rad/s, W).
    pub angular_velocity: Vector3<f64>,
    /// Arc length travelled since the start (m).
    pub s: f64,
    /// Speed along the path (m/s).
    pub speed: f64,
    /// Acceleration along the path (m/s²).
    pub path_acceleration: f64,
    /// Jerk along the path (m/s³).
    pub path_jerk: f64,
    /// Sequence number of the segment being executed.
    pub seq: u64,
    /// Its source line (0 if none).
    pub source_line: u32,
    /// Its flags.
    pub flags: SegmentFlags,
    /// Filament per metre of path of the current piece (m/m); the filament rate is `flow · speed`.
    pub flow: f64,
    /// Filament speed (m/s) pushed during a dwell that carries filament (a slicer's retraction).
    pub dwell_filament_rate: f64,
    /// The program's pressure advance for the current segment (s), if it set one.
    pub pressure_advance: Option<f64>,
    /// What the engine is doing.
    pub motion: Motion,
    /// Where the cell's external axes are (rad or m; entries past the cell's count 0): they
    /// move in proportion to the path over a segment, and smoothly over a dwell that turns them.
    pub axes: [f64; MAX_EXTERNAL_AXES],
    /// Their velocities (rad/s or m/s).
    pub axes_velocity: [f64; MAX_EXTERNAL_AXES],
}

/// A path sample of a tool at rest at the origin, extruding nothing (what the extruder sees
/// outside a job).
pub(crate) fn rest_sample() -> PathSample {
    PathSample {
        position: Vector3::zeros(),
        velocity: Vector3::zeros(),
        acceleration: Vector3::zeros(),
        orientation: UnitQuaternion::identity(),
        angular_velocity: Vector3::zeros(),
        s: 0.0,
        speed: 0.0,
        path_acceleration: 0.0,
        path_jerk: 0.0,
        seq: 0,
        source_line: 0,
        flags: SegmentFlags::default(),
        flow: 0.0,
        dwell_filament_rate: 0.0,
        pressure_advance: None,
        motion: Motion::Idle,
        axes: [0.0; MAX_EXTERNAL_AXES],
        axes_velocity: [0.0; MAX_EXTERNAL_AXES],
    }
}

/// Counters for status and tests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PathStats {
    /// Segments accepted into the intake queue.
    pub accepted: u64,
    /// Zero-length moves skipped (each is also reported once through `last_skipped`).
    pub skipped_zero_length: u64,
    /// Sequence number of the last skipped zero-length segment.
    pub last_skipped: Option<u64>,
    /// Segments refused as invalid.
    pub rejected: u64,
    /// Corners blended.
    pub blends: u64,
    /// Times the engine came to rest at the end of the path with the job unfinished.
    pub underruns: u64,
    /// Trajectory computations.
    pub replans: u64,
    /// Times a limit could not be met from the current state (after a sudden override or speed
    /// scale drop) and the engine braked as hard as allowed instead, towards the lowest boundary
    /// speed within its stopping distance, until a position plan fit again (one count per episode).
    pub forced_brakes: u64,
    /// Re-plans whose solver answer was slower than the rest of the current trajectory to the same
    /// boundary, which was kept instead (see `current_is_sooner` in the executor).
    pub solver_detours: u64,
    /// Junction updates done by the backward pass.
    pub plan_work: u64,
}

/// A piece of the executed path with the limits at its start boundary.
#[derive(Clone, Copy, Debug)]
struct Piece {
    geometry: Geometry,
    /// Path position of the start (m).
    start: f64,
    /// Length (m); 0 for holds.
    length: f64,
    /// Programmed feed (m/s).
    feed: f64,
    /// Geometric speed cap inside the piece (m/s): centripetal limit and `max_speed`.
    geometric_cap: f64,
    /// Cap at the start boundary from the corner (m/s); `INFINITY` if none.
    junction_cap: f64,
    /// Filament per path length (m/m).
    flow: f64,
    /// Dwell time (s) and filament (m), holds only.
    hold_time: f64,
    hold_filament: f64,
    /// A heat wait not yet released: the hold lasts until [`PathEngine::release_wait`].
    wait: bool,
    /// Orientation at the start and the rotation vector over the piece (rad, W).
    orientation: UnitQuaternion<f64>,
    rotation: Vector3<f64>,
    /// The external axes at the start (rad or m) and their travel over the piece (over a line or
    /// arc in proportion to the path, over a hold's dwell along a smooth step).
    axes: [f64; MAX_EXTERNAL_AXES],
    axes_delta: [f64; MAX_EXTERNAL_AXES],
    seq: u64,
    source_line: u32,
    flags: SegmentFlags,
    /// A corner blend belongs half to the segment before it: up to `split` (fraction of the length)
    /// the sample reports this segment and flow; 0 for ordinary pieces.
    split: f64,
    first: (u64, u32, SegmentFlags, f64),
    /// The program's pressure advance for the segment (s), if it set one.
    pressure_advance: Option<f64>,
    // Backward pass results for the start boundary.
    vcap: f64,
    vb: f64,
    potential: f64,
    /// min potential over later boundaries, and the boundary attaining it.
    later_min: f64,
    later_arg: u64,
    /// Whether `vb` comes from the continuous braking curve (then the executor aims past this
    /// boundary at `later_arg`) rather than from slowing within this piece.
    via_chain: bool,
}

impl Piece {
    /// A piece with no length, no limits computed yet and no segment attached.
    fn new(geometry: Geometry, orientation: UnitQuaternion<f64>) -> Piece {
        Piece {
            geometry,
            start: 0.0,
            length: 0.0,
            feed: 0.0,
            geometric_cap: 0.0,
            junction_cap: f64::INFINITY,
            flow: 0.0,
            hold_time: 0.0,
            hold_filament: 0.0,
            wait: false,
            orientation,
            rotation: Vector3::zeros(),
            axes: [0.0; MAX_EXTERNAL_AXES],
            axes_delta: [0.0; MAX_EXTERNAL_AXES],
            seq: 0,
            source_line: 0,
            flags: SegmentFlags::default(),
            split: 0.0,
            first: (0, 0, SegmentFlags::default(), 0.0),
            pressure_advance: None,
            vcap: 0.0,
            vb: 0.0,
            potential: 0.0,
            later_min: 0.0,
            later_arg: 0,
            via_chain: false,
        }
    }

    fn end(&self) -> f64 {
        self.start + self.length
    }
    fn is_hold(&self) -> bool {
        matches!(self.geometry, Geometry::Hold { .. })
    }
}

/// The last line received, kept so that the corner to the next segment can be blended.
#[derive(Clone, Copy, Debug)]
struct Tail {
    /// Absolute index of the piece that runs to the segment's end.
    piece: u64,
    kind: SegmentKind,
    /// End point, unit direction at the end and full length of the segment.
    end: Vector3<f64>,
    direction_out: Vector3<f64>,
    length: f64,
    /// Length already taken from the segment's start by the previous blend (m).
    trimmed_start: f64,
    /// Orientation at the segment's start and end.
    q_start: UnitQuaternion<f64>,
    q_end: UnitQuaternion<f64>,
    /// The external axes at the segment's start and end.
    axes_start: [f64; MAX_EXTERNAL_AXES],
    axes_end: [f64; MAX_EXTERNAL_AXES],
    /// 004's ζ = v²/(a·L) of this and the previous segment.
    zeta: f64,
    zeta_previous: f64,
    feed: f64,
}

/// The executor's current trajectory.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Plan {
    /// No motion planned.
    Rest,
    /// A rsruckig trajectory to boundary `target` at path position `position`, arriving at speed
    /// `speed` with zero acceleration (`target == u64::MAX`: a braking trajectory with no target);
    /// `cap` is the speed cap it was planned under; `forced` marks a forced brake (see
    /// [`PathStats::forced_brakes`]), which the executor tries to leave for a position plan every tick.
    Ruckig { target: u64, position: f64, speed: f64, cap: f64, forced: bool },
    /// A trapezoid over one piece (stop-and-go and rules-004).
    Trapezoid { piece: u64, profile: Trapezoid },
    /// Standing still on the hold under the cursor for `duration` seconds (a dwell, or a slicer's
    /// retraction or prime). It is a plan like the others: the executor's loop spends the tick's
    /// time on it and, when it runs out inside a tick, starts whatever follows in the same tick —
    /// another dwell included.
    Dwell { duration: f64 },
}

/// The path engine. See the module documentation.
pub struct PathEngine {
    config: PathConfig,
    dt: f64,
    braking: Braking,
    intake: Ring<Segment>,
    pieces: Ring<Piece>,
    tail: Option<Tail>,
    /// End point and orientation of the last accepted segment (the next one starts there).
    last_end: Vector3<f64>,
    last_orientation: UnitQuaternion<f64>,
    /// The external axes at the end of the last accepted segment.
    last_axes: [f64; MAX_EXTERNAL_AXES],
    last_seq: Option<u64>,
    /// Path position of the end of the last piece (m).
    path_end: f64,
    /// Boundaries at or above this index wait for the backward pass.
    dirty_from: Option<u64>,
    feed_override: f64,
    /// Global speed cap from the CLIK's scale (m/s), and ticks since it last bit.
    speed_cap: f64,
    cap_quiet_ticks: u32,
    /// Consecutive ticks the caller reported a speed scale below 1.
    scaled_ticks: u32,
    replan: bool,
    // Executor.
    state: PathState,
    piece: u64,
    plan: Plan,
    plan_time: f64,
    /// Filament the dwells of this tick push (m): a dwell that begins or ends inside a tick pushes
    /// its share of that tick only, so a retraction and its prime move exactly what they say.
    tick_dwell_filament: f64,
    /// Path position where the current trapezoid starts (m).
    plan_origin: f64,
    /// Where the tool rests when no piece is left (m, W), and its orientation.
    rest_point: Vector3<f64>,
    last_piece_orientation: UnitQuaternion<f64>,
    /// Where the external axes rest when no piece is left.
    last_piece_axes: [f64; MAX_EXTERNAL_AXES],
    /// The external axes' limits ([`set_external_axes`](Self::set_external_axes)); `axis_count` used.
    axis_limits: [AxisLimits; MAX_EXTERNAL_AXES],
    axis_count: usize,
    /// Seconds of dwell completed since the start (the dwell clock); with `state.s` it is the
    /// engine's progress measure (see [`progress`](Self::progress)).
    dwell_done: f64,
    motion: Motion,
    otg: Ruckig<1, IgnoreErrorHandler>,
    input: InputParameter<1>,
    trajectory: Trajectory<1>,
    /// Where trial trajectories are computed; swapped in when one is taken.
    candidate: Trajectory<1>,
    stats: PathStats,
    /// Stop on the path and stay there (pause or controlled stop).
    held: bool,
    /// The bed's measured surface: samples out and start points in are in W, the plan in the
    /// program's space ([`BedMesh`]).
    bed_mesh: Option<BedMesh>,
    /// Test only: the executor stands still with its work left, as a planner bug would make it.
    #[cfg(test)]
    frozen: bool,
}

impl PathEngine {
    /// An engine at rest at `start` (m, W) with tool orientation `orientation`, ticking every `dt`
    /// seconds. All memory is allocated here.
    pub fn new(config: &PathConfig, dt: f64, start: Vector3<f64>, orientation: UnitQuaternion<f64>) -> Result<Self, InvalidPathConfig> {
        config.validate()?;
        if !(dt.is_finite() && dt > 0.0 && dt < 1.0) {
            return Err(InvalidPathConfig { key: "dt", message: "tick period must be in (0, 1) s" });
        }
        if !start.iter().all(|x| x.is_finite()) {
            return Err(InvalidPathConfig { key: "start", message: "start position must be finite" });
        }
        let jerk = if config.mode == PlanningMode::Lookahead { config.max_jerk } else { f64::INFINITY };
        let braking = Braking { acceleration: config.max_acceleration, jerk };
        let blank = Piece::new(Geometry::Hold { point: start }, orientation);
        let mut input = InputParameter::new(None);
        input.max_acceleration[0] = config.max_acceleration;
        input.max_jerk[0] = config.max_jerk;
        Ok(PathEngine {
            config: config.clone(),
            dt,
            braking,
            intake: Ring::new(config.queue_capacity, Segment::default()),
            pieces: Ring::new(2 * config.queue_capacity + 8, blank),
            tail: None,
            last_end: start,
            last_orientation: orientation,
            last_axes: [0.0; MAX_EXTERNAL_AXES],
            last_seq: None,
            path_end: 0.0,
            dirty_from: None,
            feed_override: 1.0,
            speed_cap: f64::INFINITY,
            cap_quiet_ticks: 0,
            scaled_ticks: 0,
            replan: false,
            state: PathState::default(),
            piece: 0,
            plan: Plan::Rest,
            plan_time: 0.0,
            tick_dwell_filament: 0.0,
            plan_origin: 0.0,
            rest_point: start,
            last_piece_orientation: orientation,
            last_piece_axes: [0.0; MAX_EXTERNAL_AXES],
            axis_limits: [AxisLimits { velocity: f64::INFINITY, acceleration: f64::INFINITY, jerk: f64::INFINITY }; MAX_EXTERNAL_AXES],
            axis_count: 0,
            dwell_done: 0.0,
            motion: Motion::Idle,
            otg: Ruckig::new(None, dt),
            input,
            trajectory: Trajectory::new(None),
            candidate: Trajectory::new(None),
            stats: PathStats::default(),
            held: false,
            bed_mesh: None,
            #[cfg(test)]
            frozen: false,
        })
    }

    /// Forgets everything queued and planned and rests at `start` (m, W) with `orientation`, as a
    /// fresh engine would, keeping the counters, the feed override and all memory. The path position
    /// starts again at 0. For a new job, or after a controlled stop has brought the tool to rest.
    pub(crate) fn reset_at(&mut self, start: Vector3<f64>, orientation: UnitQuaternion<f64>) {
        self.reset_with_axes(start, orientation, self.last_piece_axes);
    }

    /// As [`reset_at`](Self::reset_at), with the external axes at `axes` (rad or m).
    pub(crate) fn reset_with_axes(&mut self, start: Vector3<f64>, orientation: UnitQuaternion<f64>, axes: [f64; MAX_EXTERNAL_AXES]) {
        let start = self.to_program(&start);
        self.last_axes = axes;
        self.last_piece_axes = axes;
        self.intake.head = self.intake.tail;
        self.pieces.head = self.pieces.tail;
        self.piece = self.pieces.tail;
        self.tail = None;
        self.last_end = start;
        self.last_orientation = orientation;
        self.last_seq = None;
        self.path_end = 0.0;
        self.dirty_from = None;
        self.speed_cap = f64::INFINITY;
        self.cap_quiet_ticks = 0;
        self.scaled_ticks = 0;
        self.replan = false;
        self.state = PathState::default();
        self.plan = Plan::Rest;
        self.plan_time = 0.0;
        self.plan_origin = 0.0;
        self.rest_point = start;
        self.last_piece_orientation = orientation;
        self.motion = Motion::Idle;
        self.held = false;
    }

    /// Holds the tool: with `true` the path speed falls to zero as fast as the acceleration and jerk
    /// limits allow, staying on the path (a time-optimal stop, so it never runs past where the plan
    /// would have stopped), and stays there with [`Motion::Held`]; with `false` it continues. A dwell
    /// in progress runs to its end first.
    pub(crate) fn set_hold(&mut self, hold: bool) {
        if hold != self.held {
            self.held = hold;
            self.replan = true;
        }
    }

    /// Whether the engine is holding (see [`set_hold`](Self::set_hold)).
    pub(crate) fn is_held(&self) -> bool {
        self.held
    }

    /// The tool's current path state: speed (m/s) and acceleration (m/s²) along the path.
    pub(crate) fn path_motion(&self) -> (f64, f64) {
        (self.state.v, self.state.a)
    }

    /// The external axes' limits ([`set_external_axes`](Self::set_external_axes)).
    pub fn external_axes(&self) -> &[AxisLimits] {
        &self.axis_limits[..self.axis_count]
    }

    /// The cell's external axes that ride along the path (a positioner under the part), with
    /// their limits, in chain order; at most [`MAX_EXTERNAL_AXES`] (more are ignored). A segment
    /// then may carry where they are at its end (`Segment::axes`): over a line or arc they move
    /// in proportion to the path, whose speed is capped so that no axis passes
    /// [`AXIS_SPEED_SHARE`] of its speed limit, and the speed at a junction where an axis's rate
    /// along the path changes is capped so that its speed steps by no more than one tick of its
    /// acceleration; over a dwell (or a move of the axes alone) they follow a smooth step
    /// (10τ³ − 15τ⁴ + 6τ⁵), the dwell lengthened until that step keeps every axis within its speed,
    /// acceleration and jerk limits. Without axes (the default) a segment that carries them is
    /// refused. The path's own acceleration and jerk are not lowered for them: in a cell whose job
    /// turns an axis fast per metre of path, `[path] max_acceleration` must leave the axes room.
    pub fn set_external_axes(&mut self, limits: &[AxisLimits]) {
        self.axis_count = limits.len().min(MAX_EXTERNAL_AXES);
        self.axis_limits[..self.axis_count].copy_from_slice(&limits[..self.axis_count]);
    }

    /// The configuration in use.
    pub fn config(&self) -> &PathConfig {
        &self.config
    }

    /// Counters.
    pub fn stats(&self) -> &PathStats {
        &self.stats
    }

    /// Diagnostics: the executor's current plan in words (`rest`, `dwell`, `trapezoid`,
    /// `ruckig→k` with the target boundary, or `brake` for a velocity-interface stop/slow-down with
    /// no position target), and the current piece's speed cap (m/s) and blend radius (m; infinite
    /// on lines and holds).
    #[doc(hidden)]
    pub fn debug_plan(&self) -> (String, f64, f64) {
        let plan = match self.plan {
            Plan::Rest => "rest".to_string(),
            Plan::Dwell { .. } => "dwell".to_string(),
            Plan::Trapezoid { piece, .. } => format!("trapezoid {piece}"),
            Plan::Ruckig { target: u64::MAX, speed, forced, .. } => format!("{}→{speed:.4}", if forced { "forced brake" } else { "brake" }),
            Plan::Ruckig { target, position, speed, .. } => format!("ruckig→{target} @{position:.6} v{speed:.4}"),
        };
        if self.pieces.len() == 0 || self.piece >= self.pieces.tail {
            return (plan, 0.0, f64::INFINITY);
        }
        let p = self.pieces.get(self.piece);
        let radius = match p.geometry {
            Geometry::Arc { radius, .. } => radius,
            _ => f64::INFINITY,
        };
        (format!("{plan} piece {} len {:.3e}", self.piece, p.length), self.cap_of(self.piece), radius)
    }

    /// Segments the intake queue can take now (the back-pressure figure for `Status`).
    pub fn free_space(&self) -> usize {
        self.intake.room()
    }

    /// Segments accepted but not yet fully executed (intake plus lookahead).
    pub fn pending(&self) -> usize {
        self.intake.len() + self.pieces.len()
    }

    /// True when everything received has run and the engine is at rest.
    pub fn is_at_rest(&self) -> bool {
        matches!(self.motion, Motion::Idle | Motion::Starved | Motion::Finished) && self.intake.len() == 0
    }

    /// Current feed override (fraction of the programmed feed).
    pub fn feed_override(&self) -> f64 {
        self.feed_override
    }

    /// Sets the feed override (0.01 to 2); the speed follows within the acceleration and jerk
    /// limits. Out-of-range or non-finite values are clamped (NaN leaves it unchanged).
    pub fn set_feed_override(&mut self, fraction: f64) {
        if fraction.is_nan() {
            return;
        }
        let fraction = fraction.clamp(0.01, 2.0);
        if fraction != self.feed_override {
            self.feed_override = fraction;
            // Every cap depends on it: recompute the whole window. The pass must start dirty at
            // the head: marked at the tail it would stop one braking distance before the end and
            // keep the old speeds everywhere else.
            for k in self.pieces.head..self.pieces.tail {
                self.refresh_cap(k);
            }
            self.mark_dirty(self.pieces.head);
            self.backward_pass();
            self.replan = true;
        }
    }

    /// Queues a segment. It is checked against the previous end point; a refused segment changes
    /// nothing. A move of zero length is accepted and skipped (counted in the stats).
    pub fn push(&mut self, segment: &Segment) -> Result<(), SegmentError> {
        let seq = segment.seq;
        self.validate(segment).inspect_err(|_| self.stats.rejected += 1)?;
        if self.intake.room() == 0 {
            return Err(SegmentError::QueueFull { seq });
        }
        if segment.kind == SegmentKind::Heat {
            // A heat segment with a hold is a hold piece that lasts until released; one without
            // is the caller's business alone (it applies the target when the path passes its
            // sequence number) and costs the path nothing, unless it ends the job.
            let hold = segment.heat.wait != HeatWait::None;
            if hold || segment.flags.contains(SegmentFlags::LAST) {
                let marker = Segment { end: self.last_end, duration: 0.0, filament: 0.0, axes: None, ..*segment };
                self.intake.push(marker);
            }
            self.last_seq = Some(seq);
            self.stats.accepted += 1;
            return Ok(());
        }
        let turns_axes = segment.axes.is_some_and(|a| a != self.last_axes);
        if segment.kind == SegmentKind::Line && (segment.end - self.last_end).norm() < MIN_LENGTH && turns_axes {
            // A move of the external axes only (the tool stays on its point of the part, which
            // turns): a dwell, as long as the axes need (see `append`).
            let dwell = Segment { kind: SegmentKind::Dwell, end: self.last_end, duration: 0.0, filament: 0.0, ..*segment };
            self.intake.push(dwell);
            self.last_axes = segment.axes.unwrap_or(self.last_axes);
            self.last_seq = Some(seq);
            self.stats.accepted += 1;
            return Ok(());
        }
        if segment.kind == SegmentKind::Line && (segment.end - self.last_end).norm() < MIN_LENGTH {
            self.stats.skipped_zero_length += 1;
            self.stats.last_skipped = Some(seq);
            self.last_seq = Some(seq);
            if segment.flags.contains(SegmentFlags::LAST) {
                // Still mark the end of the job: a zero-length dwell carries the flag.
                let mut marker = *segment;
                marker.kind = SegmentKind::Dwell;
                marker.duration = 0.0;
                marker.filament = 0.0;
                self.intake.push(marker);
            }
            return Ok(());
        }
        self.intake.push(*segment);
        self.last_end = segment.end;
        self.last_orientation = segment.orientation;
        self.last_axes = segment.axes.unwrap_or(self.last_axes);
        self.last_seq = Some(seq);
        self.stats.accepted += 1;
        Ok(())
    }

    fn validate(&self, s: &Segment) -> Result<(), SegmentError> {
        let seq = s.seq;
        let bad = |field, reason| Err(SegmentError::Invalid { seq, field, reason });
        if let Some(last) = self.last_seq
            && seq <= last
        {
            return bad("seq", "must increase");
        }
        s.check().map_err(|e| SegmentError::Invalid { seq, field: e.field, reason: e.reason })?;
        if let Some(axes) = s.axes {
            if self.axis_count == 0 {
                return bad("axes", "moves external axes, and this cell has none");
            }
            if axes[self.axis_count..].iter().any(|a| *a != 0.0) {
                return bad("axes", "moves more external axes than this cell has");
            }
        }
        // What depends on the segments before it.
        // (A heat segment's `end` is not checked: it stands wherever the path is.)
        if s.kind == SegmentKind::Dwell && (s.end - self.last_end).norm() > 1e-9 {
            return bad("end", "a dwell must stay at the previous end point");
        }
        if s.kind == SegmentKind::Arc {
            let Some(geometry) = arc_geometry(&self.last_end, s) else {
                return bad("centre", "start lies on the arc's axis (zero radius)");
            };
            let length = geometry.length(0.0);
            let reach = (geometry.end(length) - s.end).norm();
            if reach > 1e-6 + 1e-6 * length {
                return bad("end", "does not lie where centre, normal and sweep put it");
            }
        }
        Ok(())
    }

    /// One control tick. `speed_scale` is the fraction of the current path speed the caller could
    /// follow last tick (the CLIK's joint-limit scale; 1 when unconstrained).
    pub fn step(&mut self, speed_scale: f64) -> PathSample {
        #[cfg(test)]
        if self.frozen {
            return self.sample_in_world();
        }
        #[cfg(debug_assertions)]
        let before = (self.state, self.progress().1);
        self.plan();
        self.apply_speed_scale(speed_scale);
        // A dwell runs to its end whatever arrives meanwhile (new segments, a hold, an override).
        if self.replan && !matches!(self.plan, Plan::Dwell { .. }) {
            self.replan = false;
            let moving = matches!(self.plan, Plan::Ruckig { .. });
            self.start_plan_from(self.state, 0.0, moving);
        }
        self.advance();
        #[cfg(debug_assertions)]
        self.debug_assert_progress(before);
        self.sample_in_world()
    }

    /// This tick's sample, moved onto the bed's measured surface when there is a mesh.
    fn sample_in_world(&mut self) -> PathSample {
        let mut sample = self.sample();
        if let Some(mesh) = &self.bed_mesh {
            mesh.apply(&mut sample.position, &mut sample.velocity, &mut sample.acceleration);
        }
        sample
    }

    /// Sets the bed's measured surface (`[bed.mesh]`): from the next sample on, every point put
    /// out is corrected by it and every start point given is read as in W ([`BedMesh`]). Set it
    /// before the first job (a change mid-path would jump by the difference).
    pub fn set_bed_mesh(&mut self, mesh: Option<BedMesh>) {
        self.bed_mesh = mesh;
    }

    /// The bed mesh, if one is set.
    pub fn bed_mesh(&self) -> Option<&BedMesh> {
        self.bed_mesh.as_ref()
    }

    /// A point of the program (m) in W: itself without a bed mesh.
    pub fn to_world(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.bed_mesh.as_ref().map_or(*p, |m| m.to_world(p))
    }

    /// A point in W (m) in the program's space: itself without a bed mesh.
    pub fn to_program(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.bed_mesh.as_ref().map_or(*p, |m| m.to_program(p))
    }

    /// The progress measure (path position in m plus completed dwell time in s): it never
    /// decreases, and while [`has_work`](Self::has_work) it grows every tick (the module's
    /// progress invariant). The controller's stall watchdog watches it.
    pub fn progress(&self) -> (f64, f64) {
        (self.state.s, self.dwell_done + if let Plan::Dwell { .. } = self.plan { self.plan_time } else { 0.0 })
    }

    /// Whether anything that has arrived is still to be executed: a piece the tool has not run to
    /// its end, or a dwell with time left. False when the engine is at rest at the end of what
    /// arrived (idle, starved or finished); a hold ([`set_hold`](Self::set_hold)) does not change it.
    pub(crate) fn has_work(&self) -> bool {
        if self.intake.len() > 0 {
            return true;
        }
        let s = self.state.s;
        (self.piece.max(self.pieces.head)..self.pieces.tail).any(|k| {
            let p = self.pieces.get(k);
            if p.is_hold() { p.hold_time > 0.0 || p.wait } else { p.end() > s + 1e-9 }
        })
    }

    /// The heat wait the tool stands at ([`Motion::Waiting`]): its sequence number.
    pub fn waiting_at(&self) -> Option<u64> {
        if self.motion != Motion::Waiting || self.pieces.len() == 0 || self.piece >= self.pieces.tail {
            return None;
        }
        let p = self.pieces.get(self.piece);
        p.wait.then_some(p.seq)
    }

    /// Ends the heat wait the tool stands at (the caller's condition is met): the path goes on
    /// from the next tick. Nothing happens when the tool stands at none.
    pub fn release_wait(&mut self) {
        if self.waiting_at().is_some() {
            self.pieces.get_mut(self.piece).wait = false;
            self.replan = true;
        }
    }

    /// The progress invariant (debug builds): every tick either advances the path state (s, v or a
    /// changes), advances a dwell's clock, or leaves the engine at rest with nothing executable
    /// (idle, starved or finished: every piece that arrived has run) or held by request.
    #[cfg(debug_assertions)]
    fn debug_assert_progress(&self, before: (PathState, f64)) {
        let (state, dwell) = before;
        let advanced = self.state.s != state.s || self.state.v != state.v || self.state.a != state.a || self.progress().1 > dwell;
        match self.motion {
            Motion::Moving | Motion::Dwelling => debug_assert!(
                advanced,
                "path engine made no progress while {:?}: s {} v {} a {} piece {} plan {:?}",
                self.motion, state.s, state.v, state.a, self.piece, self.plan
            ),
            Motion::Idle | Motion::Starved | Motion::Finished => debug_assert!(
                !self.has_work() || self.pieces.room() < 4 || self.intake.len() > 0,
                "path engine at rest ({:?}) with work left: s {} piece {} of {}..{}",
                self.motion,
                self.state.s,
                self.piece,
                self.pieces.head,
                self.pieces.tail
            ),
            Motion::Held => debug_assert!(self.held),
            Motion::Waiting => debug_assert!(self.waiting_at().is_some()),
        }
    }
}

#[cfg(test)]
impl PathEngine {
    /// Test only: stop advancing from the next tick on while keeping everything queued, as a stall
    /// in the planner would (the controller's watchdog must turn it into a fault).
    pub(crate) fn freeze_for_test(&mut self) {
        self.frozen = true;
    }
}

/// The angle (rad) between two unit vectors, accurate for small and large angles.
fn angle_between(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    libm::atan2(a.cross(b).norm(), a.dot(b))
}

/// Orientation a fraction `u` of the way from `a` to `b`.
fn slerp_along(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>, u: f64) -> UnitQuaternion<f64> {
    let rotation = geom::quaternion_log(&(b * a.inverse()));
    if rotation.norm_squared() == 0.0 { *a } else { geom::quaternion_exp(&(rotation * u.clamp(0.0, 1.0))) * a }
}
