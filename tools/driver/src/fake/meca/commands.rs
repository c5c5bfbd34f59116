//! The control port's commands: a frame parsed into a command with its arguments checked, and each
//! command run against the robot's state (the `[CCCC][payload]\0` format itself is the parent's).

use std::collections::BTreeSet;

use super::robot::State;
use super::{DEFAULT_JOINT_ACC, DEFAULT_VEL_TIMEOUT, JOINTS, R3_LIMITS_DEG, R3_SPEED_DEG, RT_CODES, list, msg, stamped};

/// The command names the fake knows (lower case).
const KNOWN: [&str; 34] = [
    "activaterobot",
    "home",
    "deactivaterobot",
    "reseterror",
    "pausemotion",
    "resumemotion",
    "clearmotion",
    "getstatusrobot",
    "getjoints",
    "getrttargetjointpos",
    "getrtjointpos",
    "getrttargetjointvel",
    "getrtjointvel",
    "setmonitoringinterval",
    "getmonitoringinterval",
    "setrealtimemonitoring",
    "getrealtimemonitoring",
    "setctrlportmonitoring",
    "setveltimeout",
    "getveltimeout",
    "movejointsvel",
    "setjointacc",
    "getjointacc",
    "setjointvellimit",
    "getjointvellimit",
    "setjointvel",
    "getjointvel",
    "seteob",
    "seteom",
    "connectionwatchdog",
    "getmodeljointlimits",
    "getjointlimits",
    "getfwversion",
    "getproducttype",
];

impl State {
    pub(super) fn reply(&mut self, code: u32, payload: &str) {
        if (1000..2000).contains(&code) {
            self.report.errors.push(code);
            if matches!(code, 1001..=1003) {
                self.report.garbage += 1;
            }
        }
        self.send_control(&msg(code, payload));
    }

    /// One frame from the control client (without its terminator), received at `now`.
    pub(super) fn frame(&mut self, frame: &[u8], now: u64) {
        let text = String::from_utf8_lossy(frame);
        let text = text.trim();
        let text = text.strip_prefix('-').unwrap_or(text).trim();
        if text.is_empty() {
            return;
        }
        let (name, rest) = match text.find('(') {
            Some(i) => (text[..i].trim(), Some(&text[i..])),
            None => (text, None),
        };
        let key = name.to_ascii_lowercase();
        if !KNOWN.contains(&key.as_str()) {
            self.reply(1001, "Unknown command.");
            return;
        }
        if key != "movejointsvel" {
            self.report.commands.push(name.to_string());
        }
        let args: Vec<&str> = match rest {
            None => Vec::new(),
            Some(r) => {
                let inner = r.strip_prefix('(').and_then(|r| r.strip_suffix(')'));
                match inner {
                    Some(inner) if !inner.contains(['(', ')']) => {
                        let inner = inner.trim();
                        if inner.is_empty() { Vec::new() } else { inner.split(',').map(str::trim).collect() }
                    }
                    _ => {
                        self.reply(1002, "Syntax error, symbol missing.");
                        return;
                    }
                }
            }
        };
        if args.iter().any(|a| a.is_empty()) {
            self.reply(1002, "Syntax error, symbol missing.");
            return;
        }
        self.command(&key, &args, now);
    }

    fn arg_error(&mut self) {
        self.reply(1003, "Argument error.");
    }

    /// `n` finite numbers, or None (1003 sent).
    fn numbers(&mut self, args: &[&str], n: usize) -> Option<Vec<f64>> {
        let values: Option<Vec<f64>> = args.iter().map(|a| a.parse::<f64>().ok().filter(|v| v.is_finite())).collect();
        match values {
            Some(v) if v.len() == n => Some(v),
            _ => {
                self.arg_error();
                None
            }
        }
    }

    /// One number within `lo..=hi`, or None (1003 sent).
    fn number_in(&mut self, args: &[&str], lo: f64, hi: f64) -> Option<f64> {
        let v = self.numbers(args, 1)?[0];
        if (lo..=hi).contains(&v) {
            Some(v)
        } else {
            self.arg_error();
            None
        }
    }

    /// An integer among `allowed`, or None (1003 sent).
    fn integer_of(&mut self, args: &[&str], allowed: std::ops::RangeInclusive<i64>) -> Option<i64> {
        let v = self.numbers(args, 1)?[0];
        if v.fract() == 0.0 && allowed.contains(&(v as i64)) {
            Some(v as i64)
        } else {
            self.arg_error();
            None
        }
    }

    fn no_args(&mut self, args: &[&str]) -> bool {
        if args.is_empty() {
            true
        } else {
            self.arg_error();
            false
        }
    }

