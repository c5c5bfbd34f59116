//! The EGM channel of a mechanical unit that runs apart from the robot: a positioner (or a track)
//! that the controller runs in a motion task of its own (MultiMove), with its own EGM instance
//! (`EGMSetupUC` on its own UDP device) and so its own stream of `EgmRobot` packets to a port of
//! its own. One strand command drives the arm and the unit, so strand-egm answers both from it:
//! the robot's channel keeps the cycle and clocks the service; this one is read as it comes and
//! answered with its share of the same command.
//!
//! What such a unit sends, from ABB's own code: abb_egm_rws_managers (`EGMManager`) opens one EGM
//! channel per mechanical unit group, each on its own port, and configures a group without a TCP
//! robot with `egm::RobotAxes::None`; abb_libegm's `parse()` for `None` accepts a packet only
//! when `feedBack.joints` holds no value, takes the unit's axes from `feedBack.externalJoints`
//! (degrees, or mm for a linear axis), and refuses a Cartesian pose. So the answer carries the
//! targets in `planned.externalJoints` and no robot joints. Whether a controller needs anything
//! else of a robot-less unit's answer is not confirmed from a public source
//! (`docs/protocols/external-axes.md`).
//!
//! Safety: the robot follows only while the unit does — its packets came within the robot's last
//! two cycles, with motors on and `MCI_RUNNING` — and only from the second robot cycle on after
//! the unit came back, so that the driver's guard has been reset to where the unit really is
//! before the first command (a guard that held an old table angle would start the table from
//! there). A robot packet before the unit's first one is refused: nothing is known of the unit.

use prost::Message;
use strand_ipc::MAX_JOINTS;

use super::proto::egm_header::MessageType;
use super::proto::{EgmHeader, EgmJoints, EgmPlanned, EgmSensor};
use super::{NEW_SESSION_GAP, decode_robot, from_wire, to_wire};
use crate::protocol::PacketError;

/// Robot cycles after the unit's newest packet for which its axes still count as measured: its
/// packet of a cycle may come just after the robot's, and one may be lost.
const FRESH_ROBOT_CYCLES: u32 = 2;

/// The unit's channel, as the robot channel's read and write see it.
#[derive(Clone, Debug, Default)]
pub struct Unit {
    /// The unit's axes (the cell's external axes, in chain order).
    axes: usize,
    /// Which of them are linear (mm on the wire, m here).
    linear: [bool; MAX_JOINTS],
    /// The unit's newest measured axes (rad or m), once it has sent one.
    measured: Option<[f64; MAX_JOINTS]>,
    /// Its newest packet said motors on, `MCI_RUNNING` and RAPID running.
    following: bool,
    /// Robot packets read since the unit's newest packet.
    robot_reads_since: u32,
    /// Robot packets in a row read with the unit fresh.
    fresh_run: u32,
    /// The unit's last `seqno` (its own sequence; a new EGM session restarts it).
    last_seqno: Option<u32>,
    /// The unit's `tm` of its first and newest packet (ms), for the answers' `tm`.
    first_tm: Option<u32>,
    last_tm: u32,
    /// Answers sent to the unit (their `seqno`).
    replies: u32,
    /// The unit's share of the last command written to the robot (rad or m).
    target: Option<[f64; MAX_JOINTS]>,
}

impl Unit {
    /// A unit carrying `linear.len()` axes, linear where true.
    pub(super) fn new(linear: &[bool]) -> Unit {
        let mut unit = Unit { axes: linear.len(), ..Unit::default() };
        unit.linear[..linear.len()].copy_from_slice(linear);
        unit
    }

    /// The unit's axes.
    pub fn axes(&self) -> usize {
        self.axes
    }

