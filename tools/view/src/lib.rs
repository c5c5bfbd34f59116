//! strand-view: the live view. A Foxglove WebSocket server (`foxglove.websocket.v1`) that serves
//! the channels the MCAP log writes — the same topics, the same `ros2msg` schemas, the same CDR
//! bytes — so one Foxglove layout opens the live stream and a log alike.
//!
//! It is fed by the log writer thread, never by the tick: [`LiveView::publish`] takes a message the
//! writer has already encoded, drops it if its channel was sent less than `1 / rate` ago (the
//! network gets a decimated stream; the file gets everything), and otherwise hands it to the
//! server's own threads. With no client subscribed a publish costs one atomic load.
//!
//! A viewer opened mid-print must see what came before: a [`Replay::Last`] channel
//! (`/robot_description`) keeps its last message and sends it to each client that subscribes, as a
//! ROS latched topic does; on a [`Replay::History`] channel (`/bead`) the feeder is told a client
//! has subscribed ([`LiveView::history_wanted`]) and sends that client the whole history in one
//! message ([`LiveView::send_history`]), built only when someone asks for it.
//!
//! Control: read-only unless [`ViewOptions::control`] names the service. Then the server advertises
//! `clientPublish`, and a client may publish JSON [`ControlRequest`]s on [`CONTROL_TOPIC`]; each
//! becomes one `Control` message to the service over iceoryx2, sent from a thread of its own
//! (iceoryx2 ports stay on the thread that opened them). The service acknowledges in `/status`.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Sender, channel};
use std::sync::{Arc, Mutex};

use foxglove::websocket::{Capability, ChannelView, Client, ClientChannel, ServerListener};
use foxglove::{ChannelBuilder, Context, PartialMetadata, RawChannel, Schema, SinkId, WebSocketServer, WebSocketServerHandle};
use serde::Deserialize;
use strand_ipc as ipc;

/// The client channel a viewer publishes control requests on (JSON, [`ControlRequest`]).
pub(crate) const CONTROL_TOPIC: &str = "/strand/control";

/// Why the live view could not start or add a channel.
#[derive(Debug, thiserror::Error)]
pub enum ViewError {
    /// The server could not start (address in use, not an address of this machine).
    #[error("live view on {address}: {message}")]
    Start {
        /// The address asked for.
        address: SocketAddr,
        /// What failed.
        message: String,
    },
    /// A channel could not be added.
    #[error("live view channel {topic}: {message}")]
    Channel {
        /// Its topic.
        topic: String,
        /// What failed.
        message: String,
    },
    /// A control request that cannot be sent.
    #[error("control request: {0}")]
    Control(String),
}

/// How the server starts.
#[derive(Clone, Debug)]
pub struct ViewOptions {
    /// Where it listens.
    pub address: SocketAddr,
    /// The name clients show (the robot and the config).
    pub name: String,
    /// The service to send control requests to; `None`: read-only.
    pub control: Option<ipc::ServiceNames>,
}

/// A control request as a viewer publishes it on [`CONTROL_TOPIC`]:
/// `{"command": "pause"}`, `{"command": "feed", "percent": 80}`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
pub(crate) struct ControlRequest {
    /// `pause`, `resume`, `stop`, `estop`, `clear-fault`, `feed` or `flow` (not `start`: a job
    /// starts from its feeder, which streams it).
    pub command: String,
    /// The override in percent (`feed`, `flow`).
    #[serde(default)]
    pub percent: Option<f64>,
}

impl ControlRequest {
    /// The wire command and its value (a fraction for the overrides).
    pub(crate) fn to_wire(&self) -> Result<(ipc::Command, f64), ViewError> {
        let need_percent = || {
            self.percent
                .filter(|p| p.is_finite())
                .map(|p| p / 100.0)
                .ok_or_else(|| ViewError::Control(format!("{:?} needs \"percent\": a number", self.command)))
        };
        Ok(match self.command.as_str() {
            "pause" => (ipc::Command::Pause, 0.0),
            "resume" => (ipc::Command::Resume, 0.0),
            "stop" => (ipc::Command::Stop, 0.0),
            "estop" => (ipc::Command::EmergencyStop, 0.0),
            "clear-fault" => (ipc::Command::ClearFault, 0.0),
            "feed" => (ipc::Command::FeedOverride, need_percent()?),
            "flow" => (ipc::Command::FlowOverride, need_percent()?),
            other => {
                return Err(ViewError::Control(format!(
                    "unknown command {other:?}: pause, resume, stop, estop, clear-fault, feed or flow (a job starts from its feeder)"
                )));
            }
        })
    }
}

