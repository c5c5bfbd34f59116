//! ABB EGM (Externally Guided Motion, RobotWare option 689-1) as a [`RobotProtocol`]: protobuf over
//! UDP, with the schema `egm.proto` of ros-industrial/abb_libegm (vendored in `tools/egm/proto/`,
//! BSD-3-Clause; [`proto`] is prost's code for it). Every cycle (4 ms at `\SampleRate:=4`) the robot
//! sends an `EgmRobot` — header (`seqno`, `tm` in ms, `mtype` DATA), the measured joints in
//! `feedBack` (degrees), motor, motion-control (MCI) and RAPID states — and the sensor answers with an
//! `EgmSensor`: its own header (`seqno` counting its replies, `mtype` CORRECTION) and the absolute
//! joint targets in `planned.joints` (degrees).
//!
//! The rules follow abb_libegm: a packet counts only if it is DATA with the feedback joints and the
//! states; the robot follows corrections only with motors on, `MCI_RUNNING` and RAPID running (or
//! undefined, a RobotWare quirk after restart). Before that the answer repeats the measured joints,
//! so the robot starts from where it is. A new EGM session (RAPID runs `EGMRunJoint` again) restarts
//! `seqno` at 0: that is a new epoch of the driver's sequence, not an out-of-order packet.
//!
//! External axes (a positioner's or a track's, the cell's joints after the arm's six, in chain
//! order): cell joint 6 + k is `externalJoints[k]`, read from `EgmRobot.feedBack.externalJoints`
//! (the actual axes) and answered in `EgmSensor.planned.externalJoints` (the absolute targets).
//! In abb_libegm's `proto/egm.proto` both are `optional EgmJoints externalJoints = 3` (of
//! `EgmFeedBack` — `joints = 1`, `cartesian = 2`, `time = 4` — and of `EgmPlanned`, the same
//! numbers), `EgmSensor.planned` is field 2, and the schema's comment on its
//! `EgmExternalJoints` says the values are "in degrees for rotating axis, in mm for linear axis";
//! the URDF joint's type says which ([`RobotProtocol::set_linear_axes`]). Only the cell's external axes are
//! read (abb_libegm allows six, `DEFAULT_NUMBER_OF_EXTERNAL_JOINTS`; values the robot sends beyond
//! the cell's are ignored), and a packet with fewer is refused naming them. The six robot axes are
//! rotary; a URDF whose first six joints include a prismatic one is refused. Unsure, not confirmed
//! from a public source: whether RAPID's `EGMRunJoint` must name the external axes, and whether a
//! controller sends `externalJoints` for axes outside the EGM motion group (the notes:
//! `docs/protocols/external-axes.md`).
//!
//! Where the controller runs the external axes as a mechanical unit of their own (MultiMove: a
//! positioner in its own motion task, with its own EGM instance and UDP device), they come over a
//! second channel ([`unit`], `[driver] external_axes_bind`): the robot's packets then carry the
//! six axes only, and the unit's axes are merged into them from the unit's newest packet.

pub mod proto;
pub mod unit;

use prost::Message;
use strand_ipc::MAX_JOINTS;

use crate::protocol::{Channel, Clock, PacketError, RobotPacket, RobotProtocol, UnitChannel};
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
    /// The cell's external axes (`externalJoints[0..]`, after the six robot axes); kept across
    /// sessions.
    external: usize,
    /// The external axes' own channel, when they are a mechanical unit of their own; kept across
    /// sessions.
    unit: Option<unit::Unit>,
}

impl Egm {
    /// A connection that has not seen its first packet, for an arm without external axes (the
    /// driver sets the cell's with [`RobotProtocol::set_linear_axes`]).
    pub fn new() -> Egm {
        Egm::default()
    }

    /// The external axes the packets must carry and the answers carry (`externalJoints`).
    pub fn external_axes(&self) -> usize {
        self.external
    }
}