    /// Reads one of the unit's packets (see [`crate::protocol::UnitChannel::unit_read`]).
    pub(super) fn read(&mut self, packet: &[u8]) -> Result<bool, PacketError> {
        let (robot, seqno, following) = decode_robot(packet, "the external unit's packet: ")?;
        let feedback = robot.feed_back.as_ref();
        let robot_joints = feedback.and_then(|f| f.joints.as_ref()).map_or(0, |j| j.joints.len());
        if robot_joints > 0 {
            return Err(PacketError::Malformed(format!(
                "the external unit's channel got feedBack.joints with {robot_joints} values: that is a robot's channel (a unit without a robot sends its axes in feedBack.externalJoints only); are [driver] bind and external_axes_bind swapped?"
            )));
        }
        let external = feedback.and_then(|f| f.external_joints.as_ref()).map_or(&[][..], |e| &e.joints[..]);
        if external.len() < self.axes {
            return Err(PacketError::Truncated(format!(
                "the external unit's feedBack.externalJoints has {} values; the cell has {} external axes",
                external.len(),
                self.axes
            )));
        }
        let mut measured = [0.0; MAX_JOINTS];
        for (k, v) in external[..self.axes].iter().enumerate() {
            if !v.is_finite() {
                return Err(PacketError::BadValue(format!("the external unit's axis {}: {v}", k + 1)));
            }
            measured[k] = from_wire(*v, self.linear[k]);
        }
        // Older than the newest taken (a new EGM session restarts seqno at 0: not older).
        if let Some(last) = self.last_seqno
            && seqno <= last
            && !(seqno < last && (seqno == 0 || last - seqno > NEW_SESSION_GAP))
        {
            return Ok(false);
        }
        self.last_seqno = Some(seqno);
        let tm = robot.header.as_ref().and_then(|h| h.tm).unwrap_or(0);
        self.first_tm.get_or_insert(tm);
        self.last_tm = tm;
        self.measured = Some(measured);
        self.following = following;
        self.robot_reads_since = 0;
        Ok(true)
    }

    /// At each robot packet read: the unit's measured axes go into `axes[from..]`; whether the
    /// robot may follow as far as the unit goes. Err before the unit's first packet.
    pub(super) fn merge_into(&mut self, axes: &mut [f64; MAX_JOINTS], from: usize) -> Result<bool, PacketError> {
        let Some(measured) = self.measured else {
            return Err(PacketError::Truncated(
                "the external axes' own EGM channel ([driver] external_axes_bind) has sent nothing yet: the robot waits for its unit"
                    .into(),
            ));
        };
        self.robot_reads_since = self.robot_reads_since.saturating_add(1);
        let fresh = self.robot_reads_since <= FRESH_ROBOT_CYCLES;
        self.fresh_run = if fresh { self.fresh_run.saturating_add(1) } else { 0 };
        axes[from..from + self.axes].copy_from_slice(&measured[..self.axes]);
        // From the second fresh cycle on: the first one's hold resets the guard to where the unit is.
        Ok(fresh && self.following && self.fresh_run >= 2)
    }

    /// The unit's share of the command the robot was just answered with (rad or m).
    pub(super) fn command(&mut self, axes: &[f64]) {
        let mut target = [0.0; MAX_JOINTS];
        let n = axes.len().min(self.axes);
        target[..n].copy_from_slice(&axes[..n]);
        if n == self.axes {
            self.target = Some(target);
        }
    }

    /// Whether the unit's newest packet came within the robot's last two cycles.
    pub(super) fn fresh(&self) -> bool {
        self.measured.is_some() && self.robot_reads_since <= FRESH_ROBOT_CYCLES
    }

    /// The robot's session ended: no command carries over into the next one.
    pub(super) fn robot_reset(&mut self) {
        self.target = None;
        self.fresh_run = 0;
    }

    /// The answer to the unit's newest packet: its targets in `planned.externalJoints`, no robot
    /// joints; where it is until a command was written for it.
    pub(super) fn write(&mut self, out: &mut Vec<u8>) {
        out.clear();
        let Some(measured) = self.measured else { return };
        let axes = self.target.unwrap_or(measured);
        let joints = (0..self.axes).map(|k| to_wire(axes[k], self.linear[k])).collect();
        let sensor = EgmSensor {
            header: Some(EgmHeader {
                seqno: Some(self.replies),
                tm: Some(self.last_tm.wrapping_sub(self.first_tm.unwrap_or(self.last_tm))),
                mtype: Some(MessageType::MsgtypeCorrection as i32),
            }),
            planned: Some(EgmPlanned { external_joints: Some(EgmJoints { joints }), ..Default::default() }),
            speed_ref: None,
        };
        self.replies = self.replies.wrapping_add(1);
        // Encoding into a Vec cannot fail (it grows).
        let _ = sensor.encode(out);
    }
}