/// What a client that subscribes late gets of a channel's past.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Replay {
    /// Nothing: messages from then on.
    None,
    /// The last message (a latched topic).
    Last,
    /// The history, which the feeder builds on request ([`LiveView::history_wanted`]).
    History,
}

/// A channel of the live view (an index into the server's list).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ChannelIndex(usize);

struct LiveChannel {
    raw: Arc<RawChannel>,
    /// Shortest spacing between two messages sent (ns of log time); 0: every message.
    min_spacing_ns: u64,
    last_sent_ns: Option<u64>,
    replay: Replay,
}

/// The last message of a latched channel.
struct Latched {
    raw: Arc<RawChannel>,
    message: Vec<u8>,
    log_time_ns: u64,
}

/// Bytes handed to the server, for the report (payloads only; the framing adds 13 bytes each).
#[derive(Default)]
struct Counters {
    messages: AtomicU64,
    bytes: AtomicU64,
}

/// The running server. See the crate documentation.
pub struct LiveView {
    handle: Option<WebSocketServerHandle>,
    /// The server's runtime (dropped after the server stops).
    runtime: Option<tokio::runtime::Runtime>,
    context: Arc<Context>,
    channels: Vec<LiveChannel>,
    latched: Arc<Mutex<HashMap<String, Latched>>>,
    /// Clients waiting for a history channel's past, by topic.
    history_requests: Arc<Mutex<HashMap<String, Vec<SinkId>>>>,
    counters: Arc<Counters>,
    address: SocketAddr,
}

impl LiveView {
    /// Starts the server; it runs on its own threads until [`LiveView::stop`] or drop.
    ///
    /// Its runtime has one worker thread (plus tokio's blocking pool), niced to 10: on a robot PC
    /// the view must lose every contest for a core against the control loop, including when the
    /// loop runs on SCHED_OTHER (on SCHED_FIFO it never loses anyway). Measured on 2 cores at
    /// 1 kHz, SCHED_OTHER: the default runtime (a worker per core, nice 0) raised the tick's p99
    /// cost 3.4× with a client connected.
    pub fn start(options: &ViewOptions) -> Result<LiveView, ViewError> {
        let start_error = |message: String| ViewError::Start { address: options.address, message };
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .max_blocking_threads(2)
            .thread_name("strand-view")
            .on_thread_start(|| {
                // SAFETY: setpriority on the calling thread (who = 0 with PRIO_PROCESS is this
                // thread on Linux); no memory is touched.
                unsafe { libc::setpriority(libc::PRIO_PROCESS, 0, 10) };
            })
            .enable_all()
            .build()
            .map_err(|e| start_error(e.to_string()))?;
        let context = Context::new();
        let latched: Arc<Mutex<HashMap<String, Latched>>> = Arc::default();
        let history_requests: Arc<Mutex<HashMap<String, Vec<SinkId>>>> = Arc::default();
        let control = options.control.clone().map(ControlSender::start);
        let listener = Arc::new(Listener { latched: latched.clone(), history_requests: history_requests.clone(), control });
        let mut server = WebSocketServer::new()
            .name(options.name.clone())
            .bind(options.address.ip().to_string(), options.address.port())
            .context(&context)
            .tokio_runtime(runtime.handle())
            .listener(listener.clone());
        if options.control.is_some() {
            server = server.capabilities([Capability::ClientPublish]).supported_encodings(["json"]);
        }
        let handle = server.start_blocking().map_err(|e| start_error(e.to_string()))?;
        let address = SocketAddr::new(options.address.ip(), handle.port());
        Ok(LiveView {
            handle: Some(handle),
            runtime: Some(runtime),
            context,
            channels: Vec::new(),
            latched,
            history_requests,
            counters: Arc::default(),
            address,
        })
    }

    /// Where the server listens (the real port when 0 was asked for).
    pub fn address(&self) -> SocketAddr {
        self.address
    }

