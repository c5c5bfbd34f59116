//! ABB EGM (Externally Guided Motion, RobotWare option 689-1) as a [`RobotProtocol`]: protobuf over
//! UDP, with the schema `egm.proto` of ros-industrial/abb_libegm (vendored in `tools/egm/proto/`,
//! BSD-3-Clause; [`proto`] is prost's code for it). Every cycle (4 ms at `\SampleRate:=4`) the robot
//! sends an `EgmRobot` — header (`seqno`, `tm` in ms, `mtype` DATA), the measured joints in
//! `feedBack` (degrees), motor, motion-control (MCI) and RAPID states — and the sensor answers with an
//! `EgmSensor`: its own header (`seqno` counting its replies, `mtype` CORRECTION) and the absolute
//! joint targets in `planned.joints` (degrees; a 7th axis in `planned.externalJoints`).
//!
//! The rules follow abb_libegm: a packet counts only if it is DATA with the feedback joints and the
//! states; the robot follows corrections only with motors on, `MCI_RUNNING` and RAPID running (or
//! undefined, a RobotWare quirk after restart). Before that the answer repeats the measured joints,
//! so the robot starts from where it is. A new EGM session (RAPID runs `EGMRunJoint` again) restarts
//! `seqno` at 0: that is a new epoch of the driver's sequence, not an out-of-order packet.
//! External axes (`externalJoints`) are degrees when rotary and millimetres when linear (a track):
//! the URDF joint's type says which (`set_linear_axes`). The six robot axes are rotary; a URDF whose
//! first six joints include a prismatic one is refused.

pub mod proto;

use prost::Message;
use strand_ipc::MAX_JOINTS;

use crate::protocol::{Channel, Clock, PacketError, RobotPacket, RobotProtocol};
use proto::egm_header::MessageType;
use proto::egm_mci_state::MciStateType;
use proto::egm_motor_state::MotorStateType;
use proto::egm_rapid_ctrl_exec_state::RapidCtrlExecStateType;
use proto::{EgmHeader, EgmJoints, EgmPlanned, EgmRobot, EgmSensor};

/// Robot axes EGM streams in `joints` (the rest, up to 6 more, in `externalJoints`).
pub(crate) const ROBOT_AXES: usize = 6;

/// A `seqno` this far below the last one starts a new EGM session (RAPID restarted EGM), not a
/// late packet.
const NEW_SESSION_GAP: u32 = 1000;

/// The EGM side of one connection.
#[derive(Clone, Debug, Default)]
pub struct Egm {
    /// The robot's last `seqno`, and the epoch (new EGM sessions) above it.
    last_seqno: Option<u32>,
    epoch: u64,
    /// Replies sent (the sensor's own `seqno`).
    replies: u32,
    /// The robot's `tm` of the first packet (ms), for the replies' `tm`.
    first_tm: Option<u32>,
    /// The robot's `tm` of the last packet (ms).
    last_tm: u32,
    /// Axes that are linear (mm on the wire, m here); kept across sessions.
    linear: [bool; MAX_JOINTS],
}

impl Egm {
    /// A connection that has not seen its first packet.
    pub fn new() -> Egm {
        Egm::default()
    }
}

/// An axis value on the wire (degrees, or mm when linear) in the driver's units (rad, or m).
fn from_wire(v: f64, linear: bool) -> f64 {
    if linear { v * 1e-3 } else { v.to_radians() }
}

/// An axis value in the driver's units (rad, or m) on the wire (degrees, or mm when linear).
fn to_wire(v: f64, linear: bool) -> f64 {
    if linear { v * 1e3 } else { v.to_degrees() }
}

impl RobotProtocol for Egm {
    const NAME: &'static str = "egm";
    const CLOCK: Clock = Clock::Robot;
    const CHANNEL: Channel = Channel::Datagram;
    /// An `EgmRobot` with every field is under 400 bytes; abb_libegm reads into 1024.
    const MAX_PACKET: usize = 1024;

    /// `seqno` counts packets; a new epoch (RAPID restarted EGM) is a new session, not lost cycles.
    fn cycles_between(earlier: u64, later: u64, _period: f64) -> u64 {
        if earlier >> 32 != later >> 32 { 1 } else { later.saturating_sub(earlier) }
    }

    fn set_linear_axes(&mut self, linear: &[bool]) -> Result<(), String> {
        if let Some(k) = linear.iter().take(ROBOT_AXES).position(|l| *l) {
            return Err(format!(
                "joint {} is prismatic, but EGM's six robot axes are rotary (degrees); a linear axis (a track) must come after them, as an external axis",
                k + 1
            ));
        }
        if linear.len() > MAX_JOINTS {
            return Err(format!("{} axes; at most {MAX_JOINTS}", linear.len()));
        }
        self.linear = [false; MAX_JOINTS];
        self.linear[..linear.len()].copy_from_slice(linear);
        Ok(())
    }