#[cfg(test)]
mod tests {
    use super::super::Egm;
    use crate::fake::egm::{robot_message, unit_message};
    use crate::protocol::{PacketError, RobotProtocol};
    use prost::Message;

    use crate::egm::proto::EgmSensor;
    use crate::egm::proto::egm_header::MessageType;

    const ARM: [f64; 6] = [0.0, -30.0, 30.0, 0.0, 60.0, 0.0];

    /// The KR 6's turntable as a unit of its own: six robot axes in the robot's channel, the table
    /// (rotary) in the unit's.
    fn egm() -> Egm {
        let mut egm = Egm::new();
        egm.set_linear_axes(&[false; 7]).unwrap();
        egm.split_unit_channel(6).unwrap();
        egm
    }

    fn robot(seqno: u32) -> Vec<u8> {
        robot_message(seqno, seqno * 4, &ARM, true).encode_to_vec()
    }

    fn unit(seqno: u32, table_deg: f64, following: bool) -> Vec<u8> {
        unit_message(seqno, seqno * 4, &[table_deg], following).encode_to_vec()
    }

    /// The unit's axes are merged into the robot's packet; the robot follows from the second
    /// cycle both channels stream; the robot's answer carries its six axes only and the unit's
    /// answer the table's target alone, in `planned.externalJoints` (degrees), with no robot joints.
    #[test]
    fn the_units_axes_are_merged_and_its_share_of_the_command_goes_back_on_its_own_channel() {
        let mut egm = egm();
        match egm.read(&robot(0)) {
            Err(PacketError::Truncated(why)) => assert!(why.contains("external_axes_bind") && why.contains("sent nothing yet"), "{why}"),
            other => panic!("a robot packet before the unit's first: {other:?}"),
        }
        let u = egm.unit_channel().unwrap();
        assert!(!u.unit_fresh());
        assert_eq!(u.unit_read(&unit(0, 42.5, true)), Ok(true));
        // Before any command the unit is answered with where it is.
        let mut out = Vec::new();
        u.unit_write(&mut out);
        let answer = EgmSensor::decode(&out[..]).unwrap();
        assert_eq!(answer.header.as_ref().unwrap().mtype(), MessageType::MsgtypeCorrection);
        assert_eq!(answer.planned.as_ref().unwrap().external_joints.as_ref().unwrap().joints, vec![42.5]);
        let first = egm.read(&robot(1)).unwrap();
        assert_eq!(first.dof, 7);
        assert!((first.axes[6] - 42.5f64.to_radians()).abs() < 1e-15, "{:?}", first.axes);
        assert!(!first.following, "the first cycle with the unit holds: the guard is reset to where the unit is");
        egm.unit_channel().unwrap().unit_read(&unit(1, 42.5, true)).unwrap();
        let p = egm.read(&robot(2)).unwrap();
        assert!(p.following);
        let mut target = p.axes;
        target[0] = 10f64.to_radians();
        target[6] = (-90.25f64).to_radians();
        egm.write(&target[..7], &mut out);
        let planned = EgmSensor::decode(&out[..]).unwrap().planned.unwrap();
        assert!(planned.external_joints.is_none(), "the robot's channel carries no external axes: {planned:?}");
        assert!((planned.joints.unwrap().joints[0] - 10.0).abs() < 1e-12);
        let u = egm.unit_channel().unwrap();
        u.unit_write(&mut out);
        let sensor = EgmSensor::decode(&out[..]).unwrap();
        assert_eq!(sensor.header.unwrap().seqno, Some(1), "the unit's own reply count");
        let planned = sensor.planned.unwrap();
        assert!(planned.joints.as_ref().is_none_or(|j| j.joints.is_empty()), "no robot joints for a unit without a robot");
        assert!((planned.external_joints.unwrap().joints[0] + 90.25).abs() < 1e-12);
    }

