//! The driver process's loop: the robot's UDP socket on one side, the service's ports on the other,
//! a [`Session`] deciding. Each robot packet is stamped on receipt (`CLOCK_MONOTONIC`), published as
//! the JointState that clocks the service (the service runs on the robot clock at the robot's
//! period), and answered with the service's JointCommand for that state — or a hold, if the
//! command is not there by the reply deadline. A fault latched by the session is told to the
//! service as an emergency stop. Ctrl-C (or SIGTERM) holds the robot and keeps answering until it
//! is at rest, then exits. External axes on a channel of their own (EGM MultiMove,
//! `[driver] external_axes_bind`) have a socket of their own beside the robot's ([`UnitLink`]).

use std::net::{SocketAddr, UdpSocket};
use std::os::fd::AsRawFd;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use strand::io::clock::monotonic_ns;
use strand::io::histogram::Histogram;
use strand_ipc::ports::{ClientPorts, ClientRoles};
use strand_ipc::{Command, Control, JointCommand, JointState, ServiceNames};

use crate::protocol::{Channel, Clock, RobotProtocol};
use crate::session::{Counters, DriverState, Due, ReplyKind, Session, Transition};
use crate::unit_link::{UnitCounters, UnitLink, readable};

/// How the bridge runs.
#[derive(Clone, Debug)]
pub struct BridgeOptions {
    /// The address to listen on for the robot.
    pub bind: SocketAddr,
    /// The service prefix.
    pub prefix: String,
    /// The robot's cycle (s): the JointState velocity is measured over it, and the shut-down hold
    /// lasts until the robot has been at rest for a few of them.
    pub period: f64,
    /// Stop after this many packets (0: never; for tests and benchmarks).
    pub max_packets: u64,
    /// Where the external axes' own channel listens (`[driver] external_axes_bind`), when the
    /// protocol carries them on one ([`RobotProtocol::split_unit_channel`]).
    pub unit_bind: Option<SocketAddr>,
}

/// Packets taken from the socket at most, per robot packet, to find the newest.
const MAX_DRAIN: usize = 16;

/// What a run did.
#[derive(Clone, Debug, serde::Serialize)]
pub struct BridgeReport {
    /// The session's counters.
    pub counters: Counters,
    /// Packets skipped because a newer one was already queued behind them.
    pub stale: u64,
    /// Receive → reply latency of the answers (ns).
    #[serde(skip)]
    pub latency: Histogram,
    /// The state at the end.
    pub final_state: String,
    /// The external axes' own channel, if they have one.
    pub unit: Option<UnitCounters>,
}

/// A bridge failure before it could run.
#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    /// The UDP socket.
    #[error("{address}: {source}")]
    Socket {
        /// The address it tried.
        address: SocketAddr,
        /// What the system said.
        source: std::io::Error,
    },
    /// The service's ports.
    #[error(transparent)]
    Ports(#[from] strand_ipc::ports::PortError),
}

pub(crate) fn log_transition(name: &str, t: Transition, why: &str) {
    eprintln!("strand-{name}: {:?} → {:?}{why}", t.from, t.to);
}

