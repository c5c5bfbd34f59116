//! A fake Motive: a NatNet server on the loopback that answers the handshake and streams frames
//! of a rigid body moving on a known trajectory, so the client is tested against the protocol
//! rather than against itself.
//!
//! It answers `NAT_CONNECT` with the server info (its NatNet version, a high-resolution clock of
//! `clock_hz` ticks per second — `CLOCK_MONOTONIC` scaled — and its data connection),
//! `NAT_REQUEST_MODELDEF` with the model definitions (a marker set, the rigid bodies, a skeleton,
//! a force plate, a device, a camera and, from 4.1, an asset: everything a client must skip), and
//! streams frames at `rate_hz` — to the multicast group, or (unicast) to every client that
//! connected, at the address it connected from. Each frame's camera mid-exposure is `latency`
//! before its transmit stamp, as Motive's are, and the body is where the trajectory puts it at
//! mid-exposure. It records what it sent so a test can compare.

use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4, UdpSocket};
use std::ops::Range;
use std::os::fd::AsRawFd;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use strand::io::clock::monotonic_ns;

use crate::protocol::{self, DataConnection, Description, Frame, RigidBodyDescription, RigidBodyPose, ServerInfo, Version};

/// A trajectory: time since the fake started (s) → position (m) and orientation (x, y, z, w) in
/// Motive's world. A closure, so that a simulator can stream the pose its plant is really in.
pub type Trajectory = std::sync::Arc<dyn Fn(f64) -> ([f64; 3], [f64; 4]) + Send + Sync>;

/// What the fake is.
#[derive(Clone)]
pub struct FakeConfig {
    /// The NatNet version it streams (3.0 to 4.2).
    pub version: Version,
    /// Its rigid bodies: name and id. The first moves on `trajectory`; the others stand still.
    pub bodies: Vec<(String, i32)>,
    /// Multicast to this group and data port; `None`: unicast.
    pub multicast: Option<(Ipv4Addr, u16)>,
    /// Frames per second.
    pub rate_hz: f64,
    /// Its clock's frequency (ticks per second).
    pub clock_hz: u64,
    /// Mid-exposure → transmit (s): the frame's own latency.
    pub latency: f64,
    /// Frame numbers in which the first body is not tracked (empty: none).
    pub untracked: Range<i32>,
    /// Answer nothing (a server that does not answer).
    pub silent: bool,
    /// The first body's trajectory.
    pub trajectory: Trajectory,
}

impl std::fmt::Debug for FakeConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FakeConfig")
            .field("version", &self.version)
            .field("bodies", &self.bodies)
            .field("multicast", &self.multicast)
            .field("rate_hz", &self.rate_hz)
            .field("latency", &self.latency)
            .finish_non_exhaustive()
    }
}

/// A frame as sent, for the test.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SentFrame {
    /// Its number.
    pub number: i32,
    /// Camera mid-exposure on the client's `CLOCK_MONOTONIC` (ns).
    pub mid_exposure_ns: u64,
    /// The first body's position (m, Motive's world), as sent (f32).
    pub position: [f32; 3],
    /// Its orientation (x, y, z, w), as sent.
    pub orientation: [f32; 4],
    /// Whether it was sent as tracked.
    pub tracked: bool,
}

/// A running fake Motive; stopped when dropped.
pub struct FakeMotive {
    command: SocketAddrV4,
    stop: Arc<AtomicBool>,
    sent: Arc<Mutex<Vec<SentFrame>>>,
    keepalives: Arc<AtomicU64>,
    thread: Option<JoinHandle<()>>,
}

impl FakeMotive {
    /// Starts it with its command socket on 127.0.0.1:`command_port` (0: any free port).
    pub fn start(cfg: FakeConfig, command_port: u16) -> std::io::Result<Self> {
        let command = UdpSocket::bind(SocketAddrV4::new(Ipv4Addr::LOCALHOST, command_port))?;
        command.set_read_timeout(Some(Duration::from_millis(1)))?;
        let addr = match command.local_addr()? {
            SocketAddr::V4(a) => a,
            SocketAddr::V6(_) => unreachable!("bound to an IPv4 address"),
        };
        let data = UdpSocket::bind(SocketAddrV4::new(Ipv4Addr::LOCALHOST, 0))?;
        if cfg.multicast.is_some() {
            set_multicast_interface(&data, Ipv4Addr::LOCALHOST)?;
            data.set_multicast_loop_v4(true)?;
        }
        let stop = Arc::new(AtomicBool::new(false));
        let sent = Arc::new(Mutex::new(Vec::new()));
        let keepalives = Arc::new(AtomicU64::new(0));
        let (s, r, k) = (stop.clone(), sent.clone(), keepalives.clone());
        let thread = std::thread::Builder::new().name("fake-motive".into()).spawn(move || serve(cfg, command, data, &s, &r, &k))?;
        Ok(FakeMotive { command: addr, stop, sent, keepalives, thread: Some(thread) })
    }

