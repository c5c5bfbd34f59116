//! One robot connection as a state machine, without I/O (the quinn-proto way): the bridge hands it
//! each packet and the service's command, and it says what to publish and what to answer. It owns
//! the rules the issue of a real cell needs —
//!
//! - only one sender (the configured robot, or the first one seen); every other packet, and every
//!   malformed, oversized, out-of-order or duplicate one, is counted and dropped;
//! - before the service's first valid command, and whenever the robot does not follow corrections
//!   (EGM before `MCI_RUNNING`), the answer holds the measured position;
//! - a command not there by the reply deadline is answered with a hold (the last target, braked
//!   within the acceleration limit); `max_late_cycles` of them in a row latch the hold and raise a
//!   fault for the service (the bridge sends an emergency stop); after `recover_cycles` in time the
//!   driver follows again, from where it holds;
//! - every answer passes the [`ReplyGuard`]: inside the joint limits, no jump;
//! - every deadline, given `now` ([`Session::poll`], [`Session::poll_timeout`]): the answer to a
//!   packet received at `now` is due by `now + reply_deadline` ([`Session::reply_deadline`]: the
//!   loop waits for the service's command until then, and answers with a hold after it); a robot
//!   silent for [`SILENT_CYCLES`] ends its session; a requested stop holds the robot until it is at
//!   rest.

use std::net::SocketAddr;

use crate::RobotAddress;
use strand_wire::{JointCommand, MAX_JOINTS, joint_state_flags};

use crate::axes::AxisMap;
use crate::guard::ReplyGuard;
use crate::protocol::{PacketError, RobotPacket, RobotProtocol};

/// How far outside its limits a joint may be at the start (rad): encoder noise and rounding, not a
/// wrong mapping (0.5°).
const START_LIMIT_TOLERANCE: f64 = 0.0087;

/// Cycles without an accepted packet after which the robot's session is over (RSI off, EGM
/// stopped, a restart): the next packet starts a new one.
pub(crate) const SILENT_CYCLES: f64 = 25.0;

/// Polls in a row with the guard at rest that end a stop's hold.
const REST_POLLS_TO_STOP: u32 = 5;

/// What [`Session::poll`] found due at `now`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Due {
    /// Nothing.
    Nothing,
    /// The reply deadline of the last packet passed unanswered: answer now, with a hold
    /// ([`Session::reply`] with no command).
    Reply,
    /// The robot went quiet for [`SILENT_CYCLES`]: its session ended (the transition, for the log).
    SessionEnded(Transition),
    /// A requested stop is done: the robot is at rest (a few polls in a row), or the longest stop
    /// from full speed plus 0.5 s went by, or no robot streams.
    StopDone,
}

/// The driver's state, as its log lines name it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DriverState {
    /// No packet from the robot yet.
    WaitingForRobot,
    /// The robot streams; the answers hold it until the service commands it.
    Holding,
    /// The answers carry the service's commands.
    Following,
    /// Too many late commands: the answers hold, and the service was told (a fault).
    HeldAfterFault,
}

/// What happened to a packet the session dropped.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum Dropped {
    /// From a sender other than the robot.
    #[error("from {0}, not the robot")]
    Foreign(SocketAddr),
    /// Not a packet of the protocol.
    #[error(transparent)]
    Packet(#[from] PacketError),
    /// Its sequence is not above the last one's.
    #[error("sequence {seq} after {last}: {}", if seq == last { "a duplicate" } else { "out of order" })]
    Order {
        /// Its sequence.
        seq: u64,
        /// The last accepted sequence.
        last: u64,
    },
    /// The robot's first packet puts a joint outside its URDF limits: a wrong `[driver]` axis
    /// mapping or a wrong robot config. Nothing is answered.
    #[error(
        "joint {joint} at {value:.4} (rad or m) lies outside its limits at the start: check [driver] axis_sign and axis_offset, and the robot"
    )]
    OutsideLimits {
        /// The joint (1-based, chain order).
        joint: usize,
        /// Its position (rad or m).
        value: f64,
    },
    /// More axes than the robot has, or fewer.
    #[error("{got} axes; the robot has {want}")]
    Axes {
        /// In the packet.
        got: usize,
        /// The robot's joints.
        want: usize,
    },
}

