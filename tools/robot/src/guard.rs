//! The last check before a reply leaves: never a jump, never an overshoot. Each target is held
//! inside the joint's position limits, and the step from the previous reply inside its velocity
//! limit and the change of step inside its acceleration limit, at the robot's own period.
//!
//! In step with the service, an answer is the service's command unchanged: its commands already
//! keep these limits. After a late, missed or held cycle the robot stood still (a hold, or RSI
//! throwing an answer away) while the service's command kept moving, so the answers must *catch
//! up* with a moving target. Limiting only the change of step towards it (the guard before this
//! one) accelerates until it reaches the target and only then brakes: it passes it, and the next
//! catch-up passes it the other way — it rings, and a print faults on its Cartesian error. Here
//! every joint catches up the way a time-optimal double integrator chases a target that moves at
//! the target's own velocity (estimated from the service's commands): in the target's frame the
//! relative speed never exceeds what can still brake to zero on the gap left (the discrete
//! square-root law, the same one that brakes towards the position limits), so the gap closes
//! without a sign change. The joints are also *synchronised*: each one's relative acceleration is
//! scaled so that all end together with the slowest. A hold at path speed leaves every joint's gap
//! and relative velocity proportional to the path's joint velocity, so the synchronised catch-up
//! keeps them proportional: the tool falls behind along its path and catches up along it, instead
//! of each joint arriving on its own time and the tool leaving the path sideways.
//!
//! The catch-up law uses [`CATCH_UP_SHARE`] of each joint's acceleration limit; the rest is
//! left for the target's own acceleration, so a target that brakes while it is chased is not
//! passed either. Its length is bounded (see [`catch_up_bound`]): behind a target moving at `u`
//! with a gap `g`, from rest, the catch-up takes at most `|u|/A + 2·√((|g| + u²/2A)/A)` plus two
//! cycles, with `A` the share of the acceleration limit. A clamp (an answer that is not the
//! service's command) happens only while catching up; each is counted, and the log line says which
//! joint.

use strand_wire::MAX_JOINTS;

/// The share of each joint's acceleration limit the catch-up law plans with (the rest is the
/// target's own acceleration: a target that brakes while it is chased is not passed).
pub const CATCH_UP_SHARE: f64 = 0.5;

/// Below this (rad or m) an answer is the service's command.
const SAME: f64 = 1e-12;

/// The limits of one joint, as the controller's final command stage keeps them (the shared
/// `strand-limits` crate): the guard's last stage is the same step rule.
pub use strand_limits::JointLimits;

/// The replies sent so far, and the limits they keep.
#[derive(Clone, Debug)]
pub struct ReplyGuard {
    bounds: Vec<JointLimits>,
    period: f64,
    /// The last target sent (joint space).
    last: Option<[f64; MAX_JOINTS]>,
    velocity: [f64; MAX_JOINTS],
    /// The state before the last target, for [`ReplyGuard::take_back`].
    before: Option<([f64; MAX_JOINTS], [f64; MAX_JOINTS])>,
    /// The service's last command (inside the position limits), and the cycles since it came:
    /// the target's velocity is measured between two commands.
    target: Option<[f64; MAX_JOINTS]>,
    cycles_since_target: u32,
    /// The target's velocity at the last command (rad/s or m/s).
    target_velocity: [f64; MAX_JOINTS],
    /// The last target sent was not the service's command (a hold, or a catch-up answer).
    catching_up: bool,
    /// Targets clamped so far.
    pub clamps: u64,
    /// The joint clamped last, for the log line.
    pub last_clamped_joint: Option<usize>,
}