/// Runs the bridge until `stop` is set (then holds the robot to rest and returns).
pub fn run<P: RobotProtocol>(session: &mut Session<P>, opts: &BridgeOptions, stop: &AtomicBool) -> Result<BridgeReport, BridgeError> {
    // A datagram robot sends first and servos to the newest answer: it clocks the cycle.
    const { assert!(matches!(P::CLOCK, Clock::Robot), "the UDP bridge serves robots that clock the cycle") };
    const { assert!(matches!(P::CHANNEL, Channel::Datagram), "the UDP bridge reads one packet per datagram") };
    let name = P::NAME;
    let socket = UdpSocket::bind(opts.bind).map_err(|source| BridgeError::Socket { address: opts.bind, source })?;
    let local = socket.local_addr().map_err(|source| BridgeError::Socket { address: opts.bind, source })?;
    socket.set_read_timeout(Some(Duration::from_millis(100))).map_err(|source| BridgeError::Socket { address: local, source })?;
    let ports = ClientPorts::open(
        &ServiceNames::new(&opts.prefix),
        &format!("strand-{name}"),
        ClientRoles { driver: true, feeder: true, monitor: session.protocol_mut().wants_extruder(), ..Default::default() },
    )?;
    let mut unit = match opts.unit_bind {
        Some(bind) if session.protocol_mut().unit_channel().is_some() => {
            let deadline_ns = (session.rules().reply_deadline * 1e9) as u64;
            let link = UnitLink::bind(bind, deadline_ns).map_err(|source| BridgeError::Socket { address: bind, source })?;
            let at = link.local_addr().map_err(|source| BridgeError::Socket { address: bind, source })?;
            eprintln!("strand-{name}: the external axes' own channel on {at}");
            Some(link)
        }
        _ => None,
    };
    eprintln!("strand-{name}: listening on {local}, service {}", opts.prefix);
    let mut buf = vec![0u8; 65536];
    let mut spare = vec![0u8; 65536];
    let mut stale = 0u64;
    let mut reply = Vec::with_capacity(1024);
    let mut latency = Histogram::new();
    let period_ns = (opts.period * 1e9) as u64;
    let mut previous_q: Option<[f64; strand_ipc::MAX_JOINTS]> = None;
    let mut control_seq = 0u64;
    let mut last_state_seq = 0u64;
    let mut clamps_logged = 0u64;
    let mut logged_drops = 0u64;
    loop {
        if stop.load(Ordering::Relaxed) && session.request_stop(monotonic_ns()) {
            eprintln!("strand-{name}: stop requested: holding the robot");
        }
        match session.poll(monotonic_ns()) {
            Due::StopDone => break,
            // The robot went quiet: its session is over (a new one gets a new reference).
            Due::SessionEnded(t) => {
                log_transition(name, t, " (no packet from the robot: its session ended)");
                previous_q = None;
            }
            // Every accepted packet is answered in its own pass of this loop, by its deadline.
            Due::Reply | Due::Nothing => {}
        }
        if let Some(u) = &mut unit {
            // Both channels at once: the unit's packets are taken as they come, and one whose
            // robot packet does not come is answered at its deadline.
            let now = monotonic_ns();
            let wait = u.due_at().map_or(100_000_000, |due| due.saturating_sub(now)).min(100_000_000);
            let mut ready = [false; 2];
            readable(&[socket.as_raw_fd(), u.fd()], wait, &mut ready);
            if ready[1] {
                u.take_packets(session, monotonic_ns());
            }
            u.answer_if_due(session, monotonic_ns());
            if !ready[0] {
                continue;
            }
        }
        let (n, from) = match socket.recv_from(&mut buf) {
            Ok(x) => x,
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => continue,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => {
                eprintln!("strand-{name}: receive: {e}");
                continue;
            }
        };
        // Only the newest packet matters: an answer to an older one would reach the robot after
        // its cycle. Packets queued behind a slow cycle are skipped (counted) to catch up.
        // Packets from anybody else go to the session to be refused and counted, so that no
        // other sender can push the robot's packet out.
        let (mut n, mut from) = (n, from);
        // Drain only once the robot is known (before, the first packet decides who it is), and at
        // most a few packets: a flood from elsewhere must not keep the robot's answer waiting.
        if session.is_robot(from) == Some(true) && socket.set_nonblocking(true).is_ok() {
            let mut drained = 0;
            while drained < MAX_DRAIN
                && let Ok((m, f)) = socket.recv_from(&mut spare)
            {
                drained += 1;
                if session.is_robot(f) == Some(true) {
                    // The robot's newer packet replaces the one in hand, which is stale.
                    stale += 1;
                    std::mem::swap(&mut buf, &mut spare);
                    (n, from) = (m, f);
                } else if let Err(dropped) = session.on_packet(&spare[..m], f) {
                    // Another sender's: refused and counted by the session.
                    logged_drops += 1;
                    if logged_drops <= 10 {
                        eprintln!("strand-{name}: dropped a packet: {dropped}");
                    }
                }
            }
            let _ = socket.set_nonblocking(false);
        }
        let received = monotonic_ns();
        if let Some(u) = &mut unit {
            // The unit's packet of this cycle, for the axes the service is told.
            u.catch_up(session, received, period_ns, period_ns.min((session.rules().reply_deadline * 1e9) as u64) / 4);
        }
        let (seq, q, transition) = match session.on_packet_at(received, &buf[..n], from) {
            Ok(x) => x,
            Err(dropped) => {
                logged_drops += 1;
                if logged_drops <= 10 {
                    eprintln!("strand-{name}: dropped a packet: {dropped}");
                }
                continue;
            }
        };
        if let Some(t) = transition {
            log_transition(name, t, &format!(" (robot at {from})"));
        }
        if let Some(news) = session.take_news() {
            eprintln!("strand-{name}: robot: {news}");
        }
        // With what the robot was last told, and whether it held: the service plans again from
        // there where it can.
        let state = joint_state(session, seq, received, q, &mut previous_q, opts.period);
        // Held (after a fault, or shutting down): answer the robot first, so that nothing the
        // service's side costs (a dead service's clean-up in iceoryx2 takes milliseconds) can
        // make the hold late; then see whether the service answers again.
        let held = session.stopping() || session.state() == DriverState::HeldAfterFault;
        let (kind, transition) = if held {
            let r = session.reply_hold(&mut reply);
            answer(&socket, &reply, from, received, period_ns, &mut latency, session);
            let transition = if !session.stopping() {
                // Did the service answer the last state within its cycle? (No waiting here: the
                // robot's next packet must find the driver ready.)
                let mut answered = false;
                while let Ok(Some(c)) = ports.receive_joint_command() {
                    answered |= answers(&c, last_state_seq, session.dof()) && c.valid == 1;
                }
                let _ = ports.send_joint_state(&state);
                last_state_seq = seq;
                session.note_service(answered)
            } else {
                None
            };
            (r.0, transition)
        } else if !session.robot_following() {
            // The robot does not follow corrections yet (EGM before MCI_RUNNING): hold it where it
            // is, and do not clock the service — its commands would run ahead of a robot that
            // ignores them.
            let r = session.reply_hold(&mut reply);
            answer(&socket, &reply, from, received, period_ns, &mut latency, session);
            r
        } else {
            let _ = ports.send_joint_state(&state);
            last_state_seq = seq;
            let command = wait_command(&ports, seq, session.dof(), session.reply_deadline().unwrap_or(received));
            if session.protocol_mut().wants_extruder() {
                // The extruder's command of the same tick: the service publishes it just after the
                // joints' (microseconds); waited for up to 0.1 ms within the deadline, else the
                // newest there is (the last tick's).
                let tick = command.as_ref().map(|c| c.tick);
                let until = (monotonic_ns() + 100_000).min(session.reply_deadline().unwrap_or(0));
                let mut newest = None;
                loop {
                    while let Ok(Some(e)) = ports.receive_extruder_command() {
                        newest = Some(e);
                    }
                    let current = tick.is_none_or(|t| newest.is_some_and(|e: strand_ipc::ExtruderCommand| e.tick >= t));
                    if current || monotonic_ns() >= until {
                        break;
                    }
                    std::thread::sleep(Duration::from_micros(5));
                }
                if newest.is_some() {
                    session.protocol_mut().set_extruder(newest.as_ref());
                }
            }
            let r = session.reply(command.as_ref(), &mut reply);
            answer(&socket, &reply, from, received, period_ns, &mut latency, session);
            r
        };
        if let Some(u) = &mut unit {
            // The unit's share of the same answer.
            u.answer(session, true);
        }
        if let Some(t) = transition {
            let why = if t.to == DriverState::HeldAfterFault {
                format!(
                    " ({} commands in a row missed the {} ms deadline: holding, and telling the service)",
                    session.late_run(),
                    session.rules().reply_deadline * 1e3
                )
            } else {
                String::new()
            };
            let why = if t.to == DriverState::Following && t.from == DriverState::HeldAfterFault {
                " (the service answers in time again)".to_string()
            } else {
                why
            };
            log_transition(name, t, &why);
            if t.to == DriverState::HeldAfterFault {
                control_seq += 1;
                let estop = Control {
                    seq: control_seq,
                    stamp_ns: monotonic_ns(),
                    command: Command::EmergencyStop as u32,
                    value: 0.0,
                    _reserved: 0,
                };
                let _ = ports.send_control(&estop);
            }
        }
        let clamped = session.counters.clamped;
        if kind == ReplyKind::Command && clamped > clamps_logged && clamped.is_power_of_two() {
            clamps_logged = clamped;
            eprintln!(
                "strand-{name}: warning: {} answers clamped to the joint limits so far (last: joint {})",
                session.counters.clamped,
                session.guard().last_clamped_joint.map_or(0, |j| j + 1)
            );
        }
        if opts.max_packets > 0 && session.counters.packets >= opts.max_packets {
            break;
        }
    }
    Ok(BridgeReport {
        counters: session.counters,
        stale,
        latency,
        final_state: format!("{:?}", session.state()),
        unit: unit.map(|u| u.counters),
    })
}

