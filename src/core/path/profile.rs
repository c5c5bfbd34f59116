//! Speed profiles along the path: the conservative jerk-limited braking bound the lookahead uses, and
//! the trapezoidal and triangular time scaling of 004 Eqs. 3-6 (generalised to non-zero entry and
//! exit speeds) that the `stop-and-go` and `rules-004` modes run on.

/// Acceleration and jerk along the path, with the braking bound derived from them.
///
/// A jerk-limited change of speed from v to v' < v that starts and ends at zero acceleration covers
/// `(v+v')/2 · (Δv/a + a/j)` (trapezoidal acceleration) or `(v+v')·√(Δv/j)` (triangular); both
/// are at most `(v² − v'²)/(2a) + v·a/j`. Writing `w(v) = v²/(2a) + v·a/j`, a speed v at a point is
/// safe against a later point at distance d with speed cap v' if `w(v) ≤ d + v'²/(2a)`. The bound
/// composes along the path (the `v'²/(2a)` terms form a single backward minimum), which is what lets
/// the lookahead keep one number per boundary instead of re-solving chains of short segments.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Braking {
    /// Acceleration limit along the path (m/s², > 0).
    pub acceleration: f64,
    /// Jerk limit along the path (m/s³, > 0; infinite for the acceleration-only modes).
    pub jerk: f64,
}

impl Braking {
    /// `w(v)`: the distance (m) needed to brake from v (m/s, at zero acceleration), beyond the
    /// constant-deceleration part.
    #[inline]
    pub(super) fn w(&self, v: f64) -> f64 {
        let a = self.acceleration;
        v * v / (2.0 * a) + if self.jerk.is_finite() { v * a / self.jerk } else { 0.0 }
    }

    /// The inverse of [`w`](Self::w): the highest speed (m/s) with `w(v) ≤ d` (0 for d ≤ 0).
    #[inline]
    pub(super) fn w_inverse(&self, d: f64) -> f64 {
        if d <= 0.0 {
            return 0.0;
        }
        let a = self.acceleration;
        if !self.jerk.is_finite() {
            return (2.0 * a * d).sqrt();
        }
        let b = a * a / self.jerk;
        // v² + 2bv − 2ad = 0, in the cancellation-free form.
        2.0 * a * d / (b + (b * b + 2.0 * a * d).sqrt())
    }

    /// The potential `S + v²/(2a)` of a speed cap v (m/s) at path position S (m).
    #[inline]
    pub(super) fn potential(&self, position: f64, cap: f64) -> f64 {
        position + cap * cap / (2.0 * self.acceleration)
    }

    /// The exact distance (m) of the fastest change from speed `v` down to `v_to` (m/s) that starts
    /// and ends at zero acceleration: triangular `(v+v')·√(Δv/j)` below `Δv = a²/j`, trapezoidal
    /// `(v+v')/2·(Δv/a + a/j)` above.
    pub(super) fn exact_distance(&self, v: f64, v_to: f64) -> f64 {
        let dv = v - v_to;
        if dv <= 0.0 {
            return 0.0;
        }
        let a = self.acceleration;
        if !self.jerk.is_finite() {
            return (v * v - v_to * v_to) / (2.0 * a);
        }
        if dv <= a * a / self.jerk { (v + v_to) * (dv / self.jerk).sqrt() } else { 0.5 * (v + v_to) * (dv / a + a / self.jerk) }
    }

