//! KUKA Sunrise FRI (Fast Robot Interface, LBR iiwa 7 and 14) in joint-position mode, as the FRI
//! client: the robot sends an `FRIMonitoringMessage` every send period (1–5 ms, set in the Sunrise
//! application and equal to the service's cycle), the client answers each with an
//! `FRICommandMessage` (protobuf over UDP; `docs/protocols/fri.md`).
//!
//! FRI's session decides what an answer may carry. Only in `COMMANDING_ACTIVE`, with the
//! connection quality `GOOD` or `EXCELLENT`, does the robot follow commanded positions: the
//! session follows the service then. In `COMMANDING_WAIT` (the overlay starting) the answer must
//! be the interpolator's own position (`ipoData.jointPosition`), which the controller holds; in
//! the monitoring states a header alone; in `IDLE`, nothing. The controller stops the arm with an
//! error on a commanded position that jumps: every answer in `COMMANDING_ACTIVE` is the guarded
//! command (velocity and acceleration limits at the send period), and the first one steps from
//! where the arm is. When the quality falls below `GOOD` the controller aborts the overlay and
//! the session falls back to monitoring: the robot stops by itself, the driver stops clocking the
//! service (which faults on the missing joint state), and says so.

pub mod proto;

use prost::Message;

use crate::protocol::{Channel, Clock, PacketError, RobotPacket, RobotProtocol};
use proto::{
    COMMAND_MESSAGE_ID, ConnectionQuality, FriCommandMessage, FriMonitoringMessage, JointValues, MONITORING_MESSAGE_ID, MessageCommandData,
    MessageHeader, SafetyState, SessionState,
};
use strand_ipc::MAX_JOINTS;

/// Joints of an LBR: every `JointValues` carries exactly this many.
pub(crate) const JOINTS: usize = 7;

/// What the robot said last, for the answer and for the log.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Seen {
    state: SessionState,
    quality: ConnectionQuality,
    safety: SafetyState,
    /// The interpolator's joints (rad), while an overlay is active.
    ipo: Option<[f64; JOINTS]>,
    /// The measured joints (rad).
    measured: [f64; JOINTS],
    /// The message's `sequenceCounter`, which the command reflects.
    raw_seq: u32,
    /// Whether the robot follows commands (commanding active, quality good, safety normal).
    following: bool,
}

/// The FRI client's side of the protocol.
#[derive(Default)]
pub struct Fri {
    /// The robot's `sequenceCounter` unwrapped to 64 bits: its last raw value and the wraps.
    last_raw: Option<u32>,
    wraps: u64,
    /// This client's `sequenceCounter`: one per command message sent.
    sent: u32,
    seen: Option<Seen>,
    /// A change of session state, quality or safety state not yet told.
    news: Option<String>,
    /// The send period the service runs at (ms; `[controller] rate_hz`), once set.
    period_ms: Option<f64>,
}

impl Fri {
    /// A client that has heard nothing yet.
    pub fn new() -> Fri {
        Fri::default()
    }
}

fn seven(values: &Option<JointValues>, what: &str) -> Result<Option<[f64; JOINTS]>, PacketError> {
    let Some(v) = values else { return Ok(None) };
    if v.value.len() != JOINTS {
        return Err(PacketError::BadValue(format!("{what}: {} values, an LBR has {JOINTS}", v.value.len())));
    }
    let mut q = [0.0; JOINTS];
    for (k, x) in v.value.iter().enumerate() {
        if !x.is_finite() {
            return Err(PacketError::BadValue(format!("{what}: joint {} is {x}", k + 1)));
        }
        q[k] = *x;
    }
    Ok(Some(q))
}

impl RobotProtocol for Fri {
    const NAME: &'static str = "fri";
    const CLOCK: Clock = Clock::Robot;
    const CHANNEL: Channel = Channel::Datagram;
    /// `FRI_MONITOR_MSG_MAX_SIZE` of the SDK.
    const MAX_PACKET: usize = 1500;