/// The time (s) a double integrator needs from a gap `gap` (to go, signed) and a relative velocity
/// `w` (signed, same axis) to reach the target at its velocity: the bang-bang profile with
/// acceleration `a`, its relative speed towards the target at most `cap`; continuous time.
fn time_to_go(gap: f64, w: f64, a: f64, cap: f64) -> f64 {
    let (d, toward) = if gap >= 0.0 { (gap, w) } else { (-gap, -w) };
    // From rest, `d` to go.
    let from_rest = |d: f64| if a * d <= cap * cap { 2.0 * (d / a).sqrt() } else { d / cap + cap / a };
    if toward < 0.0 {
        // Moving away: brake first, then the longer gap.
        return -toward / a + from_rest(d + toward * toward / (2.0 * a));
    }
    let stop = toward * toward / (2.0 * a);
    if stop > d {
        // It cannot stop in time: it passes and comes back.
        return toward / a + from_rest(stop - d);
    }
    let peak = (a * d + 0.5 * toward * toward).sqrt();
    if peak <= cap || toward >= cap {
        (2.0 * peak - toward) / a
    } else {
        // Up to the cap, along it, and down.
        let (up, down) = ((cap * cap - toward * toward) / (2.0 * a), cap * cap / (2.0 * a));
        (cap - toward) / a + cap / a + (d - up - down) / cap
    }
}

/// The relative speed (rad/s or m/s) a joint may close a gap with: its speed limit `limit` less
/// what the target's velocity `u` uses of it in the direction of the gap `gap`.
fn headroom(gap: f64, u: f64, limit: f64) -> f64 {
    (limit - u * gap.signum()).max(1e-9 * limit)
}

/// The longest a catch-up takes (s), by the law here: a joint at rest behind a target moving at
/// `target_velocity` (rad/s or m/s) with `gap` (rad or m) to go, with `velocity` and
/// `acceleration` its limits (rad/s, rad/s² or m/s, m/s²) and `period` the robot's cycle (s):
/// the time-optimal catch-up at the [`CATCH_UP_SHARE`] of the acceleration limit and within the
/// speed limit, plus two cycles for the discrete steps. (Braking the relative velocity −u takes
/// u/A and widens the gap by u²/2A; then the gap closes at A, at most at the speed left.)
pub fn catch_up_bound(gap: f64, target_velocity: f64, velocity: f64, acceleration: f64, period: f64) -> f64 {
    let a = CATCH_UP_SHARE * acceleration;
    let u = target_velocity * gap.signum();
    time_to_go(gap, -u, a, headroom(gap, target_velocity, velocity)) + 2.0 * period
}

impl ReplyGuard {
    /// A guard for joints with `bounds`, replying every `period` seconds (the robot's cycle).
    pub fn new(bounds: Vec<JointLimits>, period: f64) -> ReplyGuard {
        ReplyGuard {
            bounds,
            period,
            last: None,
            velocity: [0.0; MAX_JOINTS],
            before: None,
            target: None,
            cycles_since_target: 1,
            target_velocity: [0.0; MAX_JOINTS],
            catching_up: false,
            clamps: 0,
            last_clamped_joint: None,
        }
    }

    /// Starts from where the robot is (`q` measured, at rest): the next target steps from here.
    pub fn reset(&mut self, q: &[f64; MAX_JOINTS]) {
        self.last = Some(*q);
        self.velocity = [0.0; MAX_JOINTS];
        self.target = None;
        self.cycles_since_target = 1;
        self.target_velocity = [0.0; MAX_JOINTS];
        self.catching_up = false;
    }

    /// Forgets the last target: the robot never got it (it came after the robot's cycle, and the
    /// robot kept the one before). The next target steps from the one before. (The service's
    /// command is kept: it is what the next answer catches up with.)
    pub(crate) fn take_back(&mut self) {
        if let Some((last, _)) = self.before.take() {
            // The robot held its previous target this cycle: it is at rest there.
            self.last = Some(last);
            self.velocity = [0.0; MAX_JOINTS];
            self.catching_up = true;
        }
    }

    /// The robot went without an answer for one or more cycles that this guard never saw (a
    /// packet lost or skipped): it held its last target, which is the last answer sent, so it is
    /// at rest there. The next answer starts from rest (no step of two cycles' motion in one).
    pub(crate) fn robot_stood_still(&mut self) {
        self.velocity = [0.0; MAX_JOINTS];
        self.before = None;
        self.catching_up = self.last.is_some();
        // (The service was not clocked through those cycles either: its next command is one
        // step on from the last, so the target's bookkeeping stays as it is.)
    }

    /// The robot's cycle (s).
    pub fn period(&self) -> f64 {
        self.period
    }

    /// Whether the last target left the robot at rest (every joint's step below `1e-9`).
    pub fn at_rest(&self) -> bool {
        self.velocity.iter().all(|v| v.abs() * self.period < 1e-9)
    }

