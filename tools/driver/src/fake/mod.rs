//! Fake robot controllers that speak the real wire formats, for testing the drivers where no robot
//! is: [`rsi`] a KUKA KR C4 with an RSI object, [`egm`] an ABB IRC5 with EGM. Written from the
//! public descriptions (ros-industrial's kuka_rsi_simulator and abb_libegm), not from the drivers'
//! code: the RSI fake builds and reads its XML itself, the EGM fake uses only the schema.
//! [`fri`] is a KUKA Sunrise controller (LBR iiwa) with FRI, from `docs/protocols/fri.md`, its protobuf by hand.
//! [`bcap`] is a DENSO RC8 in b-CAP slave mode (TCP), from `docs/protocols/bcap.md`, its packets and
//! VARIANTs by hand; it is a TCP server with its own controller tick thread, not driven by [`run`].
//! [`meca`] is a Mecademic Meca500 R3 with its TCP text API (control and monitoring ports, velocity
//! mode), from `docs/protocols/meca500.md`; it runs its own trajectory cycle rather than [`run`].
//! [`ur`] is a Universal Robots e-Series controller (RTDE, the primary port a URScript program
//! arrives on, and the reverse interface that program connects back with), from
//! `docs/protocols/ur.md`, its RTDE packages and 8 × int32 messages by hand; it runs its own
//! controller step thread rather than [`run`].
//!
//! The loop is a controller's: a packet every `period` on absolute deadlines (`clock_nanosleep`
//! with `TIMER_ABSTIME`), the answer taken as it arrives (its round trip measured) and accepted
//! only if it comes before the next packet and matches the one it answers (RSI: the same `IPOC`), the commanded axes integrated into the actual ones
//! (with an optional first-order lag, the drives' response), and every cycle counted: answered in
//! time, late (an answer to an older packet) or missing. The actual axes are recorded so that a
//! test can check their speed and acceleration against the robot's limits.

pub mod bcap;
pub mod egm;
pub mod fri;
pub mod meca;
pub mod rsi;
pub mod ur;

use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};

use strand::io::clock::monotonic_ns;
use strand::io::histogram::Histogram;

/// A fake in virtual time refused its set-up (the message names the option and why).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct InvalidSetup(pub String);

/// The controller side of one protocol.
pub trait FakeProtocol {
    /// The packet for cycle `k` (its sequence is the protocol's), with the actual axes (degrees).
    fn packet(&mut self, k: u64, axes_deg: &[f64], out: &mut Vec<u8>);
    /// The axes (degrees, absolute) an answer commands if it answers the packet of cycle `k`;
    /// `Err(Some(j))` if it answers the older cycle `j` (late), `Err(None)` if it is not an answer.
    fn answer(&mut self, k: u64, bytes: &[u8], axes_deg: &mut [f64]) -> Result<(), Option<u64>>;
    /// The controller's own step at the end of cycle `k`, after the answer or without one: a
    /// robot that runs buffered commands (b-CAP's slave mode) takes its next one into `axes_deg`
    /// (degrees) here. A robot whose answer is its target (RSI, EGM, FRI, UR) has none.
    fn tick(&mut self, k: u64, axes_deg: &mut [f64]) {
        let _ = (k, axes_deg);
    }
}

/// How the fake runs.
#[derive(Clone, Debug)]
pub struct FakeOptions {
    /// The driver's address.
    pub driver: SocketAddr,
    /// The fake's own address (port 0: any).
    pub bind: SocketAddr,
    /// The cycle (s): 0.004 for both protocols.
    pub period: f64,
    /// Axes at the start (degrees).
    pub start_deg: Vec<f64>,
    /// First-order lag of the drives (s; 0: the actual axes are the commanded ones).
    pub lag: f64,
    /// Cycles to run (0: until stopped).
    pub cycles: u64,
    /// SCHED_FIFO priority for the fake's thread (a robot controller is hard real-time; on a
    /// shared machine a fake that is not would count its own stalls as missing answers). Refused
    /// without the privilege: it then runs as it is.
    pub rt_priority: Option<i32>,
    /// Cycles without a single answer after which it gives up (a real controller stops; RSI's
    /// ETHERNET timeout is 100 packets).
    pub give_up_after: u64,
}