/// Counters of one session (since start).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Counters {
    /// Packets accepted.
    pub packets: u64,
    /// Answers sent.
    pub replies: u64,
    /// Answers that carried the service's command for that packet.
    pub in_time: u64,
    /// Answers that held because the command was not there by the deadline.
    pub late: u64,
    /// Answers that held for another reason (before the first command, robot not following,
    /// latched after a fault, an invalid command).
    pub held: u64,
    /// Answers the guard had to clamp.
    pub clamped: u64,
    /// Faults raised (latched holds).
    pub faults: u64,
    /// Answers sent after the robot's cycle had ended (the robot discarded or delayed them).
    pub missed_cycle: u64,
    /// Robot cycles that went by without an answer the driver knew of (their packets lost, or
    /// skipped because a newer one was queued: the robot held its target through them), and
    /// ticks the driver's own loop lapsed where it clocks the cycle
    /// ([`Session::driver_lapsed`]).
    pub lost_cycles: u64,
    /// Service ticks owed to a robot that ran on through a lapse of the driver's loop, and run.
    pub owed_ticks: u64,
    /// Packets dropped: from another sender.
    pub foreign: u64,
    /// Packets dropped: malformed, truncated, a bad value, or the wrong number of axes.
    pub malformed: u64,
    /// Packets dropped: the robot's first packets, with a joint outside its limits.
    pub outside_limits: u64,
    /// Packets dropped: oversized.
    pub oversized: u64,
    /// Packets dropped: a duplicate sequence.
    pub duplicate: u64,
    /// Packets dropped: out of order.
    pub out_of_order: u64,
    /// Errors the robot answered that stopped it (the stream ended).
    pub robot_errors: u64,
}

/// What [`Session::reply`] decided.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReplyKind {
    /// The service's command, in time.
    Command,
    /// A hold: the command was late.
    Late,
    /// A hold for another reason.
    Hold,
}

/// A change of state for the log, and whether the service must be told of a fault.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Transition {
    /// From.
    pub from: DriverState,
    /// To.
    pub to: DriverState,
}

/// The rules of [`Session`] (from `[driver]`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SessionRules {
    /// The only sender accepted (None: the first one).
    pub robot: Option<RobotAddress>,
    /// Late answers in a row that latch the hold and raise a fault.
    pub max_late_cycles: u32,
    /// Answers in time in a row that release a latched hold.
    pub recover_cycles: u32,
    /// After a packet arrives, the longest wait for the service's command before the answer
    /// holds instead (s; `[driver] reply_deadline`).
    pub reply_deadline: f64,
}

/// One robot connection.
pub struct Session<P: RobotProtocol> {
    protocol: P,
    map: AxisMap,
    guard: ReplyGuard,
    rules: SessionRules,
    sender: Option<SocketAddr>,
    last_seq: Option<u64>,
    state: DriverState,
    late_run: u32,
    good_run: u32,
    current: Option<RobotPacket>,
    /// The robot kept its target through a cycle or more since the last [`Session::robot_report`].
    held: bool,
    /// When a packet was last accepted (ns, the caller's monotonic clock).
    last_accepted_ns: Option<u64>,
    /// A stop requested (when, ns) and the polls in a row at rest since.
    stop: Option<(u64, u32)>,
    /// When the answer to the last packet is due (ns), until it is sent.
    reply_due: Option<u64>,
    /// Service ticks owed for the last packet ([`Session::driver_lapsed`]).
    owed: u64,
    /// Counters since start.
    pub counters: Counters,
}