/// The JointState for an accepted packet: the measured joints stamped on receipt, with what the
/// robot was last told and whether it held (the service plans again from there where it can), and
/// the velocity over the robot's own period (the receive times carry the network's jitter).
pub(crate) fn joint_state<P: RobotProtocol>(
    session: &mut Session<P>,
    seq: u64,
    received: u64,
    q: [f64; strand_ipc::MAX_JOINTS],
    previous_q: &mut Option<[f64; strand_ipc::MAX_JOINTS]>,
    period: f64,
) -> JointState {
    let told = session.robot_report();
    let mut state = JointState {
        seq,
        stamp_ns: received,
        dof: session.dof() as u32,
        flags: told.flags,
        position: q,
        robot_target: told.target,
        robot_target_velocity: told.target_velocity,
        ..Default::default()
    };
    if let Some(p) = previous_q {
        for k in 0..state.dof as usize {
            state.velocity[k] = (q[k] - p[k]) / period;
        }
    }
    *previous_q = Some(q);
    state
}

/// Sends `reply` to the robot at `from` and records how long after the packet's receipt it left;
/// an answer that left after the robot's cycle is told to the session (the robot may have thrown
/// it away).
fn answer<P: RobotProtocol>(
    socket: &UdpSocket,
    reply: &[u8],
    from: SocketAddr,
    received: u64,
    period_ns: u64,
    latency: &mut Histogram,
    session: &mut Session<P>,
) {
    if !reply.is_empty() {
        let _ = socket.send_to(reply, from);
    }
    let took = monotonic_ns() - received;
    latency.record(took);
    if took > period_ns {
        session.answer_missed_its_cycle();
    }
}

