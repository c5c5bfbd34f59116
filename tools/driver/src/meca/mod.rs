//! The Mecademic Meca500's TCP API (the arm of paper 000) as a velocity-streaming client
//! (`docs/protocols/meca500.md`): NUL-terminated text commands on the control port (10000),
//! `[code][payload]` replies and events back, and the monitoring port (10001) streaming the joints
//! every monitoring interval, each interval closed by `[2230][t]`.
//!
//! The Meca500 takes no joint positions at a fixed rate; it takes velocities. So the driver runs
//! the cycle on its own clock (`[controller] rate_hz`): each tick, the newest joints the robot
//! reported are the JointState that clocks the service, and the answer to the service's command
//! is `MoveJointsVel` with velocity = the command's feed-forward (its step over the cycle) + `[driver]
//! velocity_gain` × (command − measured), within each joint's speed limit. The robot holds each
//! velocity until the next and stops by itself `SetVelTimeout` after the last (the driver sets it
//! from `[driver] velocity_timeout`), so an arm whose driver stops, hangs or loses the link comes to
//! rest on its own.
//!
//! This module is sans-IO: [`Meca`] reads one tick's messages (both sockets, as [`link`] collects
//! them) and writes the tick's command; every error code and event the robot sends is read here,
//! and any that means the arm stopped (a command refused, a motion error, a safety stop, the
//! robot in error or paused behind the driver's back) ends the stream, named.

pub mod link;

use std::io::Write;

use crate::protocol::{Channel, Clock, Frame, PacketError, RobotPacket, RobotProtocol};
use strand_ipc::MAX_JOINTS;

/// The Meca500's joints.
pub(crate) const JOINTS: usize = 6;

/// Where a message in a tick's packet came from (its first byte in the packet).
pub(crate) const FROM_CONTROL: u8 = b'C';
/// See [`FROM_CONTROL`].
pub const FROM_MONITOR: u8 = b'M';

/// One `[code][payload]` message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Message<'a> {
    /// The 4-digit code.
    pub code: u32,
    /// The text between the second `[` and the last `]`.
    pub payload: &'a str,
}

/// Parses `[CCCC][payload]` (None if it is not one).
pub(crate) fn parse_message(text: &str) -> Option<Message<'_>> {
    let text = text.trim_matches(|c: char| c == '\r' || c == '\n' || c == ' ');
    let rest = text.strip_prefix('[')?;
    let close = rest.find(']')?;
    let code = rest[..close].trim().parse().ok()?;
    let rest = &rest[close + 1..];
    let payload = match rest.find('[') {
        Some(open) => {
            let last = rest.rfind(']')?;
            if last < open {
                return None;
            }
            &rest[open + 1..last]
        }
        None => "",
    };
    Some(Message { code, payload })
}

/// Reads comma-separated numbers into `out`; how many there were (None: one is not a number, or
/// there are more than `out` holds).
pub(crate) fn parse_numbers(payload: &str, out: &mut [f64]) -> Option<usize> {
    let mut n = 0;
    for field in payload.split(',') {
        let field = field.trim();
        if field.is_empty() {
            continue;
        }
        *out.get_mut(n)? = field.parse().ok()?;
        n += 1;
    }
    Some(n)
}

/// The name of a Meca500 code, for messages (`docs/protocols/meca500.md` §3).
pub fn describe(code: u32) -> String {
    let name = match code {
        1000 => "command buffer full",
        1001 => "unknown command",
        1002 => "syntax error",
        1003 => "argument error (count or range)",
        1005 => "the robot is not activated",
        1006 => "the robot is not homed",
        1007 => "joint over its limit",
        1010 => "blocked by the 180° protection",
        1011 => "the robot is in error",
        1012 => "singularity",
        1013 => "activation failed",
        1014 => "homing failed",
        1016 => "out of reach",
        1025 => "the error cannot be reset: power-cycle the robot",
        1026 => "the robot must be deactivated",
        1040 => "command failed",
        1045 => "the API is locked",
        1046 => "not allowed now",
        3001 => "another client is connected to the control port",
        3002 => "firmware upgrade in progress",
        3003 => "command too long",
        3005 => "motion error (collision or overload; resettable)",
        3006 => "drive communication error (not resettable)",
        3009 => "initialisation failed",
        3016 => "command ignored",
        3025 => "gripper error",
        3026 | 3027 => "maintenance or internal error",
        3029 => "torque limit exceeded",
        3031 => "text API error",
        3032 => "protective stop (PStop2)",
        3041 => "collision",
        3049 => "work-zone error",
        3069 => "protective stop (PStop1)",
        3070 => "emergency stop",
        3080..=3087 => "safety stop (3086: the connection watchdog)",
        _ => "see the Meca500 programming manual",
    };
    format!("[{code}] {name}")
}

