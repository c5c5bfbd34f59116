//! The fake Meca500 in virtual time, for tests that put a missed cycle exactly where it hurts: no
//! sockets, no clock. The fake's own state machine takes the control port's commands
//! (`MoveJointsVel` capped to the R3's speeds, `SetVelTimeout`'s stop) and moves the joints with its
//! own trajectory (velocities ramped at the joints' accelerations, all joints together); its
//! monitoring stream (`[2026]` … `[2230]`, with the real-time `[2210]`/`[2212]` the driver asks
//! for) is handed over each cycle as the driver's link hands it to the protocol: each message
//! tagged with its port. The arm drives itself: the caller's drives are not used.

use super::{JOINTS, MecaOptions, Out, State};
use crate::fake::FakeProtocol;
use crate::meca::{FROM_CONTROL, FROM_MONITOR};

/// A Meca500 activated, homed and streaming in velocity mode, with a driver connected.
pub struct VirtualMeca {
    st: State,
    /// The driver's cycle (s).
    period: f64,
    /// The joints at the end of the last tick (deg).
    q: [f64; JOINTS],
}

impl VirtualMeca {
    /// A robot at `opts.start_deg`, set up as strand-meca sets it up: `SetJointAcc(100)`,
    /// `SetVelTimeout(velocity_timeout)`, monitoring every `monitoring_interval` (s) with the
    /// real-time joints and velocities; the driver's cycle is `period` (s, a multiple of
    /// `opts.tick`).
    pub fn new(opts: MecaOptions, period: f64, monitoring_interval: f64, velocity_timeout: f64) -> VirtualMeca {
        let opts = MecaOptions { activated: true, homed: true, ..opts };
        let mut st = State::new(&opts, 0);
        st.paused = false;
        st.joint_acc = 100.0;
        st.vel_timeout = velocity_timeout;
        st.monitoring_interval = monitoring_interval;
        st.rt.extend([2210, 2212]);
        st.control = Some(Out::sink());
        st.monitors.push(Out::sink());
        st.next_monitor_ns = 0;
        st.step(0);
        VirtualMeca { q: st.q, st, period }
    }

    /// The errors the robot raised (codes).
    pub fn errors(&self) -> &[u32] {
        &self.st.report.errors
    }

    /// `SetVelTimeout` stops counted (a velocity left to run out).
    pub fn timeouts(&self) -> u64 {
        self.st.report.timeouts
    }

    fn now(&self, k: u64) -> u64 {
        (k as f64 * self.period * 1e9).round() as u64
    }
}

/// Moves the messages in `from` (each ending in a NUL) into `out`, each tagged with `tag`.
fn take_tagged(from: &mut Out, tag: u8, out: &mut Vec<u8>) {
    for m in from.pending.split(|b| *b == 0).filter(|m| !m.is_empty()) {
        out.push(tag);
        out.extend_from_slice(m);
        out.push(0);
    }
    from.pending.clear();
}

impl FakeProtocol for VirtualMeca {
    /// Everything both ports sent since the last cycle.
    fn packet(&mut self, _k: u64, _axes_deg: &[f64], out: &mut Vec<u8>) {
        out.clear();
        if let Some(c) = self.st.control.as_mut() {
            take_tagged(c, FROM_CONTROL, out);
        }
        for m in &mut self.st.monitors {
            take_tagged(m, FROM_MONITOR, out);
        }
    }

    /// The driver's commands of cycle `k` (NUL-terminated), taken at the cycle's start.
    fn answer(&mut self, k: u64, bytes: &[u8], _axes_deg: &mut [f64]) -> Result<(), Option<u64>> {
        let now = self.now(k);
        let mut any = false;
        for frame in bytes.split(|b| *b == 0).filter(|f| !f.is_empty()) {
            self.st.frame(frame, now);
            any = true;
        }
        if any { Ok(()) } else { Err(None) }
    }

    /// The robot's trajectory over the cycle, at its own tick.
    fn tick(&mut self, k: u64, axes_deg: &mut [f64]) {
        let (from, to) = (self.now(k), self.now(k + 1));
        let tick_ns = ((self.st.tick * 1e9).round() as u64).max(1);
        let mut t = from + tick_ns;
        while t <= to {
            self.st.step(t);
            t += tick_ns;
        }
        self.q = self.st.q;
        for (a, q) in axes_deg.iter_mut().zip(&self.q) {
            *a = *q;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_velocity_moves_the_joints_until_the_velocity_timeout() {
        let opts = MecaOptions { tick: 0.001, start_deg: [0.0; JOINTS], ..Default::default() };
        let mut meca = VirtualMeca::new(opts, 0.004, 0.002, 0.02);
        let (mut target, mut out) = (vec![0.0; JOINTS], Vec::new());
        meca.packet(0, &target.clone(), &mut out);
        let text = String::from_utf8_lossy(&out).to_string();
        assert!(text.contains("M[2210]") && text.contains("M[2230]"), "{text}");
        meca.answer(0, b"MoveJointsVel(10,0,0,0,0,0)\0", &mut target).unwrap();
        for k in 0..25 {
            meca.tick(k, &mut target);
        }
        // 10 deg/s for 20 ms (less the ramp), then stopped by the timeout.
        assert!((0.1..0.25).contains(&target[0]), "{target:?}");
        assert_eq!(meca.timeouts(), 1);
        let at_rest = target[0];
        for k in 25..50 {
            meca.tick(k, &mut target);
        }
        assert_eq!(target[0], at_rest);
        assert!(meca.errors().is_empty(), "{:?}", meca.errors());
    }
}
