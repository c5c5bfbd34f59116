//! The driver process's loop for the interfaces the driver connects to (b-CAP's slave mode, the
//! Meca500, UR's RTDE and reverse interface): a [`DriverLink`] carries the cycle's exchange — the answer out, the
//! robot's state back — and a [`Session`] decides, as in [`crate::bridge`] for the interfaces that
//! send first. Each state the robot returns is stamped on receipt and published as the JointState
//! that clocks the service; the answer is the service's command for it, or a hold if it is not
//! there by the reply deadline. The robot is never left without an answer for its next cycle: a
//! dropped packet is answered with a hold too. An error the robot reports (it stopped) ends the
//! stream: the service is told (an emergency stop) and the caller gives the robot back. Ctrl-C holds
//! the robot to rest first.

use std::os::fd::AsRawFd;
use std::sync::atomic::{AtomicBool, Ordering};

use strand::config::Config;
use strand::config::driver::DriverConfig;
use strand::io::clock::monotonic_ns;
use strand::io::histogram::Histogram;
use strand_ipc::ports::{ClientPorts, ClientRoles};
use strand_ipc::{Command, Control, ServiceNames};

use crate::bridge::{BridgeReport, answers, joint_state, log_transition, wait_command};
use crate::protocol::{Clock, PacketError, RobotProtocol};
use crate::session::{DriverState, Dropped, Due, ReplyKind, Session};

/// Why a link failed.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum LinkError {
    /// The socket.
    #[error("{0}")]
    Io(String),
    /// The robot closed the connection.
    #[error("{0}")]
    Closed(String),
    /// The robot refused a call (the message names the call and the robot's code).
    #[error("{0}")]
    Refused(String),
    /// Setting the robot up for streaming failed (the message names the step).
    #[error("setting the robot up: {0}")]
    Setup(String),
}

/// The cycle's transport, for an interface the driver connects to.
pub trait DriverLink {
    /// The robot controller's address.
    fn peer(&self) -> std::net::SocketAddr;
    /// Sends the answer: at once, or at the driver's next tick where the driver clocks the cycle.
    fn send(&mut self, answer: &[u8]) -> Result<(), LinkError>;
    /// The robot's next state packet, waiting until `deadline_ns` (`CLOCK_MONOTONIC`) at most.
    fn receive(&mut self, deadline_ns: u64) -> Result<Option<&[u8]>, LinkError>;
    /// Gives the robot back (b-CAP: slave mode off, motor off, the arm given back; the Meca500: a
    /// zero velocity) the moment the stream ends — a robot that runs on buffered commands stops
    /// with an error when they run out. Returns what failed, named.
    fn finish(&mut self) -> Vec<String>;
    /// Ticks of the driver's own clock that went by without running before the state just
    /// received (its process stalled), where the driver clocks the cycle; once. 0 by default.
    fn lapsed(&mut self) -> u64 {
        0
    }
    /// Whether the link carries the extruder's command (UR: a standard analog output).
    fn wants_extruder(&self) -> bool {
        false
    }
    /// The extruder's newest command: the filament's speed into the hot end (m/s), for a link
    /// that carries it.
    fn extruder(&mut self, filament_rate: f64) -> Result<(), LinkError> {
        let _ = filament_rate;
        Ok(())
    }
}

/// Everything before an interface's first cycle, done by the link that then carries the cycles —
/// b-CAP: the service, the arm, motor on and slave mode; the Meca500: activation, homing, velocity
/// mode and monitoring; UR: the RTDE recipes, strand's servo program sent, and its connection back.
pub trait Handshake<P: RobotProtocol>: DriverLink + Sized {
    /// Connects to the robot `driver` names and sets it up for streaming as `cfg` says; tells the
    /// session's protocol what the set-up learnt (b-CAP's robot handle, UR's recipe, the
    /// Meca500's speed limits and gain). Returns the link and the first answer, which starts the
    /// exchange where the robot answers commands (b-CAP: a hold where the arm is), or nothing. If
    /// it fails part-way, the robot is given back first.
    fn handshake(cfg: &Config, driver: &DriverConfig, session: &mut Session<P>) -> Result<(Self, Vec<u8>), LinkError>;
}

