//! A joint's limits, and the one rule that keeps a joint inside them from one step to the next.
//!
//! Two stages limit joint motion: the controller's final command stage (every command the service
//! publishes) and each driver's reply guard (every answer that leaves for the robot, after a hold
//! or a missed cycle as well). They used to do it each their own way — the controller let a joint
//! run at full speed into its position limit and stop there dead, the guard braked before it — and
//! the guard kept its own copy of these limits without the jerk. Both now take a step through
//! [`JointLimits::step`]: within the speed limit, within the acceleration limit of the velocity it
//! has, never faster towards a position limit than it can still brake to rest before it, and never
//! further out than the limit (or than where it is, if it starts outside).

/// Limits of one joint. Position and velocity come from the URDF; acceleration and jerk from config
/// (URDF before 1.2 has none; a 1.2 file's values are used until config sets them), `f64::INFINITY`
/// when neither gives one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointLimits {
    /// Lowest position (rad or m); `-inf` for a continuous joint.
    pub lower: f64,
    /// Highest position (rad or m); `+inf` for a continuous joint.
    pub upper: f64,
    /// Largest speed (rad/s or m/s).
    pub velocity: f64,
    /// Largest acceleration (rad/s² or m/s²).
    pub acceleration: f64,
    /// Largest jerk (rad/s³ or m/s³).
    pub jerk: f64,
}

/// One step a joint took ([`JointLimits::step`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointStep {
    /// Where it is after the step (rad or m).
    pub position: f64,
    /// Its velocity over the step (rad/s or m/s).
    pub velocity: f64,
    /// The step is not the one wanted: a limit held it.
    pub clamped: bool,
}

impl JointLimits {
    /// Midpoint of the position range (rad or m); 0 for a continuous joint.
    pub fn middle(&self) -> f64 {
        if self.lower.is_finite() && self.upper.is_finite() { 0.5 * (self.lower + self.upper) } else { 0.0 }
    }

    /// The fastest a joint may move towards a position limit `room` away (rad or m) in a step of
    /// `dt` (s) so that, braking from there by the acceleration limit every step (as
    /// [`JointLimits::step`] moves: the position advances by each step's velocity), it still comes
    /// to rest before the limit (rad/s or m/s). The discrete square-root law, exact for those
    /// steps: from `v` in `[m·Δv, (m+1)·Δv)` (`Δv = a·dt`) the step and the braking after it cover
    /// `dt·((m+1)·v − Δv·m(m+1)/2)`, so a joint that follows it never brakes harder than the
    /// acceleration limit, which the continuous law `√(2·a·room)` would break near the end.
    /// Infinite for a continuous joint; 0 at or past the limit.
    pub(crate) fn speed_to_stop_within(&self, room: f64, dt: f64) -> f64 {
        let room = room.max(0.0);
        let dv = self.acceleration * dt;
        if !dv.is_finite() || !room.is_finite() {
            // No acceleration limit: it may stop on the limit in one step (or has no limit).
            return room / dt;
        }
        // The number of whole braking steps: the largest m with dt·Δv·m(m+1)/2 ≤ room.
        let covered = |m: f64| dt * dv * m * (m + 1.0) / 2.0;
        let mut m = ((-1.0 + (1.0 + 8.0 * room / (dt * dv)).sqrt()) / 2.0).floor().max(0.0);
        if covered(m) > room && m > 0.0 {
            m -= 1.0;
        } else if covered(m + 1.0) <= room {
            m += 1.0;
        }
        ((room / dt + dv * m * (m + 1.0) / 2.0) / (m + 1.0)).min((m + 1.0) * dv)
    }

    /// Whether `room` (rad or m) is surely more than a joint at `speed` (> 0, rad/s or m/s) needs
    /// to brake before a limit, so that [`JointLimits::speed_to_stop_within`] is above `speed`
    /// and need not be evaluated. Braking in steps from `v = (m + f)·Δv` covers
    /// `dt·Δv·(m+1)(m/2 + f) ≤ v²/(2a) + dt·(v + Δv)/2`; a room of `v²/(2a) + dt·(v + Δv)` leaves
    /// `dt·(v + Δv)/2` to spare, about `Δv/2` of speed above `v`: far beyond any rounding, so the
    /// step taken is the one the law would give, to the bit. Multiplied out: no division.
    #[inline]
    fn room_is_ample(&self, room: f64, speed: f64, dt: f64) -> bool {
        let a = self.acceleration;
        let dv = a * dt;
        dv > 0.0 && dv.is_finite() && 2.0 * a * room >= speed * speed + 2.0 * a * dt * (speed + dv)
    }