/// What a run saw.
#[derive(Clone, Default, serde::Serialize)]
pub struct FakeReport {
    /// Packets sent.
    pub cycles: u64,
    /// Cycles answered before the next packet.
    pub in_time: u64,
    /// Answers that came after their cycle (to an older packet).
    pub late: u64,
    /// Cycles with no answer at all.
    pub missing: u64,
    /// Datagrams that were no answer of the protocol.
    pub garbage: u64,
    /// Whether it gave up (`give_up_after` silent cycles).
    pub gave_up: bool,
    /// The actual axes at every cycle (degrees).
    #[serde(skip)]
    pub axes: Vec<Vec<f64>>,
    /// Packet sent → its answer received, for the answers in time (ns).
    #[serde(skip)]
    pub round_trip: Histogram,
    /// Per cycle: whether its target came from an answer in time (false: held over a missing or
    /// late answer, as a controller with HOLDON does — the axes then step when answers resume).
    #[serde(skip)]
    pub fresh: Vec<bool>,
    /// Per channel ([`run_channels`]): the cycles it sent and got its answer in time.
    pub channel_in_time: Vec<u64>,
    /// When the first cycle's packet went out (ns, `CLOCK_MONOTONIC`): `axes[k]` is the robot at
    /// `start_ns + k · period_ns` (what a cell test lines the axes up with the other devices by).
    pub start_ns: u64,
    /// The cycle (ns).
    pub period_ns: u64,
}

impl std::fmt::Debug for FakeReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // The axes are thousands of rows: their count only.
        f.debug_struct("FakeReport")
            .field("cycles", &self.cycles)
            .field("in_time", &self.in_time)
            .field("late", &self.late)
            .field("missing", &self.missing)
            .field("garbage", &self.garbage)
            .field("gave_up", &self.gave_up)
            .field("axes", &self.axes.len())
            .finish()
    }
}

impl FakeReport {
    /// The share of cycles answered in time (1 for a run of no cycle).
    pub fn in_time_share(&self) -> f64 {
        if self.cycles == 0 { 1.0 } else { self.in_time as f64 / self.cycles as f64 }
    }

    /// The largest speed and acceleration of each axis over the run (deg/s, deg/s²), over the
    /// cycles that followed answers in time (a missed answer makes the axes step when answers
    /// resume: that is the lateness, counted in `missing` and `late`, not the commands). `period`
    /// is the robot's cycle and `lag` the drives' time constant (s).
    pub fn max_rates(&self, period: f64, lag: f64) -> (Vec<f64>, Vec<f64>) {
        let n = self.axes.first().map_or(0, Vec::len);
        let (mut v_max, mut a_max) = (vec![0.0f64; n], vec![0.0f64; n]);
        // Rows near a cycle without a fresh answer carry its step, spread by the drive lag over
        // the next cycles (to 5 % of it after three time constants): they measure the lateness,
        // not the commands.
        let spread = 2 + (3.0 * lag / period).ceil() as usize;
        for (i, w) in self.axes.windows(3).enumerate() {
            if (i.saturating_sub(spread)..=i + spread).any(|r| !self.fresh.get(r).copied().unwrap_or(true)) {
                continue;
            }
            for k in 0..n {
                let v1 = (w[1][k] - w[0][k]) / period;
                let v2 = (w[2][k] - w[1][k]) / period;
                v_max[k] = v_max[k].max(v1.abs()).max(v2.abs());
                a_max[k] = a_max[k].max(((v2 - v1) / period).abs());
            }
        }
        (v_max, a_max)
    }
}

fn sleep_until(deadline_ns: u64) {
    let ts =
        libc::timespec { tv_sec: (deadline_ns / 1_000_000_000) as libc::time_t, tv_nsec: (deadline_ns % 1_000_000_000) as libc::c_long };
    // SAFETY: clock_nanosleep with a valid timespec and no remainder pointer (absolute time).
    unsafe { while libc::clock_nanosleep(libc::CLOCK_MONOTONIC, libc::TIMER_ABSTIME, &ts, std::ptr::null_mut()) == libc::EINTR {} }
}

/// SCHED_FIFO at `priority` for the calling thread, if given and permitted (without the privilege
/// it runs as it is): a robot controller is hard real-time.
pub(crate) fn real_time(priority: Option<i32>) {
    if let Some(priority) = priority {
        let param = libc::sched_param { sched_priority: priority };
        // SAFETY: this thread (0), a valid sched_param. Failure (no privilege) leaves it as it is.
        unsafe {
            libc::sched_setscheduler(0, libc::SCHED_FIFO, &param);
        }
    }
}

/// Sends what of `pending` the socket `fd` takes now, without blocking (a controller's thread never
/// waits on a slow client), dropping what went out; false if the connection is dead (an error
/// other than a full socket buffer), or if more than `limit` bytes are left unread: a client that
/// stopped reading is dropped, as a robot controller drops it, instead of growing the buffer.
pub(crate) fn send_pending(fd: std::os::fd::RawFd, pending: &mut Vec<u8>, limit: usize) -> bool {
    while !pending.is_empty() {
        // SAFETY: a valid socket and buffer; MSG_DONTWAIT makes this one call non-blocking
        // without touching the descriptor's flags (the reader shares them).
        let n = unsafe { libc::send(fd, pending.as_ptr().cast(), pending.len(), libc::MSG_DONTWAIT | libc::MSG_NOSIGNAL) };
        if n > 0 {
            pending.drain(..n as usize);
        } else {
            match std::io::Error::last_os_error().kind() {
                std::io::ErrorKind::Interrupted => {}
                std::io::ErrorKind::WouldBlock => break,
                _ => return false,
            }
        }
    }
    pending.len() <= limit
}