/// Whether a message means the arm stopped or will not move (an error code, a stop event).
fn stops_the_arm(code: u32) -> bool {
    matches!(code, 1000..=1999 | 3001..=3003 | 3005 | 3006 | 3009 | 3025..=3027 | 3029 | 3031 | 3032 | 3041 | 3049 | 3069 | 3070 | 3080..=3087)
}

/// The client's side of the stream.
pub struct Meca {
    /// The cycle (s).
    period: f64,
    /// `SetVelTimeout` (s): how long the arm keeps its last velocity.
    velocity_timeout: f64,
    /// Velocity = feed-forward + gain × position error (1/s).
    gain: f64,
    /// Speed limits (rad/s).
    speed: [f64; JOINTS],
    /// Ticks: the packet sequence.
    ticks: u64,
    /// The newest joints the robot reported (rad) and their robot time (µs).
    joints: Option<[f64; JOINTS]>,
    /// The last target sent (rad): the feed-forward's start.
    last_target: Option<[f64; JOINTS]>,
    /// Joints of a monitoring interval not yet closed by its `[2230]`.
    open_joints: Option<[f64; JOINTS]>,
    /// Whether the open interval's joints came from the encoders (`[2210]`, preferred over 2026).
    open_from_encoders: bool,
}

impl Meca {
    /// A client on a cycle of `period` (s), with `gain` (1/s).
    pub fn new(period: f64, gain: f64) -> Meca {
        Meca {
            period,
            velocity_timeout: 0.0,
            gain,
            speed: [f64::INFINITY; JOINTS],
            ticks: 0,
            joints: None,
            last_target: None,
            open_joints: None,
            open_from_encoders: false,
        }
    }

    /// The gain on the position error (1/s; `[driver] velocity_gain`).
    pub(crate) fn set_gain(&mut self, gain: f64) {
        self.gain = gain;
    }

    /// The velocity timeout the link set (s; `[driver] velocity_timeout`): how long the arm runs on
    /// at its last velocity when commands stop.
    pub fn set_velocity_timeout(&mut self, seconds: f64) {
        self.velocity_timeout = seconds.max(0.0);
    }

    /// The speed limits the velocities keep (rad/s, the URDF's).
    pub fn set_speed_limits(&mut self, speed: &[f64]) {
        for (s, v) in self.speed.iter_mut().zip(speed) {
            *s = *v;
        }
    }

    /// Takes one message; an error that stopped the arm comes back as its description.
    fn take(&mut self, from: u8, m: Message<'_>) -> Result<(), String> {
        if stops_the_arm(m.code) {
            let side = if from == FROM_CONTROL { "control port" } else { "monitoring port" };
            return Err(format!("the robot sent {} on its {side}: {}", describe(m.code), m.payload));
        }
        let mut v = [0.0; 8];
        match m.code {
            // Status: activated, homed, simulation, error, paused, eob, eom.
            2007 => {
                let n = parse_numbers(m.payload, &mut v).ok_or_else(|| format!("[2007] status unreadable: {}", m.payload))?;
                if n >= 5 && v[3] != 0.0 {
                    return Err(format!(
                        "the robot reports an error ([2007] {}): see its event log; strand-meca clears it at the next start",
                        m.payload
                    ));
                }
                if n >= 5 && (v[0] == 0.0 || v[1] == 0.0) {
                    return Err(format!("the robot is no longer activated and homed ([2007] {})", m.payload));
                }
                if n >= 5 && v[4] != 0.0 {
                    return Err(format!("the robot's motion was paused or cleared behind the driver's back ([2007] {})", m.payload));
                }
            }
            // Joints: encoders (t, q…) preferred, else the legacy joints (q…).
            2210 | 2026 => {
                let n = parse_numbers(m.payload, &mut v);
                let (q, encoders) = match (m.code, n) {
                    (2210, Some(7)) => (&v[1..7], true),
                    (2026, Some(6)) => (&v[..6], false),
                    _ => return Ok(()),
                };
                if encoders || !self.open_from_encoders {
                    let mut j = [0.0; JOINTS];
                    for (a, b) in j.iter_mut().zip(q) {
                        *a = b.to_radians();
                    }
                    if j.iter().all(|x| x.is_finite()) {
                        self.open_joints = Some(j);
                        self.open_from_encoders = encoders;
                    }
                }
            }
            // The end of a monitoring interval: its joints are the newest.
            2230 => {
                if let Some(j) = self.open_joints.take() {
                    self.joints = Some(j);
                }
                self.open_from_encoders = false;
            }
            _ => {}
        }
        Ok(())
    }
}

