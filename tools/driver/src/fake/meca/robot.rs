//! The robot's state and its trajectory: the status, the joints' velocities ramped towards the
//! last command every tick (stopped at a limit, a timeout or a pause), and the monitoring stream
//! every interval. One lock holds it, shared by the tick thread, the control reader and the watch.

use std::collections::BTreeSet;

use super::{
    DEFAULT_JOINT_ACC, DEFAULT_MONITORING_INTERVAL, DEFAULT_VEL_TIMEOUT, JOINTS, MecaOptions, MecaReport, Out, R3_LIMITS_DEG, list, msg,
    stamped,
};

/// "major.minor.patch" as a comparable triple (missing or unreadable parts 0).
fn parse_version(v: &str) -> (u32, u32, u32) {
    let mut parts = v.trim().trim_start_matches('v').split('.').map(|p| p.parse::<u32>().unwrap_or(0));
    (parts.next().unwrap_or(0), parts.next().unwrap_or(0), parts.next().unwrap_or(0))
}

pub(super) struct State {
    t0_ns: u64,
    pub(super) tick: f64,
    accel: [f64; JOINTS],
    pub(super) home_ns: u64,
    pub(super) version: String,
    fw: (u32, u32, u32),

    pub(super) activated: bool,
    pub(super) homed: bool,
    pub(super) error: bool,
    pub(super) paused: bool,
    eob: bool,
    eom: bool,
    pub(super) homing_until: Option<u64>,
    pub(super) q: [f64; JOINTS],
    pub(super) v: [f64; JOINTS],
    /// The accepted MoveJointsVel (capped, deg/s) and when it arrived.
    pub(super) cmd: [f64; JOINTS],
    pub(super) cmd_at: Option<u64>,
    pub(super) vel_timeout: f64,
    pub(super) joint_acc: f64,
    pub(super) joint_vel_limit: f64,
    pub(super) joint_vel: f64,
    pub(super) monitoring_interval: f64,
    pub(super) next_monitor_ns: u64,
    pub(super) rt: BTreeSet<u32>,
    pub(super) eob_enabled: bool,
    pub(super) eom_enabled: bool,
    pub(super) watchdog: Option<(f64, u64)>,

    pub(super) control: Option<Out>,
    pub(super) control_gen: u64,
    pub(super) ctrl_monitoring: bool,
    pub(super) monitors: Vec<Out>,
    last_status: [bool; 7],

    pub(super) report: MecaReport,
    pub(super) vel_in_interval: bool,
}

impl State {
    pub(super) fn new(opts: &MecaOptions, t0_ns: u64) -> State {
        let activated = opts.activated;
        let mut s = State {
            t0_ns,
            tick: if opts.tick.is_finite() && opts.tick > 0.0 { opts.tick } else { 0.001 },
            accel: opts.accel_deg,
            home_ns: (opts.home_time.max(0.0) * 1e9) as u64,
            version: opts.version.clone(),
            fw: parse_version(&opts.version),
            activated,
            homed: activated && opts.homed,
            error: false,
            paused: !activated,
            eob: true,
            eom: true,
            homing_until: None,
            q: opts.start_deg,
            v: [0.0; JOINTS],
            cmd: [0.0; JOINTS],
            cmd_at: None,
            vel_timeout: DEFAULT_VEL_TIMEOUT,
            joint_acc: DEFAULT_JOINT_ACC,
            joint_vel_limit: 100.0,
            joint_vel: 100.0,
            monitoring_interval: DEFAULT_MONITORING_INTERVAL,
            next_monitor_ns: t0_ns,
            rt: BTreeSet::new(),
            eob_enabled: true,
            eom_enabled: false,
            watchdog: None,
            control: None,
            control_gen: 0,
            ctrl_monitoring: false,
            monitors: Vec::new(),
            last_status: [false; 7],
            report: MecaReport::default(),
            vel_in_interval: false,
        };
        s.last_status = s.status();
        s
    }

    pub(super) fn status(&self) -> [bool; 7] {
        [self.activated, self.homed, false, self.error, self.paused, self.eob, self.eom]
    }

    pub(super) fn status_payload(&self) -> String {
        self.status().iter().map(|b| if *b { "1" } else { "0" }).collect::<Vec<_>>().join(",")
    }

    pub(super) fn t_us(&self, now: u64) -> u64 {
        now.saturating_sub(self.t0_ns) / 1000
    }

    pub(super) fn at_least(&self, major: u32, minor: u32) -> bool {
        (self.fw.0, self.fw.1) >= (major, minor)
    }

    pub(super) fn send_control(&mut self, bytes: &[u8]) {
        if let Some(c) = self.control.as_mut() {
            c.push(bytes);
        }
    }

    /// To every monitoring client, and to the control client if it asked for the stream.
    fn send_monitors(&mut self, bytes: &[u8]) {
        for m in &mut self.monitors {
            m.push(bytes);
        }
        if self.ctrl_monitoring {
            self.send_control(bytes);
        }
    }

    /// A `[2007]` everywhere if the status changed (or `force`).
    pub(super) fn publish_status(&mut self, force: bool) {
        let status = self.status();
        if force || status != self.last_status {
            self.last_status = status;
            let m = msg(2007, &self.status_payload());
            self.send_monitors(&m);
        }
    }

    /// The velocity command is dropped: the arm decelerates.
    pub(super) fn drop_velocity(&mut self) {
        self.cmd = [0.0; JOINTS];
        self.cmd_at = None;
    }

