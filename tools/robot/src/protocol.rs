//! The one small trait every robot interface implements, split as ros2_control splits a hardware
//! interface: [`RobotProtocol::read`] the robot's state from a packet, [`RobotProtocol::write`] a
//! command. A write need not answer a packet: where the robot clocks the cycle the command goes
//! back as the answer to the newest state (the protocol keeps from its read what the answer echoes:
//! RSI's `IPOC`, FRI's sequence counter), where the driver clocks it the command is the cycle's
//! (b-CAP's `slvMove`, the Meca500's `MoveJointsVel`). Besides, a protocol says what carries its
//! state ([`Channel`]: a datagram, or framed bytes of a stream, cut by [`RobotProtocol::frame`])
//! and who clocks the cycle ([`Clock`]); the set-up before the first cycle is the driver's
//! handshake hook. A protocol knows its wire format and its start-up rules (RSI's reference axes,
//! EGM's motion-control state, FRI's session), nothing of sockets, the service or limits — so the
//! next interface (FANUC Stream Motion, Franka) is one new module.

use strand_wire::MAX_JOINTS;

pub use crate::channel::{Channel, Frame};

/// A robot packet, decoded.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobotPacket {
    /// The packet's own sequence: EGM's header `seqno`, RSI's `IPOC`. Increases packet to packet;
    /// a packet whose sequence does not is out of order or a duplicate.
    pub seq: u64,
    /// Measured axis angles of the robot controller, in its own axes (rad; the protocols send
    /// degrees).
    pub axes: [f64; MAX_JOINTS],
    /// Axes in the packet.
    pub dof: usize,
    /// The robot follows corrections now (EGM: motors on and `MCI_RUNNING`; RSI: always, once the
    /// first packet set the reference).
    pub following: bool,
}

/// Why a packet was dropped.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum PacketError {
    /// Not the protocol's format (not protobuf / not XML, a wrong message type).
    #[error("malformed: {0}")]
    Malformed(String),
    /// The format, but a field the protocol needs is missing or cut short.
    #[error("truncated: {0}")]
    Truncated(String),
    /// Longer than any packet of the protocol.
    #[error("oversized: {0} bytes")]
    Oversized(usize),
    /// A number that is not finite, or more axes than the robot has.
    #[error("bad value: {0}")]
    BadValue(String),
    /// The robot answered with an error that stopped it (b-CAP's HRESULTs in slave mode): the
    /// stream is over, the driver tells the service and gives the robot back.
    #[error("the robot stopped: {0}")]
    RobotError(String),
}

/// Who clocks the cycle: what a state arriving means, and what an answer that comes late does.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Clock {
    /// The robot sends its state every cycle and servos to the newest answer (EGM, RSI, FRI, UR's
    /// reverse interface): a state arriving is the tick. An answer later than the robot's cycle
    /// was not its target that cycle — the robot held the previous one — so the guard takes it
    /// back ([`crate::session::Session::answer_missed_its_cycle`]) and the next answer catches up
    /// from the hold; over a stream (UR) such an answer is not sent at all, lest the robot run it a
    /// cycle late and then step back to the next one.
    Robot,
    /// The driver sends on its own clock and the robot's answer is its state (b-CAP's slave mode,
    /// the Meca500's velocity mode), at the period the driver is configured for
    /// ([`RobotProtocol::set_period`]): the robot runs every command in order (b-CAP's buffer; the
    /// Meca500 keeps its last velocity), so a late command delays the motion; it is counted, not
    /// taken back.
    Driver,
}

/// A robot controller's streaming interface.
pub trait RobotProtocol {
    /// Its name in messages (`egm`, `rsi`).
    const NAME: &'static str;
    /// Who clocks the cycle.
    const CLOCK: Clock;
    /// What carries the robot's state.
    const CHANNEL: Channel;
    /// The longest packet it sends (bytes); longer ones are dropped as oversized.
    const MAX_PACKET: usize;

