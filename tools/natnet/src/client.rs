//! The I/O loop around the [`Session`]: the command socket (and, for multicast, the data socket
//! joined to Motive's group), `poll(2)` until the session's next deadline, every datagram stamped
//! on `CLOCK_MONOTONIC` as it is read, and each pose published on `<prefix>/base_pose`.
//!
//! Where frames arrive: multicast frames on the data port (any number of clients, each joined to
//! the group on `[tracker] local_interface`); unicast frames at the address the client connected
//! from — the command socket — which is why the command socket is read for frames too, and why the
//! session sends keep-alives on it.

use std::io::ErrorKind;
use std::net::{Ipv4Addr, SocketAddrV4, UdpSocket};
use std::os::fd::{AsRawFd, FromRawFd};
use std::sync::atomic::{AtomicBool, Ordering};

use strand::config::tracker::{TrackerConfig, Transmission};
use strand::io::clock::monotonic_ns;
use strand::io::histogram::Histogram;
use strand_ipc::ServiceNames;
use strand_ipc::ports::{ClientPorts, ClientRoles};
use thiserror::Error;

use crate::mapping::FrameMapping;
use crate::session::{Counters, Event, Ready, Session, SessionConfig, SessionError};

/// The largest datagram read (Motive's frames with many markers reach tens of kB).
const MAX_DATAGRAM: usize = 65_536 + 4;

/// Why the client stopped before it was asked to.
#[derive(Debug, Error)]
pub enum ClientError {
    /// The handshake or the session failed (names what to check).
    #[error(transparent)]
    Session(#[from] SessionError),
    /// A socket could not be opened or used.
    #[error("{what}: {error}")]
    Socket {
        /// What was being done.
        what: String,
        /// The OS error.
        error: std::io::Error,
    },
    /// The service's ports could not be opened or published to.
    #[error("iceoryx2: {0}")]
    Ports(String),
}

/// What a run did: the counters, and arrival → publish latency.
#[derive(Clone, Debug)]
pub struct Report {
    /// What came in and went out.
    pub counters: Counters,
    /// From a frame's datagram read off the socket to its pose published (ns).
    pub latency: Histogram,
    /// What the handshake learnt, if it finished.
    pub ready: Option<Ready>,
}

/// Where to publish and when to stop.
pub struct RunOptions<'a> {
    /// The service prefix (`<prefix>/base_pose`).
    pub prefix: String,
    /// Set to stop (signal handler, test).
    pub stop: &'a AtomicBool,
}

fn socket_error(what: impl Into<String>) -> impl FnOnce(std::io::Error) -> ClientError {
    let what = what.into();
    move |error| ClientError::Socket { what, error }
}

fn ipv4(text: &str, key: &str) -> Result<Ipv4Addr, ClientError> {
    text.parse().map_err(|_| ClientError::Socket {
        what: format!("[tracker] {key} = {text:?}"),
        error: std::io::Error::new(ErrorKind::InvalidInput, "not an IPv4 address"),
    })
}

/// A UDP socket on `port` of every address with SO_REUSEADDR (several clients of one multicast
/// group on one machine), joined to `group` on `interface`.
fn multicast_socket(port: u16, group: Ipv4Addr, interface: Ipv4Addr) -> std::io::Result<UdpSocket> {
    // SAFETY: plain socket calls on a descriptor this function owns; it is closed on every error
    // path by the UdpSocket that takes it over first.
    let socket = unsafe {
        let fd = libc::socket(libc::AF_INET, libc::SOCK_DGRAM | libc::SOCK_CLOEXEC, 0);
        if fd < 0 {
            return Err(std::io::Error::last_os_error());
        }
        let socket = UdpSocket::from_raw_fd(fd);
        let one: libc::c_int = 1;
        let len = std::mem::size_of::<libc::c_int>() as libc::socklen_t;
        if libc::setsockopt(fd, libc::SOL_SOCKET, libc::SO_REUSEADDR, &one as *const _ as *const libc::c_void, len) != 0 {
            return Err(std::io::Error::last_os_error());
        }
        let addr = libc::sockaddr_in {
            sin_family: libc::AF_INET as libc::sa_family_t,
            sin_port: port.to_be(),
            sin_addr: libc::in_addr { s_addr: u32::from(Ipv4Addr::UNSPECIFIED).to_be() },
            sin_zero: [0; 8],
        };
        if libc::bind(fd, &addr as *const _ as *const libc::sockaddr, std::mem::size_of::<libc::sockaddr_in>() as libc::socklen_t) != 0 {
            return Err(std::io::Error::last_os_error());
        }
        socket
    };
    socket.join_multicast_v4(&group, &interface)?;
    Ok(socket)
}

