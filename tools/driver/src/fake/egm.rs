//! An ABB IRC5 with EGM in joint mode, as far as the wire shows it: every cycle an `EgmRobot` —
//! header (`seqno` counting from 0, `tm` in ms, `MSGTYPE_DATA`), the actual joints in `feedBack`
//! (degrees), motors on, the motion-control state (`MCI_STOPPED` for the first `stopped_cycles`,
//! as while `EGMRunJoint` ramps in, then `MCI_RUNNING`) and RAPID running; the answer is an
//! `EgmSensor` with the absolute joint targets in `planned.joints` (degrees). Like the controller it
//! takes the newest answer, in time if it arrives during the cycle. Corrections are applied only
//! while `MCI_RUNNING`, as the controller does.

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
    /// The newest answer's `seqno` taken so far.
    last_seqno: Option<u64>,
}

impl FakeEgm {
    /// A controller whose EGM session runs after `stopped_cycles`.
    pub fn new(stopped_cycles: u64, period_ms: u32) -> FakeEgm {
        FakeEgm { stopped_cycles, period_ms, last_seqno: None }
    }
}

impl FakeProtocol for FakeEgm {
    fn packet(&mut self, k: u64, axes: &[f64], out: &mut Vec<u8>) {
        let m = robot_message(k as u32, (k as u32).wrapping_mul(self.period_ms), axes, k >= self.stopped_cycles);
        out.clear();
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
        let joints = sensor.planned.and_then(|p| p.joints).ok_or(None)?.joints;
        if joints.len() < axes.len().min(6) || joints.iter().any(|j| !j.is_finite()) {
            return Err(None);
        }
        if k >= self.stopped_cycles {
            for (a, j) in axes.iter_mut().zip(joints) {
                *a = j;
            }
        }
        Ok(())
    }
}

/// An `EgmRobot` as a controller sends it: for the fake controller and the tests.
pub(crate) fn robot_message(seqno: u32, tm: u32, joints_deg: &[f64], following: bool) -> EgmRobot {
    use crate::egm::proto::{EgmFeedBack, EgmHeader, EgmJoints, EgmMciState, EgmMotorState, EgmRapidCtrlExecState};
    let (robot, external) = joints_deg.split_at(joints_deg.len().min(crate::egm::ROBOT_AXES));
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
