//! The client's state machine, without I/O: connect → model definitions → streaming, every
//! deadline of the handshake and the keep-alives, and each frame turned into a `BasePose` or into
//! nothing.
//!
//! Time comes in as arguments (`CLOCK_MONOTONIC` ns), packets as bytes; what to send comes out.
//! The I/O loop (`client.rs`) only moves bytes and calls [`Session::poll`] by
//! [`Session::next_deadline`]. So the handshake's retries and timeouts are tested without sockets.
//!
//! **The timestamp.** A frame carries three stamps in Motive's clock: camera mid-exposure, data
//! received and transmit. Their difference transmit − mid-exposure is the frame's own latency
//! inside Motive (exposure, readout, solving); the client's arrival time minus that latency is the
//! capture time on the client's `CLOCK_MONOTONIC`, short only by the network transit (tens of µs on
//! a switched LAN; `[base] measurement_delay` can add a constant for it).
//!
//! **Untracked frames publish nothing.** A frame in which Motive lost the body (its tracking
//! flag clear, or the body absent) is counted and dropped, so the service sees the tracker fall
//! silent and `[base] timeout` stops the job as for any stale sensor; the next tracked frame
//! publishes again.

use std::net::SocketAddrV4;

use strand_ipc::BasePose;
use thiserror::Error;

use crate::mapping::FrameMapping;
use crate::protocol::{self, Description, FRAME_MODELS_CHANGED, ParseError, ServerInfo, Version};

/// Retry the connect or the model definitions request this often while unanswered (ns).
const RETRY_NS: u64 = 250_000_000;
/// A frame number this far behind the last one is Motive counting from the start again.
const RESTART_FRAMES: i32 = 1000;

/// What the session needs besides the mapping.
#[derive(Clone, Debug, PartialEq)]
pub struct SessionConfig {
    /// Motive's command address (for messages).
    pub server: SocketAddrV4,
    /// The rigid body's name.
    pub rigid_body: String,
    /// Whether the client listens for multicast (must match Motive).
    pub multicast: bool,
    /// Longest wait for each handshake answer (ns).
    pub connect_timeout_ns: u64,
    /// Unicast keep-alive period (ns).
    pub keepalive_ns: u64,
}

/// Why the session cannot go on. Each names what to check.
#[derive(Clone, Debug, PartialEq, Error)]
pub enum SessionError {
    /// No server info within the timeout.
    #[error(
        "no answer from a NatNet server at {server} within {seconds:.1} s ({tries} connect requests sent): is Motive running with streaming on (Edit → Settings → Streaming → NatNet: Enable), and are [tracker] server and command_port (--server) its address and command port?"
    )]
    NoAnswer {
        /// Motive's command address.
        server: SocketAddrV4,
        /// The timeout (s).
        seconds: f64,
        /// Connect packets sent.
        tries: u32,
    },
    /// No model definitions within the timeout.
    #[error("the NatNet server at {server} answered the connect but sent no model definitions within {seconds:.1} s")]
    NoModelDefinitions {
        /// Motive's command address.
        server: SocketAddrV4,
        /// The timeout (s).
        seconds: f64,
    },
    /// The rigid body is not in the model definitions.
    #[error("the NatNet server at {server} has no rigid body named {name:?} ([tracker] rigid_body); it has: {available}")]
    RigidBodyNotFound {
        /// Motive's command address.
        server: SocketAddrV4,
        /// The name looked for.
        name: String,
        /// The rigid bodies it has, listed.
        available: String,
    },
    /// A server older than NatNet 3.0.
    #[error("{app} {app_version} streams NatNet {version}; strand-natnet reads NatNet 3.0 to 4.2 (Motive 2.0 or later)")]
    Unsupported {
        /// The server application.
        app: String,
        /// Its version.
        app_version: Version,
        /// Its NatNet version.
        version: Version,
    },
    /// Unicast against multicast.
    #[error("Motive streams {motive} (its Transmission Type) but [tracker] transmission = {ours:?}: set one to the other")]
    TransmissionMismatch {
        /// What Motive does.
        motive: &'static str,
        /// What the config says.
        ours: &'static str,
    },
    /// A handshake packet that cannot be read.
    #[error("NatNet server at {server}: unreadable {what}: {error}")]
    Garbled {
        /// Motive's command address.
        server: SocketAddrV4,
        /// Which packet.
        what: &'static str,
        /// Why.
        error: ParseError,
    },
}