/// What the driver last told the robot, for the JointState that clocks the service
/// (`JointState::flags`, `robot_target`, `robot_target_velocity`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobotReport {
    /// `strand_wire::joint_state_flags` bits.
    pub flags: u32,
    /// The target the robot holds (joint space, rad or m).
    pub target: [f64; MAX_JOINTS],
    /// Its velocity (rad/s or m/s).
    pub target_velocity: [f64; MAX_JOINTS],
}

impl<P: RobotProtocol> Session<P> {
    /// A session speaking `protocol`, mapping axes with `map`, guarding answers with `guard`.
    pub fn new(protocol: P, map: AxisMap, guard: ReplyGuard, rules: SessionRules) -> Self {
        Session {
            protocol,
            map,
            guard,
            rules,
            sender: None,
            last_seq: None,
            state: DriverState::WaitingForRobot,
            late_run: 0,
            good_run: 0,
            current: None,
            held: false,
            last_accepted_ns: None,
            stop: None,
            reply_due: None,
            owed: 0,
            counters: Counters::default(),
        }
    }

    /// Takes a packet as [`Session::on_packet`] does, received at `now_ns` (monotonic): an
    /// accepted one restarts the silence [`Session::poll`] watches, and its answer is due by
    /// `now_ns` + the reply deadline ([`Session::reply_deadline`]).
    pub fn on_packet_at(
        &mut self,
        now_ns: u64,
        bytes: &[u8],
        from: SocketAddr,
    ) -> Result<(u64, [f64; MAX_JOINTS], Option<Transition>), Dropped> {
        let r = self.on_packet(bytes, from);
        if r.is_ok() {
            self.last_accepted_ns = Some(now_ns);
            self.reply_due = Some(now_ns + (self.rules.reply_deadline.max(0.0) * 1e9) as u64);
        }
        r
    }

    /// When the answer to the last packet taken by [`Session::on_packet_at`] is due (ns, the
    /// caller's monotonic clock), until it is sent: the loop waits for the service's command until
    /// then, and answers with a hold after it.
    pub fn reply_deadline(&self) -> Option<u64> {
        self.reply_due
    }

    /// A stop was asked for at `now_ns` (Ctrl-C): from now on every answer holds, until
    /// [`Session::poll`] says [`Due::StopDone`]. True the first time.
    pub fn request_stop(&mut self, now_ns: u64) -> bool {
        if self.stop.is_some() {
            return false;
        }
        self.stop = Some((now_ns, 0));
        true
    }

    /// Whether a stop was asked for.
    pub fn stopping(&self) -> bool {
        self.stop.is_some()
    }

    /// The deadlines the session owns, at `now_ns`: the last packet's reply deadline
    /// ([`Due::Reply`]), the robot's silence (its session ends after [`SILENT_CYCLES`]), and a
    /// requested stop's hold (done when the guard's target has been at
    /// rest for a few polls — the loops poll once a cycle — or after the slowest joint's stop from
    /// full speed plus 0.5 s). Call it once per cycle, and when a wait for the robot times out.
    pub fn poll(&mut self, now_ns: u64) -> Due {
        if self.reply_due.is_some_and(|due| now_ns >= due) {
            return Due::Reply;
        }
        if let Some((since, rest)) = self.stop {
            let rest = if self.guard.at_rest() { rest + 1 } else { 0 };
            self.stop = Some((since, rest));
            let cap = ((self.guard.longest_stop() + 0.5) * 1e9) as u64;
            if rest > REST_POLLS_TO_STOP || now_ns.saturating_sub(since) > cap || self.state == DriverState::WaitingForRobot {
                return Due::StopDone;
            }
        }
        let silent_ns = (SILENT_CYCLES * self.guard.period() * 1e9) as u64;
        if self.state != DriverState::WaitingForRobot
            && self.last_accepted_ns.is_some_and(|t| now_ns.saturating_sub(t) > silent_ns)
            && let Some(t) = self.reset()
        {
            return Due::SessionEnded(t);
        }
        Due::Nothing
    }

