//! The fake UR controller's state machine in virtual time, for tests that put a missed cycle
//! exactly where it hurts: no sockets, no clock. The RTDE data package is encoded by the fake's own
//! output fields, and the reverse-interface message is taken by the fake's own rules (§2.4: a
//! setpoint stepping a joint faster than 20 rad/s is ignored; `MODE_STOPPED` ends the program);
//! the read timeout each message announces ends the program when the next message is later than
//! it (the script's read, §2.7). The drives are the caller's: it reports the actual joints each
//! cycle and moves them towards the target an answer sets.

use super::controller::State;
use super::rtde::{DATA, OutField, package};
use super::{JOINTS, MODE_SERVOJ, RUNTIME_PLAYING, UrOptions};
use crate::fake::{FakeProtocol, InvalidSetup};

/// A UR controller running strand's program, on a cycle of `UrOptions::step`.
pub struct VirtualUr {
    st: State,
    fields: Vec<OutField>,
    /// The read timeout the last message announced (ms), and when it came (s).
    timeout_ms: i32,
    last_message: Option<f64>,
    /// Why the program ended, once it has.
    ended: Option<String>,
}

impl VirtualUr {
    /// A controller whose RTDE output recipe (id 1) is `outputs` (comma-separated names), with
    /// strand's program already playing (the handshake is not simulated here). Unknown names are
    /// refused, named.
    pub fn new(opts: UrOptions, outputs: &str) -> Result<VirtualUr, InvalidSetup> {
        let fields = outputs
            .split(',')
            .map(|n| OutField::of(n.trim()).ok_or_else(|| InvalidSetup(format!("output {n:?} is not one the fake knows"))))
            .collect::<Result<Vec<_>, _>>()?;
        let mut st = State::new(&opts, 0);
        st.program_running = true;
        st.runtime_state = RUNTIME_PLAYING;
        st.program_gen = 1;
        Ok(VirtualUr { st, fields, timeout_ms: 0, last_message: None, ended: None })
    }

    /// Why the program ended (a read timeout, a clean stop), if it has.
    pub fn ended(&self) -> Option<&str> {
        self.ended.as_deref()
    }
}

impl FakeProtocol for VirtualUr {
    /// The data package of cycle `k`: the actual joints the caller's drives reached.
    fn packet(&mut self, k: u64, axes_deg: &[f64], out: &mut Vec<u8>) {
        let dt = self.st.opts.step;
        let now = k as f64 * dt;
        // The script's read: the next message is due within the timeout the last one announced.
        if self.st.program_running
            && let Some(t) = self.last_message
            && now - t > f64::from(self.timeout_ms) * 1e-3 + 1e-9
        {
            self.st.report.timeouts += 1;
            self.st.end_program();
            self.ended = Some(format!("no message for {:.0} ms: the read timed out ({} ms)", (now - t) * 1e3, self.timeout_ms));
        }
        for j in 0..JOINTS {
            let q = axes_deg.get(j).copied().unwrap_or(0.0).to_radians();
            self.st.qd[j] = if k == 0 { 0.0 } else { (q - self.st.q[j]) / dt };
            self.st.q[j] = q;
        }
        self.st.time = now;
        let snap = self.st.snapshot();
        let mut payload = vec![1u8];
        for f in &self.fields {
            f.encode(&snap, &mut payload);
        }
        out.clear();
        out.extend_from_slice(&package(DATA, &payload));
    }

    /// A reverse-interface message (8 × i32) answering cycle `k`: the servo target.
    fn answer(&mut self, k: u64, bytes: &[u8], axes_deg: &mut [f64]) -> Result<(), Option<u64>> {
        if !self.st.program_running || bytes.len() != 32 {
            return Err(None);
        }
        let mut f = [0i32; 8];
        for (i, v) in f.iter_mut().enumerate() {
            *v = i32::from_be_bytes([bytes[4 * i], bytes[4 * i + 1], bytes[4 * i + 2], bytes[4 * i + 3]]);
        }
        let mut timeout = self.timeout_ms;
        if !self.st.reverse_message(f, &mut timeout) {
            self.ended = Some("the driver stopped the program".into());
            return Err(None);
        }
        self.timeout_ms = timeout;
        self.last_message = Some(k as f64 * self.st.opts.step);
        if self.st.control_mode == MODE_SERVOJ {
            for (a, t) in axes_deg.iter_mut().zip(&self.st.target) {
                *a = t.to_degrees();
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn message(timeout_ms: i32, q: &[f64; JOINTS]) -> Vec<u8> {
        let mut f = vec![timeout_ms];
        f.extend(q.iter().map(|v| (v * super::super::MULT_JOINTSTATE).round() as i32));
        f.push(MODE_SERVOJ);
        f.iter().flat_map(|v| v.to_be_bytes()).collect()
    }

    #[test]
    fn messages_set_the_target_and_a_late_one_times_the_program_out() {
        let opts = UrOptions { step: 0.004, start_q: [0.0; JOINTS], ..Default::default() };
        let mut ur = VirtualUr::new(opts, "timestamp,actual_q,runtime_state").unwrap();
        let (mut target, mut out) = (vec![0.0; JOINTS], Vec::new());
        ur.packet(0, &target.clone(), &mut out);
        // Size, 'U', recipe 1, 8 + 48 + 4 bytes.
        assert_eq!((u16::from_be_bytes([out[0], out[1]]), out[2], out[3]), (64, b'U', 1));
        ur.answer(0, &message(20, &[0.01, 0.0, 0.0, 0.0, 0.0, 0.0]), &mut target).unwrap();
        assert!((target[0] - 0.01f64.to_degrees()).abs() < 1e-9, "{target:?}");
        // 20 ms later is in time; 24 ms is not.
        ur.packet(5, &target.clone(), &mut out);
        assert_eq!(ur.ended(), None);
        ur.packet(6, &target.clone(), &mut out);
        assert!(ur.ended().is_some_and(|w| w.contains("timed out")), "{:?}", ur.ended());
        assert_eq!(u32::from_be_bytes(out[out.len() - 4..].try_into().unwrap()), super::super::RUNTIME_STOPPED);
        assert!(VirtualUr::new(UrOptions::default(), "actual_q,no_such_field").is_err());
    }
}