/// Counters of what came in (reported at exit and in `--stats`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Counters {
    /// Frames read.
    pub frames: u64,
    /// Poses published.
    pub published: u64,
    /// Frames with the body present but not tracked (nothing published).
    pub untracked: u64,
    /// Frames without the body (nothing published).
    pub missing: u64,
    /// Frames whose body pose was not finite or not a unit quaternion (nothing published).
    pub invalid: u64,
    /// Frames with a number not after the last one (duplicates, reordered; dropped).
    pub out_of_order: u64,
    /// Packets that could not be read (dropped).
    pub malformed: u64,
    /// Frames before the rigid body was known (dropped).
    pub early: u64,
    /// Frames without a usable latency (no server clock; stamped at arrival).
    pub unstamped: u64,
    /// Model definitions asked again because Motive said its models changed.
    pub redefinitions: u64,
}

/// What the handshake learnt (printed once streaming).
#[derive(Clone, Debug, PartialEq)]
pub struct Ready {
    /// The server's answer to the connect.
    pub server: ServerInfo,
    /// The rigid body's id in frames.
    pub body_id: i32,
}

/// What one packet or one poll asks of the I/O loop.
#[derive(Clone, Debug, PartialEq)]
pub enum Event {
    /// Nothing to do.
    Nothing,
    /// Send this to Motive's command port.
    Send(Vec<u8>),
    /// The handshake is done (the first time; again after a redefinition, with the new id).
    Ready(Ready),
    /// Publish this pose.
    Pose(BasePose),
    /// The body stopped being tracked (said once; the next [`Event::Pose`] means it is back).
    Lost,
}

#[derive(Clone, Debug, PartialEq)]
enum State {
    Connecting { since_ns: u64, next_ns: u64, tries: u32 },
    Describing { since_ns: u64, next_ns: u64 },
    Streaming { body_id: i32, keepalive_ns: u64, redefining: bool },
}

/// The NatNet client session. See the module docs.
#[derive(Clone, Debug)]
pub struct Session {
    cfg: SessionConfig,
    mapping: FrameMapping,
    state: State,
    server: Option<ServerInfo>,
    counters: Counters,
    last_frame: Option<i32>,
    /// Whether the last frame had the body tracked (`None` before the first frame).
    tracked: Option<bool>,
}

impl Session {
    /// A session that has sent nothing yet.
    pub fn new(cfg: SessionConfig, mapping: FrameMapping) -> Self {
        Session {
            cfg,
            mapping,
            state: State::Connecting { since_ns: 0, next_ns: 0, tries: 0 },
            server: None,
            counters: Counters::default(),
            last_frame: None,
            tracked: None,
        }
    }

    /// The counters so far.
    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// The server's answer to the connect, once it came.
    pub fn server(&self) -> Option<&ServerInfo> {
        self.server.as_ref()
    }

    /// Whether the handshake is done and frames are turned into poses.
    pub fn streaming(&self) -> bool {
        matches!(self.state, State::Streaming { .. })
    }

    /// The connect packet; the handshake's clock starts at `now_ns`.
    pub fn start(&mut self, now_ns: u64) -> Vec<u8> {
        self.state = State::Connecting { since_ns: now_ns, next_ns: now_ns + RETRY_NS, tries: 1 };
        protocol::connect_packet()
    }

    /// When [`Session::poll`] wants to be called next (ns).
    pub fn next_deadline(&self) -> u64 {
        match self.state {
            State::Connecting { since_ns, next_ns, .. } => next_ns.min(since_ns + self.cfg.connect_timeout_ns),
            State::Describing { since_ns, next_ns } => next_ns.min(since_ns + self.cfg.connect_timeout_ns),
            State::Streaming { keepalive_ns, .. } => keepalive_ns,
        }
    }

