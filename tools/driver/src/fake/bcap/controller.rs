//! The RC8's controller state and its tick: slave mode, the command buffer, the speed and
//! acceleration checks a command must pass, the latched errors, and the drives following the
//! target. One lock holds it, shared by the tick thread, the session and the watch.

use std::collections::VecDeque;

use strand::io::clock::monotonic_ns;

use super::BcapOptions;
use super::wire::{MAX_JOINTS, hr};
use crate::fake::FakeReport;

/// The controller's state (one lock: the tick, the session and the watch share it).
pub(super) struct Ctrl {
    joints: usize,
    pub(super) actual: Vec<f64>,
    pub(super) target: Vec<f64>,
    /// The last two commands taken (the robot at rest at slave-mode entry: both its position).
    prev: Vec<f64>,
    prev2: Vec<f64>,
    pub(super) arm_taken: bool,
    pub(super) motor_on: bool,
    /// When a pending Motor on (noWait or timed out) completes (monotonic ns).
    pub(super) motor_on_at: Option<u64>,
    pub(super) send_fmt: u32,
    pub(super) recv_fmt: u32,
    pub(super) ts_us: bool,
    pub(super) slave_mode: u32,
    pub(super) buffer: VecDeque<[f64; MAX_JOINTS]>,
    /// A command was taken since slave mode was entered.
    pub(super) streaming: bool,
    /// Commands popped by the tick (mode-2 holds wait for it to move).
    pub(super) pops: u64,
    pub(super) latched: Option<u32>,
    pub(super) errors: Vec<u32>,
    pub(super) connected: bool,
    pub(super) released: bool,
    pub(super) slave_ticks: u64,
    pub(super) next_handle: u32,
    pub(super) report: FakeReport,
    pub(super) calls: Vec<String>,
    pub(super) slv_moves: u64,
    pub(super) buffer_full: u64,
}

impl Ctrl {
    /// A controller at `start` (degrees), disconnected, the motor off.
    pub(super) fn new(start: &[f64]) -> Ctrl {
        Ctrl {
            joints: start.len(),
            actual: start.to_vec(),
            target: start.to_vec(),
            prev: start.to_vec(),
            prev2: start.to_vec(),
            arm_taken: false,
            motor_on: false,
            motor_on_at: None,
            send_fmt: 0,
            recv_fmt: 0x0002,
            ts_us: false,
            slave_mode: 0,
            buffer: VecDeque::with_capacity(4),
            streaming: false,
            pops: 0,
            latched: None,
            errors: Vec::new(),
            connected: false,
            released: false,
            slave_ticks: 0,
            next_handle: 1,
            report: FakeReport::default(),
            calls: Vec::new(),
            slv_moves: 0,
            buffer_full: 0,
        }
    }

    pub(super) fn latch(&mut self, code: u32) {
        self.errors.push(code);
        self.latched = Some(code);
        self.leave_slave(true);
        if code & 0x8000_0000 != 0 && (code >> 24) & 0xF >= 4 {
            self.motor_on = false;
            self.motor_on_at = None;
        }
    }

    /// Slave mode 0, the buffer dropped; `stop`: the robot stops where it is.
    pub(super) fn leave_slave(&mut self, stop: bool) {
        self.slave_mode = 0;
        self.buffer.clear();
        self.streaming = false;
        if stop {
            self.target.clone_from(&self.actual);
        }
    }

    pub(super) fn enter_slave(&mut self, mode: u32) {
        self.leave_slave(false);
        self.slave_mode = mode;
        self.target.clone_from(&self.actual);
        self.prev.clone_from(&self.actual);
        self.prev2.clone_from(&self.actual);
    }

    pub(super) fn resolve_motor(&mut self, now: u64) {
        if self.motor_on_at.is_some_and(|at| now >= at) {
            self.motor_on = true;
            self.motor_on_at = None;
        }
    }

    /// The error a command would latch against the previous two.
    fn check(&self, cmd: &[f64], opts: &BcapOptions) -> Option<u32> {
        let c = opts.cycle;
        let limit = |l: &[f64], j: usize| l.get(j).copied().unwrap_or(f64::INFINITY) * (1.0 + 1e-9);
        for j in 0..self.joints {
            if ((cmd[j] - self.prev[j]) / c).abs() > limit(&opts.speed_limit_deg, j) {
                return Some(hr::E_SPEED + j as u32 + 1);
            }
        }
        for j in 0..self.joints {
            if ((cmd[j] - 2.0 * self.prev[j] + self.prev2[j]) / (c * c)).abs() > limit(&opts.accel_limit_deg, j) {
                return Some(hr::E_ACCEL + j as u32 + 1);
            }
        }
        None
    }

    pub(super) fn tick(&mut self, alpha: f64, opts: &BcapOptions) {
        self.resolve_motor(monotonic_ns());
        let mut row = None;
        if self.slave_mode != 0 {
            self.slave_ticks += 1;
            if let Some(cmd) = self.buffer.pop_front() {
                self.pops += 1;
                row = Some(true);
                let cmd = &cmd[..self.joints];
                match self.check(cmd, opts) {
                    Some(code) => self.latch(code),
                    None => {
                        std::mem::swap(&mut self.prev2, &mut self.prev);
                        self.prev.copy_from_slice(cmd);
                        self.target.copy_from_slice(cmd);
                        self.streaming = true;
                    }
                }
            } else if self.streaming {
                row = Some(false);
                self.latch(hr::E_BUF_EMPTY);
            }
        }
        for (a, t) in self.actual.iter_mut().zip(&self.target) {
            *a += alpha * (t - *a);
        }
        if let Some(fresh) = row {
            let r = &mut self.report;
            r.cycles += 1;
            if fresh {
                r.in_time += 1;
            } else {
                r.missing += 1;
            }
            r.fresh.push(fresh);
            r.axes.push(self.actual.clone());
        }
    }

    /// The 8 joints (degrees, unused 0).
    pub(super) fn joints8(&self) -> [f64; MAX_JOINTS] {
        let mut q = [0.0; MAX_JOINTS];
        q[..self.joints].copy_from_slice(&self.actual);
        q
    }
}
