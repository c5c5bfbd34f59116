//! The executor: one loop over plans (a rsruckig trajectory to the next binding boundary, a
//! trapezoid, a dwell) that spends each tick's time, the forced brake when no plan fits, and the
//! tick's sample.

#[allow(clippy::wildcard_imports)]
use super::*;

impl PathEngine {
    pub(super) fn apply_speed_scale(&mut self, scale: f64) {
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
    pub(super) fn locate(&mut self, s: f64) {
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
            self.last_piece_axes = {
                let p = self.pieces.get(self.pieces.head);
                super::blend::sum(&p.axes, &p.axes_delta)
            };
            self.pieces.pop();
        }
    }

    pub(super) fn cap_of(&self, k: u64) -> f64 {
        piece_cap(self.pieces.get(k), self.feed_override, self.config.max_speed).min(self.speed_cap)
    }

    /// Plans from `state`, reached `elapsed` seconds into the tick being computed.
    pub(super) fn start_plan(&mut self, state: PathState, elapsed: f64) {
        self.start_plan_from(state, elapsed, false);
    }

    /// As [`start_plan`](Self::start_plan); `event` marks a re-plan in the middle of a trajectory
    /// (new segments, override, speed scale), which may keep the current one if nothing better fits.
    pub(super) fn start_plan_from(&mut self, state: PathState, elapsed: f64, event: bool) {
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
                if current.wait {
                    // A heat wait: stand here until released (`settle_at_rest` says Waiting).
                    self.state = PathState { s: state.s.max(current.start), v: 0.0, a: 0.0, j: 0.0 };
                    self.plan = Plan::Rest;
                    return;
                }
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

    pub(super) fn boundary_position(&self, k: u64) -> f64 {
        if k >= self.pieces.tail { self.path_end } else { self.pieces.get(k).start }
    }

    pub(super) fn boundary_speed(&self, k: u64) -> f64 {
        if k >= self.pieces.tail { 0.0 } else { self.pieces.get(k).vb }
    }

    pub(super) fn plan_ruckig(&mut self, state: PathState, event: bool, previous_time: f64) {
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
            Some(arrival) if event && self.current_is_sooner(target, position, arrival, vrun, previous_time) => {
                self.stats.solver_detours += 1;
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
    pub(super) fn current_meets_boundaries(&self, vrun: f64) -> bool {
        let Plan::Ruckig { target, speed, cap, forced: false, .. } = self.plan else { return false };
        if target == u64::MAX || cap > vrun * (1.0 + 1e-9) {
            return false;
        }
        // The target itself by the speed the plan arrives at: sampled, the arrival time found by
        // position can land an ulp early, where a stop is still a few nm/s from rest.
        if target <= self.pieces.tail && speed > self.boundary_speed(target) * (1.0 + 1e-9) + 1e-12 {
            return false;
        }
        let mut k = self.piece + 1;
        while k < target.min(self.pieces.tail + 1) && k <= self.piece + TARGET_WALK as u64 {
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

    /// Whether the current trajectory, aimed at the same boundary (`target` at `position`, m)
    /// arriving at the same speed (`arrival`, m/s) and still within today's limits under `vrun`,
    /// gets there sooner than the candidate just planned from a state `previous_time` seconds into
    /// it. It should never: by Bellman's principle the rest of a time-optimal trajectory is
    /// time-optimal from any of its states. But rsruckig 3.0.1 can answer such a state with a
    /// valid profile far slower than that rest: where the state's coast to zero acceleration
    /// lands on the speed limit to the bit, and on about 1 % of the states of random trajectories
    /// (measured: up to seconds slower, a 0.15 m travel taking 1.17 s instead of 0.66 s). Following
    /// the current trajectory is then both valid and faster.
    pub(super) fn current_is_sooner(&self, target: u64, position: f64, arrival: f64, vrun: f64, previous_time: f64) -> bool {
        let same_aim = matches!(self.plan, Plan::Ruckig { target: t, position: p, speed, forced: false, .. }
            if t == target && p == position && (speed - arrival).abs() <= 1e-9 * arrival.max(1e-3));
        same_aim
            && self.candidate.get_duration() > self.trajectory.get_duration() - previous_time + 1e-6
            && self.current_meets_boundaries(vrun)
    }

    /// The highest speed (m/s) at which the tool may arrive at boundary `k` (at zero acceleration)
    /// and still slow to the next boundary's speed within piece `k`: the exact hop, not the
    /// conservative chain bound, so it may exceed `vb_k`.
    pub(super) fn arrival_bound(&self, k: u64) -> f64 {
        if k >= self.pieces.tail {
            return 0.0;
        }
        hop_speed(&self.braking, self.pieces.get(k), self.boundary_speed(k + 1))
    }

    /// The speed a forced brake aims at from `state`: `speed`, lowered to the boundary speed of
    /// every boundary the tool could reach before coming to rest.
    pub(super) fn brake_floor(&self, state: PathState, speed: f64) -> f64 {
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
    pub(super) fn ruckig_to(&mut self, state: PathState, position: f64, speed: f64, speed_cap: f64, vmax: f64) -> Option<f64> {
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
    pub(super) fn slower_arrival(&mut self, state: PathState, position: f64, speed: f64, vmax: f64) -> Option<f64> {
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
    pub(super) fn ruckig_check(&mut self, state: PathState, position: f64, speed: f64, vmax: f64) -> Result<(), bool> {
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

    pub(super) fn ruckig_velocity(&mut self, state: PathState, speed: f64) {
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

    pub(super) fn plan_trapezoid(&mut self, state: PathState) {
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
    pub(super) fn enter_dwell(&mut self) {
        let p = *self.pieces.get(self.piece);
        self.motion = Motion::Dwelling;
        self.state = PathState { s: self.state.s.max(p.start), v: 0.0, a: 0.0, j: 0.0 };
        self.plan = Plan::Dwell { duration: p.hold_time };
    }

    /// Advances the executor by one tick: `t` is the time since the current plan started, at the
    /// end of this tick. Each pass of the loop either returns inside the current plan or spends
    /// the plan's whole remaining time and starts the next one from where it ended, in the same
    /// tick; so every plan — trajectory, trapezoid or dwell — hands over to the next the same way.
    pub(super) fn advance(&mut self) {
        let mut t = self.plan_time + self.dt;
        self.tick_dwell_filament = 0.0;
        for _ in 0..1024 {
            match self.plan {
                Plan::Rest => {
                    self.settle_at_rest();
                    return;
                }
                Plan::Dwell { duration } => {
                    // The part of this tick inside the dwell: from where the tick (or the dwell,
                    // if it began inside the tick) starts to where the tick (or the dwell) ends.
                    let p = self.pieces.get(self.piece);
                    if p.hold_time > 0.0 {
                        let inside = t.min(duration) - (t - self.dt).max(0.0);
                        self.tick_dwell_filament += p.hold_filament / p.hold_time * inside.max(0.0);
                    }
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

    pub(super) fn settle_at_rest(&mut self) {
        self.state.v = 0.0;
        self.state.a = 0.0;
        self.state.j = 0.0;
        self.plan_time = 0.0;
        let was_moving = self.motion == Motion::Moving;
        if self.held {
            self.motion = Motion::Held;
            return;
        }
        if self.pieces.len() > 0 && self.piece < self.pieces.tail && self.pieces.get(self.piece).wait {
            self.motion = Motion::Waiting;
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

    pub(super) fn finish(&mut self) {
        self.motion = Motion::Finished;
    }

    pub(super) fn check_cap_raise(&mut self) {
        if let Plan::Ruckig { cap, .. } = self.plan
            && self.cap_of(self.piece) > cap * (1.0 + 1e-9)
        {
            self.replan = true;
        }
    }

    pub(super) fn ruckig_state(&self, t: f64) -> PathState {
        candidate_state(&self.trajectory, t)
    }

    pub(super) fn sample_geometry(&self) -> PathPoint {
        if self.pieces.len() == 0 || self.piece >= self.pieces.tail {
            return PathPoint { position: self.rest_point, tangent: Vector3::zeros(), curvature: Vector3::zeros() };
        }
        let p = self.pieces.get(self.piece);
        let local = (self.state.s - p.start).clamp(0.0, p.length);
        p.geometry.point(local, p.length)
    }

    pub(super) fn sample(&mut self) -> PathSample {
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
            let dwell_rate = self.tick_dwell_filament / self.dt;
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
        let (axes, axes_velocity) = self.sample_axes();
        PathSample {
            axes,
            axes_velocity,
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

impl PathEngine {
    /// The external axes and their velocities at the cursor (see [`PathSample::axes`]).
    fn sample_axes(&self) -> ([f64; MAX_EXTERNAL_AXES], [f64; MAX_EXTERNAL_AXES]) {
        if self.pieces.len() == 0 || self.piece >= self.pieces.tail {
            return (self.last_piece_axes, [0.0; MAX_EXTERNAL_AXES]);
        }
        let p = self.pieces.get(self.piece);
        let (fraction, rate) = if p.is_hold() {
            match self.plan {
                // The smooth step over the dwell: S(τ) = 10τ³ − 15τ⁴ + 6τ⁵, S'(τ) = 30τ²(1 − τ)².
                Plan::Dwell { duration } if duration > 0.0 && self.motion == Motion::Dwelling => {
                    let tau = (self.plan_time / duration).clamp(0.0, 1.0);
                    let step = tau * tau * tau * (10.0 + tau * (-15.0 + 6.0 * tau));
                    let slope = 30.0 * tau * tau * (1.0 - tau) * (1.0 - tau) / duration;
                    (step, slope)
                }
                // Done (its time spent) or not begun.
                _ => (if p.hold_time == 0.0 { 1.0 } else { 0.0 }, 0.0),
            }
        } else if p.length > 0.0 {
            (((self.state.s - p.start) / p.length).clamp(0.0, 1.0), self.state.v / p.length)
        } else {
            (0.0, 0.0)
        };
        (std::array::from_fn(|i| p.axes[i] + p.axes_delta[i] * fraction), std::array::from_fn(|i| p.axes_delta[i] * rate))
    }
}

/// The state of a one-DoF trajectory at time `t`.
pub(super) fn candidate_state(trajectory: &Trajectory<1>, t: f64) -> PathState {
    let mut p = DataArrayOrVec::Stack([0.0f64; 1]);
    let mut v = DataArrayOrVec::Stack([0.0f64; 1]);
    let mut a = DataArrayOrVec::Stack([0.0f64; 1]);
    let mut j = DataArrayOrVec::Stack([0.0f64; 1]);
    let mut section = None;
    trajectory.at_time(t, &mut Some(&mut p), &mut Some(&mut v), &mut Some(&mut a), &mut Some(&mut j), &mut section);
    PathState { s: p[0], v: v[0].max(0.0), a: a[0], j: j[0] }
}

/// The lowest velocity of one constant-jerk phase starting at (`v`, `a`) and lasting `t`.
pub(super) fn phase_min_velocity(v: f64, a: f64, j: f64, t: f64) -> f64 {
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