    /// Retries, keep-alives and timeouts due at `now_ns`.
    pub fn poll(&mut self, now_ns: u64) -> Result<Event, SessionError> {
        let timeout = self.cfg.connect_timeout_ns;
        match &mut self.state {
            State::Connecting { since_ns, next_ns, tries } => {
                if now_ns >= *since_ns + timeout {
                    return Err(SessionError::NoAnswer { server: self.cfg.server, seconds: timeout as f64 * 1e-9, tries: *tries });
                }
                if now_ns >= *next_ns {
                    *next_ns = now_ns + RETRY_NS;
                    *tries += 1;
                    return Ok(Event::Send(protocol::connect_packet()));
                }
            }
            State::Describing { since_ns, next_ns } => {
                if now_ns >= *since_ns + timeout {
                    return Err(SessionError::NoModelDefinitions { server: self.cfg.server, seconds: timeout as f64 * 1e-9 });
                }
                if now_ns >= *next_ns {
                    *next_ns = now_ns + RETRY_NS;
                    return Ok(Event::Send(protocol::request_packet(protocol::NAT_REQUEST_MODELDEF)));
                }
            }
            State::Streaming { keepalive_ns, .. } => {
                if now_ns >= *keepalive_ns {
                    *keepalive_ns = now_ns + self.cfg.keepalive_ns;
                    // Unicast subscriptions expire without it; multicast needs none.
                    if !self.cfg.multicast {
                        return Ok(Event::Send(protocol::request_packet(protocol::NAT_KEEPALIVE)));
                    }
                }
            }
        }
        Ok(Event::Nothing)
    }

    /// One datagram from Motive (on either socket) that arrived at `arrival_ns`
    /// (`CLOCK_MONOTONIC`). Unreadable frames are counted and dropped; an unreadable handshake
    /// answer is an error.
    pub fn handle(&mut self, arrival_ns: u64, datagram: &[u8]) -> Result<Event, SessionError> {
        let (id, payload) = match protocol::split(datagram) {
            Ok(x) => x,
            Err(_) => {
                self.counters.malformed += 1;
                return Ok(Event::Nothing);
            }
        };
        match id {
            protocol::NAT_SERVERINFO => self.on_server_info(arrival_ns, payload),
            protocol::NAT_MODELDEF => self.on_model_definitions(arrival_ns, payload),
            protocol::NAT_FRAMEOFDATA => Ok(self.on_frame(arrival_ns, payload)),
            _ => Ok(Event::Nothing),
        }
    }

    fn on_server_info(&mut self, now_ns: u64, payload: &[u8]) -> Result<Event, SessionError> {
        if !matches!(self.state, State::Connecting { .. }) {
            return Ok(Event::Nothing);
        }
        let info = protocol::parse_server_info(payload).map_err(|error| SessionError::Garbled {
            server: self.cfg.server,
            what: "server info",
            error,
        })?;
        if !info.natnet_version.at_least(3, 0) {
            return Err(SessionError::Unsupported { app: info.app_name, app_version: info.app_version, version: info.natnet_version });
        }
        if let Some(c) = info.connection
            && c.multicast != self.cfg.multicast
        {
            let name = |m: bool| if m { "multicast" } else { "unicast" };
            return Err(SessionError::TransmissionMismatch { motive: name(c.multicast), ours: name(self.cfg.multicast) });
        }
        self.server = Some(info);
        self.state = State::Describing { since_ns: now_ns, next_ns: now_ns + RETRY_NS };
        Ok(Event::Send(protocol::request_packet(protocol::NAT_REQUEST_MODELDEF)))
    }