impl RobotProtocol for Meca {
    const NAME: &'static str = "meca";
    const CLOCK: Clock = Clock::Driver;
    const CHANNEL: Channel = Channel::Stream;

    /// One message on either port, up to its NUL (a newline ends one too); a tick's packet is the
    /// messages of both ports since the last tick ([`link`] collects them).
    fn frame(buffered: &[u8]) -> Frame {
        match buffered.iter().position(|b| *b == 0 || *b == b'\n') {
            Some(end) => Frame::Packet(end + 1),
            None => Frame::Incomplete,
        }
    }
    const MAX_PACKET: usize = 256 * 1024;

    fn set_linear_axes(&mut self, linear: &[bool]) -> Result<(), String> {
        if linear.len() != JOINTS {
            return Err(format!("{} joints; the Meca500 has {JOINTS}", linear.len()));
        }
        match linear.iter().position(|l| *l) {
            Some(k) => Err(format!("joint {} is prismatic; the Meca500's are all rotary", k + 1)),
            None => Ok(()),
        }
    }

    fn set_period(&mut self, period: f64) {
        self.period = period;
    }

    /// One tick's messages (each: its socket's tag byte, the text, a NUL): the newest joints of a
    /// closed monitoring interval are the state; before the first one, nothing is.
    fn read(&mut self, packet: &[u8]) -> Result<RobotPacket, PacketError> {
        for frame in packet.split(|b| *b == 0) {
            let Some((&from, text)) = frame.split_first() else { continue };
            let Ok(text) = std::str::from_utf8(text) else {
                return Err(PacketError::Malformed("a message that is not text".into()));
            };
            if let Some(m) = parse_message(text) {
                self.take(from, m).map_err(PacketError::RobotError)?;
            }
        }
        let Some(j) = self.joints else {
            return Err(PacketError::Truncated("no joints from the monitoring port yet".into()));
        };
        self.ticks += 1;
        let mut axes = [0.0; MAX_JOINTS];
        axes[..JOINTS].copy_from_slice(&j);
        Ok(RobotPacket { seq: self.ticks, axes, dof: JOINTS, following: true })
    }

    /// The arm keeps its last velocity until `SetVelTimeout`.
    fn runs_on_for(&self) -> f64 {
        self.velocity_timeout
    }

    fn reset(&mut self) {
        self.joints = None;
        self.last_target = None;
        self.open_joints = None;
    }