    fn read(&mut self, packet: &[u8]) -> Result<RobotPacket, PacketError> {
        if packet.len() > Self::MAX_PACKET {
            return Err(PacketError::Oversized(packet.len()));
        }
        let robot = EgmRobot::decode(packet).map_err(|e| PacketError::Malformed(format!("EgmRobot: {e}")))?;
        let header = robot.header.as_ref().ok_or_else(|| PacketError::Truncated("no header".into()))?;
        if header.mtype() != MessageType::MsgtypeData {
            return Err(PacketError::Malformed(format!("mtype {:?}, not MSGTYPE_DATA", header.mtype())));
        }
        let seqno = header.seqno.ok_or_else(|| PacketError::Truncated("no header.seqno".into()))?;
        let feedback =
            robot.feed_back.as_ref().and_then(|f| f.joints.as_ref()).ok_or_else(|| PacketError::Truncated("no feedBack.joints".into()))?;
        if feedback.joints.len() != ROBOT_AXES {
            return Err(PacketError::Truncated(format!("feedBack.joints has {} values, not {ROBOT_AXES}", feedback.joints.len())));
        }
        let external = robot.feed_back.as_ref().and_then(|f| f.external_joints.as_ref()).map_or(&[][..], |e| &e.joints[..]);
        if ROBOT_AXES + external.len() > MAX_JOINTS {
            return Err(PacketError::BadValue(format!("{} external axes", external.len())));
        }
        let mut axes = [0.0; MAX_JOINTS];
        for (k, v) in feedback.joints.iter().chain(external).enumerate() {
            if !v.is_finite() {
                return Err(PacketError::BadValue(format!("joint {}: {v}", k + 1)));
            }
            axes[k] = from_wire(*v, self.linear[k]);
        }
        let (motors, mci, rapid) = (
            robot.motor_state.as_ref().ok_or_else(|| PacketError::Truncated("no motorState".into()))?.state(),
            robot.mci_state.as_ref().ok_or_else(|| PacketError::Truncated("no mciState".into()))?.state(),
            robot.rapid_exec_state.as_ref().map_or(RapidCtrlExecStateType::RapidUndefined, |r| r.state()),
        );
        let following = motors == MotorStateType::MotorsOn
            && mci == MciStateType::MciRunning
            && matches!(rapid, RapidCtrlExecStateType::RapidRunning | RapidCtrlExecStateType::RapidUndefined);
        if let Some(last) = self.last_seqno
            && seqno < last
            && (seqno == 0 || last - seqno > NEW_SESSION_GAP)
        {
            self.epoch += 1 << 32;
        }
        self.last_seqno = Some(seqno);
        let tm = header.tm.unwrap_or(0);
        self.first_tm.get_or_insert(tm);
        self.last_tm = tm;
        Ok(RobotPacket { seq: self.epoch + u64::from(seqno), axes, dof: ROBOT_AXES + external.len(), following })
    }

    fn reset(&mut self) {
        *self = Egm { linear: self.linear, ..Egm::default() };
    }