    fn on_model_definitions(&mut self, now_ns: u64, payload: &[u8]) -> Result<Event, SessionError> {
        let redefining = matches!(self.state, State::Streaming { redefining: true, .. });
        if !(matches!(self.state, State::Describing { .. }) || redefining) {
            return Ok(Event::Nothing);
        }
        let Some(server) = self.server.clone() else { return Ok(Event::Nothing) };
        let defs = match protocol::parse_model_definitions(payload, server.natnet_version) {
            Ok(d) => d,
            Err(error) if !redefining => return Err(SessionError::Garbled { server: self.cfg.server, what: "model definitions", error }),
            Err(_) => {
                self.counters.malformed += 1;
                return Ok(Event::Nothing);
            }
        };
        let bodies: Vec<_> = defs
            .iter()
            .filter_map(|d| match d {
                Description::RigidBody(b) => Some(b),
                _ => None,
            })
            .collect();
        let Some(body) = bodies.iter().find(|b| b.name == self.cfg.rigid_body) else {
            let available = if bodies.is_empty() {
                "no rigid bodies (create one in Motive and check Streaming → Rigid Bodies is on)".to_string()
            } else {
                bodies.iter().map(|b| format!("{:?} (id {})", b.name, b.id)).collect::<Vec<_>>().join(", ")
            };
            return Err(SessionError::RigidBodyNotFound { server: self.cfg.server, name: self.cfg.rigid_body.clone(), available });
        };
        let keepalive_ns = match self.state {
            State::Streaming { keepalive_ns, .. } => keepalive_ns,
            _ => now_ns + self.cfg.keepalive_ns,
        };
        self.state = State::Streaming { body_id: body.id, keepalive_ns, redefining: false };
        Ok(Event::Ready(Ready { server, body_id: body.id }))
    }

    fn on_frame(&mut self, arrival_ns: u64, payload: &[u8]) -> Event {
        let (body_id, redefining) = match self.state {
            State::Streaming { body_id, redefining, .. } => (body_id, redefining),
            _ => {
                self.counters.early += 1;
                return Event::Nothing;
            }
        };
        let Some(server) = &self.server else { return Event::Nothing };
        let frame = match protocol::parse_frame(payload, server.natnet_version) {
            Ok(f) => f,
            Err(_) => {
                self.counters.malformed += 1;
                return Event::Nothing;
            }
        };
        self.counters.frames += 1;
        // A small step back is a duplicate or a reordered datagram; a large one is Motive
        // restarting its count (a new take, a playback loop), which goes on.
        if self.last_frame.is_some_and(|last| frame.number <= last && last - frame.number < RESTART_FRAMES) {
            self.counters.out_of_order += 1;
            return Event::Nothing;
        }
        self.last_frame = Some(frame.number);
        if frame.params & FRAME_MODELS_CHANGED != 0 && !redefining {
            // The body's id may have changed: ask again, and go on with the old id meanwhile.
            self.counters.redefinitions += 1;
            if let State::Streaming { redefining, .. } = &mut self.state {
                *redefining = true;
            }
            return Event::Send(protocol::request_packet(protocol::NAT_REQUEST_MODELDEF));
        }
        let Some(body) = frame.rigid_bodies.iter().find(|b| b.id == body_id) else {
            self.counters.missing += 1;
            return self.lost();
        };
        if !body.tracked() {
            self.counters.untracked += 1;
            return self.lost();
        }
        let Some((position, orientation)) = self.mapping.base_pose(body.position, body.orientation) else {
            self.counters.invalid += 1;
            return Event::Nothing;
        };
        let latency_ns = frame_latency_ns(&frame, server.clock_hz);
        if latency_ns.is_none() {
            self.counters.unstamped += 1;
        }
        self.tracked = Some(true);
        self.counters.published += 1;
        // The packet's own sequence, as the robot drivers do: Motive's frame number.
        Event::Pose(BasePose {
            seq: frame.number.max(0) as u64,
            stamp_ns: arrival_ns.saturating_sub(latency_ns.unwrap_or(0)),
            position,
            orientation,
        })
    }

    /// The body is not tracked in this frame: say so on the first such frame after a tracked one
    /// (or the first frame of all).
    fn lost(&mut self) -> Event {
        let was = self.tracked.replace(false);
        if was != Some(false) { Event::Lost } else { Event::Nothing }
    }
}

/// Transmit − mid-exposure in ns, if the server gave its clock and the stamps are ordered and
/// under a second (anything else is not a latency).
pub fn frame_latency_ns(frame: &protocol::Frame, clock_hz: u64) -> Option<u64> {
    if clock_hz == 0 || frame.mid_exposure == 0 || frame.transmit < frame.mid_exposure {
        return None;
    }
    let ticks = (frame.transmit - frame.mid_exposure) as u128;
    let ns = ticks * 1_000_000_000 / clock_hz as u128;
    (ns < 1_000_000_000).then_some(ns as u64)
}