    /// The next instant (ns) [`Session::poll`] may have something due without a packet: the
    /// robot's silence limit, or a stop's cap. None: nothing pending.
    pub fn poll_timeout(&self) -> Option<u64> {
        let silence = (self.state != DriverState::WaitingForRobot)
            .then_some(self.last_accepted_ns)
            .flatten()
            .map(|t| t + (SILENT_CYCLES * self.guard.period() * 1e9) as u64);
        let stop = self.stop.map(|(since, _)| since + ((self.guard.longest_stop() + 0.5) * 1e9) as u64);
        [silence, stop, self.reply_due].into_iter().flatten().min()
    }

    /// Its state.
    pub fn state(&self) -> DriverState {
        self.state
    }

    /// The robot's address (once a packet was accepted).
    pub fn sender(&self) -> Option<SocketAddr> {
        self.sender
    }

    /// The robot's joints.
    pub fn dof(&self) -> usize {
        self.map.dof()
    }

    /// A hold from the guard, or (before the guard has a target) the measured joints.
    fn hold_or_measured(&mut self, packet: &RobotPacket) -> [f64; MAX_JOINTS] {
        let measured = self.map.joints_from_axes(&packet.axes[..packet.dof]);
        self.guard.hold().unwrap_or(measured)
    }

    /// Whether `from` is the robot: the configured address, or the sender accepted first (None:
    /// not known yet — nothing configured, no packet accepted).
    pub fn is_robot(&self, from: SocketAddr) -> Option<bool> {
        match (self.rules.robot, self.sender) {
            (Some(robot), _) => Some(robot.matches(from)),
            (None, Some(first)) => Some(first == from),
            (None, None) => None,
        }
    }

    /// Ends the connection (the robot stopped streaming: RSI off, EGM stopped, a controller
    /// restart): the next packet starts a new one — new reference, new sequence, new sender if
    /// none is configured — and the robot is held until the service commands it again.
    pub fn reset(&mut self) -> Option<Transition> {
        self.protocol.reset();
        self.sender = None;
        self.last_seq = None;
        self.current = None;
        self.last_accepted_ns = None;
        self.reply_due = None;
        self.owed = 0;
        self.late_run = 0;
        self.good_run = 0;
        self.enter(DriverState::WaitingForRobot)
    }

    /// Whether the robot follows corrections now (the last accepted packet says so).
    pub fn robot_following(&self) -> bool {
        self.current.is_some_and(|p| p.following)
    }

    /// The rules it keeps.
    pub fn rules(&self) -> &SessionRules {
        &self.rules
    }

    /// Late answers in a row so far.
    pub fn late_run(&self) -> u32 {
        self.late_run
    }

    /// Answers the last accepted packet with a hold, whatever the service says (shutting down).
    pub fn reply_hold(&mut self, out: &mut Vec<u8>) -> (ReplyKind, Option<Transition>) {
        let Some(packet) = self.current else {
            out.clear();
            return (ReplyKind::Hold, None);
        };
        let q = self.hold_or_measured(&packet);
        let axes = self.map.axes_from_joints(&q[..self.map.dof()]);
        // A held robot deposits nothing.
        self.protocol.set_extruder(None);
        self.protocol.write(&axes[..packet.dof], out);
        self.counters.held += 1;
        self.counters.replies += 1;
        self.held = true;
        self.reply_due = None;
        (ReplyKind::Hold, None)
    }

    /// After a hold was sent while [`DriverState::HeldAfterFault`]: whether the service answered
    /// this packet in time. `recover_cycles` in a row release the hold.
    pub fn note_service(&mut self, in_time: bool) -> Option<Transition> {
        if self.state != DriverState::HeldAfterFault {
            return None;
        }
        if !in_time {
            self.good_run = 0;
            return None;
        }
        self.good_run += 1;
        if self.good_run >= self.rules.recover_cycles {
            self.late_run = 0;
            return self.enter(DriverState::Following);
        }
        None
    }