    /// The longest a hold takes to bring the robot to rest from full speed (s).
    pub(crate) fn longest_stop(&self) -> f64 {
        self.bounds.iter().map(|b| b.velocity / b.acceleration.max(1e-9)).fold(0.0, f64::max)
    }

    /// The last target sent (None before the first).
    pub fn last(&self) -> Option<&[f64; MAX_JOINTS]> {
        self.last.as_ref()
    }

    /// Whether the last target sent was not the service's command: a hold, a cycle the robot
    /// stood through, or an answer catching up.
    pub(crate) fn catching_up(&self) -> bool {
        self.catching_up
    }

    /// The velocity of the last target sent (rad/s or m/s).
    pub fn velocity(&self) -> &[f64; MAX_JOINTS] {
        &self.velocity
    }

    /// `target` (joint space), the service's command, moving at `velocity` (its own, rad/s or
    /// m/s, as the command says), within the limits from the last reply; records it as sent. In
    /// step, it is `target` itself; behind it (after a hold), the synchronised catch-up described
    /// in the module's documentation.
    ///
    /// The target's velocity is measured between two commands, except when the command steps
    /// from the last answer at its own velocity: a service told of a hold (`JointState::HELD`)
    /// planned again from where the robot is, so the command is in step at once (its step from
    /// the command before, which the robot never reached, is not its velocity).
    pub fn admit(&mut self, target: &[f64; MAX_JOINTS], velocity: &[f64; MAX_JOINTS]) -> [f64; MAX_JOINTS] {
        let Some(prev) = self.last else {
            // Nothing sent yet: the caller resets to the measured position first.
            self.last = Some(*target);
            return *target;
        };
        self.before = Some((prev, self.velocity));
        let dt = self.period;
        let n = self.bounds.len();
        let mut clamped = None;
        // The target inside the limits, its velocity over the cycles since the last command, and
        // the chase in the target's frame: the gap the target had one cycle ago (at its
        // velocity), and the answers' velocity relative to it.
        let [mut x, mut u, mut gap, mut w, mut share, mut cap] = [[0.0; MAX_JOINTS]; 6];
        let mut slowest = 0.0f64;
        let from_the_robot = self.bounds.iter().enumerate().all(|(k, b)| {
            let step = velocity[k] * dt;
            velocity[k].is_finite()
                && velocity[k].abs() <= b.velocity
                && (target[k] - prev[k] - step).abs() <= SAME * (1.0 + target[k].abs())
        });
        for (k, b) in self.bounds.iter().enumerate() {
            let mut xk = target[k];
            if !xk.is_finite() {
                xk = self.target.map_or(prev[k], |t| t[k]);
                clamped = Some(k);
            }
            x[k] = xk.clamp(b.lower, b.upper);
            u[k] = if from_the_robot {
                velocity[k]
            } else {
                self.target.map_or(0.0, |t| (x[k] - t[k]) / (dt * f64::from(self.cycles_since_target))).clamp(-b.velocity, b.velocity)
            };
            gap[k] = x[k] - u[k] * dt - prev[k];
            w[k] = self.velocity[k] - u[k];
            share[k] = CATCH_UP_SHARE * b.acceleration;
            cap[k] = headroom(gap[k], u[k], b.velocity);
            slowest = slowest.max(time_to_go(gap[k], w[k], share[k], cap[k]));
        }
        // Synchronised: a joint that would arrive sooner than the slowest chases with less
        // acceleration, so that all arrive together (its gap and relative speed shrink in
        // proportion with the slowest joint's: the tool comes back along its path).
        if slowest > 2.0 * dt {
            for k in 0..n {
                share[k] = synchronised(gap[k], w[k], share[k], cap[k], dt, slowest);
            }
        }
        let mut out = prev;
        for (k, b) in self.bounds.iter().enumerate() {
            // The relative speed towards the target: land on it this cycle if that is slow
            // enough to stop there (in step: the gap is nought, and the answer is the target);
            // else the square-root law. Towards the target it speeds up by the (synchronised)
            // share of the acceleration at most, so that the joints' chases stay in proportion;
            // braking is never held back (a target that brakes hard must not be passed). The
            // change is counted from the relative speed against the target's velocity as it was:
            // a target that accelerates uses its own part of the limit, not the chase's.
            let d = gap[k].abs();
            let h = 0.5 * share[k] * dt;
            let law = (-h + (h * h + 2.0 * share[k] * d).sqrt()).max(0.0);
            let toward_was = (self.velocity[k] - self.target_velocity[k]) * gap[k].signum();
            let w_new = if d / dt <= law { gap[k] / dt } else { law.min(toward_was + share[k] * dt) * gap[k].signum() };
            let v_chase = u[k] + w_new;
            // The step itself by the controller's own rule: within the speed and acceleration
            // limits, and never faster than what can still stop before a position limit.
            let mut x_out = b.step(prev[k], self.velocity[k], v_chase, dt).position;
            if (x_out - x[k]).abs() <= SAME && x[k] == target[k] {
                // In step: the service's command itself, to the bit.
                x_out = x[k];
            } else {
                clamped = Some(k);
            }
            self.velocity[k] = (x_out - prev[k]) / dt;
            out[k] = x_out;
        }
        if clamped.is_some() {
            self.clamps += 1;
            self.last_clamped_joint = clamped;
        }
        self.catching_up = clamped.is_some();
        self.target = Some(x);
        self.target_velocity = u;
        self.cycles_since_target = 1;
        self.last = Some(out);
        out
    }

