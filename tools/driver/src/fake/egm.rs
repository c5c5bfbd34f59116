//! An ABB IRC5 with EGM in joint mode, as far as the wire shows it: every cycle an `EgmRobot` —
//! header (`seqno` counting from 0, `tm` in ms, `MSGTYPE_DATA`), the actual joints in `feedBack`
//! (degrees; its external axes, the axes after the six, in `feedBack.externalJoints`, degrees or
//! mm), motors on, the motion-control state (`MCI_STOPPED` for the first `stopped_cycles`, as while
//! `EGMRunJoint` ramps in, then `MCI_RUNNING`) and RAPID running; the answer is an `EgmSensor` with
//! the absolute joint targets in `planned.joints` (degrees) and, for its external axes,
//! `planned.externalJoints` (the schema's `EgmExternalJoints`: degrees for a rotating axis, mm for
//! a linear one). Like the controller it takes the newest answer, in time if it arrives during the
//! cycle. Corrections are applied only while `MCI_RUNNING`, as the controller does; an answer
//! without a target for each of its axes is no answer.
//!
//! [`FakeEgm::unit`] is the EGM channel of a mechanical unit without a robot that runs in a motion
//! task of its own (MultiMove: a positioner with its own EGM instance and UDP device; with
//! [`super::run_channels`] beside the robot's channel, on the same cycle). From abb_libegm's
//! `parse()` for such a group (`RobotAxes::None`): `feedBack.joints` holds no value and the
//! unit's axes are `feedBack.externalJoints`; it follows `planned.externalJoints`, and an answer
//! carrying robot joints is not for it. It can fall silent and stream again ([`FakeEgm::mute`]),
//! as when its RAPID task stops and starts again.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use prost::Message;

use super::FakeProtocol;
use crate::egm::proto::egm_header::MessageType;
use crate::egm::proto::egm_mci_state::MciStateType;
use crate::egm::proto::egm_motor_state::MotorStateType;
use crate::egm::proto::egm_rapid_ctrl_exec_state::RapidCtrlExecStateType;
use crate::egm::proto::{EgmRobot, EgmSensor};

/// The fake IRC5's EGM side.
pub struct FakeEgm {
    /// Cycles sent with `MCI_STOPPED` before `MCI_RUNNING`.
    pub stopped_cycles: u64,
    /// The cycle (ms).
    pub period_ms: u32,
    /// While set it sends nothing (its RAPID task stopped), and streams again when cleared.
    pub mute: Arc<AtomicBool>,
    /// The newest answer's `seqno` taken so far.
    last_seqno: Option<u64>,
    /// The robot axes in `joints` (6; 0 for a unit without a robot), the rest in `externalJoints`.
    robot_axes: usize,
}

impl FakeEgm {
    /// A controller whose EGM session runs after `stopped_cycles`.
    pub fn new(stopped_cycles: u64, period_ms: u32) -> FakeEgm {
        FakeEgm { stopped_cycles, period_ms, mute: Arc::default(), last_seqno: None, robot_axes: crate::egm::ROBOT_AXES }
    }

    /// The channel of a mechanical unit without a robot in a motion task of its own (MultiMove):
    /// all its axes in `externalJoints`.
    pub fn unit(stopped_cycles: u64, period_ms: u32) -> FakeEgm {
        FakeEgm { robot_axes: 0, ..FakeEgm::new(stopped_cycles, period_ms) }
    }
}

impl FakeProtocol for FakeEgm {
    fn packet(&mut self, k: u64, axes: &[f64], out: &mut Vec<u8>) {
        out.clear();
        if self.mute.load(Ordering::Relaxed) {
            return;
        }
        let (robot, external) = axes.split_at(axes.len().min(self.robot_axes));
        let m = egm_robot(k as u32, (k as u32).wrapping_mul(self.period_ms), robot, external, k >= self.stopped_cycles);
        let _ = m.encode(out);
    }

    fn answer(&mut self, k: u64, bytes: &[u8], axes: &mut [f64]) -> Result<(), Option<u64>> {
        let sensor = EgmSensor::decode(bytes).map_err(|_| None)?;
        let header = sensor.header.ok_or(None)?;
        if header.mtype() != MessageType::MsgtypeCorrection {
            return Err(None);
        }
        // Like the controller, take the newest answer: one that arrives during the cycle is in
        // time (EGM answers carry the sensor's own count, not the packet's, so an answer cannot be
        // matched to its packet); an answer older than one already taken is late.
        let seqno = u64::from(header.seqno.ok_or(None)?);
        if self.last_seqno.is_some_and(|last| seqno <= last) {
            return Err(Some(k.saturating_sub(1)));
        }
        self.last_seqno = Some(seqno);
        let planned = sensor.planned.ok_or(None)?;
        let joints = planned.joints.map_or(Vec::new(), |j| j.joints);
        if self.robot_axes == 0 && !joints.is_empty() {
            // Robot joints for a unit without a robot: not its answer.
            return Err(None);
        }
        let external = planned.external_joints.map_or(Vec::new(), |e| e.joints);
        let (robot_axes, external_axes) = axes.split_at_mut(axes.len().min(self.robot_axes));
        if joints.len() < robot_axes.len() || external.len() < external_axes.len() || joints.iter().chain(&external).any(|j| !j.is_finite())
        {
            return Err(None);
        }
        if k >= self.stopped_cycles {
            for (a, j) in robot_axes.iter_mut().zip(joints).chain(external_axes.iter_mut().zip(external)) {
                *a = j;
            }
        }
        Ok(())
    }
}