/// What every EGM channel reads first: the `EgmRobot`, its `seqno`, and whether the controller
/// follows corrections (motors on, `MCI_RUNNING`, RAPID running or undefined — a RobotWare quirk
/// after a restart). `whose` begins the errors' text (empty for the robot's channel).
fn decode_robot(packet: &[u8], whose: &str) -> Result<(EgmRobot, u32, bool), PacketError> {
    let robot = EgmRobot::decode(packet).map_err(|e| PacketError::Malformed(format!("{whose}EgmRobot: {e}")))?;
    let header = robot.header.as_ref().ok_or_else(|| PacketError::Truncated(format!("{whose}no header")))?;
    if header.mtype() != MessageType::MsgtypeData {
        return Err(PacketError::Malformed(format!("{whose}mtype {:?}, not MSGTYPE_DATA", header.mtype())));
    }
    let seqno = header.seqno.ok_or_else(|| PacketError::Truncated(format!("{whose}no header.seqno")))?;
    let (motors, mci, rapid) = (
        robot.motor_state.as_ref().ok_or_else(|| PacketError::Truncated(format!("{whose}no motorState")))?.state(),
        robot.mci_state.as_ref().ok_or_else(|| PacketError::Truncated(format!("{whose}no mciState")))?.state(),
        robot.rapid_exec_state.as_ref().map_or(RapidCtrlExecStateType::RapidUndefined, |r| r.state()),
    );
    let following = motors == MotorStateType::MotorsOn
        && mci == MciStateType::MciRunning
        && matches!(rapid, RapidCtrlExecStateType::RapidRunning | RapidCtrlExecStateType::RapidUndefined);
    Ok((robot, seqno, following))
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

    /// The cell's joints: the six robot axes (rotary), then its external axes, rotary (degrees on
    /// the wire) or linear (mm).
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
        self.external = linear.len().saturating_sub(ROBOT_AXES);
        Ok(())
    }

    fn read(&mut self, packet: &[u8]) -> Result<RobotPacket, PacketError> {
        if packet.len() > Self::MAX_PACKET {
            return Err(PacketError::Oversized(packet.len()));
        }
        let (robot, seqno, mut following) = decode_robot(packet, "")?;
        let feedback =
            robot.feed_back.as_ref().and_then(|f| f.joints.as_ref()).ok_or_else(|| PacketError::Truncated("no feedBack.joints".into()))?;
        if feedback.joints.len() != ROBOT_AXES {
            return Err(PacketError::Truncated(format!("feedBack.joints has {} values, not {ROBOT_AXES}", feedback.joints.len())));
        }
        // In the robot's own channel, or (a unit of their own) merged in from the unit's.
        let in_robot_channel = if self.unit.is_some() { 0 } else { self.external };
        let external = robot.feed_back.as_ref().and_then(|f| f.external_joints.as_ref()).map_or(&[][..], |e| &e.joints[..]);
        if external.len() < in_robot_channel {
            return Err(PacketError::Truncated(format!(
                "feedBack.externalJoints has {} values; the cell has {} external axes (joints {}..{})",
                external.len(),
                self.external,
                ROBOT_AXES + 1,
                ROBOT_AXES + self.external
            )));
        }
        let external = &external[..in_robot_channel];
        let mut axes = [0.0; MAX_JOINTS];
        for (k, v) in feedback.joints.iter().chain(external).enumerate() {
            if !v.is_finite() {
                return Err(PacketError::BadValue(format!("joint {}: {v}", k + 1)));
            }
            axes[k] = from_wire(*v, self.linear[k]);
        }
        if let Some(unit) = &mut self.unit {
            following &= unit.merge_into(&mut axes, ROBOT_AXES)?;
        }
        if let Some(last) = self.last_seqno
            && seqno < last
            && (seqno == 0 || last - seqno > NEW_SESSION_GAP)
        {
            self.epoch += 1 << 32;
        }
        self.last_seqno = Some(seqno);
        let tm = robot.header.as_ref().and_then(|h| h.tm).unwrap_or(0);
        self.first_tm.get_or_insert(tm);
        self.last_tm = tm;
        Ok(RobotPacket { seq: self.epoch + u64::from(seqno), axes, dof: ROBOT_AXES + self.external, following })
    }

    fn reset(&mut self) {
        let mut unit = self.unit.take();
        if let Some(u) = &mut unit {
            u.robot_reset();
        }
        *self = Egm { linear: self.linear, external: self.external, unit, ..Egm::default() };
    }

    /// The absolute targets: `planned.joints` (the six robot axes, degrees) and, for the cell's
    /// external axes, `planned.externalJoints` (degrees, or mm for a linear axis).
    fn write(&mut self, axes: &[f64], out: &mut Vec<u8>) {
        out.clear();
        let n = axes.len().min(ROBOT_AXES + self.external);
        let wire = |from: usize, to: usize| (from..to).map(|k| to_wire(axes[k], self.linear[k])).collect::<Vec<f64>>();
        let robot = wire(0, n.min(ROBOT_AXES));
        let external = match &mut self.unit {
            // The unit's share goes over its own channel.
            Some(unit) => {
                unit.command(&axes[ROBOT_AXES.min(n)..n]);
                None
            }
            None if n > ROBOT_AXES => Some(EgmJoints { joints: wire(ROBOT_AXES, n) }),
            None => None,
        };
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

    /// The external axes (all of them: the cell has one chain) on a channel of their own.
    fn split_unit_channel(&mut self, arm: usize) -> Result<(), String> {
        if arm != ROBOT_AXES {
            return Err(format!("the arm has {arm} joints; EGM's robot channel carries {ROBOT_AXES}"));
        }
        if self.external == 0 {
            return Err(
                "the cell has no external axes (a [positioner] or [track] in the robot file) to put on a channel of their own".into()
            );
        }
        self.unit = Some(unit::Unit::new(&self.linear[ROBOT_AXES..ROBOT_AXES + self.external]));
        Ok(())
    }

    fn unit_channel(&mut self) -> Option<&mut dyn UnitChannel> {
        self.unit.as_mut().map(|u| u as &mut dyn UnitChannel)
    }
}