    /// One step of `dt` (s) for a joint at `position` moving at `velocity`, that wants to move at
    /// `wanted` (rad, rad/s; or m, m/s): the wanted velocity within the speed limit and within the
    /// acceleration limit of `velocity` (a joint already faster than its limit slows at the
    /// acceleration limit), never faster towards a position limit than
    /// [`JointLimits::speed_to_stop_within`] allows (this one wins over the acceleration window:
    /// a limit is never passed), and the position never further out than the limit, or than where
    /// it is if it starts outside. `clamped` when the step is not the wanted one (beyond
    /// `1e-9 × (1 + velocity limit)`, or the position held).
    pub fn step(&self, position: f64, velocity: f64, wanted: f64, dt: f64) -> JointStep {
        let dv = self.acceleration * dt;
        let (mut lo, mut hi) = ((-self.velocity).max(velocity - dv), self.velocity.min(velocity + dv));
        if lo > hi {
            // Faster than the limit already (a robot that starts moving, or a limit lowered):
            // slow down at the acceleration limit.
            let v = if velocity > 0.0 { velocity - dv } else { velocity + dv };
            (lo, hi) = (v, v);
        }
        // The braking law (a square root and three divisions a side) only where it may bind: a
        // joint far from a limit, or moving away from it, is not slowed by it.
        let v = wanted.max(lo).min(hi);
        let down = if v > 0.0 || (v < 0.0 && self.room_is_ample(position - self.lower, -v, dt)) {
            f64::INFINITY
        } else {
            self.speed_to_stop_within(position - self.lower, dt)
        };
        let v = v.max(-down);
        let up = if v < 0.0 || (v > 0.0 && self.room_is_ample(self.upper - position, v, dt)) {
            f64::INFINITY
        } else {
            self.speed_to_stop_within(self.upper - position, dt)
        };
        let v = v.min(up);
        let tol = 1e-9 * (1.0 + self.velocity);
        let mut clamped = !(v >= wanted - tol && v <= wanted + tol);
        let (q_lo, q_hi) = (self.lower.min(position), self.upper.max(position));
        let mut q = position + v * dt;
        if q > q_hi + 1e-12 || q < q_lo - 1e-12 {
            clamped = true;
        }
        q = q.max(q_lo).min(q_hi);
        JointStep { position: q, velocity: (q - position) / dt, clamped }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const L: JointLimits = JointLimits { lower: -1.0, upper: 1.0, velocity: 2.0, acceleration: 10.0, jerk: f64::INFINITY };
    const DT: f64 = 0.004;

    /// [`JointLimits::step`] as it was before it skipped the braking law where that cannot bind:
    /// both sides always evaluated.
    fn step_evaluating_both_sides(l: &JointLimits, position: f64, velocity: f64, wanted: f64, dt: f64) -> JointStep {
        let dv = l.acceleration * dt;
        let (mut lo, mut hi) = ((-l.velocity).max(velocity - dv), l.velocity.min(velocity + dv));
        if lo > hi {
            let v = if velocity > 0.0 { velocity - dv } else { velocity + dv };
            (lo, hi) = (v, v);
        }
        let up = l.speed_to_stop_within(l.upper - position, dt);
        let down = l.speed_to_stop_within(position - l.lower, dt);
        let v = wanted.max(lo).min(hi).max(-down).min(up);
        let tol = 1e-9 * (1.0 + l.velocity);
        let mut clamped = !(v >= wanted - tol && v <= wanted + tol);
        let (q_lo, q_hi) = (l.lower.min(position), l.upper.max(position));
        let mut q = position + v * dt;
        if q > q_hi + 1e-12 || q < q_lo - 1e-12 {
            clamped = true;
        }
        q = q.max(q_lo).min(q_hi);
        JointStep { position: q, velocity: (q - position) / dt, clamped }
    }

    /// Skipping the braking law where it cannot bind changes no step, to the bit: random limits
    /// (continuous joints, no acceleration limit among them), positions near and past the limits,
    /// speeds at and beyond the limit, wishes of every size (and NaN), tick lengths 125 µs to 8 ms.
    #[test]
    fn skipping_the_braking_law_where_it_cannot_bind_changes_no_bit() {
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut skipped = 0;
        for case in 0..400_000 {
            let velocity_limit = 0.1 + 5.0 * next();
            let l = JointLimits {
                lower: if case % 50 == 0 { f64::NEG_INFINITY } else { -3.0 * next() },
                upper: if case % 70 == 0 { f64::INFINITY } else { 3.0 * next() },
                velocity: velocity_limit,
                acceleration: if case % 90 == 0 { f64::INFINITY } else { 0.5 + 200.0 * next() },
                jerk: f64::INFINITY,
            };
            let dt = [0.000125, 0.001, 0.004, 0.008][case % 4];
            let span = if l.lower.is_finite() && l.upper.is_finite() { l.upper - l.lower } else { 2.0 };
            let base = if l.lower.is_finite() { l.lower } else { -1.0 };
            // Mostly within 2 % of a limit or inside; some outside.
            let position = match case % 5 {
                0 => base - 0.01 * next(),
                1 => base + 0.02 * span * next(),
                2 => base + span * (1.0 - 0.02 * next()),
                _ => base + span * (1.2 * next() - 0.1),
            };
            let velocity = velocity_limit * (2.4 * next() - 1.2);
            let wanted = match case % 7 {
                0 => f64::NAN,
                1 => velocity,
                _ => velocity_limit * (6.0 * next() - 3.0),
            };
            let (a, b) = (l.step(position, velocity, wanted, dt), step_evaluating_both_sides(&l, position, velocity, wanted, dt));
            assert_eq!(
                (a.position.to_bits(), a.velocity.to_bits(), a.clamped),
                (b.position.to_bits(), b.velocity.to_bits(), b.clamped),
                "case {case}: {l:?} at {position}, {velocity}, wanting {wanted}: {a:?} against {b:?}"
            );
            let v = wanted.max(-velocity_limit).min(velocity_limit);
            skipped += (v > 0.0 && l.room_is_ample(l.upper - position, v, dt)) as usize;
        }
        assert!(skipped > 100_000, "the law was skipped {skipped} times");
    }

    #[test]
    fn a_wanted_step_inside_every_limit_is_taken_to_the_bit() {
        let s = L.step(0.1, 0.5, 0.52, DT);
        assert_eq!((s.position, s.clamped), (0.1 + 0.52 * DT, false));
    }

    #[test]
    fn speed_and_acceleration_hold_a_jump() {
        // From rest, a jump to 1.0 rad: 0.04 rad/s more per step at most.
        let s = L.step(0.0, 0.0, 1.0 / DT, DT);
        assert!(s.clamped && (s.velocity - 10.0 * DT).abs() < 1e-12, "{s:?}");
        // Faster than the limit already: it slows at the acceleration limit.
        let s = L.step(0.0, 3.0, 3.0, DT);
        assert!((s.velocity - (3.0 - 10.0 * DT)).abs() < 1e-12 && s.clamped, "{s:?}");
    }

    #[test]
    fn a_joint_driven_at_its_limit_brakes_and_stops_on_it_within_the_acceleration() {
        // At full speed towards the upper limit, wanting to go on: it brakes in time, at the
        // acceleration limit at most, and comes to rest at the limit, never past it.
        let (mut q, mut v) = (0.0, 2.0);
        let mut worst_acc: f64 = 0.0;
        for _ in 0..2000 {
            let s = L.step(q, v, 2.0, DT);
            worst_acc = worst_acc.max(((s.velocity - v) / DT).abs());
            (q, v) = (s.position, s.velocity);
            assert!(q <= 1.0, "{q}");
        }
        assert!(worst_acc <= 10.0 * (1.0 + 1e-9), "braked at {worst_acc} rad/s²");
        assert!((q - 1.0).abs() < 1e-3 && v.abs() < 1e-6, "at rest on the limit: q {q}, v {v}");
    }

    #[test]
    fn a_joint_outside_its_limit_goes_no_further_and_may_come_back() {
        let s = L.step(1.2, 0.0, 0.5, DT);
        assert_eq!((s.position, s.velocity, s.clamped), (1.2, 0.0, true));
        let s = L.step(1.2, 0.0, -0.5, DT);
        assert!(s.velocity < 0.0 && s.position < 1.2, "{s:?}");
    }

    #[test]
    fn a_continuous_joint_has_no_position_limit() {
        let c = JointLimits { lower: f64::NEG_INFINITY, upper: f64::INFINITY, ..L };
        assert_eq!(c.middle(), 0.0);
        let s = c.step(100.0, 2.0, 2.0, DT);
        assert_eq!((s.position, s.clamped), (100.0 + 2.0 * DT, false));
    }

    #[test]
    fn from_any_feasible_state_any_wish_keeps_every_limit() {
        // Random states that can still stop before the limits, random wishes (a small LCG: the
        // crate depends on nothing), 200 steps each: inside the limits, within speed and
        // acceleration, every step.
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        for case in 0..2000 {
            let (mut q, mut v) = (-1.0 + 2.0 * next(), 0.0);
            let room_up = L.speed_to_stop_within(1.0 - q, DT).min(2.0);
            let room_down = L.speed_to_stop_within(q + 1.0, DT).min(2.0);
            v += -room_down + (room_up + room_down) * next();
            for _ in 0..200 {
                let wanted = -6.0 + 12.0 * next();
                let s = L.step(q, v, wanted, DT);
                assert!((-1.0..=1.0).contains(&s.position), "case {case}: {s:?}");
                assert!(s.velocity.abs() <= 2.0 + 1e-9, "case {case}: {s:?}");
                assert!(((s.velocity - v) / DT).abs() <= 10.0 * (1.0 + 1e-6), "case {case}: from {v} to {}", s.velocity);
                (q, v) = (s.position, s.velocity);
            }
        }
    }
}