    /// The driver's own loop lapsed `cycles` ticks before the packet just taken (its process
    /// stalled). Only a driver that clocks the cycle sees this ([`crate::protocol::Clock::Driver`]):
    /// the robot's state was there for ticks the driver did not run. A robot that runs on at its
    /// last command (the Meca500 keeps its last velocity, [`RobotProtocol::runs_on_for`]) went on
    /// along the path through them, up to that long: the service owes it those ticks
    /// ([`Session::take_owed_ticks`]), lest the arm stand ahead of the service's path and the next
    /// commands pull it back — if it was following the service's commands; one that was held ran
    /// on at a hold. A robot that runs its buffered commands (b-CAP) owes nothing. Counted in
    /// `lost_cycles`.
    pub fn driver_lapsed(&mut self, cycles: u64) {
        self.counters.lost_cycles += cycles;
        let ran_on = (self.protocol.runs_on_for() / self.guard.period() + 1e-9).floor() as u64;
        self.owed = if self.state == DriverState::Following { cycles.min(ran_on) } else { 0 };
    }

    /// The service ticks owed for the packet just taken, once: the loop publishes a JointState
    /// for each (the robot's motion spread over them, stamped a cycle apart before this one), and
    /// passes each command to [`Session::reply`] without sending its answer — the robot is past
    /// it; only the answer to the packet itself goes out. Counted in `owed_ticks`.
    pub fn take_owed_ticks(&mut self) -> u64 {
        let owed = std::mem::take(&mut self.owed);
        self.counters.owed_ticks += owed;
        owed
    }

    /// Where the robot was at owed tick `tick` (1..=`owed`) of the lapse that ended with it at
    /// `to`, from `from` at the last state published before the lapse (rad or m): the motion spread
    /// evenly over the lapse, as a robot running on at one velocity makes it.
    pub fn owed_position(&self, from: &[f64; MAX_JOINTS], to: &[f64; MAX_JOINTS], tick: u64, owed: u64) -> [f64; MAX_JOINTS] {
        let f = tick as f64 / (owed + 1) as f64;
        let mut q = *to;
        for k in 0..self.map.dof() {
            q[k] = from[k] + f * (to[k] - from[k]);
        }
        q
    }

    /// Takes an owed tick's command ([`Session::take_owed_ticks`]) through the guard as any
    /// answer — the robot ran on along it — writing its answer into `out`, which is not sent: the
    /// answer to the packet is still due. An owed command that did not come in time (the loop
    /// waits for it no longer than the packet's reply deadline) is skipped, not counted late:
    /// the robot is past that tick, and only the packet's own answer can leave it without one.
    pub fn reply_owed(&mut self, command: Option<&JointCommand>, out: &mut Vec<u8>) -> (ReplyKind, Option<Transition>) {
        let Some(command) = command else {
            out.clear();
            return (ReplyKind::Late, None);
        };
        let command = Some(command);
        let due = self.reply_due;
        let answered = self.current.is_some();
        let r = self.reply(command, out);
        if answered {
            self.counters.replies -= 1;
        }
        self.reply_due = due;
        r
    }

    /// The last answer left after the robot's cycle (the bridge measured it): the robot stood at
    /// its previous target that cycle, so the guard forgets the answer, and the next one catches
    /// up from where the robot really is, at rest. That holds whether the protocol's robot throws
    /// the late answer away (RSI) or would take it a cycle late (EGM): by then the answer to the
    /// next packet, stepping from the held target, is the newest, and the robot takes the newest.
    /// Counted in `missed_cycle`.
    pub fn answer_missed_its_cycle(&mut self) {
        self.counters.missed_cycle += 1;
        self.guard.take_back();
        self.held = true;
    }

