//! The last check before a reply leaves: never a jump. Each target is held inside the joint's
//! position limits, and the step from the previous reply inside its velocity limit and the change
//! of step inside its acceleration limit, at the robot's own period. A target that needs clamping
//! is clamped, and counted: the service's commands already respect these limits, so a clamp means
//! something upstream went wrong (a restart, a skipped cycle), and the log line says which joint.

use strand_ipc::MAX_JOINTS;

/// The limits of one joint (rad, rad/s, rad/s²; or m, m/s, m/s²).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointBounds {
    /// Lowest position.
    pub lower: f64,
    /// Highest position.
    pub upper: f64,
    /// Largest speed.
    pub velocity: f64,
    /// Largest acceleration.
    pub acceleration: f64,
}

/// The replies sent so far, and the limits they keep.
#[derive(Clone, Debug)]
pub struct ReplyGuard {
    bounds: Vec<JointBounds>,
    period: f64,
    /// The last target sent (joint space).
    last: Option<[f64; MAX_JOINTS]>,
    velocity: [f64; MAX_JOINTS],
    /// The state before the last target, for [`ReplyGuard::take_back`].
    before: Option<([f64; MAX_JOINTS], [f64; MAX_JOINTS])>,
    /// Targets clamped so far.
    pub clamps: u64,
    /// The joint clamped last, for the log line.
    pub last_clamped_joint: Option<usize>,
}

impl ReplyGuard {
    /// A guard for joints with `bounds`, replying every `period` seconds (the robot's cycle).
    pub fn new(bounds: Vec<JointBounds>, period: f64) -> ReplyGuard {
        ReplyGuard { bounds, period, last: None, velocity: [0.0; MAX_JOINTS], before: None, clamps: 0, last_clamped_joint: None }
    }

    /// Starts from where the robot is (`q` measured, at rest): the next target steps from here.
    pub fn reset(&mut self, q: &[f64; MAX_JOINTS]) {
        self.last = Some(*q);
        self.velocity = [0.0; MAX_JOINTS];
    }

    /// Forgets the last target: the robot never got it (it came after the robot's cycle, and the
    /// robot kept the one before). The next target steps from the one before.
    pub fn take_back(&mut self) {
        if let Some((last, _)) = self.before.take() {
            // The robot held its previous target this cycle: it is at rest there.
            self.last = Some(last);
            self.velocity = [0.0; MAX_JOINTS];
        }
    }

    /// Whether the last target left the robot at rest (every joint's step below `1e-9`).
    pub fn at_rest(&self) -> bool {
        self.velocity.iter().all(|v| v.abs() * self.period < 1e-9)
    }

    /// The longest a hold takes to bring the robot to rest from full speed (s).
    pub fn longest_stop(&self) -> f64 {
        self.bounds.iter().map(|b| b.velocity / b.acceleration.max(1e-9)).fold(0.0, f64::max)
    }

    /// The last target sent (None before the first).
    pub fn last(&self) -> Option<&[f64; MAX_JOINTS]> {
        self.last.as_ref()
    }

    /// `target` (joint space) within the limits from the last reply; records it as sent.
    pub fn admit(&mut self, target: &[f64; MAX_JOINTS]) -> [f64; MAX_JOINTS] {
        let Some(prev) = self.last else {
            // Nothing sent yet: the caller resets to the measured position first.
            self.last = Some(*target);
            return *target;
        };
        self.before = Some((prev, self.velocity));
        let dt = self.period;
        let mut out = prev;
        let mut clamped = None;
        for (k, b) in self.bounds.iter().enumerate() {
            let mut x = target[k];
            if !x.is_finite() {
                x = prev[k];
                clamped = Some(k);
            }
            let x_in = x.clamp(b.lower, b.upper);
            // The step this cycle, inside what the acceleration allows from the last step, and
            // inside the velocity limit; braking first if the last step already was too fast.
            let v_wanted = (x_in - prev[k]) / dt;
            let dv = b.acceleration * dt;
            // Never faster than what can still stop before a position limit (the discrete
            // square-root law: after this step, braking at the acceleration limit stops in time).
            let stop = |room: f64| {
                let h = 0.5 * dv;
                (-h + (h * h + 2.0 * b.acceleration * room.max(0.0)).sqrt()).max(0.0)
            };
            let v_up = b.velocity.min(stop(b.upper - prev[k]));
            let v_down = b.velocity.min(stop(prev[k] - b.lower));
            let v = v_wanted.clamp(self.velocity[k] - dv, self.velocity[k] + dv).clamp(-v_down, v_up);
            let x_out = (prev[k] + v * dt).clamp(b.lower, b.upper);
            if (x_out - x).abs() > 1e-12 {
                clamped = Some(k);
            }
            self.velocity[k] = (x_out - prev[k]) / dt;
            out[k] = x_out;
        }
        if clamped.is_some() {
            self.clamps += 1;
            self.last_clamped_joint = clamped;
        }
        self.last = Some(out);
        out
    }