    fn set_linear_axes(&mut self, linear: &[bool]) -> Result<(), String> {
        if linear.len() != JOINTS {
            return Err(format!("FRI drives an LBR's {JOINTS} joints; this robot has {}", linear.len()));
        }
        match linear.iter().position(|l| *l) {
            Some(k) => Err(format!("joint {} is linear; an LBR's joints all turn", k + 1)),
            None => Ok(()),
        }
    }

    fn set_period(&mut self, period: f64) {
        self.period_ms = Some(period * 1e3);
    }

    fn read(&mut self, packet: &[u8]) -> Result<RobotPacket, PacketError> {
        let m = FriMonitoringMessage::decode(packet).map_err(|e| PacketError::Malformed(format!("not an FRI monitoring message: {e}")))?;
        if m.header.message_identifier != MONITORING_MESSAGE_ID {
            return Err(PacketError::Malformed(format!(
                "message identifier {:#x}, not a monitoring message ({MONITORING_MESSAGE_ID:#x})",
                m.header.message_identifier
            )));
        }
        let info = m.connection_info.ok_or_else(|| PacketError::Truncated("no connectionInfo".into()))?;
        let state = SessionState::try_from(info.session_state)
            .map_err(|_| PacketError::BadValue(format!("session state {}", info.session_state)))?;
        let quality =
            ConnectionQuality::try_from(info.quality).map_err(|_| PacketError::BadValue(format!("connection quality {}", info.quality)))?;
        if let (Some(robot), Some(ours)) = (info.send_period, self.period_ms)
            && (f64::from(robot) - ours).abs() > 1e-6
        {
            // The service would tick at another rate than the robot's: every speed and limit
            // would be off by the ratio.
            return Err(PacketError::BadValue(format!(
                "the robot sends every {robot} ms (connectionInfo.sendPeriod; the Sunrise application's send period), \
                 strand runs every {ours} ms ([controller] rate_hz = {}): make them equal",
                1e3 / ours
            )));
        }
        let measured = m.monitor_data.as_ref().map(|d| &d.measured_joint_position);
        let q = seven(measured.unwrap_or(&None), "measuredJointPosition")?
            .ok_or_else(|| PacketError::Truncated("no monitorData.measuredJointPosition".into()))?;
        let ipo = seven(&m.ipo_data.as_ref().and_then(|d| d.joint_position.clone()), "ipoData.jointPosition")?;
        let safety =
            m.robot_info.and_then(|r| r.safety_state).and_then(|s| SafetyState::try_from(s).ok()).unwrap_or(SafetyState::NormalOperation);
        // The robot's counter is 32 bits: unwrapped, so that the session's order check holds
        // across a wrap (49 days at 1 ms).
        let raw = m.header.sequence_counter;
        if self.last_raw.is_some_and(|last| raw < last && last - raw > u32::MAX / 2) {
            self.wraps += 1;
        }
        self.last_raw = Some(raw);
        let following =
            state == SessionState::CommandingActive && quality >= ConnectionQuality::Good && safety == SafetyState::NormalOperation;
        let seen = Seen { state, quality, safety, ipo, measured: q, raw_seq: raw, following };
        if self.seen.is_none_or(|s| (s.state, s.quality, s.safety) != (state, quality, safety)) {
            self.news = Some(match self.seen {
                None => format!("FRI session {state:?}, quality {quality:?}, {safety:?}"),
                Some(s) => format!("FRI session {:?} → {state:?}, quality {:?} → {quality:?}, {safety:?}", s.state, s.quality),
            });
        }
        self.seen = Some(seen);
        let mut axes = [0.0; MAX_JOINTS];
        axes[..JOINTS].copy_from_slice(&q);
        Ok(RobotPacket { seq: (self.wraps << 32) | u64::from(raw), axes, dof: JOINTS, following })
    }

    fn reset(&mut self) {
        *self = Fri { sent: self.sent, period_ms: self.period_ms, ..Fri::default() };
    }