    /// The robot's cycles from the packet with sequence `earlier` to the one with `later` (1 for
    /// the next packet). More than one means cycles in between went unanswered — a packet lost
    /// on the way, or skipped because a newer one was already queued — and the robot held its
    /// target through them. By default the sequence counts packets (EGM's `seqno`); a protocol
    /// whose sequence is a clock says how it converts (RSI's `IPOC`, in ms), with `period` the
    /// cycle (s).
    fn cycles_between(earlier: u64, later: u64, period: f64) -> u64 {
        let _ = period;
        later.saturating_sub(earlier)
    }

    /// Which of the robot's axes are linear (prismatic URDF joints), in chain order: the vendors
    /// send linear axes in millimetres where rotary ones are in degrees, so the protocol converts
    /// them apart (to and from metres). Called once, before the first packet. An axis the protocol
    /// cannot carry as linear is refused with the reason.
    fn set_linear_axes(&mut self, linear: &[bool]) -> Result<(), String>;

    /// The robot's cycle as the driver is configured for it (s; `[controller] rate_hz`). Called
    /// once, before the first packet; a protocol whose robot says its own cycle (FRI's
    /// `sendPeriod`) refuses packets that disagree. Ignored by default.
    fn set_period(&mut self, period: f64) {
        let _ = period;
    }

    /// Where the next packet ends in a stream's buffered bytes (`buffered` is never empty), for
    /// a [`Channel::Stream`] protocol; a datagram is its own packet (the default).
    fn frame(buffered: &[u8]) -> Frame {
        Frame::Packet(buffered.len())
    }

    /// Reads the robot's state from one packet: a datagram, or a stream's packet as
    /// [`RobotProtocol::frame`] cut it (the Meca500: a tick's messages).
    fn read(&mut self, packet: &[u8]) -> Result<RobotPacket, PacketError>;

    /// How long the robot runs on at its last command when commands stop coming (s): 0, the
    /// default, where it holds its last target (EGM, RSI, FRI, UR's `servoj`) or runs what it has
    /// buffered and then stops with an error (b-CAP); the Meca500's `SetVelTimeout`, through which
    /// it keeps its last velocity. After the driver's own loop lapsed (where the driver clocks the
    /// cycle) the service owes the robot the ticks it ran on for
    /// ([`crate::session::Session::driver_lapsed`]).
    fn runs_on_for(&self) -> f64 {
        0.0
    }

    /// Forgets the connection (the robot's interface session ended: RSI off, EGM stopped, a
    /// controller restart): the next packet starts a new one.
    fn reset(&mut self);

    /// A change the robot reported that the driver's log should say (FRI's session state and
    /// connection quality), once; None by default. Not on a protocol's hot path: called once per
    /// packet, it allocates only when something changed.
    fn take_news(&mut self) -> Option<String> {
        None
    }

    /// A speed scaling the robot applies to its motion now (0..1; UR's speed slider × its
    /// trajectory limiter), once per change; None by default. The service is told to scale its
    /// feed to it, so that the path slows instead of the robot falling behind its commands.
    fn take_speed_scaling(&mut self) -> Option<f64> {
        None
    }

    /// Writes into `out` (cleared first) the command that the robot's axes go to `axes` (rad, or
    /// m for a linear axis; the robot's own axes, as many as its packets carry). Where the robot
    /// clocks the cycle it answers the newest packet read; an empty `out` sends nothing (FRI
    /// after its session ended).
    fn write(&mut self, axes: &[f64], out: &mut Vec<u8>);

    /// Takes the cell's external axes (the joints after `arm`) off the robot's channel onto a
    /// channel of their own ([`UnitChannel`]): the controller runs them as a mechanical unit of
    /// another motion task (ABB MultiMove: a positioner with its own EGM instance and UDP
    /// device). Called once, after [`RobotProtocol::set_linear_axes`]. Refused by default: the
    /// protocol carries every joint in one channel.
    fn split_unit_channel(&mut self, arm: usize) -> Result<(), String> {
        let _ = arm;
        Err(format!("{} carries every joint in the robot's channel: no channel of their own for the external axes", Self::NAME))
    }

