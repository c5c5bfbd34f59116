//! Universal Robots e-Series (and CB3) as strand drives them (`docs/protocols/ur.md`): RTDE (TCP
//! 30004) streams the robot's joints, modes and speed scaling every controller cycle (500 Hz;
//! 125 Hz on a CB3), and a URScript program strand sends to the robot's script port (30002)
//! connects back to the driver (the reverse interface, 50001) and servos the arm to each 8 × int32
//! message it reads — the read timeout, the joints × 1,000,000, the control mode — with `servoj`
//! (`[driver] lookahead_time`, `servo_gain`). The robot clocks the cycle: each RTDE data package is
//! the JointState that clocks the service, and the answer is the guarded command for it.
//!
//! Every message carries a read timeout (`[driver] read_timeout`, [`READ_TIMEOUT_MS`] by default): a driver that stops, hangs or loses
//! the link leaves the program without a message, and it stops the arm (`stopj`) by itself. On
//! stop the driver sends the STOPPED mode and the program ends cleanly. A protective or emergency
//! stop (any safety mode but NORMAL and REDUCED), the program stopping, or the robot leaving
//! RUNNING ends the stream as a fault naming the mode. The robot's speed scaling (its speed slider
//! × its trajectory limiter's scaling) is told to the service as a feed override, so that the
//! service slows the path instead of the robot falling behind its commands.
//!
//! - [`rtde`] — RTDE's packages and recipes.
//! - [`Ur`] — the [`RobotProtocol`]: a data package in, a reverse-interface message out.
//! - [`script()`] — strand's URScript program.
//! - [`link`] — the connections.

pub mod link;
pub mod rtde;

use crate::protocol::{Channel, Clock, Frame, PacketError, RobotPacket, RobotProtocol};
use strand_ipc::MAX_JOINTS;

/// A UR's joints.
pub(crate) const JOINTS: usize = 6;
/// The joints' fixed-point factor on the reverse interface (µrad).
pub(crate) const MULT_JOINTSTATE: f64 = 1_000_000.0;
/// The robot's read timeout announced in each message by default (ms; `[driver] read_timeout`):
/// 10 cycles at 500 Hz. Longer silences stop the program and the arm.
pub(crate) const READ_TIMEOUT_MS: i32 = 20;
/// Control modes of the reverse interface.
pub mod mode {
    /// Servo to the joint positions (`servoj`).
    pub(crate) const SERVOJ: i32 = 1;
    /// End the program.
    pub const STOPPED: i32 = -2;
}

/// One reverse-interface message: 8 × int32, big-endian (32 bytes).
pub fn message(out: &mut Vec<u8>, timeout_ms: i32, q: &[f64], mode: i32) {
    out.clear();
    out.extend_from_slice(&timeout_ms.to_be_bytes());
    for k in 0..JOINTS {
        let v = q.get(k).copied().unwrap_or(0.0) * MULT_JOINTSTATE;
        let v = if v.is_finite() { v.round().clamp(i32::MIN as f64, i32::MAX as f64) as i32 } else { 0 };
        out.extend_from_slice(&v.to_be_bytes());
    }
    out.extend_from_slice(&mode.to_be_bytes());
}

/// The client's side.
pub struct Ur {
    /// The output recipe's id (the link's setup sets it).
    recipe: u8,
    /// Data packages taken: the packet sequence.
    packages: u64,
    /// The controller's own clock of the last package (s): a package not after it is old.
    last_timestamp: Option<f64>,
    /// Whether the program was seen playing.
    playing: bool,
    /// The last (robot mode, safety mode, runtime state), for the news.
    modes: Option<(i32, i32, u32)>,
    news: Option<String>,
    /// The speed scaling told to the service last, and one not yet told.
    scaling_told: f64,
    scaling_new: Option<f64>,
    /// The read timeout each message announces (ms).
    read_timeout_ms: i32,
}

impl Default for Ur {
    fn default() -> Self {
        Ur::new()
    }
}

impl Ur {
    /// A client whose output recipe is not set up yet.
    pub fn new() -> Ur {
        Ur {
            recipe: 1,
            packages: 0,
            last_timestamp: None,
            playing: false,
            modes: None,
            news: None,
            scaling_told: 1.0,
            scaling_new: None,
            read_timeout_ms: READ_TIMEOUT_MS,
        }
    }

    /// The output recipe's id.
    pub(crate) fn set_recipe(&mut self, id: u8) {
        self.recipe = id;
    }