    /// `MoveJointsVel` in deg/s, fixed-point: the target's step over the cycle plus the gain on
    /// the error between the target and the newest measured joints, within the speed limits.
    fn write(&mut self, axes: &[f64], out: &mut Vec<u8>) {
        out.clear();
        let mut target = [0.0; JOINTS];
        target.copy_from_slice(&axes[..JOINTS]);
        let measured = self.joints.unwrap_or(target);
        let _ = write!(out, "MoveJointsVel(");
        for k in 0..JOINTS {
            let ff = self.last_target.map_or(0.0, |p| (target[k] - p[k]) / self.period);
            let v = (ff + self.gain * (target[k] - measured[k])).clamp(-self.speed[k], self.speed[k]);
            let v = if v.is_finite() { v } else { 0.0 };
            let _ = write!(out, "{}{:.4}", if k > 0 { "," } else { "" }, v.to_degrees());
        }
        out.extend_from_slice(b")\0");
        self.last_target = Some(target);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn packet(messages: &[(u8, &str)]) -> Vec<u8> {
        let mut p = Vec::new();
        for (from, text) in messages {
            p.push(*from);
            p.extend_from_slice(text.as_bytes());
            p.push(0);
        }
        p
    }

    #[test]
    fn messages_parse_and_errors_are_named() {
        assert_eq!(parse_message("[2007][1,1,0,0,0,1,1]"), Some(Message { code: 2007, payload: "1,1,0,0,0,1,1" }));
        assert_eq!(
            parse_message("[3000][Connected to Meca500 R3 v9.3.0]"),
            Some(Message { code: 3000, payload: "Connected to Meca500 R3 v9.3.0" })
        );
        assert_eq!(parse_message("[3012]"), Some(Message { code: 3012, payload: "" }));
        assert_eq!(parse_message("hello"), None);
        let mut v = [0.0; 7];
        assert_eq!(parse_numbers("12, 1.5,-3e0", &mut v), Some(3));
        assert_eq!(parse_numbers("1,x", &mut v), None);
        assert!(describe(1011).contains("in error") && describe(3005).contains("motion error"));
    }

    #[test]
    fn the_newest_closed_interval_is_the_state_and_a_stop_ends_the_stream() {
        let mut m = Meca::new(0.004, 20.0);
        // No interval closed yet: no state.
        assert!(matches!(m.read(&packet(&[(FROM_MONITOR, "[2026][1,2,3,4,5,6]")])), Err(PacketError::Truncated(_))));
        // Closed: the encoders' joints win over the legacy ones.
        let p = m
            .read(&packet(&[
                (FROM_MONITOR, "[2026][1,2,3,4,5,6]"),
                (FROM_MONITOR, "[2210][1000,10,20,30,40,50,60]"),
                (FROM_MONITOR, "[2230][1000]"),
                (FROM_CONTROL, "[3012][]"),
            ]))
            .unwrap();
        assert_eq!((p.seq, p.dof), (1, 6));
        assert!((p.axes[5] - 60f64.to_radians()).abs() < 1e-12);
        // A tick without a new interval: the newest joints again, the next sequence.
        let p = m.read(&[]).unwrap();
        assert_eq!(p.seq, 2);
        assert!((p.axes[0] - 10f64.to_radians()).abs() < 1e-12);
        for (from, text, says) in [
            (FROM_CONTROL, "[1011][The robot is in error.]", "in error"),
            (FROM_CONTROL, "[3005][Motion error.]", "motion error"),
            (FROM_MONITOR, "[2007][1,1,0,1,1,1,1]", "reports an error"),
            (FROM_MONITOR, "[2007][1,1,0,0,1,1,1]", "paused"),
        ] {
            match m.read(&packet(&[(from, text)])) {
                Err(PacketError::RobotError(why)) => assert!(why.contains(says), "{why}"),
                other => panic!("{text}: {other:?}"),
            }
        }
    }

    #[test]
    fn the_velocity_is_the_steps_feed_forward_plus_the_gain_on_the_error_within_the_limits() {
        let mut m = Meca::new(0.004, 20.0);
        m.set_speed_limits(&[1.0; 6]);
        m.joints = Some([0.0; JOINTS]);
        let mut out = Vec::new();
        m.write(&[0.01, 0.0, 0.0, 0.0, 0.0, 0.0], &mut out);
        // No step yet: 20 × 0.01 rad/s = 11.4592 deg/s on J1.
        assert_eq!(std::str::from_utf8(&out).unwrap(), "MoveJointsVel(11.4592,0.0000,0.0000,0.0000,0.0000,0.0000)\0");
        m.joints = Some([0.01, 0.0, 0.0, 0.0, 0.0, 0.0]);
        m.write(&[0.012, 0.5, 0.0, 0.0, 0.0, 0.0], &mut out);
        let text = std::str::from_utf8(&out).unwrap();
        // J1: 0.002 / 0.004 + 20 × 0.002 = 0.54 rad/s; J2 clamped to 1 rad/s.
        assert!(text.starts_with(&format!("MoveJointsVel({:.4},{:.4},", 0.54f64.to_degrees(), 1f64.to_degrees())), "{text}");
    }
}