impl UnitChannel for unit::Unit {
    fn unit_read(&mut self, packet: &[u8]) -> Result<bool, PacketError> {
        if packet.len() > Egm::MAX_PACKET {
            return Err(PacketError::Oversized(packet.len()));
        }
        self.read(packet)
    }

    fn unit_write(&mut self, out: &mut Vec<u8>) {
        self.write(out);
    }

    fn unit_fresh(&self) -> bool {
        self.fresh()
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

    /// A rotary table as the 7th axis: `feedBack.externalJoints[0]` in degrees, rad inside, and the
    /// answer's `planned.externalJoints[0]` the absolute target in degrees; the encoded fields are
    /// the schema's numbers (feedBack 2 → externalJoints 3; planned 2 → externalJoints 3).
    #[test]
    fn a_rotary_external_axis_is_read_and_answered_in_external_joints() {
        let mut egm = Egm::new();
        let m = robot_message(1, 4, &[0.0, -30.0, 30.0, 0.0, 60.0, 0.0, 42.5, 7.0], true);
        // Not the cell's: an arm alone reads none of them.
        assert_eq!(egm.read(&m.encode_to_vec()).unwrap().dof, 6);
        egm.set_linear_axes(&[false; 7]).unwrap();
        assert_eq!(egm.external_axes(), 1);
        let p = egm.read(&m.encode_to_vec()).unwrap();
        assert_eq!(p.dof, 7, "one external axis: the robot's second value is not the cell's");
        assert_eq!(p.axes[6], 42.5f64.to_radians());
        assert_eq!(p.axes[7], 0.0);
        let mut target = p.axes;
        target[6] = (-90.25f64).to_radians();
        let mut out = Vec::new();
        egm.write(&target[..7], &mut out);
        let planned = EgmSensor::decode(&out[..]).unwrap().planned.unwrap();
        assert_eq!(planned.external_joints.unwrap().joints, vec![-90.25]);
        assert!((planned.joints.unwrap().joints[2] - 30.0).abs() < 1e-12);
        // The wire itself: EgmSensor field 2 (planned), in it field 3 (externalJoints), in it
        // field 1 (joints, a double, fixed64: tag 0x09).
        let wire = (-90.25f64).to_le_bytes();
        let inner = [&[0x09u8][..], &wire[..]].concat();
        let external = [&[0x1a, inner.len() as u8][..], &inner[..]].concat();
        assert!(out.windows(external.len()).any(|w| w == external.as_slice()), "{out:x?}");
        // A packet without the cell's external axis is refused, naming it.
        let arm_only = robot_message(2, 8, &[0.0, -30.0, 30.0, 0.0, 60.0, 0.0], true);
        match egm.read(&arm_only.encode_to_vec()) {
            Err(PacketError::Truncated(why)) => {
                assert!(why.contains("externalJoints has 0 values") && why.contains("joints 7..7"), "{why}")
            }
            other => panic!("{other:?}"),
        }
    }

    /// A track as the 7th axis: millimetres on the wire, metres in the driver; a rotary external
    /// axis stays in degrees; a prismatic joint among the six robot axes is refused.
    #[test]
    fn a_linear_external_axis_is_millimetres_on_the_wire() {
        let mut egm = Egm::new();
        let e = egm.set_linear_axes(&[false, true, false, false, false, false, false]).unwrap_err();
        assert!(e.contains("joint 2 is prismatic"), "{e}");
        let m = robot_message(1, 4, &[0.0, -30.0, 30.0, 0.0, 60.0, 0.0, 1250.0], true);
        egm.set_linear_axes(&[false; 7]).unwrap();
        let rotary = egm.read(&m.encode_to_vec()).unwrap();
        assert_eq!(rotary.axes[6], 1250f64.to_radians());
        egm.set_linear_axes(&[false, false, false, false, false, false, true]).unwrap();
        let p = egm.read(&m.encode_to_vec()).unwrap();
        assert_eq!(p.dof, 7);
        assert_eq!(p.axes[6], 1.25);
        assert!((p.axes[1] + 30f64.to_radians()).abs() < 1e-15);
        let mut target = p.axes;
        target[6] = 0.5;
        let mut out = Vec::new();
        egm.write(&target[..7], &mut out);
        let planned = EgmSensor::decode(&out[..]).unwrap().planned.unwrap();
        assert_eq!(planned.external_joints.unwrap().joints, vec![500.0]);
        assert!((planned.joints.unwrap().joints[1] + 30.0).abs() < 1e-12);
        // A new EGM session keeps the axes' kinds.
        egm.reset();
        assert_eq!(egm.read(&m.encode_to_vec()).unwrap().axes[6], 1.25);
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