/// Whether `cmd` answers state `seq` of a cell of `dof` joints (the arm's and its external axes').
/// A command for another count of joints (a service run with another robot file) answers nothing:
/// its missing joints would read as 0 and move the robot there. It is said once, and the driver
/// holds as for a late command (then faults, and the service is told).
pub(crate) fn answers(cmd: &JointCommand, seq: u64, dof: usize) -> bool {
    static SAID: AtomicBool = AtomicBool::new(false);
    if cmd.dof as usize != dof {
        if !SAID.swap(true, Ordering::Relaxed) {
            eprintln!(
                "strand-driver: the service commands {} joints and this cell has {dof} (the arm's and its external axes'): its commands are not taken; do the service and the driver load the same robot file?",
                cmd.dof
            );
        }
        return false;
    }
    cmd.state_seq == seq
}

/// The command answering state `seq` of a cell of `dof` joints, if it comes by `deadline_ns`
/// (older ones are drained).
///
/// It polls with short high-resolution sleeps instead of blocking on the command's event: that
/// wait is a socket receive timeout, which the kernel counts in scheduler ticks (4 ms at HZ=250),
/// so a late command would make the hold miss the robot's cycle. The service answers in tens of
/// microseconds, so the polling is short.
pub(crate) fn wait_command(ports: &ClientPorts, seq: u64, dof: usize, deadline_ns: u64) -> Option<JointCommand> {
    loop {
        while let Ok(Some(cmd)) = ports.receive_joint_command() {
            if answers(&cmd, seq, dof) {
                return Some(cmd);
            }
        }
        let now = monotonic_ns();
        if now >= deadline_ns {
            return None;
        }
        std::thread::sleep(Duration::from_nanos((deadline_ns - now).min(20_000)));
    }
}
