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

use nalgebra::{UnitQuaternion, Vector3};
use rsruckig::prelude::*;

use super::config::{InvalidPathConfig, PathConfig, PlanningMode};
use super::geometry::{Geometry, arc_geometry};
use super::profile::{Braking, PathState, Trapezoid};
use super::segment::{Segment, SegmentFlags, SegmentKind};
use crate::kin::geom;

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
    /// Orientation at the start and the rotation vector over the piece (rad, W).
    orientation: UnitQuaternion<f64>,
    rotation: Vector3<f64>,
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
            orientation,
            rotation: Vector3::zeros(),
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
    /// 004's ζ = v²/(a·L) of this and the previous segment.
    zeta: f64,
    zeta_previous: f64,
    feed: f64,
}

/// A fixed-capacity ring addressed by absolute indices.
struct Ring<T: Copy> {
    items: Vec<T>,
    head: u64,
    tail: u64,
}

impl<T: Copy> Ring<T> {
    fn new(capacity: usize, fill: T) -> Self {
        Ring { items: vec![fill; capacity], head: 0, tail: 0 }
    }
    fn len(&self) -> usize {
        (self.tail - self.head) as usize
    }
    fn room(&self) -> usize {
        self.items.len() - self.len()
    }
    fn get(&self, index: u64) -> &T {
        &self.items[(index % self.items.len() as u64) as usize]
    }
    fn get_mut(&mut self, index: u64) -> &mut T {
        let n = self.items.len() as u64;
        &mut self.items[(index % n) as usize]
    }
    fn push(&mut self, item: T) -> u64 {
        debug_assert!(self.room() > 0);
        let index = self.tail;
        *self.get_mut(index) = item;
        self.tail += 1;
        index
    }
    fn pop(&mut self) -> Option<T> {
        (self.head < self.tail).then(|| {
            let item = *self.get(self.head);
            self.head += 1;
            item
        })
    }
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
    /// Path position where the current trapezoid starts (m).
    plan_origin: f64,
    /// Where the tool rests when no piece is left (m, W), and its orientation.
    rest_point: Vector3<f64>,
    last_piece_orientation: UnitQuaternion<f64>,
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
            plan_origin: 0.0,
            rest_point: start,
            last_piece_orientation: orientation,
            dwell_done: 0.0,
            motion: Motion::Idle,
            otg: Ruckig::new(None, dt),
            input,
            trajectory: Trajectory::new(None),
            candidate: Trajectory::new(None),
            stats: PathStats::default(),
            held: false,
            #[cfg(test)]
            frozen: false,
        })
    }

    /// Forgets everything queued and planned and rests at `start` (m, W) with `orientation`, as a
    /// fresh engine would, keeping the counters, the feed override and all memory. The path position
    /// starts again at 0. For a new job, or after a controlled stop has brought the tool to rest.
    pub fn reset_at(&mut self, start: Vector3<f64>, orientation: UnitQuaternion<f64>) {
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
    pub fn set_hold(&mut self, hold: bool) {
        if hold != self.held {
            self.held = hold;
            self.replan = true;
        }
    }

    /// Whether the engine is holding (see [`set_hold`](Self::set_hold)).
    pub fn is_held(&self) -> bool {
        self.held
    }

    /// The tool's current path state: speed (m/s) and acceleration (m/s²) along the path.
    pub fn path_motion(&self) -> (f64, f64) {
        (self.state.v, self.state.a)
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
        // What depends on the segments before it.
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

    fn refresh_cap(&mut self, k: u64) {
        let over = self.feed_override;
        let max_speed = self.config.max_speed;
        let previous_cap = if k > self.pieces.head { Some(piece_cap(self.pieces.get(k - 1), over, max_speed)) } else { None };
        let p = self.pieces.get_mut(k);
        let own = piece_cap(p, over, max_speed);
        let mut vcap = p.junction_cap.min(own);
        if let Some(prev) = previous_cap {
            vcap = vcap.min(prev);
        }
        if p.is_hold() {
            vcap = 0.0;
        }
        p.vcap = vcap;
    }

    fn mark_dirty(&mut self, from: u64) {
        self.dirty_from = Some(self.dirty_from.map_or(from, |d| d.min(from)));
    }

    /// Updates `vb` and the later minimum of the potential from the end back, stopping where
    /// nothing changes any more or beyond one braking distance of the change. Returns the work done.
    fn backward_pass(&mut self) -> usize {
        let Some(changed) = self.dirty_from.take() else { return 0 };
        let horizon = self.braking.w(self.config.max_speed) + 1e-6;
        let end = self.pieces.tail;
        let change_position = if changed < end { self.pieces.get(changed).start } else { self.path_end };
        let mut later_min = self.braking.potential(self.path_end, 0.0);
        let mut later_arg = end;
        let mut work = 0;
        let mut k = end;
        while k > self.pieces.head {
            k -= 1;
            work += 1;
            self.refresh_cap(k);
            let braking = self.braking;
            let p = self.pieces.get_mut(k);
            let unchanged = p.later_min == later_min && p.later_arg == later_arg;
            // Two plans make a speed at this boundary safe: slowing to the next boundary's vb
            // within this piece (exact, arriving at zero acceleration), or one continuous braking
            // curve to the boundary holding the later minimum (the composable bound). Either will
            // do; the executor follows the one that allows more.
            let next_vb = if k + 1 < end { self.pieces.get(k + 1).vb } else { 0.0 };
            let p = self.pieces.get(k);
            let hop = braking.reach(p.length - hop_margin(p.length), next_vb, p.vcap);
            let chain = braking.w_inverse(later_min - p.start);
            let vb = p.vcap.min(hop.max(chain));
            let via_chain = chain > hop;
            let p = self.pieces.get_mut(k);
            p.via_chain = via_chain;
            let potential = braking.potential(p.start, vb);
            // Below a boundary whose speed did not change, sits at its cap, and whose later
            // minimum only rose, every stored value is still safe (at worst slower than it could
            // be), so the pass can stop there: this keeps appending to a long run of tiny segments
            // cheap, where the end's potential is the later minimum of every boundary.
            let saturated_and_relaxed = p.vb == vb && vb == p.vcap && later_min >= p.later_min;
            let unchanged = (unchanged && p.vb == vb && p.potential == potential) || saturated_and_relaxed;
            p.later_min = later_min;
            p.later_arg = later_arg;
            p.vb = vb;
            p.potential = potential;
            let start = p.start;
            if potential <= later_min {
                later_min = potential;
                later_arg = k;
            }
            if k < changed && (unchanged || change_position - start > horizon) {
                break;
            }
        }
        self.stats.plan_work += work as u64;
        work
    }

    /// Moves segments from the intake queue into the lookahead within the tick's budget.
    fn plan(&mut self) {
        // One segment's pass is atomic (it is bounded by the pieces within one braking distance of
        // the change); the budget decides how many segments are taken in per tick.
        let mut budget = self.config.plan_budget;
        while budget > 0 && self.intake.len() > 0 && self.pieces.room() >= 4 {
            let Some(segment) = self.intake.pop() else { break };
            self.append(&segment);
            self.replan = true;
            budget = budget.saturating_sub(self.backward_pass().max(1));
        }
    }

    /// Turns one segment into pieces, blending the corner from the previous line in lookahead mode.
    fn append(&mut self, s: &Segment) {
        let start_point = self.tail.map_or(self.current_end_point(), |t| t.end);
        match s.kind {
            SegmentKind::Dwell => {
                self.tail = None;
                let piece = self.new_piece(Geometry::Hold { point: start_point }, 0.0, s, 0.0);
                let index = self.pieces.push(Piece { hold_time: s.duration, hold_filament: s.filament, ..piece });
                self.path_end = self.pieces.get(index).end();
                self.mark_dirty(index);
            }
            SegmentKind::Line | SegmentKind::Arc => {
                let (geometry, length, direction_in, direction_out) = if s.kind == SegmentKind::Line {
                    let delta = s.end - start_point;
                    let length = delta.norm();
                    let direction = delta / length;
                    (Geometry::Line { start: start_point, direction }, length, direction, direction)
                } else {
                    let geometry = arc_geometry(&start_point, s).unwrap_or(Geometry::Line { start: start_point, direction: Vector3::x() });
                    let length = geometry.length(0.0);
                    let d_in = geometry.point(0.0, length).tangent.normalize();
                    let d_out = geometry.point(length, length).tangent.normalize();
                    (geometry, length, d_in, d_out)
                };
                let flow = if s.extrudes() || s.filament != 0.0 { s.filament / length } else { 0.0 };
                let q_start = self.tail.map_or(self.pieces_end_orientation(), |t| t.q_end);
                let zeta = s.feed * s.feed / (self.config.max_acceleration * length);
                let mut junction_cap = f64::INFINITY;
                let mut trimmed_start = 0.0;
                let mut piece_geometry = geometry;
                let mut piece_length = length;
                if let Some(tail) = self.tail {
                    let turn = angle_between(&tail.direction_out, &direction_in);
                    match self.config.mode {
                        PlanningMode::StopAndGo => junction_cap = 0.0,
                        PlanningMode::Rules004 => {
                            if !self.rules_004_continue(&tail, zeta, turn) {
                                junction_cap = 0.0;
                            }
                        }
                        PlanningMode::Lookahead => {
                            if turn < STRAIGHT {
                            } else if tail.kind == SegmentKind::Line && s.kind == SegmentKind::Line && turn < std::f64::consts::PI - 1e-6 {
                                match self.blend(&tail, s, length, direction_in, turn) {
                                    Some(trim) => {
                                        trimmed_start = trim;
                                        piece_geometry =
                                            Geometry::Line { start: start_point + direction_in * trim, direction: direction_in };
                                        piece_length = length - trim;
                                    }
                                    None => junction_cap = self.kink_cap(turn),
                                }
                            } else {
                                junction_cap = self.kink_cap(turn);
                            }
                        }
                    }
                } else if self.pieces.len() > 0 || self.state.v > 0.0 {
                    // After a dwell or from an unknown direction: start from rest.
                    junction_cap = 0.0;
                }
                let mut piece = self.new_piece(piece_geometry, piece_length, s, flow);
                piece.junction_cap = junction_cap;
                piece.geometric_cap = self.centripetal_cap(geometry.min_radius());
                let q_trim = slerp_along(&q_start, &s.orientation, trimmed_start / length);
                piece.orientation = q_trim;
                piece.rotation = geom::quaternion_log(&(s.orientation * q_trim.inverse()));
                let index = self.pieces.push(piece);
                self.path_end = self.pieces.get(self.pieces.tail - 1).end();
                self.mark_dirty(self.tail.map_or(index, |t| t.piece).min(index));
                let zeta_previous = self.tail.map_or(0.0, |t| t.zeta);
                self.tail = Some(Tail {
                    piece: index,
                    kind: s.kind,
                    end: s.end,
                    direction_out,
                    length,
                    trimmed_start,
                    q_start,
                    q_end: s.orientation,
                    zeta,
                    zeta_previous,
                    feed: s.feed,
                });
            }
        }
    }

    fn new_piece(&self, geometry: Geometry, length: f64, s: &Segment, flow: f64) -> Piece {
        let start = if self.pieces.len() > 0 { self.pieces.get(self.pieces.tail - 1).end() } else { self.state.s };
        Piece {
            start,
            length,
            feed: s.feed,
            geometric_cap: self.config.max_speed,
            flow,
            seq: s.seq,
            source_line: s.source_line,
            flags: s.flags,
            pressure_advance: s.pressure_advance,
            ..Piece::new(geometry, s.orientation)
        }
    }

    fn current_end_point(&self) -> Vector3<f64> {
        if self.pieces.len() > 0 {
            let p = self.pieces.get(self.pieces.tail - 1);
            p.geometry.end(p.length)
        } else {
            self.sample_geometry().position
        }
    }

    fn pieces_end_orientation(&self) -> UnitQuaternion<f64> {
        if self.pieces.len() > 0 {
            let p = self.pieces.get(self.pieces.tail - 1);
            geom::quaternion_exp(&p.rotation) * p.orientation
        } else {
            self.last_piece_orientation
        }
    }

    /// 004 Table I: does the tool pass from the tail segment s_i into the new one s_{i+1} at speed?
    /// Phases (1) and (2) continue; (3), (1)+(3) and segments no rule covers stop at the end.
    fn rules_004_continue(&self, tail: &Tail, zeta_next: f64, turn: f64) -> bool {
        let cos_phi = libm::cos(turn);
        let eps = self.config.corner_cosine;
        let (z_prev, z_i, z_next) = (tail.zeta_previous, tail.zeta, zeta_next);
        // Rule (1): a curve starts at s_i (phase (1) if it goes on, (1)+(3) if it turns sharply).
        let rule_1 = z_prev < 1.0 && z_i > 1.0 && z_next > 1.0;
        // Rule (2): inside a curve (phase (2), or (3) at a sharp turn).
        let rule_2 = z_prev > 1.0 && z_i > 1.0 && z_next > 1.0;
        // Rule (3) and long segments come to rest (normal planning).
        (rule_1 || rule_2) && cos_phi >= eps
    }

    /// The speed at a kink that cannot be blended: tiny kinks at speed, larger ones slowly.
    /// The speed cap (m/s) on a curve of `radius` (m): the centripetal limit, planned at
    /// [`CENTRIPETAL_PLANNING_SHARE`] of it, and `max_speed`.
    fn centripetal_cap(&self, radius: f64) -> f64 {
        self.config.max_speed.min((CENTRIPETAL_PLANNING_SHARE * self.config.centripetal_acceleration * radius).sqrt())
    }

    fn kink_cap(&self, turn: f64) -> f64 {
        if turn <= self.config.max_kink { f64::INFINITY } else { self.config.centripetal_acceleration * self.dt / turn }
    }

    /// Blends the corner between the tail line and a new line with a tangent arc that stays within
    /// the deviation tolerance and uses at most half of the new line. Trims the tail piece and
    /// appends the arc; returns the length trimmed from the new line, or None if no blend fits.
    fn blend(&mut self, tail: &Tail, s: &Segment, length: f64, direction_in: Vector3<f64>, turn: f64) -> Option<f64> {
        let half = 0.5 * turn;
        let (tan_half, cos_half) = (libm::tan(half), libm::cos(half));
        let tolerance = self.config.deviation_tolerance;
        // Deviation of the arc midpoint from the corner: r (1/cos(φ/2) − 1).
        let r_tolerance = tolerance * cos_half / (1.0 - cos_half);
        let available_tail = tail.length - tail.trimmed_start;
        let mut d = (r_tolerance * tan_half).min(available_tail).min(0.5 * length);
        // The tail piece may already be under way: keep the blend beyond where the tool could stop.
        let tail_piece = *self.pieces.get(tail.piece);
        let stop = self.state.s + self.braking.stopping_distance(self.state.v, self.state.a);
        d = d.min(tail_piece.end() - stop);
        if d < 1e-7 {
            return None;
        }
        let radius = d / tan_half;
        let corner = tail.end;
        let p_in = corner - tail.direction_out * d;
        let bisector = (direction_in - tail.direction_out).normalize();
        let centre = corner + bisector * (radius / cos_half);
        let e1 = (p_in - centre).normalize();
        let normal = e1.cross(&tail.direction_out).normalize();
        let e2 = normal.cross(&e1);
        let geometry = Geometry::Arc { centre, e1, e2, normal, radius, radius_rate: 0.0, pitch: 0.0, sweep: turn };
        let arc_length = radius * turn;
        // Trim the tail piece.
        {
            let tp = self.pieces.get_mut(tail.piece);
            tp.length = (tp.length - d).max(0.0);
            let rotation_fraction =
                if tail.length - tail.trimmed_start > 0.0 { tp.length / (tail.length - tail.trimmed_start) } else { 1.0 };
            tp.rotation *= rotation_fraction;
        }
        let q_in = slerp_along(&tail.q_start, &tail.q_end, (tail.length - d) / tail.length);
        let q_out = slerp_along(&tail.q_end, &s.orientation, d / length);
        let blend_start = self.pieces.get(tail.piece).end();
        let mut arc = self.new_piece(geometry, arc_length, s, 0.0);
        arc.start = blend_start;
        arc.feed = tail.feed.min(s.feed);
        arc.geometric_cap = self.centripetal_cap(radius);
        // Each half of the blend keeps its own segment's filament per metre, so the bead keeps its
        // cross-section; the blend is shorter than the two trimmed ends, by (1 − φ/(2 tan(φ/2))).
        arc.flow = if s.extrudes() || s.filament != 0.0 { s.filament / length } else { 0.0 };
        arc.split = 0.5;
        arc.first = (tail_piece.seq, tail_piece.source_line, tail_piece.flags, tail_piece.flow);
        arc.orientation = q_in;
        arc.rotation = geom::quaternion_log(&(q_out * q_in.inverse()));
        self.pieces.push(arc);
        self.stats.blends += 1;
        Some(d)
    }

    /// One control tick. `speed_scale` is the fraction of the current path speed the caller could
    /// follow last tick (the CLIK's joint-limit scale; 1 when unconstrained).
    pub fn step(&mut self, speed_scale: f64) -> PathSample {
        #[cfg(test)]
        if self.frozen {
            return self.sample();
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
        self.sample()
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
    pub fn has_work(&self) -> bool {
        if self.intake.len() > 0 {
            return true;
        }
        let s = self.state.s;
        (self.piece.max(self.pieces.head)..self.pieces.tail).any(|k| {
            let p = self.pieces.get(k);
            if p.is_hold() { p.hold_time > 0.0 } else { p.end() > s + 1e-9 }
        })
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
        }
    }

    fn apply_speed_scale(&mut self, scale: f64) {
        let scale = if scale.is_finite() { scale.clamp(0.0, 1.0) } else { 0.0 };
        // A few scaled ticks are a blip (a base-pose correction, a rounding edge): the CLIK has
        // already kept the limits; only a scale that persists for 5 ticks says the path is too fast.
        let persistent = scale < 1.0 - 1e-9 && self.scaled_ticks >= 4;
        self.scaled_ticks = if scale < 1.0 - 1e-9 { self.scaled_ticks.saturating_add(1) } else { 0 };
        if persistent && self.state.v > 0.0 {
            let cap = (scale * self.state.v * 0.98).max(1e-4);
            if cap < self.speed_cap {
                self.speed_cap = cap;
                self.cap_quiet_ticks = 0;
                self.replan = true;
            }
        } else if self.speed_cap.is_finite() {
            self.cap_quiet_ticks += 1;
            // Recover in 25 % steps every 10 ms once the caller keeps up again.
            if self.cap_quiet_ticks as f64 * self.dt >= 0.01 {
                self.cap_quiet_ticks = 0;
                self.speed_cap *= 1.25;
                if self.speed_cap >= self.config.max_speed * 2.0 {
                    self.speed_cap = f64::INFINITY;
                }
                self.replan = true;
            }
        }
    }

    /// Piece containing path position `s` at or after the cursor (holds are entered when reached).
    fn locate(&mut self, s: f64) {
        while self.piece + 1 < self.pieces.tail {
            let p = self.pieces.get(self.piece);
            // Pieces ending within a nanometre count as passed: a blend can leave a line remainder of a
            // few ulps, too short to plan a trajectory over.
            let next_is_hold = self.pieces.get(self.piece + 1).is_hold();
            if p.is_hold() || s < p.end() - if next_is_hold { 0.0 } else { 1e-9 } {
                break;
            }
            self.piece += 1;
        }
        // Forget pieces behind the cursor.
        while self.pieces.head < self.piece {
            self.last_piece_orientation = {
                let p = self.pieces.get(self.pieces.head);
                geom::quaternion_exp(&p.rotation) * p.orientation
            };
            self.pieces.pop();
        }
    }

    fn cap_of(&self, k: u64) -> f64 {
        piece_cap(self.pieces.get(k), self.feed_override, self.config.max_speed).min(self.speed_cap)
    }

    /// Plans from `state`, reached `elapsed` seconds into the tick being computed.
    fn start_plan(&mut self, state: PathState, elapsed: f64) {
        self.start_plan_from(state, elapsed, false);
    }

    /// As [`start_plan`](Self::start_plan); `event` marks a re-plan in the middle of a trajectory
    /// (new segments, override, speed scale), which may keep the current one if nothing better fits.
    fn start_plan_from(&mut self, state: PathState, elapsed: f64, event: bool) {
        let previous_time = self.plan_time;
        self.plan_time = elapsed;
        self.state = state;
        if self.held {
            self.locate(state.s);
            if state.v <= 1e-12 && state.a.abs() <= 1e-12 {
                self.plan = Plan::Rest;
            } else {
                // The time-optimal stop from here: the shortest distance any jerk-limited stop needs.
                self.ruckig_velocity(state, 0.0);
                std::mem::swap(&mut self.trajectory, &mut self.candidate);
                self.plan = Plan::Ruckig { target: u64::MAX, position: f64::NAN, speed: 0.0, cap: 0.0, forced: false };
            }
            return;
        }
        loop {
            self.locate(state.s);
            if self.pieces.len() == 0 || self.piece >= self.pieces.tail {
                self.plan = Plan::Rest;
                return;
            }
            let current = *self.pieces.get(self.piece);
            if current.is_hold() && state.v <= 1e-12 {
                if current.hold_time > 0.0 {
                    self.enter_dwell();
                    return;
                }
                if self.piece + 1 < self.pieces.tail {
                    self.piece += 1;
                    continue;
                }
                self.plan = Plan::Rest;
                return;
            }
            break;
        }
        match self.config.mode {
            PlanningMode::Lookahead => self.plan_ruckig(state, event, previous_time),
            _ => self.plan_trapezoid(state),
        }
    }

    fn boundary_position(&self, k: u64) -> f64 {
        if k >= self.pieces.tail { self.path_end } else { self.pieces.get(k).start }
    }

    fn boundary_speed(&self, k: u64) -> f64 {
        if k >= self.pieces.tail { 0.0 } else { self.pieces.get(k).vb }
    }

    fn plan_ruckig(&mut self, state: PathState, event: bool, previous_time: f64) {
        let vrun = self.cap_of(self.piece);
        if vrun <= 1e-12 {
            // Standing on a hold while still creeping (within rounding of it): come to rest.
            self.ruckig_velocity(state, 0.0);
            std::mem::swap(&mut self.trajectory, &mut self.candidate);
            self.plan = Plan::Ruckig { target: u64::MAX, position: f64::NAN, speed: 0.0, cap: 0.0, forced: false };
            return;
        }
        let end = self.pieces.tail;
        let mut target = None;
        let mut arrival_cap = vrun;
        let mut jumped_over = None;
        let mut k = self.piece + 1;
        while k <= end && k <= self.piece + TARGET_WALK as u64 {
            let vb = self.boundary_speed(k);
            if vb < vrun {
                let mut m = k;
                if k < end {
                    // Aim straight at the boundary whose braking curve holds this one down, so that
                    // braking over many short pieces is one S-curve: any profile that decelerates
                    // at most at `a` into that boundary stays under its v² curve, which lies under
                    // the caps of the boundaries in between (their potentials are higher).
                    // The bound is conservative, not exact, so the trajectory is checked at this
                    // boundary below and falls back to stopping the braking here if it is too fast.
                    let p = self.pieces.get(k);
                    if vb < p.vcap && p.via_chain {
                        m = p.later_arg;
                        jumped_over = Some(k);
                    }
                }
                target = Some((m, self.boundary_speed(m)));
                arrival_cap = if m < end { self.pieces.get(m).vcap } else { 0.0 };
                break;
            }
            k += 1;
        }
        let (target, speed) = target.unwrap_or((k.min(end), vrun));
        let speed = speed.min(vrun);
        let position = self.boundary_position(target);
        if position - state.s <= 1e-12 && state.v <= 1e-12 && target >= end {
            self.plan = Plan::Rest;
            return;
        }
        self.stats.replans += 1;
        let mut planned = self.ruckig_to(state, position, speed, arrival_cap.min(vrun).max(speed), vrun);
        let (mut target, mut speed, mut position) = (target, speed, position);
        if let (Some(_), Some(k)) = (planned, jumped_over) {
            let (at, cap) = {
                let p = self.pieces.get(k);
                (p.start, p.vcap)
            };
            let passing = self.candidate.get_first_time_at_position(0, at).map(|t| candidate_state(&self.candidate, t).v);
            if passing.is_none_or(|v| v > cap * (1.0 + 1e-9)) {
                // Braking straight through would pass this boundary too fast: stop braking here.
                target = k;
                position = at;
                speed = self.boundary_speed(k).min(vrun);
                planned = self.ruckig_to(state, at, speed, cap.min(vrun).max(speed), vrun);
            }
        }
        // A re-plan from a state on the current trajectory can find the boundary's speed out of
        // reach by rounding (the current trajectory is time-optimal, at the edge of feasibility)
        // and fall back to the lowest speed reachable under the boundary's cap — faster than the
        // current trajectory arrives, and too fast for a cap just after it. The current
        // trajectory still meets the boundary's speed: keep it.
        let keeps_current = |arrival: f64, plan: &Plan| {
            event
                && arrival > speed * (1.0 + 1e-9) + 1e-12
                && matches!(*plan, Plan::Ruckig { target: t, position: p, speed: old, cap, forced: false }
                    if t == target && p == position && old <= speed * (1.0 + 1e-9) + 1e-12 && cap <= vrun * (1.0 + 1e-9))
        };
        // Arriving faster than the boundary's speed (the state cannot slow down in time: a feed
        // override or speed-scale drop while accelerating) is safe only if the piece after the
        // boundary still slows to its own boundary speed from there, starting at zero
        // acceleration as a position plan ends. Otherwise the position plan would throw away the
        // deceleration it has built up at every boundary and pass a tight corner further on too
        // fast: brake hardest instead (below), which reaches every speed at the earliest point.
        if let Some(arrival) = planned
            && arrival > speed * (1.0 + 1e-9) + 1e-12
            && !keeps_current(arrival, &self.plan)
            && arrival > self.arrival_bound(target) * (1.0 + 1e-9) + 1e-12
        {
            planned = self.slower_arrival(state, position, speed, vrun);
        }
        match planned {
            Some(arrival) if keeps_current(arrival, &self.plan) => {
                self.plan_time = previous_time;
            }
            Some(speed) => {
                std::mem::swap(&mut self.trajectory, &mut self.candidate);
                self.plan = Plan::Ruckig { target, position, speed, cap: vrun, forced: false };
            }
            None if event && self.current_meets_boundaries(vrun) => {
                // A re-plan mid-trajectory found nothing better (numerically at the edge of
                // feasibility, or new segments moved the target): keep following the current
                // trajectory — but only if it passes every boundary up to its target no faster
                // than today's boundary speeds, under a cap no higher than today's. After a feed
                // override or speed-scale drop it would cruise through the new, lower limits:
                // brake instead, below.
                self.plan_time = previous_time;
            }
            None => {
                // The limits cannot be met from here (override or speed-scale drop): brake along
                // the path as hard as allowed. Braking hardest reaches any speed at the earliest
                // point any plan could, so aiming at the lowest boundary speed within the stopping
                // distance meets every cap that can still be met; the executor tries a position
                // plan again every tick and leaves the brake as soon as one fits.
                let floor = self.brake_floor(state, speed.min(vrun));
                let braking = matches!(self.plan, Plan::Ruckig { forced: true, .. });
                if event && matches!(self.plan, Plan::Ruckig { forced: true, speed, .. } if speed <= floor * (1.0 + 1e-9) + 1e-12) {
                    // Already braking at least that far: keep the brake.
                    self.plan_time = previous_time;
                    return;
                }
                if !braking {
                    self.stats.forced_brakes += 1;
                }
                self.ruckig_velocity(state, floor);
                std::mem::swap(&mut self.trajectory, &mut self.candidate);
                self.plan = Plan::Ruckig { target: u64::MAX, position: f64::NAN, speed: floor, cap: vrun, forced: true };
            }
        }
    }

    /// Whether the current trajectory, planned under cap `≤ vrun`, passes every boundary from here
    /// to its target at no more than that boundary's speed now (the caps may have changed since
    /// it was planned). Only for a position plan (not a brake).
    fn current_meets_boundaries(&self, vrun: f64) -> bool {
        let Plan::Ruckig { target, cap, forced: false, .. } = self.plan else { return false };
        if target == u64::MAX || cap > vrun * (1.0 + 1e-9) {
            return false;
        }
        let mut k = self.piece + 1;
        while k <= target.min(self.pieces.tail) && k <= self.piece + TARGET_WALK as u64 {
            let Some(t) = self.trajectory.get_first_time_at_position(0, self.boundary_position(k)) else {
                // The trajectory ends before this boundary.
                break;
            };
            if candidate_state(&self.trajectory, t).v > self.boundary_speed(k) * (1.0 + 1e-9) + 1e-12 {
                return false;
            }
            k += 1;
        }
        true
    }

    /// The highest speed (m/s) at which the tool may arrive at boundary `k` (at zero acceleration)
    /// and still slow to the next boundary's speed within piece `k`: the exact hop, not the
    /// conservative chain bound, so it may exceed `vb_k`.
    fn arrival_bound(&self, k: u64) -> f64 {
        if k >= self.pieces.tail {
            return 0.0;
        }
        let p = self.pieces.get(k);
        self.braking.reach(p.length - hop_margin(p.length), self.boundary_speed(k + 1), p.vcap)
    }

    /// The speed a forced brake aims at from `state`: `speed`, lowered to the boundary speed of
    /// every boundary the tool could reach before coming to rest.
    fn brake_floor(&self, state: PathState, speed: f64) -> f64 {
        let reach = state.s + self.braking.stopping_distance(state.v, state.a) + 1e-9;
        let mut floor = speed;
        let mut k = self.piece + 1;
        while k <= self.pieces.tail && k <= self.piece + TARGET_WALK as u64 && self.boundary_position(k) <= reach {
            floor = floor.min(self.boundary_speed(k));
            k += 1;
        }
        floor.max(0.0)
    }

    /// A position-interface trajectory to (`position`, `speed`, 0) that neither overshoots nor
    /// backs up. If `speed` is out of reach from below, the highest reachable speed under it is
    /// found by bisection; if the state is too fast to arrive that slowly (the conservative margin
    /// of the braking bound was spent on an earlier boundary), the lowest reachable speed up to
    /// `speed_cap` (the boundary's own cap) is used. Returns the arrival speed, or None.
    fn ruckig_to(&mut self, state: PathState, position: f64, speed: f64, speed_cap: f64, vmax: f64) -> Option<f64> {
        match self.ruckig_check(state, position, speed, vmax) {
            Ok(()) => Some(speed),
            Err(too_fast) => {
                // The reachable arrival speeds form an interval; too fast, the answer is its lower
                // end above `speed`, too slow, its upper end below.
                let (mut lo, mut hi) = if too_fast { (speed, speed_cap) } else { (0.0, speed) };
                let mut found = None;
                if too_fast {
                    match self.ruckig_check(state, position, speed_cap, vmax) {
                        Ok(()) => found = Some(speed_cap),
                        // Even the boundary's own cap is too slow to arrive at: only a slower
                        // arrival may still exist.
                        Err(true) => return self.slower_arrival(state, position, speed, vmax),
                        // The cap needs more run-up than there is: the answer lies below it.
                        Err(false) => {}
                    }
                }
                // Holding the current speed is the usual answer over a very short piece.
                let hold = state.v.clamp(lo, hi);
                if state.a.abs() < 1e-9 && self.ruckig_check(state, position, hold, vmax).is_ok() {
                    if too_fast {
                        hi = hold
                    } else {
                        lo = hold
                    }
                    found = Some(hold);
                }
                // To a fraction of a ppm: arriving too fast by the bisection's last step would
                // carry the tool into the next piece over its cap by as much.
                for _ in 0..48 {
                    if hi - lo <= 1e-12 + 1e-10 * hi {
                        break;
                    }
                    let mid = 0.5 * (lo + hi);
                    match self.ruckig_check(state, position, mid, vmax) {
                        Ok(()) => {
                            found = Some(mid);
                            if too_fast { hi = mid } else { lo = mid }
                        }
                        Err(true) => lo = mid,
                        Err(false) => hi = mid,
                    }
                }
                let Some(found) = found else {
                    return if too_fast { self.slower_arrival(state, position, speed, vmax) } else { None };
                };
                self.ruckig_check(state, position, found, vmax).ok().map(|_| found)
            }
        }
    }

    /// The highest arrival speed below `speed` (m/s) at which a trajectory from `state` reaches
    /// `position`, or None. Needed because the arrival speeds reachable over a short distance are
    /// not one interval: slowing from v to v' at zero acceleration at both ends takes
    /// `(v + v')·√((v − v')/j)` in its triangular range, which *grows* as v' falls from v to v/3
    /// and shrinks below. When a boundary's speed rose after the tool committed to its run-up (the
    /// later boundaries arrived), that speed can be out of reach while a slower one is not, and
    /// slower at a boundary is always safe for everything after it. Leaves the trajectory in
    /// `candidate`.
    fn slower_arrival(&mut self, state: PathState, position: f64, speed: f64, vmax: f64) -> Option<f64> {
        self.ruckig_check(state, position, 0.0, vmax).ok()?;
        // 0 is reachable and `speed` is not: bisect for the top of the lower interval.
        let (mut lo, mut hi) = (0.0, speed);
        for _ in 0..48 {
            if hi - lo <= 1e-12 + 1e-10 * hi {
                break;
            }
            let mid = 0.5 * (lo + hi);
            match self.ruckig_check(state, position, mid, vmax) {
                Ok(()) => lo = mid,
                Err(_) => hi = mid,
            }
        }
        self.ruckig_check(state, position, lo, vmax).ok().map(|_| lo)
    }

    /// Computes the trajectory to (`position`, `speed`, 0); Err(true) if it would overshoot (too
    /// fast), Err(false) if it would back up (too slow).
    fn ruckig_check(&mut self, state: PathState, position: f64, speed: f64, vmax: f64) -> Result<(), bool> {
        self.input.control_interface = ControlInterface::Position;
        self.input.current_position[0] = state.s;
        self.input.current_velocity[0] = state.v;
        self.input.current_acceleration[0] = state.a;
        self.input.target_position[0] = position;
        self.input.target_velocity[0] = speed;
        self.input.target_acceleration[0] = 0.0;
        self.input.max_velocity[0] = vmax.max(speed);
        self.input.max_acceleration[0] = self.config.max_acceleration;
        self.input.max_jerk[0] = self.config.max_jerk;
        let result = self.otg.calculate(&self.input, &mut self.candidate);
        if !matches!(result, Ok(RuckigResult::Working) | Ok(RuckigResult::Finished)) {
            return Err(false);
        }
        // A trajectory that leaves [start, target] or backs up is infeasible. Which way: a target
        // faster than now needs more run-up than there is (too slow); a slower one cannot be
        // braked to in time (too fast).
        let too_fast = speed < state.v;
        let extrema = self.candidate.get_position_extrema()[0];
        let slack = 1e-9 + 1e-12 * position.abs();
        if extrema.max > position + slack || extrema.min < state.s - slack {
            return Err(too_fast);
        }
        // The tool must never back up along the path, not even for a moment inside the range.
        let profile = &self.candidate.get_profiles()[0][0];
        let mut v_min = f64::INFINITY;
        for i in 0..2 {
            if profile.brake.t[i] > 0.0 {
                v_min = v_min.min(phase_min_velocity(profile.brake.v[i], profile.brake.a[i], profile.brake.j[i], profile.brake.t[i]));
            }
        }
        for i in 0..7 {
            v_min = v_min.min(phase_min_velocity(profile.v[i], profile.a[i], profile.j[i], profile.t[i]));
        }
        if v_min < -1e-9 {
            return Err(too_fast);
        }
        Ok(())
    }

    fn ruckig_velocity(&mut self, state: PathState, speed: f64) {
        self.input.control_interface = ControlInterface::Velocity;
        self.input.current_position[0] = state.s;
        self.input.current_velocity[0] = state.v;
        self.input.current_acceleration[0] = state.a;
        self.input.target_velocity[0] = speed.max(0.0);
        self.input.target_acceleration[0] = 0.0;
        self.input.max_velocity[0] = state.v.max(speed).max(1e-9);
        // The velocity interface always has a solution for finite inputs within the limits.
        let _ = self.otg.calculate(&self.input, &mut self.candidate);
    }

    fn plan_trapezoid(&mut self, state: PathState) {
        let mut k = self.piece;
        while self.pieces.get(k).end() - state.s <= 1e-12 {
            if k + 1 >= self.pieces.tail || self.pieces.get(k + 1).is_hold() {
                if k + 1 < self.pieces.tail {
                    self.piece = k + 1;
                    let elapsed = self.plan_time;
                    self.start_plan(state, elapsed);
                } else {
                    self.plan = Plan::Rest;
                }
                return;
            }
            k += 1;
        }
        self.piece = k;
        let p = *self.pieces.get(k);
        let v_cruise = self.cap_of(k);
        let v_exit = self.boundary_speed(k + 1).min(v_cruise);
        let remaining = p.end() - state.s;
        let profile = Trapezoid::new(remaining, state.v, v_exit, v_cruise, self.config.max_acceleration);
        self.stats.replans += 1;
        self.plan = Plan::Trapezoid { piece: k, profile };
        self.plan_origin = state.s;
    }

    /// Starts the dwell of the hold under the cursor; the executor's loop spends time on it.
    fn enter_dwell(&mut self) {
        let p = *self.pieces.get(self.piece);
        self.motion = Motion::Dwelling;
        self.state = PathState { s: self.state.s.max(p.start), v: 0.0, a: 0.0, j: 0.0 };
        self.plan = Plan::Dwell { duration: p.hold_time };
    }

    /// Advances the executor by one tick: `t` is the time since the current plan started, at the
    /// end of this tick. Each pass of the loop either returns inside the current plan or spends
    /// the plan's whole remaining time and starts the next one from where it ended, in the same
    /// tick; so every plan — trajectory, trapezoid or dwell — hands over to the next the same way.
    fn advance(&mut self) {
        let mut t = self.plan_time + self.dt;
        for _ in 0..1024 {
            match self.plan {
                Plan::Rest => {
                    self.settle_at_rest();
                    return;
                }
                Plan::Dwell { duration } => {
                    if t < duration {
                        self.plan_time = t;
                        self.motion = Motion::Dwelling;
                        return;
                    }
                    // The dwell ended `rest` seconds before the end of this tick: mark the hold
                    // done and go on with what follows for the rest of the tick.
                    let rest = t - duration;
                    self.dwell_done += duration;
                    self.pieces.get_mut(self.piece).hold_time = 0.0;
                    self.motion = Motion::Moving;
                    self.start_plan(self.state, self.dt - rest);
                    t = rest;
                }
                Plan::Ruckig { target, position, speed, forced, .. } => {
                    let duration = self.trajectory.get_duration();
                    if t < duration {
                        self.plan_time = t;
                        self.state = self.ruckig_state(t);
                        self.motion = Motion::Moving;
                        self.locate(self.state.s);
                        self.check_cap_raise();
                        // A forced brake lasts only until a position plan fits again.
                        self.replan |= forced;
                        return;
                    }
                    let rest = t - duration;
                    // The trajectory's samples can pass its target by rounding (1e-11 m); its end
                    // is the target, but never behind a position already reported: s never backs up.
                    let end_state = if target == u64::MAX {
                        self.ruckig_state(duration)
                    } else {
                        PathState { s: position.max(self.state.s), v: speed, a: 0.0, j: 0.0 }
                    };
                    self.start_plan(end_state, self.dt - rest);
                    t = rest;
                }
                Plan::Trapezoid { piece, profile } => {
                    let duration = profile.duration();
                    if t < duration {
                        let st = profile.at(t);
                        self.plan_time = t;
                        self.state = PathState { s: self.plan_origin + st.s, v: st.v, a: st.a, j: st.j };
                        self.motion = Motion::Moving;
                        self.locate(self.state.s);
                        return;
                    }
                    let rest = t - duration;
                    let end = self.pieces.get(piece).end();
                    let end_state = PathState { s: end.max(self.state.s), v: profile.v_out, a: 0.0, j: 0.0 };
                    if self.piece == piece && piece + 1 < self.pieces.tail {
                        self.piece = piece + 1;
                    }
                    self.start_plan(end_state, self.dt - rest);
                    t = rest;
                }
            }
        }
    }

    fn settle_at_rest(&mut self) {
        self.state.v = 0.0;
        self.state.a = 0.0;
        self.state.j = 0.0;
        self.plan_time = 0.0;
        let was_moving = self.motion == Motion::Moving;
        if self.held {
            self.motion = Motion::Held;
            return;
        }
        let last = self.pieces.len() > 0 && self.pieces.get(self.pieces.tail - 1).flags.contains(SegmentFlags::LAST);
        if last && self.intake.len() == 0 && self.state.s >= self.path_end - 1e-9 {
            self.finish();
        } else if self.pieces.len() > 0 || self.intake.len() > 0 {
            if was_moving {
                self.stats.underruns += 1;
            }
            self.motion = Motion::Starved;
        } else {
            self.motion = Motion::Idle;
        }
    }

    fn finish(&mut self) {
        self.motion = Motion::Finished;
    }

    fn check_cap_raise(&mut self) {
        if let Plan::Ruckig { cap, .. } = self.plan
            && self.cap_of(self.piece) > cap * (1.0 + 1e-9)
        {
            self.replan = true;
        }
    }

    fn ruckig_state(&self, t: f64) -> PathState {
        candidate_state(&self.trajectory, t)
    }

    fn sample_geometry(&self) -> super::geometry::PathPoint {
        if self.pieces.len() == 0 || self.piece >= self.pieces.tail {
            return super::geometry::PathPoint { position: self.rest_point, tangent: Vector3::zeros(), curvature: Vector3::zeros() };
        }
        let p = self.pieces.get(self.piece);
        let local = (self.state.s - p.start).clamp(0.0, p.length);
        p.geometry.point(local, p.length)
    }

    fn sample(&mut self) -> PathSample {
        let state = self.state;
        let point = self.sample_geometry();
        self.rest_point = point.position;
        let mut pressure_advance = None;
        let (orientation, angular_velocity, seq, source_line, flags, flow, dwell_rate) = if self.pieces.len() > 0
            && self.piece < self.pieces.tail
        {
            let p = self.pieces.get(self.piece);
            let u = if p.length > 0.0 { ((state.s - p.start) / p.length).clamp(0.0, 1.0) } else { 0.0 };
            let q = if p.rotation.norm_squared() > 0.0 { geom::quaternion_exp(&(p.rotation * u)) * p.orientation } else { p.orientation };
            let w = if p.length > 0.0 { p.rotation * (state.v / p.length) } else { Vector3::zeros() };
            let dwell_rate = if self.motion == Motion::Dwelling && p.hold_time > 0.0 { p.hold_filament / p.hold_time } else { 0.0 };
            pressure_advance = p.pressure_advance;
            if u < p.split {
                let (seq, line, flags, flow) = p.first;
                (q, w, seq, line, flags, flow, dwell_rate)
            } else {
                (q, w, p.seq, p.source_line, p.flags, p.flow, dwell_rate)
            }
        } else {
            (self.last_piece_orientation, Vector3::zeros(), 0, 0, SegmentFlags::default(), 0.0, 0.0)
        };
        PathSample {
            position: point.position,
            velocity: point.tangent * state.v,
            acceleration: point.curvature * (state.v * state.v) + point.tangent * state.a,
            orientation,
            angular_velocity,
            s: state.s,
            speed: state.v,
            path_acceleration: state.a,
            path_jerk: state.j,
            seq,
            source_line,
            flags,
            flow,
            dwell_filament_rate: dwell_rate,
            pressure_advance,
            motion: self.motion,
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

/// The state of a one-DoF trajectory at time `t`.
fn candidate_state(trajectory: &Trajectory<1>, t: f64) -> PathState {
    let mut p = DataArrayOrVec::Stack([0.0f64; 1]);
    let mut v = DataArrayOrVec::Stack([0.0f64; 1]);
    let mut a = DataArrayOrVec::Stack([0.0f64; 1]);
    let mut j = DataArrayOrVec::Stack([0.0f64; 1]);
    let mut section = None;
    trajectory.at_time(t, &mut Some(&mut p), &mut Some(&mut v), &mut Some(&mut a), &mut Some(&mut j), &mut section);
    PathState { s: p[0], v: v[0].max(0.0), a: a[0], j: j[0] }
}

/// The lowest velocity of one constant-jerk phase starting at (`v`, `a`) and lasting `t`.
fn phase_min_velocity(v: f64, a: f64, j: f64, t: f64) -> f64 {
    let end = v + a * t + 0.5 * j * t * t;
    let mut lowest = v.min(end);
    if j != 0.0 {
        let tau = -a / j;
        if tau > 0.0 && tau < t {
            lowest = lowest.min(v + a * tau + 0.5 * j * tau * tau);
        }
    }
    lowest
}

/// Length (m) the backward pass keeps in hand when it slows from one boundary to the next within a
/// piece. Without it the boundary speed sits exactly on the edge of feasibility (the bisection of
/// [`Braking::reach`] finds it to the last ulp), and the executor's position-interface plan over
/// the piece, a degenerate problem there, comes out a hair too long or not at all.
fn hop_margin(length: f64) -> f64 {
    1e-9 + 1e-6 * length
}

/// The speed cap inside a piece (m/s): feed × override, the geometric cap.
fn piece_cap(p: &Piece, feed_override: f64, max_speed: f64) -> f64 {
    if p.is_hold() { 0.0 } else { (p.feed * feed_override).min(p.geometric_cap).min(max_speed) }
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