/// An `EgmRobot` as a controller sends it, for the tests.
#[cfg(test)]
pub(crate) fn robot_message(seqno: u32, tm: u32, joints_deg: &[f64], following: bool) -> EgmRobot {
    let (robot, external) = joints_deg.split_at(joints_deg.len().min(crate::egm::ROBOT_AXES));
    egm_robot(seqno, tm, robot, external, following)
}

/// An `EgmRobot` of a mechanical unit without a robot (MultiMove): its axes in `externalJoints`,
/// none in `joints`; for the tests.
#[cfg(test)]
pub(crate) fn unit_message(seqno: u32, tm: u32, axes_deg: &[f64], following: bool) -> EgmRobot {
    egm_robot(seqno, tm, &[], axes_deg, following)
}

fn egm_robot(seqno: u32, tm: u32, robot: &[f64], external: &[f64], following: bool) -> EgmRobot {
    use crate::egm::proto::{EgmFeedBack, EgmHeader, EgmJoints, EgmMciState, EgmMotorState, EgmRapidCtrlExecState};
    EgmRobot {
        header: Some(EgmHeader { seqno: Some(seqno), tm: Some(tm), mtype: Some(MessageType::MsgtypeData as i32) }),
        feed_back: Some(EgmFeedBack {
            joints: Some(EgmJoints { joints: robot.to_vec() }),
            external_joints: (!external.is_empty()).then(|| EgmJoints { joints: external.to_vec() }),
            ..Default::default()
        }),
        motor_state: Some(EgmMotorState { state: MotorStateType::MotorsOn as i32 }),
        mci_state: Some(EgmMciState { state: if following { MciStateType::MciRunning } else { MciStateType::MciStopped } as i32 }),
        mci_convergence_met: Some(true),
        rapid_exec_state: Some(EgmRapidCtrlExecState { state: RapidCtrlExecStateType::RapidRunning as i32 }),
        ..Default::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::egm::proto::{EgmHeader, EgmJoints, EgmPlanned};

    fn answer(seqno: u32, joints: &[f64], external: Option<&[f64]>) -> Vec<u8> {
        EgmSensor {
            header: Some(EgmHeader { seqno: Some(seqno), tm: Some(0), mtype: Some(MessageType::MsgtypeCorrection as i32) }),
            planned: Some(EgmPlanned {
                joints: Some(EgmJoints { joints: joints.to_vec() }),
                external_joints: external.map(|e| EgmJoints { joints: e.to_vec() }),
                ..Default::default()
            }),
            speed_ref: None,
        }
        .encode_to_vec()
    }

    /// A controller with a table as its 7th axis sends it in `feedBack.externalJoints` and follows
    /// `planned.externalJoints`; an answer without it is no answer.
    #[test]
    fn the_external_axes_are_sent_and_followed() {
        let mut fake = FakeEgm::new(0, 4);
        let mut out = Vec::new();
        fake.packet(0, &[0.0, -30.0, 30.0, 0.0, 60.0, 0.0, 12.5], &mut out);
        let m = EgmRobot::decode(&out[..]).unwrap();
        assert_eq!(m.feed_back.unwrap().external_joints.unwrap().joints, vec![12.5]);
        let mut axes = vec![0.0; 7];
        fake.answer(0, &answer(0, &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0], Some(&[-45.0])), &mut axes).unwrap();
        assert_eq!(axes, [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, -45.0]);
        assert_eq!(fake.answer(1, &answer(1, &[1.0; 6], None), &mut axes), Err(None));
        assert_eq!(fake.answer(1, &answer(2, &[1.0; 6], Some(&[f64::NAN])), &mut axes), Err(None));
        assert_eq!(axes[6], -45.0);
    }

    /// A unit without a robot (MultiMove) sends its axes in `externalJoints` and none in `joints`,
    /// follows `planned.externalJoints`, and takes no answer with robot joints; silent, it sends
    /// nothing.
    #[test]
    fn a_unit_without_a_robot_streams_external_joints_only() {
        let mut fake = FakeEgm::unit(0, 4);
        let mut out = Vec::new();
        fake.packet(0, &[12.5], &mut out);
        let m = EgmRobot::decode(&out[..]).unwrap();
        let feedback = m.feed_back.unwrap();
        assert!(feedback.joints.is_none_or(|j| j.joints.is_empty()));
        assert_eq!(feedback.external_joints.unwrap().joints, vec![12.5]);
        let mut axes = vec![12.5];
        assert_eq!(fake.answer(0, &answer(0, &[1.0; 6], Some(&[-45.0])), &mut axes), Err(None));
        fake.answer(0, &answer(1, &[], Some(&[-45.0])), &mut axes).unwrap();
        assert_eq!(axes, [-45.0]);
        fake.mute.store(true, Ordering::Relaxed);
        fake.packet(3, &[12.5], &mut out);
        assert!(out.is_empty());
    }
}