/// A controller's step loop: `step(deadline)` every `step_ns` from `t0` (ns, `CLOCK_MONOTONIC`) on
/// absolute deadlines until `stopped()`. A second behind (a stopped machine), it starts again from
/// now rather than run the backlog in a burst.
pub(crate) fn every(t0: u64, step_ns: u64, stopped: impl Fn() -> bool, mut step: impl FnMut(u64)) {
    let (mut base, mut k) = (t0, 0u64);
    while !stopped() {
        k += 1;
        let mut deadline = base + k * step_ns;
        let now = monotonic_ns();
        if now > deadline + 1_000_000_000 {
            base = now - k * step_ns;
            deadline = now;
        }
        sleep_until(deadline);
        step(deadline);
    }
}

/// One channel of a fake controller: the interface it speaks, the driver's address it sends to,
/// and the controller's axes it carries. A controller streams one channel per robot; ABB's
/// MultiMove streams one EGM channel per motion task (a robot, and a positioner in a task of its
/// own), every channel on the same controller cycle.
pub struct FakeChannel<'a> {
    /// The interface.
    pub protocol: &'a mut dyn FakeProtocol,
    /// The driver's address for this channel.
    pub driver: SocketAddr,
    /// The controller's axes it carries (indices into `FakeOptions::start_deg`).
    pub axes: std::ops::Range<usize>,
}

/// Runs the fake controller until `opts.cycles`, `stop`, or it gives up: one channel to
/// `opts.driver` carrying every axis.
pub fn run(protocol: &mut dyn FakeProtocol, opts: &FakeOptions, stop: &AtomicBool) -> std::io::Result<FakeReport> {
    let axes = 0..opts.start_deg.len();
    run_channels(&mut [FakeChannel { protocol, driver: opts.driver, axes }], opts, stop)
}