/// How the loop runs.
#[derive(Clone, Debug)]
pub struct PacedOptions {
    /// The service prefix.
    pub prefix: String,
    /// The robot's cycle (s).
    pub period: f64,
    /// Longest wait for the robot's state after an answer (s): beyond it the robot is gone.
    pub state_timeout: f64,
    /// Stop after this many states (0: never; tests and benchmarks).
    pub max_packets: u64,
}

/// How the stream ended, and what giving the robot back said.
#[derive(Debug)]
pub struct Ended {
    /// Why.
    pub end: StreamEnd,
    /// The steps of giving the robot back that failed (named).
    pub release_failed: Vec<String>,
}

/// Why the stream ended.
#[derive(Debug)]
pub enum StreamEnd {
    /// Stopped (Ctrl-C, `max_packets`) with the robot held to rest.
    Stopped,
    /// The robot reported an error (it stopped), went silent or closed the link.
    Robot(String),
}

/// Whether `fd` has something to read within `timeout_ns` (ppoll on a high-resolution timer: a
/// socket's receive timeout counts in scheduler ticks, 4 ms at HZ=250).
pub fn readable(fd: &impl AsRawFd, timeout_ns: u64) -> bool {
    let mut p = libc::pollfd { fd: fd.as_raw_fd(), events: libc::POLLIN, revents: 0 };
    let ts = libc::timespec { tv_sec: (timeout_ns / 1_000_000_000) as libc::time_t, tv_nsec: (timeout_ns % 1_000_000_000) as libc::c_long };
    // SAFETY: one valid pollfd, a valid timespec, no signal mask.
    let n = unsafe { libc::ppoll(&mut p, 1, &ts, std::ptr::null()) };
    n > 0 && p.revents & (libc::POLLIN | libc::POLLHUP | libc::POLLERR) != 0
}

/// Sleeps until `deadline_ns` (`CLOCK_MONOTONIC`, absolute: no drift from one tick to the next).
pub(crate) fn sleep_until(deadline_ns: u64) {
    let ts =
        libc::timespec { tv_sec: (deadline_ns / 1_000_000_000) as libc::time_t, tv_nsec: (deadline_ns % 1_000_000_000) as libc::c_long };
    // SAFETY: clock_nanosleep with a valid timespec and no remainder pointer (absolute time).
    unsafe { while libc::clock_nanosleep(libc::CLOCK_MONOTONIC, libc::TIMER_ABSTIME, &ts, std::ptr::null_mut()) == libc::EINTR {} }
}

