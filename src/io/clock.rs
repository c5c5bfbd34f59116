//! The cycle clock: when each control tick starts, how late it woke, and the counters of late
//! wake-ups, overruns and skipped periods.
//!
//! All times are nanoseconds of `CLOCK_MONOTONIC` (u64), the same clock as every timestamp on the
//! wire. Deadlines are absolute (tick k is due at `start + (k + 1) · period`), so a late wake-up
//! never shifts the ticks after it.

use serde::{Deserialize, Serialize};

/// Now, in ns of `CLOCK_MONOTONIC`. Tick-path safe (a vDSO call, no allocation).
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `ts` is a valid out-pointer; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// What starts a tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum ClockMode {
    /// `timer`: an absolute `clock_nanosleep` on `CLOCK_MONOTONIC` at the configured rate
    /// ([`TimerClock`]).
    Timer,
    /// `robot`: one tick per `JointState` arrival; the robot driver's cycle is the clock.
    Robot,
    /// `free-run`: no waiting, the next tick starts when the last one ends (simulation, CI). The log
    /// is complete here: a tick waits for a free log slot instead of dropping its record.
    FreeRun,
}

/// One wake-up of [`TimerClock::wait`]. All fields in ns (`CLOCK_MONOTONIC`) except the count.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Wake {
    /// The deadline this tick was due at (ns).
    pub deadline_ns: u64,
    /// When the wait returned (ns); never before `deadline_ns`.
    pub woke_ns: u64,
    /// `woke_ns - deadline_ns` (ns).
    pub lateness_ns: u64,
    /// Deadlines skipped before this one because the thread was more than a period behind when it
    /// called `wait` (count; 0 normally).
    pub missed_periods: u64,
}

/// A periodic clock with absolute deadlines: sleeps with `clock_nanosleep(CLOCK_MONOTONIC,
/// TIMER_ABSTIME)` until `spin_ns` before the deadline, then busy-reads the clock until the deadline.
/// Never bursts: a thread that fell more than a period behind skips the deadlines already passed
/// (counted in [`Wake::missed_periods`]) and runs the latest one at once.
#[derive(Clone, Debug)]
pub struct TimerClock {
    period_ns: u64,
    spin_ns: u64,
    late_threshold_ns: u64,
    /// The deadline the next `wait` sleeps to (ns); 0 before `start`.
    next_deadline_ns: u64,
}

impl TimerClock {
    /// A clock with tick period `period_ns` (ns, > 0), a busy-spin of `spin_ns` (ns, 0 = pure sleep;
    /// clamped to the period) before each deadline, and the lateness (ns) above which a wake-up
    /// counts as late in [`CycleStats`].
    ///
    /// # Panics
    /// If `period_ns` is 0 (a configuration error, caught at start-up).
    pub fn new(period_ns: u64, spin_ns: u64, late_threshold_ns: u64) -> Self {
        assert!(period_ns > 0, "TimerClock period must be > 0 ns");
        TimerClock { period_ns, spin_ns: spin_ns.min(period_ns), late_threshold_ns, next_deadline_ns: 0 }
    }

    /// Sets the first deadline one period after `now_ns` (ns). Tick-path safe.
    pub fn start(&mut self, now_ns: u64) {
        self.next_deadline_ns = now_ns + self.period_ns;
    }

    /// The tick period (ns).
    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }

    /// The busy-spin before each deadline (ns).
    pub fn spin_ns(&self) -> u64 {
        self.spin_ns
    }

    /// The lateness above which a wake-up counts as late (ns).
    pub fn late_threshold_ns(&self) -> u64 {
        self.late_threshold_ns
    }

    /// The deadline the next [`wait`](Self::wait) returns at (ns); after a `wait`, the deadline of
    /// the next tick, i.e. when the current tick's work must be done. 0 before `start`.
    pub(crate) fn next_deadline_ns(&self) -> u64 {
        self.next_deadline_ns
    }

    /// Waits for the next deadline and returns the wake-up. Starts the clock at "now" if
    /// [`start`](Self::start) was not called. Retries the sleep on `EINTR` (the deadline is absolute,
    /// so a signal costs nothing). Tick-path safe: no allocation, only `clock_gettime` and
    /// `clock_nanosleep`.
    pub fn wait(&mut self) -> Wake {
        let now = monotonic_ns();
        if self.next_deadline_ns == 0 {
            self.start(now);
        }
        let mut missed = 0;
        if now >= self.next_deadline_ns + self.period_ns {
            // More than one period behind: skip the deadlines that have passed, keep the latest.
            missed = (now - self.next_deadline_ns) / self.period_ns;
            self.next_deadline_ns += missed * self.period_ns;
        }
        let deadline = self.next_deadline_ns;
        sleep_until_ns(deadline - self.spin_ns.min(deadline));
        let mut woke = monotonic_ns();
        while woke < deadline {
            std::hint::spin_loop();
            woke = monotonic_ns();
        }
        self.next_deadline_ns = deadline + self.period_ns;
        Wake { deadline_ns: deadline, woke_ns: woke, lateness_ns: woke.saturating_sub(deadline), missed_periods: missed }
    }
}

/// Sleeps until `deadline_ns` (ns, `CLOCK_MONOTONIC`, absolute), retrying on `EINTR`. Returns at once
/// for a deadline in the past. Tick-path safe.
pub(crate) fn sleep_until_ns(deadline_ns: u64) {
    let ts =
        libc::timespec { tv_sec: (deadline_ns / 1_000_000_000) as libc::time_t, tv_nsec: (deadline_ns % 1_000_000_000) as libc::c_long };
    loop {
        // SAFETY: `ts` is a valid timespec; the remainder pointer may be null with TIMER_ABSTIME.
        let rc = unsafe { libc::clock_nanosleep(libc::CLOCK_MONOTONIC, libc::TIMER_ABSTIME, &ts, std::ptr::null_mut()) };
        if rc != libc::EINTR {
            // 0, or EINVAL/ENOTSUP which cannot happen with these arguments; the caller re-reads the
            // clock either way.
            return;
        }
    }
}