    /// The read timeout each message announces (s; rounded to whole ms, at least 1).
    pub fn set_read_timeout(&mut self, seconds: f64) {
        self.read_timeout_ms = ((seconds * 1e3).round() as i32).max(1);
    }
}

impl RobotProtocol for Ur {
    const NAME: &'static str = "ur";
    const CLOCK: Clock = Clock::Robot;
    /// RTDE's TCP stream; the state is its data package.
    const CHANNEL: Channel = Channel::Stream;

    fn frame(buffered: &[u8]) -> Frame {
        rtde::frame(buffered)
    }
    const MAX_PACKET: usize = 4096;

    fn set_linear_axes(&mut self, linear: &[bool]) -> Result<(), String> {
        if linear.len() != JOINTS {
            return Err(format!("{} joints; a UR arm has {JOINTS}", linear.len()));
        }
        match linear.iter().position(|l| *l) {
            Some(k) => Err(format!("joint {} is prismatic; a UR's are all rotary", k + 1)),
            None => Ok(()),
        }
    }

    /// An RTDE data package: the joints, and whether the robot runs strand's program now.
    fn read(&mut self, packet: &[u8]) -> Result<RobotPacket, PacketError> {
        let d = rtde::read_data(packet, self.recipe).map_err(|e| PacketError::Malformed(e.0))?;
        let finite = d.actual_q.iter().all(|q| q.is_finite()) && d.timestamp.is_finite();
        if !finite {
            return Err(PacketError::BadValue(format!("actual_q {:?} at {}", d.actual_q, d.timestamp)));
        }
        if self.last_timestamp.is_some_and(|t| d.timestamp <= t) {
            return Err(PacketError::Malformed(format!(
                "controller time {} s after {:?} s: an old package",
                d.timestamp, self.last_timestamp
            )));
        }
        self.last_timestamp = Some(d.timestamp);
        let modes = (d.robot_mode, d.safety_mode, d.runtime_state);
        if self.modes != Some(modes) {
            self.news = Some(format!(
                "{}, {}, program {}",
                rtde::robot_mode_name(d.robot_mode),
                rtde::safety_mode_name(d.safety_mode),
                rtde::runtime_state_name(d.runtime_state)
            ));
            self.modes = Some(modes);
        }
        if !(1..=2).contains(&d.safety_mode) {
            return Err(PacketError::RobotError(format!(
                "the robot stopped: safety mode {} (clear it on the teach pendant and start strand-ur again)",
                rtde::safety_mode_name(d.safety_mode)
            )));
        }
        let playing = d.robot_mode == 7 && d.runtime_state == 2;
        if self.playing && !playing {
            return Err(PacketError::RobotError(format!(
                "strand's program stopped on the robot ({}, program {}): a read timeout, the pendant or another program",
                rtde::robot_mode_name(d.robot_mode),
                rtde::runtime_state_name(d.runtime_state)
            )));
        }
        self.playing |= playing;
        let scaling = (d.speed_scaling * d.target_speed_fraction).clamp(0.0, 1.0);
        if scaling.is_finite() && (scaling - self.scaling_told).abs() > 0.005 {
            self.scaling_told = scaling;
            self.scaling_new = Some(scaling);
        }
        self.packages += 1;
        let mut axes = [0.0; MAX_JOINTS];
        axes[..JOINTS].copy_from_slice(&d.actual_q);
        Ok(RobotPacket { seq: self.packages, axes, dof: JOINTS, following: playing })
    }

    fn reset(&mut self) {
        self.last_timestamp = None;
        self.playing = false;
    }

    fn take_news(&mut self) -> Option<String> {
        self.news.take()
    }

    fn take_speed_scaling(&mut self) -> Option<f64> {
        self.scaling_new.take()
    }

    /// The servo target: `axes` (rad), with the read timeout for the robot's next read.
    fn write(&mut self, axes: &[f64], out: &mut Vec<u8>) {
        message(out, self.read_timeout_ms, axes, mode::SERVOJ);
    }
}