    fn take_news(&mut self) -> Option<String> {
        self.news.take()
    }

    /// The command message answering the newest monitoring message: its sequence counter
    /// reflected, the joints only while commanding (the interpolator's position until the robot
    /// follows), nothing once the session is over.
    fn write(&mut self, axes: &[f64], out: &mut Vec<u8>) {
        out.clear();
        let Some(seen) = self.seen else { return };
        let position = match seen.state {
            // The session is over: nothing is answered.
            SessionState::Idle => return,
            SessionState::MonitoringWait | SessionState::MonitoringReady => None,
            // The overlay starts: hold the interpolator's position, as the controller demands.
            SessionState::CommandingWait => seen.ipo.map(|q| q.to_vec()),
            SessionState::CommandingActive => {
                Some(if seen.following { axes[..JOINTS].to_vec() } else { seen.ipo.unwrap_or(seen.measured).to_vec() })
            }
        };
        let m = FriCommandMessage {
            header: MessageHeader {
                message_identifier: COMMAND_MESSAGE_ID,
                sequence_counter: self.sent,
                reflected_sequence_counter: seen.raw_seq,
            },
            command_data: position.map(|value| MessageCommandData { joint_position: Some(JointValues { value }) }),
        };
        self.sent = self.sent.wrapping_add(1);
        let _ = m.encode(out);
    }
}

#[cfg(test)]
mod tests {
    use super::proto::{ConnectionInfo, MessageIpoData, MessageMonitorData, RobotInfo};
    use super::*;

    fn monitoring(seq: u32, state: SessionState, quality: ConnectionQuality, q: [f64; JOINTS], ipo: Option<[f64; JOINTS]>) -> Vec<u8> {
        FriMonitoringMessage {
            header: MessageHeader { message_identifier: MONITORING_MESSAGE_ID, sequence_counter: seq, reflected_sequence_counter: 0 },
            robot_info: Some(RobotInfo { number_of_joints: Some(7), safety_state: Some(0) }),
            monitor_data: Some(MessageMonitorData { measured_joint_position: Some(JointValues { value: q.to_vec() }) }),
            connection_info: Some(ConnectionInfo {
                session_state: state as i32,
                quality: quality as i32,
                send_period: Some(4),
                receive_multiplier: Some(1),
            }),
            ipo_data: ipo
                .map(|p| proto::MessageIpoData { joint_position: Some(JointValues { value: p.to_vec() }), client_command_mode: Some(1) }),
        }
        .encode_to_vec()
    }

    #[test]
    fn each_session_state_gets_the_answer_fri_demands() {
        let q = [0.1, 0.2, 0.3, -1.0, 0.5, 0.6, 0.7];
        let ipo = [0.1001, 0.2, 0.3, -1.0, 0.5, 0.6, 0.7];
        let command = [0.11, 0.2, 0.3, -1.0, 0.5, 0.6, 0.7, 0.0];
        let mut fri = Fri::new();
        let mut out = Vec::new();
        let answer = |out: &[u8]| FriCommandMessage::decode(out).unwrap();
        // Monitoring: not following, a header alone that reflects the robot's counter.
        let p = fri.read(&monitoring(10, SessionState::MonitoringReady, ConnectionQuality::Good, q, None)).unwrap();
        assert!(!p.following);
        assert_eq!(&p.axes[..7], &q);
        fri.write(&command, &mut out);
        let a = answer(&out);
        assert_eq!(
            (a.header.message_identifier, a.header.sequence_counter, a.header.reflected_sequence_counter),
            (COMMAND_MESSAGE_ID, 0, 10)
        );
        assert!(a.command_data.is_none());
        assert!(fri.take_news().unwrap().contains("MonitoringReady"));
        // The overlay starting: the interpolator's position, whatever the session would send.
        let p = fri.read(&monitoring(11, SessionState::CommandingWait, ConnectionQuality::Good, q, Some(ipo))).unwrap();
        assert!(!p.following);
        fri.write(&command, &mut out);
        let a = answer(&out);
        assert_eq!(a.header.sequence_counter, 1);
        assert_eq!(a.command_data.unwrap().joint_position.unwrap().value, ipo);
        // Commanding with a good link: the command.
        let p = fri.read(&monitoring(12, SessionState::CommandingActive, ConnectionQuality::Excellent, q, Some(ipo))).unwrap();
        assert!(p.following);
        fri.write(&command, &mut out);
        assert_eq!(answer(&out).command_data.unwrap().joint_position.unwrap().value, &command[..7]);
        // A poor link while commanding: not followed (the controller aborts the overlay).
        let p = fri.read(&monitoring(13, SessionState::CommandingActive, ConnectionQuality::Fair, q, Some(ipo))).unwrap();
        assert!(!p.following);
        assert!(fri.take_news().unwrap().contains("Excellent → Fair"));
        // The command written then holds the interpolator's position, reflecting this message.
        fri.write(&command, &mut out);
        let a = answer(&out);
        assert_eq!(a.header.reflected_sequence_counter, 13);
        assert_eq!(a.command_data.unwrap().joint_position.unwrap().value, ipo);
        // Idle: nothing is sent.
        fri.read(&monitoring(14, SessionState::Idle, ConnectionQuality::Poor, q, None)).unwrap();
        fri.write(&command, &mut out);
        assert!(out.is_empty());
    }