    /// The last target again (a hold), braking any motion left within the acceleration limit.
    /// Before any target ([`ReplyGuard::reset`] first), None.
    pub fn hold(&mut self) -> Option<[f64; MAX_JOINTS]> {
        let prev = self.last?;
        self.before = Some((prev, self.velocity));
        self.catching_up = true;
        // The service's command did not come this cycle: its next one is a cycle further on.
        self.cycles_since_target = self.cycles_since_target.saturating_add(1);
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

/// The acceleration (at most `a`) with which a chase from (`gap`, `w`) within `cap` takes `time`
/// (s), if it can be that slow without passing the target; else the slowest that does not pass it.
fn synchronised(gap: f64, w: f64, a: f64, cap: f64, period: f64, time: f64) -> f64 {
    let t = |a: f64| time_to_go(gap, w, a, cap);
    if t(a) >= time {
        return a;
    }
    // Approaching: below w²/(2d + w·dt) the discrete law could no longer brake onto the target
    // (the speed it allows on the gap is below what one cycle's braking reaches).
    let toward = if gap >= 0.0 { w } else { -w };
    let lowest = if toward > 0.0 && gap != 0.0 { (toward * toward / (2.0 * gap.abs() + toward * period)) * (1.0 + 1e-9) } else { a * 1e-6 };
    if lowest >= a {
        return a;
    }
    let (mut lo, mut hi) = (lowest, a);
    if t(lo) <= time {
        return lo;
    }
    // The time falls as the acceleration grows: keep t(lo) > time ≥ t(hi).
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if t(mid) > time {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    hi
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A command that does not say its velocity: the guard measures it between commands.
    const UNSAID: [f64; MAX_JOINTS] = [f64::NAN; MAX_JOINTS];

    fn guard() -> ReplyGuard {
        let b = JointLimits { lower: -1.0, upper: 1.0, velocity: 1.0, acceleration: 10.0, jerk: f64::INFINITY };
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
            let out = g.admit(&target, &UNSAID);
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
            g.admit(&t, &UNSAID);
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
            let x = g.admit(&t, &UNSAID)[0];
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
            g.admit(&t, &UNSAID);
        }
        let before = g.last().unwrap()[0];
        t[0] += 0.0001;
        g.admit(&t, &UNSAID);
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
            let out = g.admit(&t, &UNSAID);
            assert!(out[0] == 0.0 && out[1] <= 1.0);
        }
        assert_eq!(g.clamps, 1000);
    }

    /// Two joints at constant `speed` (rad/s; limits 1 rad/s, 10 rad/s²), reached with the target
    /// accelerating at 3 rad/s²; then `missed` answers the robot threw away; after `brake_after`
    /// more cycles the target brakes to rest at 4.5 rad/s² (within the 5 rad/s² the catch-up
    /// leaves it). Returns the guard's answers and the targets from the first missed cycle on.
    fn chase(speed: [f64; 2], missed: usize, brake_after: Option<usize>) -> (Vec<[f64; 2]>, Vec<[f64; 2]>, u64) {
        let b = JointLimits { lower: -10.0, upper: 10.0, velocity: 1.0, acceleration: 10.0, jerk: f64::INFINITY };
        let mut g = ReplyGuard::new(vec![b; 2], 0.004);
        g.reset(&[0.0; MAX_JOINTS]);
        let (mut x, mut v) = ([0.0f64; 2], [0.0f64; 2]);
        let mut t = [0.0; MAX_JOINTS];
        let (mut outs, mut targets) = (Vec::new(), Vec::new());
        for cycle in 0..1000 {
            // The target: up to speed at 3 rad/s², then (optionally) braking to rest at 5 rad/s².
            for k in 0..2 {
                let want = if brake_after.is_some_and(|c| cycle >= 300 + c) { 0.0 } else { speed[k] };
                let a = if want == 0.0 { 4.5 } else { 3.0 };
                v[k] += (want - v[k]).clamp(-a * 0.004, a * 0.004);
                x[k] += v[k] * 0.004;
            }
            t[..2].copy_from_slice(&x);
            let out = g.admit(&t, &UNSAID);
            if cycle < 300 {
                assert_eq!(&out[..2], &t[..2], "in step, the answer is the command (cycle {cycle})");
                continue;
            }
            if cycle < 300 + missed {
                g.take_back();
                outs.push([g.last().unwrap()[0], g.last().unwrap()[1]]);
            } else {
                outs.push([out[0], out[1]]);
            }
            targets.push([t[0], t[1]]);
        }
        (outs, targets, g.clamps)
    }

    #[test]
    fn a_catch_up_after_missed_cycles_never_passes_the_target_and_ends_within_its_bound() {
        // A print's joint speeds, and speeds near the limit (where the catch-up has little
        // speed left to close the gap with).
        for (speed, missed) in [[0.3, -0.12], [0.8f64, -0.3]].into_iter().flat_map(|s| [1, 3, 10].map(|m| (s, m))) {
            let (outs, targets, clamps) = chase(speed, missed, None);
            let mut caught_up = None;
            let (mut v_prev, mut prev) = ([0.0; 2], outs[0]);
            // From the last held cycle on, the robot moves again.
            for (i, (o, t)) in outs.iter().zip(&targets).enumerate().skip(missed - 1) {
                for k in 0..2 {
                    // Behind, in the direction of travel, or on it: never past.
                    let ahead = (o[k] - t[k]) * speed[k].signum();
                    assert!(ahead <= 1e-12, "{missed} missed: joint {k} {ahead} rad past its target at cycle {i}");
                    if i >= missed {
                        let v = (o[k] - prev[k]) / 0.004;
                        assert!(v.abs() <= 1.0 + 1e-9, "speed {v}");
                        assert!(((v - v_prev[k]) / 0.004).abs() <= 10.0 + 1e-6, "acceleration {}", (v - v_prev[k]) / 0.004);
                        v_prev[k] = v;
                    }
                }
                prev = *o;
                if caught_up.is_none() && o == t {
                    caught_up = Some(i);
                }
            }
            // In step again at answer `at`; the robot moved again from answer `missed` on.
            let at = caught_up.unwrap_or_else(|| panic!("{missed} missed: never caught up"));
            let cycles = at + 1 - missed;
            eprintln!("{speed:?} rad/s, {missed} missed: caught up after {cycles} cycles");
            // The bound, for the slowest joint (they end together).
            let bound = (0..2).map(|k| catch_up_bound(missed as f64 * speed[k] * 0.004, speed[k], 1.0, 10.0, 0.004)).fold(0.0, f64::max);
            assert!(cycles as f64 * 0.004 <= bound, "{missed} missed: caught up in {cycles} cycles, bound {bound} s");
            // Clamped only while catching up: the answers thrown away after the first, and those
            // before the one in step.
            assert_eq!(clamps as usize, at - 1, "{missed} missed");
        }
    }

    #[test]
    fn the_joints_catch_up_together_so_the_tool_stays_on_its_path() {
        // Joint 0 moves 0.3 rad/s, joint 1 −0.12 rad/s: a straight line in joint space. Behind,
        // the answers stay on that line (the gaps keep their ratio) until they are back on the
        // target.
        let (outs, targets, _) = chase([0.3, -0.12], 10, None);
        for (o, t) in outs.iter().zip(&targets) {
            let (g0, g1) = (t[0] - o[0], t[1] - o[1]);
            if g0.abs() > 1e-6 {
                let ratio = g1 / g0;
                assert!((ratio + 0.12 / 0.3).abs() < 0.01, "off the line: gaps {g0} {g1}");
            }
        }
    }

    #[test]
    fn a_target_that_brakes_while_it_is_chased_is_not_passed() {
        for missed in [1, 3, 10] {
            let speed = [0.8f64, -0.3];
            let (outs, targets, _) = chase(speed, missed, Some(missed + 2));
            for (i, (o, t)) in outs.iter().zip(&targets).enumerate() {
                for k in 0..2 {
                    let ahead = (o[k] - t[k]) * speed[k].signum();
                    assert!(ahead <= 1e-12, "{missed} missed: joint {k} {ahead} rad past its braking target at cycle {i}");
                }
            }
            assert_eq!(outs.last(), targets.last(), "at rest on the target");
        }
    }

    #[test]
    fn after_late_cycles_held_to_rest_the_answers_catch_up_without_passing() {
        let b = JointLimits { lower: -10.0, upper: 10.0, velocity: 1.0, acceleration: 10.0, jerk: f64::INFINITY };
        let mut g = ReplyGuard::new(vec![b], 0.004);
        g.reset(&[0.0; MAX_JOINTS]);
        let mut t = [0.0; MAX_JOINTS];
        let mut v = 0.0f64;
        for cycle in 0..600 {
            // Up to 0.5 rad/s at 2 rad/s².
            v = (v + 2.0 * 0.004).min(0.5);
            t[0] += v * 0.004;
            if (200..203).contains(&cycle) {
                g.hold();
                continue;
            }
            let out = g.admit(&t, &UNSAID);
            assert!(out[0] <= t[0] + 1e-12, "past the target at {cycle}: {} > {}", out[0], t[0]);
            if cycle > 300 {
                assert_eq!(out[0], t[0], "caught up by {cycle}");
            }
        }
    }

    #[test]
    fn a_command_planned_again_from_the_held_target_is_in_step_at_once() {
        // In step at 0.5 rad/s on joint 0, then one hold: the robot brakes from there.
        let mut g = guard();
        let v = 0.5;
        let (mut t, mut vt) = ([0.0; MAX_JOINTS], 0.0f64);
        for _ in 0..50 {
            // Up to speed at 5 rad/s² (half the limit), then on at it.
            vt = (vt + 5.0 * 0.004).min(v);
            t[0] += vt * 0.004;
            let mut vel = [0.0; MAX_JOINTS];
            vel[0] = vt;
            assert_eq!(g.admit(&t, &vel), t);
        }
        let held = g.hold().unwrap();
        assert!(g.catching_up());
        let held_velocity = g.velocity()[0];
        assert!((held_velocity - (v - 10.0 * 0.004)).abs() < 1e-12, "{held_velocity}");
        // The service, told of the hold, plans again from the held target at its velocity: its
        // command steps from there. The guard answers it unchanged (no catch-up, no clamp) ...
        let clamps = g.clamps;
        let mut q = held;
        let mut qd = held_velocity;
        for _ in 0..20 {
            qd = (qd + 2.0 * 0.004).min(v);
            q[0] += qd * 0.004;
            let mut vel = [0.0; MAX_JOINTS];
            vel[0] = qd;
            assert_eq!(g.admit(&q, &vel), q);
        }
        assert_eq!(g.clamps, clamps);
        assert!(!g.catching_up());
        // ... where a command that went on from the old one is caught up with (clamped).
        let mut g2 = guard();
        let (mut t, mut vt) = ([0.0; MAX_JOINTS], 0.0f64);
        for _ in 0..50 {
            vt = (vt + 5.0 * 0.004).min(v);
            t[0] += vt * 0.004;
            assert_eq!(g2.admit(&t, &UNSAID), t);
        }
        g2.hold();
        t[0] += 2.0 * v * 0.004;
        let out = g2.admit(&t, &UNSAID);
        assert!(out[0] < t[0] && g2.catching_up());
    }
}
