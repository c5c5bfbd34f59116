//! The FRI messages strand reads and writes, as prost types: the fields of `FRIMonitoringMessage`
//! and `FRICommandMessage` that a joint-position client needs, with their wire numbers and types.
//! KUKA ships no `.proto` (only nanopb code inside its client SDK, under its own licence); these
//! types are written from the wire facts collected in `docs/protocols/fri.md` §2 (field numbers,
//! types, enum values), not from KUKA's text. Fields strand does not use are left out: protobuf
//! decoders skip unknown fields, and a command carries only what it sets.
#![allow(missing_docs)]

/// `MessageHeader`: the message's kind and the two sequence counters.
#[derive(Clone, Copy, PartialEq, prost::Message)]
pub struct MessageHeader {
    /// [`MONITORING_MESSAGE_ID`] from the robot, [`COMMAND_MESSAGE_ID`] from the client.
    #[prost(uint32, required, tag = "1")]
    pub message_identifier: u32,
    /// The sender's own count of messages.
    #[prost(uint32, required, tag = "2")]
    pub sequence_counter: u32,
    /// The other side's last `sequence_counter` received.
    #[prost(uint32, required, tag = "3")]
    pub reflected_sequence_counter: u32,
}

/// `JointValues`: one value per joint (rad or N·m), seven on an LBR; unpacked on the wire, as the
/// SDK writes them.
#[derive(Clone, PartialEq, prost::Message)]
pub struct JointValues {
    #[prost(double, repeated, packed = "false", tag = "1")]
    pub value: Vec<f64>,
}

/// `ConnectionInfo`: the FRI session's state and the connection's quality.
#[derive(Clone, Copy, PartialEq, prost::Message)]
pub struct ConnectionInfo {
    #[prost(enumeration = "SessionState", required, tag = "1")]
    pub session_state: i32,
    #[prost(enumeration = "ConnectionQuality", required, tag = "2")]
    pub quality: i32,
    /// The robot's send period (ms).
    #[prost(uint32, optional, tag = "3")]
    pub send_period: Option<u32>,
    /// Monitoring messages per command the robot expects.
    #[prost(uint32, optional, tag = "4")]
    pub receive_multiplier: Option<u32>,
}

/// `RobotInfo`: the arm's safety state (the rest is not used).
#[derive(Clone, Copy, PartialEq, prost::Message)]
pub struct RobotInfo {
    #[prost(int32, optional, tag = "1")]
    pub number_of_joints: Option<i32>,
    #[prost(enumeration = "SafetyState", optional, tag = "2")]
    pub safety_state: Option<i32>,
}

/// `MessageMonitorData`: the measured joints.
#[derive(Clone, PartialEq, prost::Message)]
pub struct MessageMonitorData {
    #[prost(message, optional, tag = "1")]
    pub measured_joint_position: Option<JointValues>,
}

/// `MessageIpoData`: the interpolator's position (only while an overlay is active) and the mode.
#[derive(Clone, PartialEq, prost::Message)]
pub struct MessageIpoData {
    #[prost(message, optional, tag = "1")]
    pub joint_position: Option<JointValues>,
    #[prost(enumeration = "ClientCommandMode", optional, tag = "10")]
    pub client_command_mode: Option<i32>,
}

/// `MessageCommandData`: the commanded joint positions (rad, absolute).
#[derive(Clone, PartialEq, prost::Message)]
pub struct MessageCommandData {
    #[prost(message, optional, tag = "1")]
    pub joint_position: Option<JointValues>,
}

/// `FRIMonitoringMessage`: what the robot sends every `send_period`.
#[derive(Clone, PartialEq, prost::Message)]
pub struct FriMonitoringMessage {
    #[prost(message, required, tag = "1")]
    pub header: MessageHeader,
    #[prost(message, optional, tag = "2")]
    pub robot_info: Option<RobotInfo>,
    #[prost(message, optional, tag = "3")]
    pub monitor_data: Option<MessageMonitorData>,
    #[prost(message, optional, tag = "4")]
    pub connection_info: Option<ConnectionInfo>,
    #[prost(message, optional, tag = "5")]
    pub ipo_data: Option<MessageIpoData>,
}

/// `FRICommandMessage`: the client's answer.
#[derive(Clone, PartialEq, prost::Message)]
pub struct FriCommandMessage {
    #[prost(message, required, tag = "1")]
    pub header: MessageHeader,
    #[prost(message, optional, tag = "2")]
    pub command_data: Option<MessageCommandData>,
}

/// `messageIdentifier` of a monitoring message (0x245142).
pub const MONITORING_MESSAGE_ID: u32 = 0x24_5142;
/// `messageIdentifier` of a command message (0x34001).
pub const COMMAND_MESSAGE_ID: u32 = 0x3_4001;

/// `FRISessionState`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, prost::Enumeration)]
#[repr(i32)]
pub enum SessionState {
    Idle = 0,
    MonitoringWait = 1,
    MonitoringReady = 2,
    CommandingWait = 3,
    CommandingActive = 4,
}

/// `FRIConnectionQuality`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, prost::Enumeration)]
#[repr(i32)]
pub enum ConnectionQuality {
    Poor = 0,
    Fair = 1,
    Good = 2,
    Excellent = 3,
}

/// `SafetyState`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, prost::Enumeration)]
#[repr(i32)]
pub enum SafetyState {
    NormalOperation = 0,
    SafetyStopLevel0 = 1,
    SafetyStopLevel1 = 2,
    SafetyStopLevel2 = 3,
}

/// `ClientCommandMode`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, prost::Enumeration)]
#[repr(i32)]
pub enum ClientCommandMode {
    NoCommandMode = 0,
    Position = 1,
    Wrench = 2,
    Torque = 3,
}