    /// The external axes' own channel, once [`RobotProtocol::split_unit_channel`] made one.
    fn unit_channel(&mut self) -> Option<&mut dyn UnitChannel> {
        None
    }

    /// Puts the extruder's command into every answer as the robot's own outputs (KUKA RSI: an
    /// analog output for the drive's speed and a digital one to enable it, wired on the controller
    /// to `$ANOUT`/`$OUT`), in the same packet as the joints. Called once, before the first
    /// packet. Refused by default: the protocol has no outputs for it.
    fn set_extruder_output(&mut self, output: ExtruderOutput) -> Result<(), String> {
        let _ = output;
        Err(format!("{} carries no extruder output in the robot's packet", Self::NAME))
    }

    /// Whether the answers carry the extruder's command ([`RobotProtocol::set_extruder_output`]).
    fn wants_extruder(&self) -> bool {
        false
    }

    /// The extruder's command for the next answer: the service's newest, or None to stop the
    /// extruder (the answer holds the robot).
    fn set_extruder(&mut self, command: Option<&strand_wire::ExtruderCommand>) {
        let _ = command;
    }
}

/// How an extruder's command goes out as a robot's own outputs: an analog value (volts) from the
/// volumetric flow, and a digital enable while material is deposited.
#[derive(Clone, Debug, PartialEq)]
pub struct ExtruderOutput {
    /// The protocol's name of the analog value (RSI: a RECEIVE tag, `Element.Attribute` or
    /// `Element`).
    pub tag: String,
    /// The protocol's name of the enable (1 while extruding, else 0); empty: none.
    pub enable_tag: String,
    /// Volts per mm³/s of volumetric flow (V·s/mm³).
    pub volts_per_flow: f64,
    /// Volts at no flow (V).
    pub volts_offset: f64,
    /// The lowest and highest volts sent (V).
    pub volts_min: f64,
    /// See `volts_min` (V).
    pub volts_max: f64,
}

impl ExtruderOutput {
    /// The analog value (V) and the enable for `command` (None: stopped: the offset, clamped, and
    /// disabled). A retraction (negative flow) clamps to `volts_min`.
    pub fn signal(&self, command: Option<&strand_wire::ExtruderCommand>) -> (f64, bool) {
        let flow = command.map_or(0.0, |c| c.volumetric_rate * 1e9);
        let flow = if flow.is_finite() { flow } else { 0.0 };
        let on = command.is_some_and(|c| c.flags & strand_wire::extruder_flags::EXTRUDING != 0) && flow > 0.0;
        ((self.volts_offset + self.volts_per_flow * flow).clamp(self.volts_min, self.volts_max), on)
    }
}

/// The channel of a mechanical unit that streams apart from the robot (ABB MultiMove: a positioner
/// in its own motion task has its own EGM channel on its own UDP port) though one command drives
/// both. The robot's channel keeps the cycle: the driver feeds this channel's packets to it as
/// they come, the robot channel's [`RobotProtocol::read`] merges the unit's newest measured axes
/// into the robot's packet (not following while the unit is silent or not following), and its
/// [`RobotProtocol::write`] keeps the unit's share of the command for [`UnitChannel::unit_write`].
pub trait UnitChannel {
    /// Reads one of the unit's packets: its measured axes and state, for the robot's next read.
    /// False: a packet older than one already taken (out of order, a duplicate), dropped.
    fn unit_read(&mut self, packet: &[u8]) -> Result<bool, PacketError>;

    /// Writes into `out` (cleared first) the answer to the unit's newest packet: its share of the
    /// last command written to the robot, or — until the robot follows, and after the unit was
    /// silent — where the unit is.
    fn unit_write(&mut self, out: &mut Vec<u8>);

    /// Whether the unit's newest packet came within the robot's last two cycles (counted in the
    /// robot's packets, not in time, so that a replay decides the same).
    fn unit_fresh(&self) -> bool;
}