/// Runs the cycle until `stop` (then holds the robot to rest), `max_packets`, or the robot ends
/// it; then gives the robot back ([`DriverLink::finish`]). `first` is the answer that starts the exchange where the robot answers commands (b-CAP's
/// first `slvMove`, holding the arm where it is; empty if the robot streams by itself): it goes
/// out once the service's ports are open, since from then on the robot needs one every cycle.
pub fn run<P: RobotProtocol, L: DriverLink>(
    session: &mut Session<P>,
    link: &mut L,
    first: &[u8],
    opts: &PacedOptions,
    stop: &AtomicBool,
) -> Result<(BridgeReport, Ended), strand_ipc::ports::PortError> {
    let name = P::NAME;
    let ports = ClientPorts::open(
        &ServiceNames::new(&opts.prefix),
        &format!("strand-{name}"),
        ClientRoles { driver: true, feeder: true, monitor: link.wants_extruder(), ..Default::default() },
    )?;
    let peer = link.peer();
    eprintln!("strand-{name}: streaming to {peer}, service {}", opts.prefix);
    let mut started = first.is_empty() || link.send(first).is_ok();
    let mut reply = Vec::with_capacity(1024);
    let mut latency = Histogram::new();
    let period_ns = (opts.period * 1e9) as u64;
    let timeout_ns = (opts.state_timeout * 1e9) as u64;
    let mut previous_q: Option<[f64; strand_ipc::MAX_JOINTS]> = None;
    let mut control_seq = 0u64;
    // The JointStates' own sequence: one per service tick, owed ticks included.
    let mut state_seq = 0u64;
    let mut last_state_seq = 0u64;
    let mut owed_answer = Vec::with_capacity(1024);
    let mut logged_drops = 0u64;
    let mut clamps_logged = 0u64;
    let estop = |ports: &ClientPorts, seq: &mut u64| {
        *seq += 1;
        let c = Control { seq: *seq, stamp_ns: monotonic_ns(), command: Command::EmergencyStop as u32, value: 0.0, _reserved: 0 };
        let _ = ports.send_control(&c);
    };
    let end = loop {
        if !std::mem::replace(&mut started, true) {
            break StreamEnd::Robot("the first command did not go out".into());
        }
        if stop.load(Ordering::Relaxed) && session.request_stop(monotonic_ns()) {
            eprintln!("strand-{name}: stop requested: holding the robot");
        }
        if session.poll(monotonic_ns()) == Due::StopDone {
            break StreamEnd::Stopped;
        }
        let waited = monotonic_ns();
        let bytes = match link.receive(waited + timeout_ns) {
            Ok(Some(b)) => b,
            Ok(None) => break StreamEnd::Robot(format!("no state from the robot in {} s", opts.state_timeout)),
            Err(e) => break StreamEnd::Robot(e.to_string()),
        };
        let received = monotonic_ns();
        let (_, q, transition) = match session.on_packet_at(received, bytes, peer) {
            Ok(x) => x,
            Err(Dropped::Packet(PacketError::RobotError(why))) => break StreamEnd::Robot(why),
            Err(dropped) => {
                logged_drops += 1;
                if logged_drops <= 10 {
                    eprintln!("strand-{name}: dropped a packet: {dropped}");
                }
                // The robot still needs its next command: the hold.
                session.reply_hold(&mut reply);
                if let Err(e) = link.send(&reply) {
                    break StreamEnd::Robot(e.to_string());
                }
                continue;
            }
        };
        session.driver_lapsed(link.lapsed());
        if let Some(t) = transition {
            log_transition(name, t, &format!(" (robot at {peer})"));
        }
        if let Some(news) = session.take_news() {
            eprintln!("strand-{name}: robot: {news}");
        }
        if let Some(scaling) = session.take_speed_scaling() {
            // The robot slows its motion (its speed slider): the service slows the path to match,
            // on top of the operator's feed override.
            eprintln!("strand-{name}: robot: speed scaling {:.0} %: the service's path follows it", scaling * 100.0);
            control_seq += 1;
            let c = Control {
                seq: control_seq,
                stamp_ns: monotonic_ns(),
                command: Command::RobotSpeedScaling as u32,
                value: scaling.clamp(0.01, 1.0),
                _reserved: 0,
            };
            let _ = ports.send_control(&c);
        }
        if link.wants_extruder() {
            let mut newest = None;
            while let Ok(Some(e)) = ports.receive_extruder_command() {
                newest = Some(e.filament_rate);
            }
            if let Some(speed) = newest
                && let Err(e) = link.extruder(speed)
            {
                break StreamEnd::Robot(e.to_string());
            }
        }
        let held = session.stopping() || session.state() == DriverState::HeldAfterFault;
        let owed = session.take_owed_ticks();
        let mut owed_transition = None;
        if session.robot_following() && !held && owed > 0 {
            // The driver's loop lapsed and the robot ran on along its last command: the service
            // owes it the ticks it missed, each a state a cycle apart before this one with the
            // robot's motion spread over them; their answers are not sent (the robot is past them).
            let from = previous_q.unwrap_or(q);
            for i in 1..=owed {
                let qi = session.owed_position(&from, &q, i, owed);
                state_seq += 1;
                let stamp = received.saturating_sub((owed + 1 - i) * period_ns);
                let _ = ports.send_joint_state(&joint_state(session, state_seq, stamp, qi, &mut previous_q, opts.period));
                // Within the packet's own reply deadline: the owed ticks must not make its answer late.
                let command = wait_command(&ports, state_seq, session.dof(), session.reply_deadline().unwrap_or(received));
                if let (_, Some(t)) = session.reply_owed(command.as_ref(), &mut owed_answer) {
                    owed_transition = Some(t);
                }
            }
        }
        state_seq += 1;
        let seq = state_seq;
        let state = joint_state(session, seq, received, q, &mut previous_q, opts.period);
        let (kind, transition) = if !session.robot_following() && !held {
            // The robot does not follow yet (UR: strand's program not playing): hold it where it
            // is, and do not clock the service.
            let r = session.reply_hold(&mut reply);
            if let Err(e) = answer(link, &reply, received, period_ns, &mut latency, session) {
                break StreamEnd::Robot(e.to_string());
            }
            r
        } else if held {
            let r = session.reply_hold(&mut reply);
            if let Err(e) = answer(link, &reply, received, period_ns, &mut latency, session) {
                break StreamEnd::Robot(e.to_string());
            }
            let transition = if !session.stopping() {
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
        } else {
            let _ = ports.send_joint_state(&state);
            last_state_seq = seq;
            let command = wait_command(&ports, seq, session.dof(), session.reply_deadline().unwrap_or(received));
            let r = session.reply(command.as_ref(), &mut reply);
            if let Err(e) = answer(link, &reply, received, period_ns, &mut latency, session) {
                break StreamEnd::Robot(e.to_string());
            }
            r
        };
        for t in [owed_transition, transition].into_iter().flatten() {
            let why = match (t.from, t.to) {
                (_, DriverState::HeldAfterFault) => format!(
                    " ({} commands in a row missed the {} ms deadline: holding, and telling the service)",
                    session.late_run(),
                    session.rules().reply_deadline * 1e3
                ),
                (DriverState::HeldAfterFault, DriverState::Following) => " (the service answers in time again)".to_string(),
                _ => String::new(),
            };
            log_transition(name, t, &why);
            if t.to == DriverState::HeldAfterFault {
                estop(&ports, &mut control_seq);
            }
        }
        let clamped = session.counters.clamped;
        if kind == ReplyKind::Command && clamped > clamps_logged && clamped.is_power_of_two() {
            clamps_logged = clamped;
            eprintln!(
                "strand-{name}: warning: {} answers clamped to the joint limits so far (last: joint {})",
                clamped,
                session.guard().last_clamped_joint.map_or(0, |j| j + 1)
            );
        }
        if opts.max_packets > 0 && session.counters.packets >= opts.max_packets {
            break StreamEnd::Stopped;
        }
    };
    // Give the robot back at once: the service's ports are closed after it.
    let release_failed = link.finish();
    if let StreamEnd::Robot(why) = &end {
        // The robot stopped by itself: the service must stop too (it faults and stops extruding).
        eprintln!("strand-{name}: the stream ended: {why}");
        estop(&ports, &mut control_seq);
    }
    let report = BridgeReport { counters: session.counters, stale: 0, latency, final_state: format!("{:?}", session.state()), unit: None };
    Ok((report, Ended { end, release_failed }))
}

/// Sends the answer to the state received at `received` (ns) and records how long after it the
/// answer left. Where the robot clocks the cycle ([`Clock::Robot`], UR), an answer not ready
/// within the robot's cycle is not sent: the robot held its previous target that cycle and its
/// next state is already out, so the session takes the answer back and the next one catches up
/// from the hold (sent late over a stream, it would be run a cycle late and the next answer,
/// stepping from the hold, would step back). Where the driver clocks ([`Clock::Driver`]: b-CAP's
/// buffer, the Meca500's velocity), the robot runs every answer in order: a late one delays the
/// motion, it does not stop it, so it is sent and counted (`missed_cycle`); a buffer that runs dry
/// is an error the robot reports.
fn answer<P: RobotProtocol, L: DriverLink>(
    link: &mut L,
    reply: &[u8],
    received: u64,
    period_ns: u64,
    latency: &mut Histogram,
    session: &mut Session<P>,
) -> Result<(), LinkError> {
    if P::CLOCK == Clock::Robot && monotonic_ns() - received > period_ns {
        latency.record(monotonic_ns() - received);
        session.answer_missed_its_cycle();
        return Ok(());
    }
    link.send(reply)?;
    let took = monotonic_ns() - received;
    latency.record(took);
    if took > period_ns {
        match P::CLOCK {
            Clock::Robot => session.answer_missed_its_cycle(),
            Clock::Driver => session.counters.missed_cycle += 1,
        }
    }
    Ok(())
}