    /// The last target again (a hold), braking any motion left within the acceleration limit.
    /// Before any target ([`ReplyGuard::reset`] first), None.
    pub fn hold(&mut self) -> Option<[f64; MAX_JOINTS]> {
        let prev = self.last?;
        self.before = Some((prev, self.velocity));
        let dt = self.period;
        let mut out = prev;
        for (k, b) in self.bounds.iter().enumerate() {
            // Come to rest as fast as the acceleration limit allows: a held robot that was moving
            // must not stop in one cycle (that is a jump in velocity).
            let dv = b.acceleration * dt;
            let v = if self.velocity[k] > 0.0 { (self.velocity[k] - dv).max(0.0) } else { (self.velocity[k] + dv).min(0.0) };
            // No clamp to the limits: a hold stays where the robot is, even a hair outside them
            // (the session refuses a robot that starts clearly outside).
            out[k] = prev[k] + v * dt;
            self.velocity[k] = (out[k] - prev[k]) / dt;
        }
        self.last = Some(out);
        Some(out)
    }

    /// The first joint of `q` outside its limits by more than `tolerance` (rad or m), if any.
    pub fn outside_limits(&self, q: &[f64; MAX_JOINTS], tolerance: f64) -> Option<usize> {
        self.bounds.iter().enumerate().find(|(k, b)| q[*k] < b.lower - tolerance || q[*k] > b.upper + tolerance).map(|(k, _)| k)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn guard() -> ReplyGuard {
        let b = JointBounds { lower: -1.0, upper: 1.0, velocity: 1.0, acceleration: 10.0 };
        let mut g = ReplyGuard::new(vec![b; 2], 0.004);
        g.reset(&[0.0; MAX_JOINTS]);
        g
    }

    #[test]
    fn a_jump_is_spread_over_cycles_within_the_limits() {
        let mut g = guard();
        let target = {
            let mut t = [0.0; MAX_JOINTS];
            t[0] = 0.5;
            t
        };
        let (mut prev, mut v_prev) = (0.0, 0.0);
        for _ in 0..400 {
            let out = g.admit(&target);
            let v = (out[0] - prev) / 0.004;
            assert!(v.abs() <= 1.0 + 1e-9, "speed {v}");
            assert!(((v - v_prev) / 0.004).abs() <= 10.0 + 1e-6, "acceleration {}", (v - v_prev) / 0.004);
            (prev, v_prev) = (out[0], v);
        }
        assert!(g.clamps > 0);
        assert!((prev - 0.5).abs() < 0.05, "it gets there: {prev}");
    }

    #[test]
    fn a_hold_brakes_within_the_acceleration_limit() {
        let mut g = guard();
        let mut t = [0.0; MAX_JOINTS];
        let mut before = 0.0;
        for k in 1..=100 {
            t[0] = (k as f64 * 0.004 * 0.5).min(0.9);
            before = g.last().unwrap()[0];
            g.admit(&t);
        }
        let mut prev = g.last().unwrap()[0];
        let mut v_prev = (prev - before) / 0.004;
        assert!(v_prev > 0.4, "moving: {v_prev}");
        for _ in 0..100 {
            let x = g.hold().unwrap()[0];
            let v = (x - prev) / 0.004;
            assert!(((v - v_prev) / 0.004).abs() <= 10.0 + 1e-6);
            (prev, v_prev) = (x, v);
        }
        assert_eq!(v_prev, 0.0, "at rest");
    }

    #[test]
    fn a_limit_is_approached_braking_not_hit() {
        // A target past the upper limit (1 rad), from 0.5 rad: the guard brakes in time.
        let mut g = guard();
        let mut t = [0.0; MAX_JOINTS];
        t[0] = 5.0;
        g.reset(&{
            let mut q = [0.0; MAX_JOINTS];
            q[0] = 0.5;
            q
        });
        let (mut prev, mut v_prev) = (0.5, 0.0);
        for _ in 0..500 {
            let x = g.admit(&t)[0];
            let v = (x - prev) / 0.004;
            assert!(x <= 1.0 + 1e-12, "past the limit: {x}");
            assert!(((v - v_prev) / 0.004).abs() <= 10.0 + 1e-6, "{} rad/s² at {x}", (v - v_prev) / 0.004);
            (prev, v_prev) = (x, v);
        }
        assert!(prev > 0.99 && v_prev.abs() < 1e-9, "at the limit, at rest: {prev} {v_prev}");
    }

    #[test]
    fn a_taken_back_target_leaves_the_robot_at_rest_where_it_was() {
        let mut g = guard();
        let mut t = [0.0; MAX_JOINTS];
        for k in 1..=50 {
            t[0] = k as f64 * 0.0001;
            g.admit(&t);
        }
        let before = g.last().unwrap()[0];
        t[0] += 0.0001;
        g.admit(&t);
        g.take_back();
        assert_eq!(g.last().unwrap()[0], before);
        assert!(g.at_rest(), "the robot held its previous target: at rest");
    }

    #[test]
    fn non_finite_and_out_of_range_targets_are_refused() {
        let mut g = guard();
        let mut t = [0.0; MAX_JOINTS];
        t[0] = f64::NAN;
        t[1] = 5.0;
        for _ in 0..1000 {
            let out = g.admit(&t);
            assert!(out[0] == 0.0 && out[1] <= 1.0);
        }
        assert_eq!(g.clamps, 1000);
    }
}
