//! The arm and the controller's state: one lock holds it, shared by the step thread, the RTDE
//! sessions, the program and the watch. The step moves the joints (servoj's speed limit, stopj's
//! deceleration), records the report's row and sends each started RTDE session its data package.

use std::net::{Shutdown, TcpStream};

use super::rtde::{DATA, Outputs, Session, Snapshot, package};
use super::{
    JOINTS, MODE_SERVOJ, MODE_UNINITIALIZED, ROBOT_MODE_RUNNING, RUNTIME_STOPPED, SAFETY_NORMAL, STOPJ_ACCELERATION, UrOptions, UrReport,
};

#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Motion {
    /// At rest.
    Hold,
    /// Following `target` (servoj).
    Servo,
    /// Decelerating to rest at [`STOPJ_ACCELERATION`].
    Stopping,
}

pub(super) struct State {
    pub(super) opts: UrOptions,
    pub(super) t0: u64,
    pub(super) time: f64,
    pub(super) q: [f64; JOINTS],
    pub(super) qd: [f64; JOINTS],
    pub(super) target: [f64; JOINTS],
    pub(super) motion: Motion,
    pub(super) robot_mode: i32,
    pub(super) safety_mode: i32,
    pub(super) runtime_state: u32,
    pub(super) program_running: bool,
    pub(super) control_mode: i32,
    pub(super) fresh: bool,
    pub(super) program_gen: u64,
    pub(super) reverse: Option<TcpStream>,
    pub(super) servo_args: Option<(Option<f64>, Option<f64>)>,
    pub(super) speed_scaling: f64,
    pub(super) speed_fraction: f64,
    pub(super) analog: [(u8, f64); 2],
    pub(super) digital: u8,
    pub(super) bit_registers: u64,
    pub(super) int_registers: [i32; 48],
    pub(super) double_registers: [f64; 48],
    pub(super) sessions: Vec<Session>,
    pub(super) next_session: u64,
    /// Inputs owned by a session (name, session id): another session asking for them gets IN_USE.
    pub(super) owners: Vec<(String, u64)>,
    pub(super) report: UrReport,
}

impl State {
    pub(super) fn new(opts: &UrOptions, t0: u64) -> State {
        State {
            opts: opts.clone(),
            t0,
            time: 0.0,
            q: opts.start_q,
            qd: [0.0; JOINTS],
            target: opts.start_q,
            motion: Motion::Hold,
            robot_mode: ROBOT_MODE_RUNNING,
            safety_mode: SAFETY_NORMAL,
            runtime_state: RUNTIME_STOPPED,
            program_running: false,
            control_mode: MODE_UNINITIALIZED,
            fresh: false,
            program_gen: 0,
            reverse: None,
            servo_args: None,
            speed_scaling: 1.0,
            speed_fraction: 1.0,
            analog: [(0, 0.0); 2],
            digital: 0,
            bit_registers: 0,
            int_registers: [0; 48],
            double_registers: [0.0; 48],
            sessions: Vec::new(),
            next_session: 1,
            owners: Vec::new(),
            report: UrReport::default(),
        }
    }

    pub(super) fn snapshot(&self) -> Snapshot {
        Snapshot {
            time: self.time,
            q: self.q,
            qd: self.qd,
            target_q: if self.motion == Motion::Servo { self.target } else { self.q },
            robot_mode: self.robot_mode,
            safety_mode: self.safety_mode,
            runtime_state: self.runtime_state,
            speed_scaling: self.speed_scaling,
            speed_fraction: self.speed_fraction,
            program_running: self.program_running,
        }
    }

    /// One controller step at `deadline` (ns).
    pub(super) fn step(&mut self, deadline: u64) {
        let dt = self.opts.step;
        self.time = deadline.saturating_sub(self.t0) as f64 * 1e-9;
        match self.motion {
            Motion::Servo => {
                for j in 0..JOINTS {
                    let lim = self.opts.speed_limit[j].abs() * dt;
                    let d = (self.target[j] - self.q[j]).clamp(-lim, lim);
                    self.q[j] += d;
                    self.qd[j] = d / dt;
                }
            }
            Motion::Stopping => {
                let dv = STOPJ_ACCELERATION * dt;
                let mut moving = false;
                for j in 0..JOINTS {
                    let v = self.qd[j];
                    let nv = v.signum() * (v.abs() - dv).max(0.0);
                    self.q[j] += 0.5 * (v + nv) * dt;
                    self.qd[j] = nv;
                    moving |= nv != 0.0;
                }
                if !moving {
                    self.motion = Motion::Hold;
                }
            }
            Motion::Hold => self.qd = [0.0; JOINTS],
        }
        if self.program_running && self.control_mode == MODE_SERVOJ {
            let r = &mut self.report.report;
            r.axes.push(self.q.iter().map(|q| q.to_degrees()).collect());
            r.fresh.push(self.fresh);
            r.cycles += 1;
            if self.fresh {
                r.in_time += 1;
            } else {
                r.missing += 1;
            }
        }
        self.fresh = false;
        // The RTDE stream: each started session at its own frequency, on step boundaries, the
        // newest state; a package is skipped while the client has not taken the last one.
        let snap = self.snapshot();
        for s in &mut self.sessions {
            let Outputs::Valid(fields) = &s.outputs else { continue };
            if !s.started || s.conn.dead {
                continue;
            }
            s.phase += s.frequency * dt;
            if s.phase < 1.0 - 1e-9 {
                continue;
            }
            s.phase = (s.phase - 1.0).clamp(0.0, 0.999);
            if !s.conn.pending.is_empty() {
                s.conn.flush();
                continue;
            }
            let mut payload = Vec::with_capacity(256);
            payload.push(1u8);
            for f in fields {
                f.encode(&snap, &mut payload);
            }
            s.conn.push(&package(DATA, &payload));
        }
    }

    /// Ends the running program (the arm decelerates to rest, the reverse socket is closed).
    pub(super) fn end_program(&mut self) {
        self.program_gen += 1;
        self.program_running = false;
        self.runtime_state = RUNTIME_STOPPED;
        self.control_mode = MODE_UNINITIALIZED;
        self.stop_arm();
        if let Some(r) = self.reverse.take() {
            let _ = r.shutdown(Shutdown::Both);
        }
    }

    pub(super) fn stop_arm(&mut self) {
        if self.motion != Motion::Hold {
            self.motion = Motion::Stopping;
        }
    }
}