    /// Adds a channel: CDR messages of the `ros2msg` schema `schema_name` (text `schema`), sent at
    /// most `rate_hz` times a second (0: every message); `replay` says what a client that
    /// subscribes later gets of its past.
    pub fn add_channel(
        &mut self,
        topic: &str,
        schema_name: &str,
        schema: &str,
        rate_hz: f64,
        replay: Replay,
    ) -> Result<ChannelIndex, ViewError> {
        let raw = ChannelBuilder::new(topic)
            .message_encoding("cdr")
            .schema(Schema::new(schema_name, "ros2msg", schema.as_bytes().to_vec()))
            .context(&self.context)
            .build_raw()
            .map_err(|e| ViewError::Channel { topic: topic.to_string(), message: e.to_string() })?;
        match replay {
            Replay::Last => {
                let slot = Latched { raw: raw.clone(), message: Vec::new(), log_time_ns: 0 };
                self.latched.lock().expect("not poisoned").insert(topic.to_string(), slot);
            }
            Replay::History => {
                self.history_requests.lock().expect("not poisoned").insert(topic.to_string(), Vec::new());
            }
            Replay::None => {}
        }
        let min_spacing_ns = if rate_hz > 0.0 { (1e9 / rate_hz) as u64 } else { 0 };
        self.channels.push(LiveChannel { raw, min_spacing_ns, last_sent_ns: None, replay });
        Ok(ChannelIndex(self.channels.len() - 1))
    }

    /// Offers one encoded message (log time in Unix ns). Sent when its channel is due and a client
    /// subscribes to it; dropped otherwise (a [`Replay::Last`] channel always keeps it).
    pub fn publish(&mut self, channel: ChannelIndex, log_time_ns: u64, message: &[u8]) {
        let Some(ch) = self.channels.get_mut(channel.0) else { return };
        if ch.replay == Replay::Last
            && let Ok(mut latched) = self.latched.lock()
            && let Some(slot) = latched.get_mut(ch.raw.topic())
        {
            slot.message.clear();
            slot.message.extend_from_slice(message);
            slot.log_time_ns = log_time_ns;
        }
        if !ch.raw.has_sinks() {
            return;
        }
        if let Some(last) = ch.last_sent_ns
            && log_time_ns.saturating_sub(last) < ch.min_spacing_ns
            && log_time_ns >= last
        {
            return;
        }
        ch.last_sent_ns = Some(log_time_ns);
        ch.raw.log_with_meta(message, PartialMetadata { log_time: Some(log_time_ns) });
        self.counters.messages.fetch_add(1, Ordering::Relaxed);
        self.counters.bytes.fetch_add(message.len() as u64, Ordering::Relaxed);
    }

    /// True when a client has subscribed to this [`Replay::History`] channel since its history was
    /// last sent: build the history and [`send_history`](LiveView::send_history) it. One lock,
    /// no allocation.
    pub fn history_wanted(&self, channel: ChannelIndex) -> bool {
        let Some(ch) = self.channels.get(channel.0).filter(|c| c.replay == Replay::History) else { return false };
        self.history_requests.lock().is_ok_and(|r| r.get(ch.raw.topic()).is_some_and(|v| !v.is_empty()))
    }

    /// Sends `message` (the channel's history) to every client waiting for it, and to no other;
    /// an empty `message` (no history yet) only clears the requests.
    pub fn send_history(&mut self, channel: ChannelIndex, log_time_ns: u64, message: &[u8]) {
        let Some(ch) = self.channels.get(channel.0) else { return };
        let waiting = self.history_requests.lock().ok().and_then(|mut r| r.get_mut(ch.raw.topic()).map(std::mem::take)).unwrap_or_default();
        for sink in waiting.into_iter().filter(|_| !message.is_empty()) {
            ch.raw.log_with_meta_to_sink(message, PartialMetadata { log_time: Some(log_time_ns) }, Some(sink));
            self.counters.messages.fetch_add(1, Ordering::Relaxed);
            self.counters.bytes.fetch_add(message.len() as u64, Ordering::Relaxed);
        }
    }

    /// Messages and payload bytes handed to the server so far (for every subscribed client).
    pub fn sent(&self) -> (u64, u64) {
        (self.counters.messages.load(Ordering::Relaxed), self.counters.bytes.load(Ordering::Relaxed))
    }

    /// Stops the server and closes every connection.
    pub fn stop(mut self) {
        self.shut_down();
    }