    fn write(&mut self, axes: &[f64], out: &mut Vec<u8>) {
        out.clear();
        let n = axes.len();
        let wire = |from: usize, to: usize| (from..to).map(|k| to_wire(axes[k], self.linear[k])).collect::<Vec<f64>>();
        let robot = wire(0, n.min(ROBOT_AXES));
        let external = if n > ROBOT_AXES { Some(EgmJoints { joints: wire(ROBOT_AXES, n) }) } else { None };
        let sensor = EgmSensor {
            header: Some(EgmHeader {
                seqno: Some(self.replies),
                tm: Some(self.last_tm.wrapping_sub(self.first_tm.unwrap_or(self.last_tm))),
                mtype: Some(MessageType::MsgtypeCorrection as i32),
            }),
            planned: Some(EgmPlanned { joints: Some(EgmJoints { joints: robot }), external_joints: external, ..Default::default() }),
            speed_ref: None,
        };
        self.replies = self.replies.wrapping_add(1);
        // Encoding into a Vec cannot fail (it grows).
        let _ = sensor.encode(out);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::fake::egm::robot_message;

    fn packet(seqno: u32, following: bool) -> Vec<u8> {
        robot_message(seqno, seqno * 4, &[0.0, -30.0, 30.0, 0.0, 60.0, 0.0], following).encode_to_vec()
    }

    #[test]
    fn a_robot_message_decodes_and_the_reply_carries_absolute_degrees() {
        let mut egm = Egm::new();
        let p = egm.read(&packet(7, true)).unwrap();
        assert_eq!((p.seq, p.dof, p.following), (7, 6, true));
        assert!((p.axes[1] + 30f64.to_radians()).abs() < 1e-15);
        let mut target = p.axes;
        target[0] = 10f64.to_radians();
        let mut out = Vec::new();
        egm.write(&target[..6], &mut out);
        let sensor = EgmSensor::decode(&out[..]).unwrap();
        let h = sensor.header.unwrap();
        assert_eq!((h.seqno, h.mtype()), (Some(0), MessageType::MsgtypeCorrection));
        let j = sensor.planned.unwrap().joints.unwrap().joints;
        assert!((j[0] - 10.0).abs() < 1e-12 && (j[1] + 30.0).abs() < 1e-12, "{j:?}");
    }

    /// A track as the 7th axis: millimetres on the wire, metres in the driver; a rotary external
    /// axis stays in degrees; a prismatic joint among the six robot axes is refused.
    #[test]
    fn a_linear_external_axis_is_millimetres_on_the_wire() {
        let mut egm = Egm::new();
        let e = egm.set_linear_axes(&[false, true, false, false, false, false, false]).unwrap_err();
        assert!(e.contains("joint 2 is prismatic"), "{e}");
        let m = robot_message(1, 4, &[0.0, -30.0, 30.0, 0.0, 60.0, 0.0, 1250.0], true);
        let rotary = egm.read(&m.encode_to_vec()).unwrap();
        assert!((rotary.axes[6] - 1250f64.to_radians()).abs() < 1e-12);
        egm.set_linear_axes(&[false, false, false, false, false, false, true]).unwrap();
        let p = egm.read(&m.encode_to_vec()).unwrap();
        assert_eq!(p.dof, 7);
        assert!((p.axes[6] - 1.25).abs() < 1e-15 && (p.axes[1] + 30f64.to_radians()).abs() < 1e-15);
        let mut target = p.axes;
        target[6] = 0.5;
        let mut out = Vec::new();
        egm.write(&target[..7], &mut out);
        let planned = EgmSensor::decode(&out[..]).unwrap().planned.unwrap();
        assert_eq!(planned.external_joints.unwrap().joints, vec![500.0]);
        assert!((planned.joints.unwrap().joints[1] + 30.0).abs() < 1e-12);
        // A new EGM session keeps the axes' kinds.
        egm.reset();
        assert!((egm.read(&m.encode_to_vec()).unwrap().axes[6] - 1.25).abs() < 1e-15);
    }

    #[test]
    fn not_following_before_mci_running_and_a_new_session_is_a_new_epoch() {
        let mut egm = Egm::new();
        assert!(!egm.read(&packet(5000, false)).unwrap().following);
        let restarted = egm.read(&packet(0, true)).unwrap();
        assert!(restarted.seq > 5000, "a restarted EGM session continues the sequence: {}", restarted.seq);
        // A packet a few behind is out of order (the session drops it), not a new session.
        let late = egm.read(&packet(0, true)).unwrap();
        assert_eq!(late.seq, restarted.seq);
    }

    #[test]
    fn bad_packets_are_named() {
        let mut egm = Egm::new();
        let good = packet(1, true);
        assert!(matches!(egm.read(&good[..good.len() / 2]), Err(PacketError::Malformed(_) | PacketError::Truncated(_))));
        assert!(matches!(egm.read(b"\xff\xff\xff\xff"), Err(PacketError::Malformed(_))));
        let mut m = robot_message(1, 4, &[0.0; 6], true);
        m.header.as_mut().unwrap().mtype = Some(MessageType::MsgtypeCorrection as i32);
        assert!(matches!(egm.read(&m.encode_to_vec()), Err(PacketError::Malformed(_))));
        let m = robot_message(1, 4, &[0.0; 5], true);
        assert!(matches!(egm.read(&m.encode_to_vec()), Err(PacketError::Truncated(_))));
        let m = robot_message(1, 4, &[0.0, f64::NAN, 0.0, 0.0, 0.0, 0.0], true);
        assert!(matches!(egm.read(&m.encode_to_vec()), Err(PacketError::BadValue(_))));
        let mut m = robot_message(1, 4, &[0.0; 6], true);
        m.mci_state = None;
        assert!(matches!(egm.read(&m.encode_to_vec()), Err(PacketError::Truncated(_))));
        assert!(matches!(egm.read(&vec![0u8; 2000]), Err(PacketError::Oversized(2000))));
    }
}