/// strand's URScript program (our own, `docs/protocols/ur.md` §2.6): it connects back to the
/// driver at `host:port`, servos with `servoj` to the newest joints it read, and stops the arm
/// (`stopj`) when a read times out or the driver sends STOPPED.
pub fn script(host: &str, port: u16, lookahead_time: f64, gain: f64) -> String {
    format!(
        r#"def strand_servo():
  textmsg("strand: connecting to the driver at {host}:{port}")
  if not socket_open("{host}", {port}, "strand_reverse"):
    textmsg("strand: the driver at {host}:{port} does not answer")
    halt
  end
  global cmd_q = get_actual_joint_positions()
  global running = True
  thread servo_thread():
    while running:
      servoj(cmd_q, t=get_steptime(), lookahead_time={lookahead_time}, gain={gain})
    end
    stopj(4.0)
  end
  servo = run servo_thread()
  timeout = 0.0
  while running:
    msg = socket_read_binary_integer(8, "strand_reverse", timeout)
    if msg[0] == 0:
      textmsg("strand: no command within the read timeout: stopping the arm")
      running = False
    elif msg[8] == {stopped}:
      running = False
    else:
      timeout = msg[1] / 1000.0
      if msg[8] == {servoj}:
        q = [msg[2] / {mult}, msg[3] / {mult}, msg[4] / {mult}, msg[5] / {mult}, msg[6] / {mult}, msg[7] / {mult}]
        enter_critical
        cmd_q = q
        exit_critical
      end
    end
  end
  join servo
  socket_close("strand_reverse")
  textmsg("strand: program ended")
end
"#,
        stopped = mode::STOPPED,
        servoj = mode::SERVOJ,
        mult = "1000000.0",
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn data(timestamp: f64, q: f64, modes: (i32, i32, u32), scaling: f64) -> Vec<u8> {
        let mut p = vec![1u8];
        p.extend_from_slice(&timestamp.to_be_bytes());
        for k in 0..12 {
            p.extend_from_slice(&(if k < 6 { q } else { 0.0 }).to_be_bytes());
        }
        p.extend_from_slice(&modes.0.to_be_bytes());
        p.extend_from_slice(&modes.1.to_be_bytes());
        p.extend_from_slice(&modes.2.to_be_bytes());
        p.extend_from_slice(&scaling.to_be_bytes());
        p.extend_from_slice(&1.0f64.to_be_bytes());
        let mut out = Vec::new();
        rtde::encode(&mut out, rtde::kind::DATA, &p);
        out
    }

    #[test]
    fn the_reverse_message_is_the_notes_example() {
        let mut out = Vec::new();
        message(&mut out, 20, &[0.0, -1.57, 0.0, -1.57, 0.0, 0.0], mode::SERVOJ);
        let words: Vec<String> = out.chunks(4).map(|c| format!("{:08x}", u32::from_be_bytes(c.try_into().unwrap()))).collect();
        assert_eq!(words.join(" "), "00000014 00000000 ffe80b30 00000000 ffe80b30 00000000 00000000 00000001");
    }

    #[test]
    fn modes_decide_following_and_a_stop_ends_the_stream_named() {
        let mut ur = Ur::new();
        // Before the program plays: not following.
        let p = ur.read(&data(1.0, 0.1, (7, 1, 1), 1.0)).unwrap();
        assert!(!p.following && ur.take_news().unwrap().contains("STOPPED"));
        let p = ur.read(&data(1.002, 0.1, (7, 1, 2), 1.0)).unwrap();
        assert!(p.following && p.seq == 2 && (p.axes[3] - 0.1).abs() < 1e-15);
        // An old package is dropped; the speed slider at 40 % is told once.
        assert!(matches!(ur.read(&data(1.001, 0.1, (7, 1, 2), 1.0)), Err(PacketError::Malformed(_))));
        ur.read(&data(1.004, 0.1, (7, 1, 2), 0.4)).unwrap();
        assert_eq!(ur.take_speed_scaling(), Some(0.4));
        assert_eq!(ur.take_speed_scaling(), None);
        match ur.read(&data(1.006, 0.1, (7, 3, 2), 0.4)) {
            Err(PacketError::RobotError(why)) => assert!(why.contains("PROTECTIVE_STOP (3)"), "{why}"),
            other => panic!("{other:?}"),
        }
        let mut ur = Ur::new();
        ur.read(&data(1.0, 0.1, (7, 1, 2), 1.0)).unwrap();
        assert!(matches!(ur.read(&data(1.002, 0.1, (7, 1, 1), 1.0)), Err(PacketError::RobotError(_))));
    }

    #[test]
    fn the_script_names_the_driver_and_the_servo_settings() {
        let s = script("192.168.1.10", 50001, 0.03, 2000.0);
        assert!(s.starts_with("def strand_servo():") && s.trim_end().ends_with("end"));
        assert!(s.contains(r#"socket_open("192.168.1.10", 50001, "strand_reverse")"#));
        assert!(s.contains("lookahead_time=0.03, gain=2000"));
        assert!(s.contains("msg[8] == -2") && s.contains("msg[8] == 1"));
    }
}