    /// What the robot was last told, and whether it kept its target through a cycle since the
    /// last report (a late, held, missed or lost answer): the service, told, plans again from
    /// there where it can (the approach). Takes the `HELD` bit.
    pub fn robot_report(&mut self) -> RobotReport {
        let mut r = RobotReport { flags: 0, target: [0.0; MAX_JOINTS], target_velocity: [0.0; MAX_JOINTS] };
        if let Some(last) = self.guard.last() {
            r.flags |= joint_state_flags::TARGET_KNOWN;
            r.target = *last;
            r.target_velocity = *self.guard.velocity();
            if std::mem::take(&mut self.held) {
                r.flags |= joint_state_flags::HELD;
            }
            if self.guard.catching_up() {
                r.flags |= joint_state_flags::CATCHING_UP;
            }
        }
        r
    }

    /// A speed scaling the robot reported ([`RobotProtocol::take_speed_scaling`]).
    pub fn take_speed_scaling(&mut self) -> Option<f64> {
        self.protocol.take_speed_scaling()
    }

    /// A change the robot reported, for the log ([`RobotProtocol::take_news`]).
    pub fn take_news(&mut self) -> Option<String> {
        self.protocol.take_news()
    }

    /// The protocol (a driver that connects sets it up: b-CAP's robot handle).
    pub fn protocol_mut(&mut self) -> &mut P {
        &mut self.protocol
    }

    /// The guard (its clamp count and last clamped joint, for the log).
    pub fn guard(&self) -> &ReplyGuard {
        &self.guard
    }

    /// Takes a packet from `from`: the packet's sequence and the measured joints (URDF joint space,
    /// rad or m) to publish as a JointState, or why it was dropped (counted).
    pub fn on_packet(&mut self, bytes: &[u8], from: SocketAddr) -> Result<(u64, [f64; MAX_JOINTS], Option<Transition>), Dropped> {
        let r = self.accept(bytes, from);
        match &r {
            Err(Dropped::Foreign(_)) => self.counters.foreign += 1,
            Err(Dropped::Packet(PacketError::Oversized(_))) => self.counters.oversized += 1,
            Err(Dropped::Packet(PacketError::RobotError(_))) => self.counters.robot_errors += 1,
            Err(Dropped::Packet(_) | Dropped::Axes { .. }) => self.counters.malformed += 1,
            Err(Dropped::OutsideLimits { .. }) => self.counters.outside_limits += 1,
            Err(Dropped::Order { seq, last }) if seq == last => self.counters.duplicate += 1,
            Err(Dropped::Order { .. }) => self.counters.out_of_order += 1,
            Ok(_) => self.counters.packets += 1,
        }
        r
    }

    fn accept(&mut self, bytes: &[u8], from: SocketAddr) -> Result<(u64, [f64; MAX_JOINTS], Option<Transition>), Dropped> {
        let ours = match (self.rules.robot, self.sender) {
            (Some(robot), _) => robot.matches(from),
            (None, Some(first)) => first == from,
            (None, None) => true,
        };
        if !ours {
            return Err(Dropped::Foreign(from));
        }
        if bytes.len() > P::MAX_PACKET {
            return Err(PacketError::Oversized(bytes.len()).into());
        }
        let packet = self.protocol.read(bytes)?;
        if packet.dof != self.map.dof() {
            return Err(Dropped::Axes { got: packet.dof, want: self.map.dof() });
        }
        if let Some(last) = self.last_seq
            && packet.seq <= last
        {
            return Err(Dropped::Order { seq: packet.seq, last });
        }
        let q = self.map.joints_from_axes(&packet.axes[..packet.dof]);
        if self.state == DriverState::WaitingForRobot
            && let Some(joint) = self.guard.outside_limits(&q, START_LIMIT_TOLERANCE)
        {
            // A robot that starts outside the URDF's limits is a wrong axis mapping (sign,
            // offset) or a wrong robot: following it would start with a jump to the limit.
            self.protocol.reset();
            return Err(Dropped::OutsideLimits { joint: joint + 1, value: q[joint] });
        }
        if let Some(last) = self.last_seq
            && self.state != DriverState::WaitingForRobot
        {
            let cycles = P::cycles_between(last, packet.seq, self.guard.period());
            if cycles > 1 {
                // Cycles went by without an answer (lost, or skipped behind a newer packet): the
                // robot held its target through them, so it is at rest where the last answer put
                // it; the next answer must start from rest, not go on at the old speed.
                self.counters.lost_cycles += cycles - 1;
                self.guard.robot_stood_still();
                self.held = true;
            }
        }
        self.sender.get_or_insert(from);
        self.last_seq = Some(packet.seq);
        let mut transition = None;
        if self.state == DriverState::WaitingForRobot {
            self.guard.reset(&q);
            transition = self.enter(DriverState::Holding);
        }
        if !packet.following {
            // The robot ignores corrections now: the answer is where it is, so that nothing jumps
            // when it starts following.
            self.guard.reset(&q);
        }
        self.current = Some(packet);
        Ok((packet.seq, q, transition))
    }

