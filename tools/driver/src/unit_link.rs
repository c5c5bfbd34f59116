//! The socket of a mechanical unit's own channel beside the robot's, in the bridge's loop
//! ([`crate::protocol::UnitChannel`]; ABB MultiMove: a positioner in its own motion task streams
//! EGM to a port of its own). The robot's packet keeps the cycle; the unit's packet of the same
//! cycle is waited for briefly before the robot's state goes to the service (so the service sees
//! the unit's axes of this cycle, not the last), and answered right after the robot with its
//! share of the same command. A unit packet whose robot packet does not come within the reply
//! deadline is answered alone, with the last command (the robot's channel stopped, or its packet
//! was lost): a robot controller holds its last target when an answer is missing, and so would
//! the unit, but an unanswered EGM channel times out and stops.

use std::net::{SocketAddr, UdpSocket};
use std::os::fd::{AsRawFd, RawFd};

use crate::protocol::RobotProtocol;
use crate::session::Session;

/// What the unit's channel saw.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct UnitCounters {
    /// Packets taken.
    pub packets: u64,
    /// Answered right after the robot's answer of their cycle, with the same command.
    pub answered_with_robot: u64,
    /// Answered alone at their deadline (no robot packet came): the last command, or where the
    /// unit is.
    pub answered_alone: u64,
    /// Taken, then replaced by the unit's next packet before they were answered.
    pub superseded: u64,
    /// Older than a packet already taken (out of order, duplicates).
    pub out_of_order: u64,
    /// Not the unit's protocol, cut short, not finite, oversized, or a robot's packet.
    pub malformed: u64,
    /// From another sender than the unit's (the first one, on the robot's controller).
    pub foreign: u64,
    /// Robot packets that waited for the unit's packet of their cycle, and those whose wait ended
    /// without it.
    pub waited: u64,
    /// See `waited`.
    pub wait_missed: u64,
}

/// The unit's socket and what is owed to it.
pub struct UnitLink {
    socket: UdpSocket,
    /// The unit's address: the first sender on the robot controller's address.
    sender: Option<SocketAddr>,
    /// The newest taken packet not answered yet: when it came (ns).
    pending: Option<u64>,
    /// When the newest packet was taken (ns).
    last_taken_ns: Option<u64>,
    /// How long after its arrival a unit packet waits for the robot's answer (ns).
    deadline_ns: u64,
    buf: Vec<u8>,
    reply: Vec<u8>,
    /// Messages said about dropped packets (the first ten are).
    said: u32,
    /// Counters since start.
    pub counters: UnitCounters,
}

impl UnitLink {
    /// Listens on `bind` for the unit's packets; each is answered at most `deadline_ns` after it
    /// came.
    pub fn bind(bind: SocketAddr, deadline_ns: u64) -> std::io::Result<UnitLink> {
        let socket = UdpSocket::bind(bind)?;
        socket.set_nonblocking(true)?;
        Ok(UnitLink {
            socket,
            sender: None,
            pending: None,
            last_taken_ns: None,
            deadline_ns,
            buf: vec![0u8; 65536],
            reply: Vec::with_capacity(1024),
            said: 0,
            counters: UnitCounters::default(),
        })
    }