    pub(super) fn raise(&mut self, code: u32, text: &str) {
        self.error = true;
        self.paused = true;
        self.drop_velocity();
        self.report.errors.push(code);
        self.send_control(&msg(code, text));
        self.publish_status(true);
    }

    pub(super) fn disconnected(&mut self) {
        self.control = None;
        self.ctrl_monitoring = false;
        self.watchdog = None;
        self.drop_velocity();
        // §5.2: a dropped control connection pauses motion.
        if self.activated {
            self.paused = true;
        }
        self.publish_status(false);
    }

    /// One trajectory cycle ending at `now` (its deadline).
    pub(super) fn step(&mut self, now: u64) {
        let dt = self.tick;
        if let Some(until) = self.homing_until
            && now >= until
        {
            self.homing_until = None;
            if self.activated && !self.error {
                self.homed = true;
                self.reply(2002, "Homing done.");
                self.publish_status(true);
            }
        }
        if let Some((_, deadline)) = self.watchdog
            && now > deadline
        {
            self.watchdog = None;
            self.report.errors.push(3086);
            self.send_control(&msg(3086, "Connection watchdog expired."));
            if let Some(c) = self.control.as_mut() {
                c.flush();
                c.shutdown();
            }
            self.drop_velocity();
            if self.activated {
                self.paused = true;
            }
        }
        let ready = self.activated && self.homed && !self.error && !self.paused && self.control.is_some();
        if !ready {
            self.drop_velocity();
        }
        let mut target = [0.0; JOINTS];
        if let Some(at) = self.cmd_at {
            if now > at.saturating_add((self.vel_timeout * 1e9) as u64) {
                if self.cmd.iter().any(|w| *w != 0.0) {
                    self.report.timeouts += 1;
                }
                self.drop_velocity();
            } else {
                target = self.cmd;
            }
        }
        // A joint at its limit is not driven into it.
        for j in 0..JOINTS {
            let (lo, hi) = R3_LIMITS_DEG[j];
            if (self.q[j] >= hi && target[j] > 0.0) || (self.q[j] <= lo && target[j] < 0.0) {
                target[j] = 0.0;
            }
        }
        let v_old = self.v;
        if !self.activated {
            self.v = [0.0; JOINTS];
        } else {
            // All joints reach the target together, none faster than its acceleration.
            let need = (0..JOINTS)
                .map(|j| (target[j] - self.v[j]).abs() / (self.accel[j] * self.joint_acc / 100.0).max(1e-9))
                .fold(0.0f64, f64::max);
            if need <= dt {
                self.v = target;
            } else {
                for j in 0..JOINTS {
                    self.v[j] += (target[j] - self.v[j]) * dt / need;
                }
            }
        }
        for j in 0..JOINTS {
            let (lo, hi) = R3_LIMITS_DEG[j];
            let before = self.q[j];
            self.q[j] += 0.5 * (v_old[j] + self.v[j]) * dt;
            if self.q[j] >= hi || self.q[j] <= lo {
                if before < hi && before > lo {
                    self.report.limit_stops += 1;
                }
                self.q[j] = self.q[j].clamp(lo, hi);
                self.v[j] = 0.0;
            }
        }
        let moving = self.v.iter().any(|v| *v != 0.0);
        let busy = self.cmd_at.is_some() && self.cmd.iter().any(|w| *w != 0.0);
        let (eom, eob) = (!moving, !moving && !busy);
        if eom && !self.eom && self.eom_enabled {
            self.send_control(&msg(3004, "End of movement."));
        }
        if eob && !self.eob && self.eob_enabled {
            self.send_control(&msg(3012, "End of block."));
        }
        (self.eom, self.eob) = (eom, eob);
        self.publish_status(false);
        if now >= self.next_monitor_ns {
            let cycle = self.cycle(now);
            self.send_monitors(&cycle);
            if self.control.is_some() && self.activated && self.homed {
                let r = &mut self.report.report;
                r.axes.push(self.q.to_vec());
                r.cycles += 1;
                r.fresh.push(self.vel_in_interval);
                if self.vel_in_interval {
                    r.in_time += 1;
                } else {
                    r.missing += 1;
                }
            }
            self.vel_in_interval = false;
            let interval = (self.monitoring_interval * 1e9).round() as u64;
            self.next_monitor_ns += interval;
            if self.next_monitor_ns <= now {
                self.next_monitor_ns = now + interval;
            }
        }
        self.monitors.retain_mut(|m| {
            m.flush();
            !m.dead
        });
        if let Some(c) = self.control.as_mut() {
            c.flush();
        }
    }

    /// One monitoring cycle: every message stamped `t`, ended by `[2230][t]`.
    fn cycle(&self, now: u64) -> Vec<u8> {
        let t = self.t_us(now);
        let zeros = [0.0; JOINTS];
        let mut out = Vec::with_capacity(1024);
        out.extend(msg(2026, &list(&self.q)));
        out.extend(msg(2027, &list(&zeros)));
        out.extend(msg(2200, &stamped(t, &self.q)));
        out.extend(msg(2201, &stamped(t, &zeros)));
        for &code in &self.rt {
            let values: &[f64] = match code {
                2202 | 2212 => &self.v,
                2210 | 2221 => &self.q,
                2203 | 2204 | 2211 | 2213 | 2214 => &zeros,
                2222 => &[100.0],
                _ => continue,
            };
            out.extend(msg(code, &stamped(t, values)));
        }
        out.extend(msg(2230, &t.to_string()));
        out
    }
}