    #[test]
    fn bad_messages_are_refused_with_the_reason() {
        let q = [0.0; JOINTS];
        let mut fri = Fri::new();
        assert!(matches!(fri.read(b"\xff\xff\xff"), Err(PacketError::Malformed(_))));
        // A command message is not a monitoring message.
        let cmd = FriCommandMessage {
            header: MessageHeader { message_identifier: COMMAND_MESSAGE_ID, sequence_counter: 0, reflected_sequence_counter: 0 },
            command_data: None,
        }
        .encode_to_vec();
        assert!(matches!(fri.read(&cmd), Err(PacketError::Malformed(m)) if m.contains("0x34001")));
        // Six joints, a NaN, no measured joints.
        let mut six =
            FriMonitoringMessage::decode(&monitoring(1, SessionState::MonitoringWait, ConnectionQuality::Poor, q, None)[..]).unwrap();
        six.monitor_data = Some(MessageMonitorData { measured_joint_position: Some(JointValues { value: vec![0.0; 6] }) });
        assert!(matches!(fri.read(&six.encode_to_vec()), Err(PacketError::BadValue(m)) if m.contains("6 values")));
        let mut nan = q;
        nan[3] = f64::NAN;
        assert!(matches!(
            fri.read(&monitoring(2, SessionState::CommandingActive, ConnectionQuality::Good, nan, None)),
            Err(PacketError::BadValue(m)) if m.contains("joint 4")
        ));
        let mut none = six.clone();
        none.monitor_data = None;
        assert!(matches!(fri.read(&none.encode_to_vec()), Err(PacketError::Truncated(_))));
        let _ = MessageIpoData::default();
        // Another send period than the service's: refused, naming both.
        let mut fri = Fri::new();
        fri.set_period(0.001);
        assert!(matches!(
            fri.read(&monitoring(3, SessionState::MonitoringWait, ConnectionQuality::Good, q, None)),
            Err(PacketError::BadValue(m)) if m.contains("every 4 ms") && m.contains("every 1 ms")
        ));
    }

    #[test]
    fn the_robots_counter_is_unwrapped_across_its_32_bits() {
        let q = [0.0; JOINTS];
        let mut fri = Fri::new();
        let a = fri.read(&monitoring(u32::MAX - 1, SessionState::MonitoringWait, ConnectionQuality::Good, q, None)).unwrap().seq;
        let b = fri.read(&monitoring(2, SessionState::MonitoringWait, ConnectionQuality::Good, q, None)).unwrap().seq;
        assert_eq!(b - a, 4);
        assert_eq!(Fri::cycles_between(a, b, 0.001), 4);
    }
}