/// Connects to Motive as `[tracker]` says and publishes the base pose until `stop` is set or the
/// session fails. `log` gets one line per thing worth saying (ready, lost, tracked again).
pub fn run(cfg: &TrackerConfig, opts: &RunOptions<'_>, log: &mut dyn FnMut(String)) -> Result<Report, ClientError> {
    let server_ip = ipv4(&cfg.server, "server")?;
    let local = ipv4(&cfg.local_interface, "local_interface")?;
    let group = ipv4(&cfg.multicast_group, "multicast_group")?;
    let multicast = cfg.transmission == Transmission::Multicast;
    let server = SocketAddrV4::new(server_ip, cfg.command_port);

    let ports = ClientPorts::open(&ServiceNames::new(&opts.prefix), "strand-natnet", ClientRoles { tracker: true, ..Default::default() })
        .map_err(|e| ClientError::Ports(e.to_string()))?;

    let command = UdpSocket::bind(SocketAddrV4::new(local, 0)).map_err(socket_error(format!("command socket on {local}")))?;
    command.set_nonblocking(true).map_err(socket_error("command socket"))?;
    let data = if multicast {
        let s = multicast_socket(cfg.data_port, group, local)
            .map_err(socket_error(format!("data socket on port {} joined to {group} on {local}", cfg.data_port)))?;
        s.set_nonblocking(true).map_err(socket_error("data socket"))?;
        Some(s)
    } else {
        None
    };

    let mut session = Session::new(
        SessionConfig {
            server,
            rigid_body: cfg.rigid_body.clone(),
            multicast,
            connect_timeout_ns: (cfg.connect_timeout * 1e9) as u64,
            keepalive_ns: (cfg.keepalive_period * 1e9) as u64,
        },
        FrameMapping::new(cfg),
    );
    let mut report = Report { counters: Counters::default(), latency: Histogram::new(), ready: None };
    let send = |bytes: &[u8]| command.send_to(bytes, server).map(|_| ()).map_err(socket_error(format!("send to {server}")));
    send(&session.start(monotonic_ns()))?;

    let mut buf = vec![0u8; MAX_DATAGRAM];
    let mut lost = false;
    while !opts.stop.load(Ordering::Relaxed) {
        let now = monotonic_ns();
        let event = session.poll(now)?;
        if let Event::Send(bytes) = event {
            send(&bytes)?;
        }
        // Wake at the session's deadline, and at least every 100 ms to see `stop`.
        let wait_ms = (session.next_deadline().saturating_sub(monotonic_ns()) / 1_000_000).clamp(1, 100) as libc::c_int;
        let mut fds = [
            libc::pollfd { fd: command.as_raw_fd(), events: libc::POLLIN, revents: 0 },
            libc::pollfd { fd: data.as_ref().map_or(-1, |d| d.as_raw_fd()), events: libc::POLLIN, revents: 0 },
        ];
        // SAFETY: `fds` is a valid array of two pollfd; a negative fd is ignored by poll.
        let n = unsafe { libc::poll(fds.as_mut_ptr(), 2, wait_ms) };
        if n < 0 {
            let e = std::io::Error::last_os_error();
            if e.kind() == ErrorKind::Interrupted {
                continue;
            }
            return Err(ClientError::Socket { what: "poll".into(), error: e });
        }
        for socket in [Some(&command), data.as_ref()].into_iter().flatten() {
            loop {
                let len = match socket.recv_from(&mut buf) {
                    Ok((len, _)) => len,
                    Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                    Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                    // A unicast ICMP port-unreachable from a server not yet listening: retried.
                    Err(e) if e.kind() == ErrorKind::ConnectionRefused => break,
                    Err(e) => return Err(ClientError::Socket { what: "receive".into(), error: e }),
                };
                let arrival = monotonic_ns();
                match session.handle(arrival, &buf[..len])? {
                    Event::Send(bytes) => send(&bytes)?,
                    Event::Ready(r) => {
                        let s = &r.server;
                        let how = match s.connection {
                            Some(c) if c.multicast => format!("multicast {}:{}", Ipv4Addr::from(c.multicast_group), c.data_port),
                            Some(c) => format!("unicast from data port {}", c.data_port),
                            None => "transmission not said".into(),
                        };
                        log(format!(
                            "{} {} at {server}, NatNet {}, clock {} Hz, {how}; rigid body {:?} is id {}: publishing on {}/base_pose",
                            s.app_name, s.app_version, s.natnet_version, s.clock_hz, cfg.rigid_body, r.body_id, opts.prefix
                        ));
                        if s.clock_hz == 0 {
                            log("the server gave no clock frequency: poses are stamped on arrival, not capture".into());
                        }
                        report.ready = Some(r);
                    }
                    Event::Pose(pose) => {
                        ports.send_base_pose(&pose).map_err(|e| ClientError::Ports(e.to_string()))?;
                        report.latency.record(monotonic_ns().saturating_sub(arrival));
                        if lost {
                            lost = false;
                            log(format!("rigid body {:?} tracked again", cfg.rigid_body));
                        }
                    }
                    Event::Lost => {
                        lost = true;
                        log(format!(
                            "rigid body {:?} not tracked: publishing nothing until it is (the service stops the job after [base] timeout)",
                            cfg.rigid_body
                        ));
                    }
                    Event::Nothing => {}
                }
            }
        }
    }
    report.counters = session.counters();
    Ok(report)
}