    /// A unit that falls silent (its task stopped) or stops following stops the robot following
    /// at the second robot packet without it; when it streams again the robot follows from the second
    /// cycle, not the first.
    #[test]
    fn a_silent_or_stopped_unit_stops_the_robot_following_and_it_comes_back_a_cycle_later() {
        let mut egm = egm();
        for k in 0..3 {
            egm.unit_channel().unwrap().unit_read(&unit(k, 5.0, true)).unwrap();
            egm.read(&robot(k)).unwrap();
        }
        let following: Vec<bool> = (3..6).map(|k| egm.read(&robot(k)).unwrap().following).collect();
        assert_eq!(following, [true, false, false], "one of the unit's packets may be missing, not two");
        assert!(!egm.unit_channel().unwrap().unit_fresh());
        let back: Vec<bool> = (6..9)
            .map(|k| {
                egm.unit_channel().unwrap().unit_read(&unit(k - 3, 6.0, true)).unwrap();
                egm.read(&robot(k)).unwrap().following
            })
            .collect();
        assert_eq!(back, [false, true, true]);
        egm.unit_channel().unwrap().unit_read(&unit(6, 6.0, false)).unwrap();
        assert!(!egm.read(&robot(9)).unwrap().following, "MCI_STOPPED on the unit: the robot holds too");
        // The robot's session ends: the unit's last command does not carry over.
        let mut out = Vec::new();
        egm.write(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], &mut out);
        egm.reset();
        egm.unit_channel().unwrap().unit_write(&mut out);
        let joints = EgmSensor::decode(&out[..]).unwrap().planned.unwrap().external_joints.unwrap().joints;
        assert!(
            joints.len() == 1 && (joints[0] - 6.0).abs() < 1e-12,
            "after the robot's session ended the unit is answered with where it is: {joints:?}"
        );
    }

    /// Packets the unit's channel refuses, each named: a robot's packet (the two ports swapped),
    /// too few axes, a NaN; older packets are dropped and a new EGM session's restart is not.
    #[test]
    fn the_units_channel_refuses_a_robots_packet_and_names_what_is_wrong() {
        let mut egm = egm();
        let u = egm.unit_channel().unwrap();
        match u.unit_read(&robot(0)) {
            Err(PacketError::Malformed(why)) => assert!(why.contains("feedBack.joints with 6 values") && why.contains("swapped"), "{why}"),
            other => panic!("{other:?}"),
        }
        match u.unit_read(&unit_message(0, 0, &[], true).encode_to_vec()) {
            Err(PacketError::Truncated(why)) => assert!(why.contains("has 0 values") && why.contains("1 external axes"), "{why}"),
            other => panic!("{other:?}"),
        }
        assert!(matches!(u.unit_read(&unit(0, f64::NAN, true)), Err(PacketError::BadValue(_))));
        assert!(matches!(u.unit_read(&vec![0u8; 2000]), Err(PacketError::Oversized(2000))));
        assert!(matches!(u.unit_read(b"\xff\xff"), Err(PacketError::Malformed(_))));
        assert_eq!(u.unit_read(&unit(5000, 1.0, true)), Ok(true));
        assert_eq!(u.unit_read(&unit(4999, 1.0, true)), Ok(false), "an older packet");
        assert_eq!(u.unit_read(&unit(5000, 1.0, true)), Ok(false), "a duplicate");
        assert_eq!(u.unit_read(&unit(0, 1.0, true)), Ok(true), "a new EGM session");
        // A cell without external axes, or an arm of another size, has no unit to split off.
        let mut arm_only = Egm::new();
        arm_only.set_linear_axes(&[false; 6]).unwrap();
        assert!(arm_only.split_unit_channel(6).unwrap_err().contains("no external axes"));
        let mut seven = Egm::new();
        seven.set_linear_axes(&[false; 8]).unwrap();
        assert!(seven.split_unit_channel(7).unwrap_err().contains("carries 6"));
    }

    /// A track as the unit: millimetres on its wire, metres in the driver.
    #[test]
    fn a_linear_unit_axis_is_millimetres_on_its_channel() {
        let mut egm = Egm::new();
        egm.set_linear_axes(&[false, false, false, false, false, false, true]).unwrap();
        egm.split_unit_channel(6).unwrap();
        for k in 0..2 {
            egm.unit_channel().unwrap().unit_read(&unit_message(k, 0, &[1250.0], true).encode_to_vec()).unwrap();
        }
        let p = egm.read(&robot(0)).unwrap();
        assert_eq!(p.axes[6], 1.25);
        let mut out = Vec::new();
        let mut target = p.axes;
        target[6] = 0.5;
        egm.write(&target[..7], &mut out);
        egm.unit_channel().unwrap().unit_write(&mut out);
        assert_eq!(EgmSensor::decode(&out[..]).unwrap().planned.unwrap().external_joints.unwrap().joints, vec![500.0]);
    }
}