    /// The highest speed, at most `cap` (m/s), from which the tool can slow to `v_to` within
    /// `length` (m), starting and ending at zero acceleration (bisection on the exact distance).
    pub(super) fn reach(&self, length: f64, v_to: f64, cap: f64) -> f64 {
        if cap <= v_to || self.exact_distance(cap, v_to) <= length {
            return cap;
        }
        let (mut lo, mut hi) = (v_to, cap);
        for _ in 0..48 {
            let mid = 0.5 * (lo + hi);
            if self.exact_distance(mid, v_to) <= length {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        lo
    }

    /// An upper bound on the distance (m) to come to rest from speed `v` (m/s) and acceleration `a`
    /// (m/s²): first bring a positive acceleration back to zero, then brake.
    pub(super) fn stopping_distance(&self, v: f64, a: f64) -> f64 {
        if a > 0.0 && self.jerk.is_finite() {
            let t = a / self.jerk;
            let v1 = v + 0.5 * a * t;
            (v + v1) * t + self.w(v1)
        } else {
            self.w(v.max(0.0))
        }
    }
}

/// A trapezoidal (or triangular) speed profile over one piece: accelerate at `a` from `v_in`,
/// cruise at `v_peak`, decelerate at `a` to `v_out` (004 Eqs. 3-6 with v_in = v_out = 0).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(super) struct Trapezoid {
    /// Entry speed (m/s).
    pub v_in: f64,
    /// Highest speed reached (m/s).
    pub v_peak: f64,
    /// Exit speed (m/s).
    pub v_out: f64,
    /// Acceleration (m/s²).
    pub a: f64,
    /// Acceleration of the first phase (m/s²): `a`, or `−a` when the entry is above the cap.
    pub a_in: f64,
    /// Durations of the three phases (s).
    pub t_acc: f64,
    pub t_cruise: f64,
    pub t_dec: f64,
    /// Distances of the accelerating and cruising phases (m).
    pub d_acc: f64,
    pub d_cruise: f64,
}

/// Position, speed, acceleration and jerk along the path.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(super) struct PathState {
    /// Arc length (m).
    pub s: f64,
    /// Speed (m/s).
    pub v: f64,
    /// Acceleration (m/s²).
    pub a: f64,
    /// Jerk (m/s³).
    pub j: f64,
}

impl Trapezoid {
    /// The profile over `length` (m) from `v_in` to `v_out` with cruise cap `v_cruise` and
    /// acceleration `a`. The end speeds are clamped to what the length allows. An entry faster than
    /// the cap (a feed override lowered mid-piece) first slows to the cap: the first phase then
    /// decelerates, and if even braking all the way cannot reach `v_out`, the exit is as slow as
    /// braking allows.
    pub(super) fn new(length: f64, v_in: f64, v_out: f64, v_cruise: f64, a: f64) -> Trapezoid {
        let length = length.max(0.0);
        let v_in = v_in.max(0.0);
        // Exit speed reachable from the entry (and vice versa, in case the entry is too fast).
        let v_out = v_out.max(0.0).min((v_in * v_in + 2.0 * a * length).sqrt()).max((v_in * v_in - 2.0 * a * length).max(0.0).sqrt());
        let v_peak_room = ((2.0 * a * length + v_in * v_in + v_out * v_out) / 2.0).sqrt();
        let v_peak = if v_in <= v_cruise { v_cruise.min(v_peak_room).max(v_in.max(v_out)) } else { v_cruise.max(v_out) };
        let a_in = if v_peak >= v_in { a } else { -a };
        let t_acc = (v_peak - v_in).abs() / a;
        let t_dec = (v_peak - v_out) / a;
        let d_acc = if a > 0.0 { (v_peak * v_peak - v_in * v_in) / (2.0 * a_in) } else { 0.0 };
        let d_dec = (v_peak * v_peak - v_out * v_out) / (2.0 * a);
        let d_cruise = (length - d_acc - d_dec).max(0.0);
        let t_cruise = if v_peak > 0.0 { d_cruise / v_peak } else { 0.0 };
        Trapezoid { v_in, v_peak, v_out, a, a_in, t_acc, t_cruise, t_dec, d_acc, d_cruise }
    }

    /// Total duration (s), 004 Eq. 3 for a rest-to-rest trapezoid.
    pub(super) fn duration(&self) -> f64 {
        self.t_acc + self.t_cruise + self.t_dec
    }

    /// The state at time `t` (s) from the start of the piece (Eqs. 4, 5, 6).
    pub(super) fn at(&self, t: f64) -> PathState {
        let a = self.a;
        if t < self.t_acc {
            let a_in = self.a_in;
            return PathState { s: self.v_in * t + 0.5 * a_in * t * t, v: (self.v_in + a_in * t).max(0.0), a: a_in, j: 0.0 };
        }
        let t2 = t - self.t_acc;
        if t2 < self.t_cruise {
            return PathState { s: self.d_acc + self.v_peak * t2, v: self.v_peak, a: 0.0, j: 0.0 };
        }
        let t3 = (t2 - self.t_cruise).min(self.t_dec);
        PathState {
            s: self.d_acc + self.d_cruise + self.v_peak * t3 - 0.5 * a * t3 * t3,
            v: (self.v_peak - a * t3).max(0.0),
            a: if t3 < self.t_dec { -a } else { 0.0 },
            j: 0.0,
        }
    }
}