    /// The address it listens on.
    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.socket.local_addr()
    }

    /// Its socket, to wait on beside the robot's.
    pub fn fd(&self) -> RawFd {
        self.socket.as_raw_fd()
    }

    /// When the pending packet's answer is due (ns), if one is pending.
    pub fn due_at(&self) -> Option<u64> {
        self.pending.map(|t| t + self.deadline_ns)
    }

    /// Takes every packet queued on the unit's socket (without blocking), received at `now_ns`.
    pub fn take_packets<P: RobotProtocol>(&mut self, session: &mut Session<P>, now_ns: u64) {
        while let Ok((n, from)) = self.socket.recv_from(&mut self.buf) {
            // The unit's controller is the robot's: once both are known, another address is not it.
            let robot_ip = session.sender().map(|s| s.ip());
            let ours = match self.sender {
                Some(s) => s == from,
                None => robot_ip.is_none_or(|ip| ip == from.ip()),
            };
            if !ours {
                self.counters.foreign += 1;
                self.say(&format!("a packet from {from}, not the unit's"));
                continue;
            }
            let Some(unit) = session.protocol_mut().unit_channel() else { return };
            match unit.unit_read(&self.buf[..n]) {
                Ok(true) => {
                    self.sender.get_or_insert(from);
                    self.counters.packets += 1;
                    if self.pending.replace(now_ns).is_some() {
                        self.counters.superseded += 1;
                    }
                    self.last_taken_ns = Some(now_ns);
                }
                Ok(false) => self.counters.out_of_order += 1,
                Err(e) => {
                    self.counters.malformed += 1;
                    self.say(&e.to_string());
                }
            }
        }
    }

    /// Before the robot's packet received at `robot_ns` is read: takes the unit's queued packets
    /// and, if its newest came more than half a cycle (`period_ns`) before, waits up to `max_wait_ns`
    /// for the unit's packet of this cycle (both channels send on the same controller cycle).
    pub fn catch_up<P: RobotProtocol>(&mut self, session: &mut Session<P>, robot_ns: u64, period_ns: u64, max_wait_ns: u64) {
        self.take_packets(session, strand::io::clock::monotonic_ns());
        let behind = |t: Option<u64>| t.is_none_or(|t| t + period_ns / 2 < robot_ns);
        if !behind(self.last_taken_ns) {
            return;
        }
        self.counters.waited += 1;
        let end = robot_ns + max_wait_ns;
        loop {
            let now = strand::io::clock::monotonic_ns();
            if now >= end {
                break;
            }
            let mut ready = [false];
            if readable(&[self.fd()], end - now, &mut ready) && ready[0] {
                self.take_packets(session, strand::io::clock::monotonic_ns());
                if !behind(self.last_taken_ns) {
                    return;
                }
            }
        }
        self.counters.wait_missed += 1;
    }

    /// Answers the pending packet, if any: right after the robot's answer (`with_robot`), or
    /// alone when its deadline passed.
    pub fn answer<P: RobotProtocol>(&mut self, session: &mut Session<P>, with_robot: bool) {
        let (Some(_), Some(to)) = (self.pending, self.sender) else { return };
        let Some(unit) = session.protocol_mut().unit_channel() else { return };
        unit.unit_write(&mut self.reply);
        self.pending = None;
        if self.reply.is_empty() {
            return;
        }
        let _ = self.socket.send_to(&self.reply, to);
        if with_robot {
            self.counters.answered_with_robot += 1;
        } else {
            self.counters.answered_alone += 1;
        }
    }

    /// Answers the pending packet alone if its deadline passed by `now_ns`.
    pub fn answer_if_due<P: RobotProtocol>(&mut self, session: &mut Session<P>, now_ns: u64) {
        if self.due_at().is_some_and(|due| now_ns >= due) {
            self.answer(session, false);
        }
    }

    fn say(&mut self, what: &str) {
        self.said += 1;
        if self.said <= 10 {
            eprintln!("strand-driver: the external unit's channel dropped a packet: {what}");
        }
    }
}

/// Whether any of `fds` has a datagram within `timeout_ns` (ppoll on a high-resolution timer; a
/// socket's receive timeout counts in scheduler ticks, 4 ms at HZ=250: a whole cycle); `ready`
/// (as long as `fds`, at most 4) says which.
pub(crate) fn readable(fds: &[RawFd], timeout_ns: u64, ready: &mut [bool]) -> bool {
    let mut polled = [libc::pollfd { fd: -1, events: 0, revents: 0 }; 4];
    let n = fds.len().min(polled.len());
    for (p, fd) in polled.iter_mut().zip(&fds[..n]) {
        *p = libc::pollfd { fd: *fd, events: libc::POLLIN, revents: 0 };
    }
    let ts = libc::timespec { tv_sec: (timeout_ns / 1_000_000_000) as libc::time_t, tv_nsec: (timeout_ns % 1_000_000_000) as libc::c_long };
    // SAFETY: `n` valid pollfds, a valid timespec, no signal mask.
    let got = unsafe { libc::ppoll(polled.as_mut_ptr(), n as libc::nfds_t, &ts, std::ptr::null()) };
    for (r, p) in ready.iter_mut().zip(&polled[..n]) {
        *r = got > 0 && p.revents & libc::POLLIN != 0;
    }
    got > 0
}