    /// A motion-queue command may run (else 1005, 1006 or 1011 sent).
    fn queue_ready(&mut self) -> bool {
        if !self.activated {
            self.reply(1005, "Motors are not activated.");
        } else if !self.homed {
            self.reply(1006, "Homing has not been performed.");
        } else if self.error {
            self.reply(1011, "The robot is in error.");
        } else {
            return true;
        }
        false
    }

    fn activated_or_1005(&mut self) -> bool {
        if !self.activated {
            self.reply(1005, "Motors are not activated.");
        }
        self.activated
    }

    fn unknown_before(&mut self, major: u32, minor: u32) -> bool {
        if self.at_least(major, minor) {
            false
        } else {
            self.reply(1001, "Unknown command.");
            true
        }
    }

    fn command(&mut self, key: &str, args: &[&str], now: u64) {
        match key {
            "activaterobot" => {
                if !self.no_args(args) {
                } else if self.error {
                    self.reply(1011, "The robot is in error.");
                } else if self.activated {
                    if self.at_least(9, 0) {
                        self.reply(2000, "Motors activated.");
                    } else {
                        self.reply(2001, "Motors already activated.");
                    }
                } else {
                    self.activated = true;
                    self.paused = false;
                    self.vel_timeout = DEFAULT_VEL_TIMEOUT;
                    self.joint_acc = DEFAULT_JOINT_ACC;
                    self.joint_vel_limit = 100.0;
                    self.joint_vel = 100.0;
                    self.drop_velocity();
                    self.reply(2000, "Motors activated.");
                    self.publish_status(true);
                }
            }
            "home" => {
                if !self.no_args(args) || !self.activated_or_1005() {
                } else if self.error {
                    self.reply(1011, "The robot is in error.");
                } else if self.homed {
                    if self.at_least(9, 0) {
                        self.reply(2002, "Homing done.");
                    } else {
                        self.reply(2003, "Homing already done.");
                    }
                } else if self.homing_until.is_none() {
                    self.homing_until = Some(now.saturating_add(self.home_ns));
                }
            }
            "deactivaterobot" => {
                if self.no_args(args) {
                    self.activated = false;
                    self.homed = false;
                    self.homing_until = None;
                    self.paused = true;
                    self.v = [0.0; JOINTS];
                    self.drop_velocity();
                    self.reply(2004, "Motors deactivated.");
                    self.publish_status(true);
                }
            }
            "reseterror" => {
                if self.no_args(args) {
                    if self.error {
                        self.error = false;
                        self.reply(2005, "The error was reset.");
                    } else {
                        self.reply(2006, "There was no error to reset.");
                    }
                    self.publish_status(true);
                }
            }
            "pausemotion" => {
                if self.no_args(args) && self.activated_or_1005() {
                    self.paused = true;
                    self.drop_velocity();
                    self.reply(2042, "Motion paused.");
                    self.publish_status(true);
                }
            }
            "resumemotion" => {
                if !self.no_args(args) || !self.activated_or_1005() {
                } else if self.error {
                    self.reply(1011, "The robot is in error.");
                } else {
                    self.paused = false;
                    self.reply(2043, "Motion resumed.");
                    self.publish_status(true);
                }
            }
            "clearmotion" => {
                if self.no_args(args) && self.activated_or_1005() {
                    self.paused = true;
                    self.drop_velocity();
                    self.reply(2044, "The motion was cleared.");
                    self.publish_status(true);
                }
            }
            "getstatusrobot" => {
                if self.no_args(args) {
                    let p = self.status_payload();
                    self.reply(2007, &p);
                }
            }
            "getjoints" => {
                if self.no_args(args) {
                    let p = list(&self.q);
                    self.reply(2026, &p);
                }
            }
            "getrttargetjointpos" | "getrtjointpos" | "getrttargetjointvel" | "getrtjointvel" => {
                if (key == "getrttargetjointpos" && self.unknown_before(8, 4)) || !self.no_args(args) {
                    return;
                }
                let (code, values) = match key {
                    "getrttargetjointpos" => (2200, self.q),
                    "getrtjointpos" => (2210, self.q),
                    "getrttargetjointvel" => (2202, self.v),
                    _ => (2212, self.v),
                };
                let p = stamped(self.t_us(now), &values);
                self.reply(code, &p);
            }
            "setmonitoringinterval" => {
                if let Some(t) = self.number_in(args, 0.001, 1.0) {
                    self.monitoring_interval = t;
                    self.next_monitor_ns = now;
                }
            }
            "getmonitoringinterval" => {
                if self.no_args(args) {
                    let p = format!("{:.6}", self.monitoring_interval);
                    self.reply(2116, &p);
                }
            }
            "setrealtimemonitoring" => {
                let mut set = BTreeSet::new();
                for a in args {
                    if a.eq_ignore_ascii_case("all") {
                        set.extend(RT_CODES);
                    } else {
                        match a.parse::<u32>() {
                            Ok(c) if RT_CODES.contains(&c) => {
                                set.insert(c);
                            }
                            _ => return self.arg_error(),
                        }
                    }
                }
                self.rt = set;
                self.rt_reply();
            }
            "getrealtimemonitoring" => {
                if self.no_args(args) {
                    self.rt_reply();
                }
            }
            "setctrlportmonitoring" => {
                if self.unknown_before(9, 0) {
                    return;
                }
                if let Some(on) = self.integer_of(args, 0..=1) {
                    self.ctrl_monitoring = on == 1;
                    self.reply(2096, &on.to_string());
                    if self.ctrl_monitoring {
                        let m = msg(2007, &self.status_payload());
                        self.send_control(&m);
                    }
                }
            }
            "setveltimeout" => {
                if let Some(t) = self.number_in(args, 0.001, 1.0)
                    && self.queue_ready()
                {
                    self.vel_timeout = t;
                }
            }
            "movejointsvel" => {
                if let Some(w) = self.numbers(args, JOINTS)
                    && self.queue_ready()
                {
                    self.report.move_joints_vel += 1;
                    self.vel_in_interval = true;
                    if self.paused {
                        return;
                    }
                    // Capped to the speeds × SetJointVelLimit, scaled together (the direction kept).
                    let ratio = (0..JOINTS).map(|j| w[j].abs() / (R3_SPEED_DEG[j] * self.joint_vel_limit / 100.0)).fold(1.0f64, f64::max);
                    for j in 0..JOINTS {
                        self.cmd[j] = w[j] / ratio;
                    }
                    self.cmd_at = Some(now);
                }
            }
            "setjointacc" => {
                if let Some(p) = self.number_in(args, 0.001, 150.0)
                    && self.queue_ready()
                {
                    self.joint_acc = p;
                }
            }
            "setjointvellimit" => {
                if self.unknown_before(9, 3) {
                    return;
                }
                if let Some(p) = self.number_in(args, 0.001, 100.0)
                    && self.queue_ready()
                {
                    self.joint_vel_limit = p;
                }
            }
            "setjointvel" => {
                if let Some(p) = self.number_in(args, 0.001, 100.0)
                    && self.queue_ready()
                {
                    self.joint_vel = p;
                }
            }
            "getveltimeout" | "getjointacc" | "getjointvellimit" | "getjointvel" => {
                if (key == "getjointvellimit" && self.unknown_before(9, 3)) || !self.no_args(args) {
                    return;
                }
                let (code, v) = match key {
                    "getveltimeout" => (2151, self.vel_timeout),
                    "getjointacc" => (2153, self.joint_acc),
                    "getjointvellimit" => (2169, self.joint_vel_limit),
                    _ => (2152, self.joint_vel),
                };
                self.reply(code, &format!("{v:.6}"));
            }
            "seteob" | "seteom" => {
                if let Some(on) = self.integer_of(args, 0..=1) {
                    let on = on == 1;
                    if key == "seteob" {
                        self.eob_enabled = on;
                        self.reply(if on { 2054 } else { 2055 }, if on { "End of block is enabled." } else { "End of block is disabled." });
                    } else {
                        self.eom_enabled = on;
                        self.reply(
                            if on { 2052 } else { 2053 },
                            if on { "End of movement is enabled." } else { "End of movement is disabled." },
                        );
                    }
                }
            }
            "connectionwatchdog" => {
                if self.unknown_before(10, 1) {
                    return;
                }
                if let Some(t) = self.number_in(args, 0.0, f64::MAX) {
                    if t > 0.0 {
                        self.watchdog = Some((t, now.saturating_add((t * 1e9) as u64)));
                        self.reply(2177, "1");
                    } else {
                        self.watchdog = None;
                        self.reply(2177, "0");
                    }
                }
            }
            "getmodeljointlimits" | "getjointlimits" => {
                if let Some(n) = self.integer_of(args, 1..=JOINTS as i64) {
                    let (lo, hi) = R3_LIMITS_DEG[n as usize - 1];
                    let p = format!("{n},{lo:.6},{hi:.6}");
                    self.reply(if key == "getmodeljointlimits" { 2113 } else { 2090 }, &p);
                }
            }
            "getfwversion" => {
                if self.no_args(args) {
                    let p = format!("v{}", self.version);
                    self.reply(2081, &p);
                }
            }
            "getproducttype" => {
                if self.no_args(args) {
                    self.reply(2084, "Meca500");
                }
            }
            _ => self.reply(1001, "Unknown command."),
        }
    }

    fn rt_reply(&mut self) {
        let p = self.rt.iter().map(u32::to_string).collect::<Vec<_>>().join(",");
        self.reply(2117, &p);
    }
}