    fn shut_down(&mut self) {
        if let Some(h) = self.handle.take() {
            // Wait (briefly) for the connections to close, then drop the runtime's threads.
            let done = h.stop();
            if let Some(rt) = self.runtime.as_ref() {
                let _ = rt.block_on(async { tokio::time::timeout(std::time::Duration::from_secs(1), done.wait()).await });
            }
        }
        if let Some(rt) = self.runtime.take() {
            rt.shutdown_timeout(std::time::Duration::from_millis(500));
        }
    }
}

impl Drop for LiveView {
    fn drop(&mut self) {
        self.shut_down();
    }
}

/// The server's callbacks: latched messages and history requests for new subscribers, control
/// requests to the service.
struct Listener {
    latched: Arc<Mutex<HashMap<String, Latched>>>,
    history_requests: Arc<Mutex<HashMap<String, Vec<SinkId>>>>,
    control: Option<ControlSender>,
}

impl ServerListener for Listener {
    fn on_subscribe(&self, client: Client, channel: ChannelView) {
        if let (Ok(mut requests), Some(sink)) = (self.history_requests.lock(), client.sink_id())
            && let Some(waiting) = requests.get_mut(channel.topic())
        {
            waiting.push(sink);
        }
        let Ok(latched) = self.latched.lock() else { return };
        if let Some(slot) = latched.get(channel.topic())
            && !slot.message.is_empty()
        {
            slot.raw.log_with_meta_to_sink(&slot.message, PartialMetadata { log_time: Some(slot.log_time_ns) }, client.sink_id());
        }
    }

    fn on_message_data(&self, client: Client, channel: &ClientChannel, payload: &[u8]) {
        let Some(control) = &self.control else { return };
        if channel.topic != CONTROL_TOPIC {
            return;
        }
        let request = serde_json::from_slice::<ControlRequest>(payload)
            .map_err(|e| ViewError::Control(format!("not a control request ({e}): expected {{\"command\": \"pause\"}}")))
            .and_then(|r| r.to_wire());
        match request {
            Ok((command, value)) => {
                if !control.send(command, value) {
                    let e = "control requests cannot reach the service (its control ports could not be opened; see the service's log)";
                    client.send_status(foxglove::websocket::Status::error(e));
                }
            }
            Err(e) => {
                tracing::warn!("live view client {:?}: {e}", client.id());
                client.send_status(foxglove::websocket::Status::warning(e.to_string()));
            }
        }
    }
}

/// Sends control requests to the service from a thread of its own (iceoryx2 ports are not `Send`;
/// the server's callbacks run on its tokio threads).
struct ControlSender {
    requests: Mutex<Sender<(ipc::Command, f64)>>,
}

impl ControlSender {
    fn start(names: ipc::ServiceNames) -> ControlSender {
        let (tx, rx) = channel::<(ipc::Command, f64)>();
        let spawned = std::thread::Builder::new().name("strand-view-control".into()).spawn(move || {
            let roles = ipc::ports::ClientRoles { control: true, ..ipc::ports::ClientRoles::default() };
            let ports = match ipc::ports::ClientPorts::open(&names, "strand_view_control", roles) {
                Ok(p) => p,
                Err(e) => {
                    tracing::error!("live view: control requests cannot reach the service: {e}");
                    return;
                }
            };
            let mut seq = 0u64;
            while let Ok((command, value)) = rx.recv() {
                seq += 1;
                let control = ipc::Control { seq, stamp_ns: monotonic_ns(), command: command as u32, _reserved: 0, value };
                match ports.send_control(&control) {
                    Ok(_) => tracing::info!("live view: control {command:?} {value} sent"),
                    Err(e) => tracing::error!("live view: control {command:?}: {e}"),
                }
            }
        });
        if let Err(e) = spawned {
            tracing::error!("live view: no control thread: {e}");
        }
        ControlSender { requests: Mutex::new(tx) }
    }

    /// Queues a request for the control thread; false when that thread is gone (its ports could
    /// not be opened).
    fn send(&self, command: ipc::Command, value: f64) -> bool {
        self.requests.lock().is_ok_and(|tx| tx.send((command, value)).is_ok())
    }
}

/// CLOCK_MONOTONIC (ns), the clock every stamp on the wire uses.
fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `ts` is a valid out-pointer; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}