/// Counters of the cycle's timing, published in `Status`. Tick-path safe: plain arithmetic.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CycleStats {
    /// Wake-ups recorded (count).
    pub ticks: u64,
    /// Wake-ups later than the threshold (count).
    pub late_wakeups: u64,
    /// Worst wake-up lateness seen (ns).
    pub worst_lateness_ns: u64,
    /// Ticks whose work finished after the next tick's deadline (count).
    pub overruns: u64,
    /// Deadlines skipped because the thread fell more than a period behind (count).
    pub missed_periods: u64,
}

impl CycleStats {
    /// Counts a wake-up: late if `wake.lateness_ns > late_threshold_ns` (ns).
    pub(crate) fn record_wake(&mut self, wake: &Wake, late_threshold_ns: u64) {
        self.ticks += 1;
        if wake.lateness_ns > late_threshold_ns {
            self.late_wakeups += 1;
        }
        self.worst_lateness_ns = self.worst_lateness_ns.max(wake.lateness_ns);
        self.missed_periods += wake.missed_periods;
    }

    /// Counts the end of a tick's work at `end_ns` (ns): an overrun if it is after
    /// `next_deadline_ns` (ns), the deadline of the following tick.
    pub(crate) fn record_work_end(&mut self, end_ns: u64, next_deadline_ns: u64) {
        if end_ns > next_deadline_ns {
            self.overruns += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn monotonic_moves_forward() {
        let a = monotonic_ns();
        let b = monotonic_ns();
        assert!(a > 0 && b >= a);
    }

    #[test]
    fn timer_deadlines_are_absolute() {
        const PERIOD: u64 = 1_000_000;
        let mut clock = TimerClock::new(PERIOD, 0, 200_000);
        let mut stats = CycleStats::default();
        let start = monotonic_ns();
        clock.start(start);
        assert_eq!(clock.next_deadline_ns(), start + PERIOD);
        let mut k = 0u64; // index of the deadline due next
        for _ in 0..200 {
            let w = clock.wait();
            k += w.missed_periods;
            assert_eq!(w.deadline_ns, start + (k + 1) * PERIOD, "tick {k}");
            assert!(w.woke_ns >= w.deadline_ns);
            assert_eq!(w.lateness_ns, w.woke_ns - w.deadline_ns);
            assert_eq!(clock.next_deadline_ns(), w.deadline_ns + PERIOD);
            stats.record_wake(&w, clock.late_threshold_ns());
            stats.record_work_end(monotonic_ns(), clock.next_deadline_ns());
            k += 1;
        }
        assert_eq!(stats.ticks, 200);
        assert!(stats.late_wakeups <= stats.ticks);
        assert!(stats.overruns <= stats.ticks);
    }

    #[test]
    fn spinning_wakes_at_the_deadline() {
        let mut clock = TimerClock::new(500_000, 100_000, 50_000);
        for _ in 0..20 {
            let w = clock.wait();
            assert!(w.woke_ns >= w.deadline_ns);
        }
    }

    #[test]
    fn a_late_thread_skips_passed_deadlines_instead_of_bursting() {
        const PERIOD: u64 = 1_000_000;
        let mut clock = TimerClock::new(PERIOD, 0, 0);
        let start = monotonic_ns();
        clock.start(start);
        // Fall 5.5 periods behind the first deadline.
        sleep_until_ns(start + PERIOD + 5 * PERIOD + PERIOD / 2);
        let w = clock.wait();
        assert!(w.missed_periods >= 5, "{w:?}");
        assert_eq!(w.deadline_ns, start + (w.missed_periods + 1) * PERIOD);
        assert!(w.woke_ns >= w.deadline_ns);
        let mut stats = CycleStats::default();
        stats.record_wake(&w, 0);
        assert_eq!(stats.missed_periods, w.missed_periods);
        // The next tick is one period later, not immediately.
        let w2 = clock.wait();
        assert_eq!(w2.deadline_ns, w.deadline_ns + PERIOD * (1 + w2.missed_periods));
    }

    #[test]
    fn stats_count_late_wakes_and_overruns() {
        let mut s = CycleStats::default();
        s.record_wake(&Wake { deadline_ns: 100, woke_ns: 150, lateness_ns: 50, missed_periods: 0 }, 40);
        s.record_wake(&Wake { deadline_ns: 200, woke_ns: 210, lateness_ns: 10, missed_periods: 2 }, 40);
        s.record_work_end(310, 300);
        s.record_work_end(300, 300);
        assert_eq!(s, CycleStats { ticks: 2, late_wakeups: 1, worst_lateness_ns: 50, overruns: 1, missed_periods: 2 });
    }

    #[test]
    fn clock_mode_reads_kebab_case() {
        #[derive(Deserialize)]
        struct T {
            mode: ClockMode,
        }
        let t: T = toml::from_str("mode = \"free-run\"").unwrap();
        assert_eq!(t.mode, ClockMode::FreeRun);
        let t: T = toml::from_str("mode = \"robot\"").unwrap();
        assert_eq!(t.mode, ClockMode::Robot);
        assert!(toml::from_str::<T>("mode = \"FreeRun\"").is_err());
    }
}