    /// Its command address.
    pub fn command_addr(&self) -> SocketAddrV4 {
        self.command
    }

    /// The frames sent so far.
    pub fn sent(&self) -> Vec<SentFrame> {
        self.sent.lock().map(|s| s.clone()).unwrap_or_default()
    }

    /// Keep-alives received.
    pub fn keepalives(&self) -> u64 {
        self.keepalives.load(Ordering::Relaxed)
    }
}

impl Drop for FakeMotive {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn set_multicast_interface(socket: &UdpSocket, interface: Ipv4Addr) -> std::io::Result<()> {
    let addr = libc::in_addr { s_addr: u32::from(interface).to_be() };
    // SAFETY: a valid socket and a valid in_addr of the size given.
    let r = unsafe {
        libc::setsockopt(
            socket.as_raw_fd(),
            libc::IPPROTO_IP,
            libc::IP_MULTICAST_IF,
            &addr as *const _ as *const libc::c_void,
            std::mem::size_of::<libc::in_addr>() as libc::socklen_t,
        )
    };
    if r == 0 { Ok(()) } else { Err(std::io::Error::last_os_error()) }
}

fn body_description(name: &str, id: i32) -> RigidBodyDescription {
    RigidBodyDescription {
        name: name.into(),
        id,
        parent_id: -1,
        offset: [0.0; 3],
        orientation_offset: [0.0, 0.0, 0.0, 1.0],
        markers: (0..4).map(|i| ([0.05 * i as f32, 0.0, 0.02], i + 1, format!("{name}_{}", i + 1))).collect(),
    }
}

fn descriptions(cfg: &FakeConfig) -> Vec<Description> {
    let mut d = vec![Description::MarkerSet("all".into(), vec!["m1".into(), "m2".into()])];
    d.extend(cfg.bodies.iter().map(|(n, id)| Description::RigidBody(body_description(n, *id))));
    d.push(Description::Skeleton("walker".into(), 70, vec![body_description("hip", 71), body_description("knee", 72)]));
    d.push(Description::ForcePlate(1, "FP-0001".into(), vec!["Fz".into(), "Mx".into()]));
    d.push(Description::Device(2, "daq".into(), "NI-01".into(), vec!["ai0".into()]));
    d.push(Description::Camera("Prime 17W #1".into(), [1.0, 2.5, -1.0], [0.0, 0.38, 0.0, 0.92]));
    d.push(Description::Asset("glove".into(), 1, 80, vec![body_description("palm", 81)], vec![("tip".into(), 82)]));
    d
}

fn pose(id: i32, position: [f32; 3], orientation: [f32; 4], tracked: bool) -> RigidBodyPose {
    RigidBodyPose { id, position, orientation, mean_error: 0.0004, params: if tracked { protocol::BODY_TRACKED } else { 0 } }
}

fn frame(cfg: &FakeConfig, number: i32, t: f64, mid_ticks: u64, transmit_ticks: u64, tracked: bool) -> (Frame, [f32; 3], [f32; 4]) {
    let (p, q) = (cfg.trajectory)(t);
    let (p, q) = (p.map(|v| v as f32), q.map(|v| v as f32));
    let mut bodies = Vec::new();
    for (i, (_, id)) in cfg.bodies.iter().enumerate() {
        bodies.push(if i == 0 {
            // Motive sends an untracked body with a zero pose.
            if tracked { pose(*id, p, q, true) } else { pose(*id, [0.0; 3], [0.0; 4], false) }
        } else {
            pose(*id, [0.3 * i as f32, 0.0, 0.1], [0.0, 0.0, 0.0, 1.0], true)
        });
    }
    let f = Frame {
        number,
        marker_sets: vec![("all".into(), vec![[0.1, 0.2, 0.3], [0.4, 0.5, 0.6], [0.7, 0.8, 0.9]])],
        other_markers: vec![[1.0, 1.1, 1.2], [1.3, 1.4, 1.5]],
        rigid_bodies: bodies,
        skeletons: vec![(
            70,
            vec![pose(71, [0.0, 0.9, 0.0], [0.0, 0.0, 0.0, 1.0], true), pose(72, [0.0, 0.5, 0.0], [0.0, 0.0, 0.0, 1.0], true)],
        )],
        assets: vec![(80, vec![pose(81, [0.2, 1.0, 0.2], [0.0, 0.0, 0.0, 1.0], true)], vec![(82, [0.2, 1.1, 0.2], 0.014, 0, 0.0002)])],
        labeled_markers: (0..3).map(|i| (i, [0.1 * i as f32, 0.0, 0.0], 0.014, 0, 0.0001)).collect(),
        force_plates: vec![(1, vec![vec![1.0, 2.0, 3.0], vec![4.0, 5.0, 6.0]])],
        devices: vec![(2, vec![vec![0.5, 0.25]])],
        timecode: (0, 0),
        timestamp: t,
        mid_exposure: mid_ticks,
        data_received: mid_ticks + (transmit_ticks - mid_ticks) / 2,
        transmit: transmit_ticks,
        precision: (0, 0),
        params: 0,
    };
    (f, p, q)
}

fn serve(cfg: FakeConfig, command: UdpSocket, data: UdpSocket, stop: &AtomicBool, sent: &Mutex<Vec<SentFrame>>, keepalives: &AtomicU64) {
    let ticks = |ns: u64| (ns as u128 * cfg.clock_hz as u128 / 1_000_000_000) as u64;
    let start = monotonic_ns();
    let period_ns = (1e9 / cfg.rate_hz) as u64;
    let latency_ns = (cfg.latency * 1e9) as u64;
    let data_port = cfg.multicast.map_or(0, |(_, p)| p);
    let info = ServerInfo {
        app_name: "Motive".into(),
        app_version: Version([3, 1, 0, 0]),
        natnet_version: cfg.version,
        clock_hz: cfg.clock_hz,
        connection: Some(DataConnection {
            data_port: if data_port == 0 { 1511 } else { data_port },
            multicast: cfg.multicast.is_some(),
            multicast_group: cfg.multicast.map_or([239, 255, 42, 99], |(g, _)| g.octets()),
        }),
    };
    let defs = descriptions(&cfg);
    let mut clients: Vec<SocketAddr> = Vec::new();
    let mut next_frame = start + period_ns;
    let mut number = 0i32;
    let mut buf = vec![0u8; 2048];
    while !stop.load(Ordering::Relaxed) {
        if let Ok((len, from)) = command.recv_from(&mut buf)
            && !cfg.silent
            && let Ok((id, _)) = protocol::split(&buf[..len])
        {
            match id {
                protocol::NAT_CONNECT => {
                    if !clients.contains(&from) {
                        clients.push(from);
                    }
                    let _ = command.send_to(&protocol::server_info_packet(&info), from);
                }
                protocol::NAT_REQUEST_MODELDEF => {
                    let _ = command.send_to(&protocol::model_definitions_packet(&defs, cfg.version), from);
                }
                protocol::NAT_KEEPALIVE => {
                    keepalives.fetch_add(1, Ordering::Relaxed);
                }
                _ => {}
            }
        }
        let now = monotonic_ns();
        if cfg.silent || now < next_frame {
            continue;
        }
        next_frame += period_ns;
        number += 1;
        let mid = now.saturating_sub(latency_ns);
        let t = mid.saturating_sub(start) as f64 * 1e-9;
        let tracked = !cfg.untracked.contains(&number);
        // The transmit stamp is taken last, just before the send.
        let (mut f, p, q) = frame(&cfg, number, t, ticks(mid), ticks(monotonic_ns()), tracked);
        f.transmit = ticks(monotonic_ns());
        let bytes = protocol::frame_packet(&f, cfg.version);
        if let Ok(mut s) = sent.lock() {
            s.push(SentFrame { number, mid_exposure_ns: mid, position: p, orientation: q, tracked });
        }
        match cfg.multicast {
            Some((group, port)) => {
                let _ = data.send_to(&bytes, SocketAddrV4::new(group, port));
            }
            None => {
                for c in &clients {
                    let _ = data.send_to(&bytes, c);
                }
            }
        }
    }
}