    fn enter(&mut self, to: DriverState) -> Option<Transition> {
        let from = self.state;
        self.state = to;
        (from != to).then_some(Transition { from, to })
    }

    /// Encodes into `out` the answer to the last accepted packet, given the service's command for
    /// it (None: not there by the deadline). The answer's kind, and a change of state if any
    /// (to [`DriverState::HeldAfterFault`]: the caller tells the service).
    pub fn reply(&mut self, command: Option<&JointCommand>, out: &mut Vec<u8>) -> (ReplyKind, Option<Transition>) {
        let Some(packet) = self.current else {
            out.clear();
            return (ReplyKind::Hold, None);
        };
        let clamps_before = self.guard.clamps;
        let mut transition = None;
        let (kind, q) = match command {
            None => {
                self.late_run += 1;
                self.good_run = 0;
                // Only a service that was commanding the robot can fail it: before its first
                // command (starting up) a late cycle is just a hold.
                if self.late_run >= self.rules.max_late_cycles && self.state == DriverState::Following {
                    self.counters.faults += 1;
                    transition = self.enter(DriverState::HeldAfterFault);
                }
                (ReplyKind::Late, self.hold_or_measured(&packet))
            }
            Some(cmd) => {
                self.late_run = 0;
                let valid = cmd.valid == 1 && cmd.position[..self.map.dof()].iter().all(|x| x.is_finite());
                match self.state {
                    _ if !packet.following || !valid => (ReplyKind::Hold, self.hold_or_measured(&packet)),
                    DriverState::HeldAfterFault => {
                        self.good_run += 1;
                        if self.good_run >= self.rules.recover_cycles {
                            transition = self.enter(DriverState::Following);
                        }
                        (ReplyKind::Hold, self.hold_or_measured(&packet))
                    }
                    _ => {
                        if self.state != DriverState::Following {
                            transition = self.enter(DriverState::Following);
                        }
                        (ReplyKind::Command, self.guard.admit(&cmd.position, &cmd.velocity))
                    }
                }
            }
        };
        // A hold: the robot did not get the service's command this cycle.
        self.held |= kind != ReplyKind::Command;
        match kind {
            ReplyKind::Command => self.counters.in_time += 1,
            ReplyKind::Late => self.counters.late += 1,
            ReplyKind::Hold => self.counters.held += 1,
        }
        if self.guard.clamps > clamps_before {
            self.counters.clamped += 1;
        }
        let axes = self.map.axes_from_joints(&q[..self.map.dof()]);
        if kind == ReplyKind::Hold {
            // A held robot deposits nothing (a late command keeps the extruder's last value, as
            // the robot keeps its last target).
            self.protocol.set_extruder(None);
        }
        self.protocol.write(&axes[..packet.dof], out);
        self.counters.replies += 1;
        self.reply_due = None;
        (kind, transition)
    }
}