/// Runs the fake controller with several channels (`opts.driver` unused): each sends its packet
/// every cycle (none when its protocol writes none: a channel that stopped) from a socket of its
/// own on `opts.bind`'s address, and a cycle is answered in time when every channel that sent got
/// its answer before the next cycle (`FakeReport::channel_in_time` counts them apart).
pub fn run_channels(channels: &mut [FakeChannel<'_>], opts: &FakeOptions, stop: &AtomicBool) -> std::io::Result<FakeReport> {
    let n = channels.len();
    assert!((1..=4).contains(&n), "a fake controller streams 1 to 4 channels");
    let mut sockets = Vec::with_capacity(n);
    for k in 0..n {
        // The first channel binds `opts.bind`; the others any port on its address.
        let bind = if k == 0 { opts.bind } else { SocketAddr::new(opts.bind.ip(), 0) };
        let socket = UdpSocket::bind(bind)?;
        socket.set_nonblocking(true)?;
        sockets.push(socket);
    }
    let fds: Vec<std::os::fd::RawFd> = sockets.iter().map(std::os::fd::AsRawFd::as_raw_fd).collect();
    real_time(opts.rt_priority);
    let period_ns = (opts.period * 1e9).round() as u64;
    let mut actual = opts.start_deg.clone();
    let mut target = opts.start_deg.clone();
    let mut commanded = opts.start_deg.clone();
    let alpha = if opts.lag > 0.0 { 1.0 - (-opts.period / opts.lag).exp() } else { 1.0 };
    let mut report = FakeReport { channel_in_time: vec![0; n], ..FakeReport::default() };
    let mut out = Vec::with_capacity(1024);
    let mut buf = vec![0u8; 65536];
    let mut silent = 0u64;
    // Per channel: whether it sent this cycle, and the answers it took.
    let mut sent = vec![false; n];
    let mut answers = vec![0u32; n];
    let all_answered = |answers: &[u32], sent: &[bool]| sent.iter().any(|s| *s) && sent.iter().zip(answers).all(|(s, a)| !*s || *a > 0);
    let t0 = monotonic_ns() + period_ns;
    (report.start_ns, report.period_ns) = (t0, period_ns);
    let mut k = 0u64;
    sleep_until(t0);
    report.fresh.push(true);
    report.axes.push(actual.clone());
    let mut sent_at = send_cycle(channels, &sockets, 0, &actual, &mut out, &mut sent)?;
    report.cycles = 1;
    while !stop.load(Ordering::Relaxed) && (opts.cycles == 0 || k + 1 < opts.cycles) {
        // Take answers as they come until the next cycle starts: the first that answers packet
        // k is in time (its round trip recorded); answers to older packets are late.
        let next = t0 + (k + 1) * period_ns;
        answers.iter_mut().for_each(|a| *a = 0);
        let mut answered = false;
        loop {
            let now = monotonic_ns();
            if now + 20_000 >= next {
                break;
            }
            // ppoll, not SO_RCVTIMEO: a socket's receive timeout counts in scheduler ticks (4 ms at
            // HZ=250), a whole cycle; ppoll sleeps on a high-resolution timer.
            let mut ready = [false; 4];
            if !crate::unit_link::readable(&fds, next - now - 20_000, &mut ready[..n]) {
                break;
            }
            for (c, channel) in channels.iter_mut().enumerate().filter(|(c, _)| ready[*c]) {
                loop {
                    match sockets[c].recv_from(&mut buf) {
                        Ok((len, _)) => match channel.protocol.answer(k, &buf[..len], &mut commanded[channel.axes.clone()]) {
                            Ok(()) => {
                                // The newest answer counts (a controller takes the latest); two in
                                // one cycle mean the first was the last cycle's, late.
                                answers[c] += 1;
                                target[channel.axes.clone()].clone_from_slice(&commanded[channel.axes.clone()]);
                            }
                            Err(Some(_)) => report.late += 1,
                            Err(None) => report.garbage += 1,
                        },
                        Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => break,
                        Err(e) if matches!(e.kind(), std::io::ErrorKind::ConnectionRefused | std::io::ErrorKind::Interrupted) => {}
                        Err(e) => return Err(e),
                    }
                }
            }
            if !answered && all_answered(&answers, &sent) {
                answered = true;
                report.round_trip.record(monotonic_ns() - sent_at);
            }
        }
        for (c, a) in answers.iter().enumerate() {
            if *a > 1 {
                report.late += u64::from(a - 1);
            }
            if sent[c] && *a > 0 {
                report.channel_in_time[c] += 1;
            }
        }
        // Fresh: every channel's target came from its answer this cycle (a silent channel's did not).
        report.fresh.push(answered && sent.iter().all(|s| *s) && answers.iter().all(|a| *a <= 1));
        if answered {
            report.in_time += 1;
            silent = 0;
        } else {
            report.missing += 1;
            silent += 1;
            if opts.give_up_after > 0 && silent >= opts.give_up_after && report.in_time > 0 {
                report.gave_up = true;
                break;
            }
        }
        // The drives follow the target (a real controller interpolates the correction).
        for (a, t) in actual.iter_mut().zip(&target) {
            *a += alpha * (t - *a);
        }
        report.axes.push(actual.clone());
        k += 1;
        sleep_until(next);
        sent_at = send_cycle(channels, &sockets, k, &actual, &mut out, &mut sent)?;
        report.cycles += 1;
    }
    // The last packet's answers, if they come within a cycle.
    let end = monotonic_ns() + period_ns;
    answers.iter_mut().for_each(|a| *a = 0);
    while monotonic_ns() < end && !all_answered(&answers, &sent) {
        let mut ready = [false; 4];
        if !crate::unit_link::readable(&fds, end.saturating_sub(monotonic_ns()), &mut ready[..n]) {
            break;
        }
        for (c, channel) in channels.iter_mut().enumerate().filter(|(c, _)| ready[*c]) {
            if let Ok((len, _)) = sockets[c].recv_from(&mut buf)
                && channel.protocol.answer(k, &buf[..len], &mut commanded[channel.axes.clone()]).is_ok()
            {
                answers[c] += 1;
            }
        }
    }
    if all_answered(&answers, &sent) {
        report.in_time += 1;
    } else {
        report.missing += 1;
    }
    Ok(report)
}

/// Sends every channel's packet of cycle `k` (a channel whose protocol writes none sends none:
/// `sent` says which did); when the last left (ns).
fn send_cycle(
    channels: &mut [FakeChannel<'_>],
    sockets: &[UdpSocket],
    k: u64,
    actual: &[f64],
    out: &mut Vec<u8>,
    sent: &mut [bool],
) -> std::io::Result<u64> {
    for (c, channel) in channels.iter_mut().enumerate() {
        channel.protocol.packet(k, &actual[channel.axes.clone()], out);
        sent[c] = !out.is_empty();
        if sent[c] {
            send(&sockets[c], out, channel.driver)?;
        }
    }
    Ok(monotonic_ns())
}

fn send(socket: &UdpSocket, packet: &[u8], to: SocketAddr) -> std::io::Result<()> {
    match socket.send_to(packet, to) {
        Ok(_) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => Ok(()),
        Err(e) => Err(e),
    }
}
