//! The iceoryx2 ports of both sides of the wire contract: the controller's [`ServicePorts`] and the
//! feeder / driver / tracker / monitor [`ClientPorts`], over services whose quality of service is
//! fixed here, in one place, so whoever creates a service and whoever opens it agree.
//!
//! Every publish-subscribe service has an event service of the same name; publishers notify it after
//! each send, so a peer can block (robot clock, a driver waiting for its command) instead of polling.
//!
//! Quality of service ([`Qos`], all with safe overflow: a full subscriber queue overwrites its oldest
//! sample, a send never blocks):
//!
//! | service | subscriber buffer | history | publishers | subscribers |
//! |---|---|---|---|---|
//! | segments | 256 | 0 | 4 | 8 |
//! | control | 64 | 0 | 4 | 8 |
//! | joint_state, base_pose, heater_state | 16 | 0 | 4 | 8 |
//! | joint_command, extruder_command, heater_command, status | 16 | 1 | 1 | 8 |
//!
//! Segments are never lost to the overflow: flow control is credit-based. A feeder sends segment
//! sequence numbers only up to `Status.last_received_seq + Status.queue_free`, and the controller
//! drains the segment queue every tick, so at most `queue_free` segments (a few batches) are ever in
//! flight, far below the 256-batch buffer. Controls are rare and drained every tick. For joint state
//! and base pose only the latest sample matters. The controller outputs keep a history of one, so a
//! monitor that subscribes late sees the last status at the controller's next send, and allow a
//! single publisher: a second controller on the same service names fails at [`ServicePorts::open`]
//! instead of commanding the same robot.
//!
//! Memory: a segments publisher sizes its shared memory for every possible subscriber's full buffer,
//! 11.3 MB of `/dev/shm` (sparse: only touched pages are resident, unless a process that maps it
//! locks its memory with `mlockall`). Docker's default `/dev/shm` is 64 MB.
//!
//! Tick path. Receiving, waiting, publishing and the publisher counts are tick-path safe: no
//! allocation, no mutex (the ports are single-threaded), no printing, no `tracing`; they copy the
//! fixed-size payloads in and out. Publishing allocates nothing because the ports use
//! [`crate::recycling::Service`], `ipc::Service` with iceoryx2 0.10's per-loan shared state recycled
//! (plain `ipc::Service` makes one small heap allocation per sample); `tests/ports.rs` counts zero.
//! Only the error paths allocate (the [`PortError`] text): treat an error as a fault, not something
//! to retry every tick. Opening and [`cleanup_dead_nodes`] are start-up code. Opening sets
//! iceoryx2's log level to Error (its WARN about a missing config file would greet every process)
//! unless `IOX2_LOG_LEVEL` says otherwise.
//!
//! Threads: the ports are neither `Send` nor `Sync` (their shared state is single-threaded reference
//! counts, as in iceoryx2's `ipc::Service`). Open them on the thread that uses them: the cycle thread opens its own
//! [`ServicePorts`].
//!
//! Lifetimes: a subscriber maps a publisher's shared memory at its first `receive()` after the
//! publisher appeared. A sample whose publisher is dropped before that is lost, although `send`
//! counted it as delivered; once connected, samples outlive their publisher (dropped or crashed).
//! So a client that sends and exits (a one-shot `stop` command) must stay open until the
//! controller shows it was received (the next `Status`).

use core::fmt::Debug;
use core::time::Duration;

use crate::{
    BaseCommand, BasePose, Control, ExtruderCommand, HeaterCommand, HeaterState, JobProgress, JointCommand, JointState, SegmentBatch,
    ServiceNames, Status,
};
use iceoryx2::port::listener::{Listener, ListenerWaitError};
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;

/// A port error: which service, which operation, and iceoryx2's error text. Built off the tick path
/// (it allocates its text).
#[derive(Debug, thiserror::Error)]
pub enum PortError {
    /// The iceoryx2 node could not be created (bad name, no permission on `/tmp/iceoryx2` or
    /// `/dev/shm`).
    #[error("iceoryx2 node \"{node}\": {error}")]
    Node {
        /// The node name.
        node: String,
        /// iceoryx2's error.
        error: String,
    },
    /// A service could not be opened or created (bad name, incompatible type or QoS: a peer built
    /// against another contract version gets `IncompatibleTypes`).
    #[error("service \"{service}\": cannot open: {error}")]
    Open {
        /// The service name.
        service: String,
        /// iceoryx2's error.
        error: String,
    },
    /// A publisher, subscriber, notifier or listener could not be created (e.g. too many publishers:
    /// a second controller).
    #[error("service \"{service}\": cannot create {port}: {error}")]
    CreatePort {
        /// The service name.
        service: String,
        /// "publisher", "subscriber", "notifier" or "listener".
        port: &'static str,
        /// iceoryx2's error.
        error: String,
    },
    /// Receiving failed.
    #[error("service \"{service}\": receive failed: {error}")]
    Receive {
        /// The service name.
        service: String,
        /// iceoryx2's error.
        error: String,
    },
    /// Sending (loan or delivery) failed.
    #[error("service \"{service}\": send failed: {error}")]
    Send {
        /// The service name.
        service: String,
        /// iceoryx2's error.
        error: String,
    },
    /// The wake-up notification after a send failed (the sample itself was delivered).
    #[error("service \"{service}\": notify failed: {error}")]
    Notify {
        /// The service name.
        service: String,
        /// iceoryx2's error.
        error: String,
    },
    /// Waiting on an event service failed.
    #[error("service \"{service}\": wait failed: {error}")]
    Wait {
        /// The service name.
        service: String,
        /// iceoryx2's error.
        error: String,
    },
    /// Listing or cleaning up iceoryx2 nodes failed.
    #[error("iceoryx2 node list: {error}")]
    NodeList {
        /// iceoryx2's error.
        error: String,
    },
    /// A [`ClientPorts`] method was called for a role it was not opened with.
    #[error("service \"{service}\": these client ports were opened without the {role} role")]
    RoleMissing {
        /// The service name.
        service: String,
        /// The role the method needs ("feeder", "driver", "tracker" or "monitor").
        role: &'static str,
    },
}

/// The quality of service of one publish-subscribe service. Fixed at creation; an opener's values
/// are minimums the existing service must meet.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Qos {
    /// Samples a subscriber queues (count).
    pub buffer: usize,
    /// Samples a late subscriber receives from the past (count).
    pub history: usize,
    /// Publishers the service admits (count).
    pub max_publishers: usize,
    /// Subscribers the service admits (count).
    pub max_subscribers: usize,
}

/// Segment batches: a deep buffer, bounded in use by credit-based flow control (module docs).
pub(crate) const SEGMENTS_QOS: Qos = Qos { buffer: 256, history: 0, max_publishers: 4, max_subscribers: 8 };
/// Control commands.
pub(crate) const CONTROL_QOS: Qos = Qos { buffer: 64, history: 0, max_publishers: 4, max_subscribers: 8 };
/// Measurements (joint state, base pose): only the latest matters.
pub(crate) const MEASUREMENT_QOS: Qos = Qos { buffer: 16, history: 0, max_publishers: 4, max_subscribers: 8 };
/// Controller outputs (joint command, extruder command, status): one publisher, last sample kept.
pub(crate) const OUTPUT_QOS: Qos = Qos { buffer: 16, history: 1, max_publishers: 1, max_subscribers: 8 };
/// Job progress from the feeder: the last one kept for a console that opens late.
pub(crate) const JOB_PROGRESS_QOS: Qos = Qos { buffer: 4, history: 1, max_publishers: 4, max_subscribers: 8 };
/// Nodes that may use one service (count).
const MAX_NODES: usize = 20;
/// Notifiers and listeners per event service (count).
const MAX_EVENT_PORTS: usize = 16;

/// iceoryx2's `ipc::Service` with recycled per-sample state: a publish does not allocate.
type Ipc = crate::recycling::Service;

/// Silences iceoryx2's start-up WARN about a missing config file (IOX2_LOG_LEVEL still overrides).
fn quiet_iceoryx2() {
    set_log_level_from_env_or(LogLevel::Error);
}

fn create_node(node_name: &str) -> Result<Node<Ipc>, PortError> {
    quiet_iceoryx2();
    let node_err = |error: String| PortError::Node { node: node_name.to_string(), error };
    let name = NodeName::new(node_name).map_err(|e| node_err(format!("{e:?}")))?;
    NodeBuilder::new()
        .name(&name)
        // Signals are the shell's business, not iceoryx2's.
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Ipc>()
        .map_err(|e| node_err(format!("{e:?}")))
}

/// One publish-subscribe service plus its event service of the same name.
struct Channel<T: Debug + Copy + ZeroCopySend + 'static> {
    name: String,
    service: PubSubFactory<Ipc, T, ()>,
    event: iceoryx2::service::port_factory::event::PortFactory<Ipc>,
}

impl<T: Debug + Copy + ZeroCopySend + 'static> Channel<T> {
    /// Opens or creates the service `name` with `qos`, and its event service.
    fn open(node: &Node<Ipc>, name: String, qos: Qos) -> Result<Self, PortError> {
        let open_err = |error: String| PortError::Open { service: name.clone(), error };
        let service_name = ServiceName::new(&name).map_err(|e| open_err(format!("{e:?}")))?;
        let service = node
            .service_builder(&service_name)
            .publish_subscribe::<T>()
            .subscriber_max_buffer_size(qos.buffer)
            .history_size(qos.history)
            .max_publishers(qos.max_publishers)
            .max_subscribers(qos.max_subscribers)
            .max_nodes(MAX_NODES)
            .enable_safe_overflow(true)
            .open_or_create()
            .map_err(|e| open_err(format!("{e:?}")))?;
        let event = node
            .service_builder(&service_name)
            .event()
            .max_notifiers(MAX_EVENT_PORTS)
            .max_listeners(MAX_EVENT_PORTS)
            .open_or_create()
            .map_err(|e| open_err(format!("event service: {e:?}")))?;
        Ok(Channel { name, service, event })
    }

    fn port_err(&self, port: &'static str, error: String) -> PortError {
        PortError::CreatePort { service: self.name.clone(), port, error }
    }

    fn subscriber(self) -> Result<Inbox<T>, PortError> {
        let sub = self.service.subscriber_builder().create().map_err(|e| self.port_err("subscriber", format!("{e:?}")))?;
        Ok(Inbox { sub, listener: None, channel: self })
    }

    fn subscriber_with_listener(self) -> Result<Inbox<T>, PortError> {
        let listener = self.event.listener_builder().create().map_err(|e| self.port_err("listener", format!("{e:?}")))?;
        let mut inbox = self.subscriber()?;
        inbox.listener = Some(listener);
        Ok(inbox)
    }

    fn publisher(self) -> Result<Outbox<T>, PortError> {
        let publisher = self.service.publisher_builder().create().map_err(|e| self.port_err("publisher", format!("{e:?}")))?;
        let notifier = self.event.notifier_builder().create().map_err(|e| self.port_err("notifier", format!("{e:?}")))?;
        Ok(Outbox { publisher, notifier, channel: self })
    }
}

/// The receiving end of a channel (fields drop in order: ports before their service).
struct Inbox<T: Debug + Copy + ZeroCopySend + 'static> {
    sub: Subscriber<Ipc, T, ()>,
    listener: Option<Listener<Ipc>>,
    channel: Channel<T>,
}

impl<T: Debug + Copy + ZeroCopySend + 'static> Inbox<T> {
    /// The oldest queued sample, copied out. Tick-path safe.
    #[inline]
    fn receive(&self) -> Result<Option<T>, PortError> {
        match self.sub.receive() {
            Ok(Some(sample)) => Ok(Some(*sample.payload())),
            Ok(None) => Ok(None),
            Err(e) => Err(PortError::Receive { service: self.channel.name.clone(), error: format!("{e:?}") }),
        }
    }

    /// Drains the queue and returns the newest sample. Tick-path safe.
    fn latest(&self) -> Option<T> {
        let mut last = None;
        while let Ok(Some(v)) = self.receive() {
            last = Some(v);
        }
        last
    }

    /// Blocks up to `timeout_ns` for a notification and drains all pending ones.
    fn wait(&self, timeout_ns: u64) -> Result<bool, PortError> {
        match &self.listener {
            Some(listener) => wait_on(listener, &self.channel.name, timeout_ns),
            None => Ok(false),
        }
    }

    fn publishers(&self) -> usize {
        self.channel.service.dynamic_config().number_of_publishers()
    }
}

/// The sending end of a channel (fields drop in order: ports before their service).
struct Outbox<T: Debug + Copy + ZeroCopySend + 'static> {
    publisher: Publisher<Ipc, T, ()>,
    notifier: Notifier<Ipc>,
    channel: Channel<T>,
}

impl<T: Debug + Copy + ZeroCopySend + 'static> Outbox<T> {
    /// Copies `value` into shared memory, delivers it, then notifies the event service. Returns the
    /// number of subscribers that received it. Tick-path safe.
    #[inline]
    fn send(&self, value: &T) -> Result<usize, PortError> {
        let delivered = self.send_quiet(value)?;
        self.notify()?;
        Ok(delivered)
    }

    /// Copies `value` into shared memory and delivers it without waking anybody: a subscriber sees it
    /// at its next receive, a waiter at the next [`Outbox::notify`].
    #[inline]
    fn send_quiet(&self, value: &T) -> Result<usize, PortError> {
        self.publisher.send_copy(*value).map_err(|e| PortError::Send { service: self.channel.name.clone(), error: format!("{e:?}") })
    }

    /// Wakes the channel's waiters. Where one is blocked, this is the costly part of a publish: the
    /// kernel wakes a process (on this CPU, preempting the caller unless it runs SCHED_FIFO; on another,
    /// an inter-processor interrupt, a VM exit on a virtual machine).
    #[inline]
    fn notify(&self) -> Result<(), PortError> {
        self.notifier.notify().map(|_| ()).map_err(|e| PortError::Notify { service: self.channel.name.clone(), error: format!("{e:?}") })
    }
}

/// Waits on `listener` for up to `timeout_ns` (ns) and drains every pending notification (an
/// undrained listener would wake at once forever). `Ok(false)` on timeout or on an interrupting
/// signal (the caller checks its shutdown flag and waits again).
fn wait_on(listener: &Listener<Ipc>, service: &str, timeout_ns: u64) -> Result<bool, PortError> {
    let result = if timeout_ns == 0 {
        listener.try_wait(|_| {})
    } else {
        // The wait is a receive with SO_RCVTIMEO: microsecond resolution, and a zero timeout means
        // "forever". Round up to whole microseconds so a sub-µs timeout does not block for good.
        listener.timed_wait(|_| {}, Duration::from_micros(timeout_ns.div_ceil(1000)))
    };
    match result {
        Ok(n) => Ok(n > 0),
        Err(ListenerWaitError::InterruptSignal) => Ok(false),
        Err(e) => Err(PortError::Wait { service: service.to_string(), error: format!("{e:?}") }),
    }
}

/// The controller's side of the contract: subscribers for segments, control, joint state and base
/// pose, a listener on the joint-state event (robot clock), and publishers with notifiers for the
/// joint command, extruder command and status. Not `Send`: open it on the cycle thread.
pub struct ServicePorts {
    segments: Inbox<SegmentBatch>,
    control: Inbox<Control>,
    joint_state: Inbox<JointState>,
    base_pose: Inbox<BasePose>,
    heater_state: Inbox<HeaterState>,
    joint_command: Outbox<JointCommand>,
    extruder_command: Outbox<ExtruderCommand>,
    base_command: Outbox<BaseCommand>,
    heater_command: Outbox<HeaterCommand>,
    status: Outbox<Status>,
    // Last: every port above is dropped before the node.
    _node: Node<Ipc>,
}

impl ServicePorts {
    /// Creates the node `node_name` and opens (or creates) every service under `names` with the
    /// fixed QoS, then the ports. Start-up code. Fails if the controller's outputs already have a
    /// publisher (another controller on these names).
    pub fn open(names: &ServiceNames, node_name: &str) -> Result<Self, PortError> {
        let node = create_node(node_name)?;
        Ok(ServicePorts {
            segments: Channel::open(&node, names.segments(), SEGMENTS_QOS)?.subscriber()?,
            control: Channel::open(&node, names.control(), CONTROL_QOS)?.subscriber()?,
            joint_state: Channel::open(&node, names.joint_state(), MEASUREMENT_QOS)?.subscriber_with_listener()?,
            base_pose: Channel::open(&node, names.base_pose(), MEASUREMENT_QOS)?.subscriber()?,
            heater_state: Channel::open(&node, names.heater_state(), MEASUREMENT_QOS)?.subscriber()?,
            joint_command: Channel::open(&node, names.joint_command(), OUTPUT_QOS)?.publisher()?,
            extruder_command: Channel::open(&node, names.extruder_command(), OUTPUT_QOS)?.publisher()?,
            base_command: Channel::open(&node, names.base_command(), OUTPUT_QOS)?.publisher()?,
            heater_command: Channel::open(&node, names.heater_command(), OUTPUT_QOS)?.publisher()?,
            status: Channel::open(&node, names.status(), OUTPUT_QOS)?.publisher()?,
            _node: node,
        })
    }

    /// The oldest queued segment batch, copied out; `None` when the queue is empty. Tick-path safe.
    pub fn receive_segments(&self) -> Result<Option<SegmentBatch>, PortError> {
        self.segments.receive()
    }

    /// The oldest queued control command; `None` when empty. Tick-path safe.
    pub fn receive_control(&self) -> Result<Option<Control>, PortError> {
        self.control.receive()
    }

    /// The oldest queued joint state; `None` when empty. Tick-path safe.
    pub fn receive_joint_state(&self) -> Result<Option<JointState>, PortError> {
        self.joint_state.receive()
    }

    /// The oldest queued base pose; `None` when empty. Tick-path safe.
    pub fn receive_base_pose(&self) -> Result<Option<BasePose>, PortError> {
        self.base_pose.receive()
    }

    /// Publishes a joint command and notifies; returns the number of subscribers reached.
    /// Tick-path safe.
    pub fn publish_joint_command(&self, cmd: &JointCommand) -> Result<usize, PortError> {
        self.joint_command.send(cmd)
    }

    /// Publishes an extruder command and notifies; returns the number of subscribers reached.
    /// Tick-path safe.
    pub fn publish_extruder_command(&self, cmd: &ExtruderCommand) -> Result<usize, PortError> {
        self.extruder_command.send(cmd)
    }

    /// The oldest queued heater measurement; `None` when empty. Tick-path safe.
    pub fn receive_heater_state(&self) -> Result<Option<HeaterState>, PortError> {
        self.heater_state.receive()
    }

    /// Publishes the heater targets and notifies; returns the number of subscribers reached.
    /// Tick-path safe.
    pub fn publish_heater_command(&self, cmd: &HeaterCommand) -> Result<usize, PortError> {
        self.heater_command.send(cmd)
    }

    /// Publishes a moving base's setpoint and notifies; returns the number of subscribers reached.
    /// Tick-path safe.
    pub fn publish_base_command(&self, cmd: &BaseCommand) -> Result<usize, PortError> {
        self.base_command.send(cmd)
    }

    /// Publishes the status and notifies; returns the number of subscribers reached. Tick-path
    /// safe.
    pub fn publish_status(&self, status: &Status) -> Result<usize, PortError> {
        self.status.send(status)
    }

    /// Publishes the status without waking its waiters (they read it at their next receive, or when
    /// [`ServicePorts::notify_status`] wakes them); returns the number of subscribers reached.
    /// Tick-path safe.
    pub fn publish_status_quietly(&self, status: &Status) -> Result<usize, PortError> {
        self.status.send_quiet(status)
    }

    /// Wakes the waiters on the status event. Tick-path safe.
    pub fn notify_status(&self) -> Result<(), PortError> {
        self.status.notify()
    }

    /// Blocks until a joint state is announced or `timeout_ns` (ns, rounded up to whole µs) passes,
    /// then drains every pending announcement. `true` if one arrived; `false` on timeout (or an
    /// interrupting signal). 0 polls without blocking. The clock wait of the robot clock mode; the
    /// samples themselves are then read with [`receive_joint_state`](Self::receive_joint_state).
    /// Tick-path safe: a socket receive with a timeout, no allocation.
    pub fn wait_joint_state(&self, timeout_ns: u64) -> Result<bool, PortError> {
        self.joint_state.wait(timeout_ns)
    }

    /// Publishers of segment batches now (count): 0 means no feeder is connected. A crashed feeder
    /// still counts until its node is cleaned up ([`cleanup_dead_nodes`], or any iceoryx2 node being
    /// created or dropped), so a shell that wants to notice crashes calls that now and then, off the
    /// tick path. Tick-path safe.
    pub fn segment_publishers(&self) -> usize {
        self.segments.publishers()
    }

    /// Publishers of joint states now (count): 0 means the robot driver went away (a crashed one
    /// counts until cleaned up, as for [`segment_publishers`](Self::segment_publishers)).
    /// Tick-path safe.
    pub fn joint_state_publishers(&self) -> usize {
        self.joint_state.publishers()
    }

    /// Publishers of base poses now (count): 0 means tracking went away. Tick-path safe.
    pub fn base_pose_publishers(&self) -> usize {
        self.base_pose.publishers()
    }
}

/// The roles a [`ClientPorts`] plays; it opens only the services they need.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ClientRoles {
    /// Publishes segment batches and control commands.
    pub feeder: bool,
    /// Publishes joint states; subscribes to joint commands and can wait on their event.
    pub driver: bool,
    /// Publishes base poses.
    pub tracker: bool,
    /// Subscribes to status (and can wait on its event) and to extruder commands.
    pub monitor: bool,
    /// Publishes control commands only (an operator's console: `strand ctl`, the live view). Unlike
    /// a feeder it holds no segment publisher, so it never hides a lost feeder from the service.
    pub control: bool,
    /// Subscribes to the feeder's [`JobProgress`] (a console). A feeder publishes it.
    pub progress: bool,
    /// Subscribes to the [`BaseCommand`]: a moving base's controller (the simulator's free flyer,
    /// a mobile platform's bridge).
    pub base: bool,
    /// Subscribes to joint states and base poses as measured (`strand calibrate`: the arm's joints
    /// and the tracker's pose at each touch). A driver or a tracker publishes them.
    pub measurements: bool,
    /// Publishes [`HeaterState`] and subscribes to the [`HeaterCommand`]: whoever owns the heaters
    /// (the simulator's thermal model, a Klipper extruder board's process).
    pub heater: bool,
}

/// The other side of the contract: a feeder, robot driver (or simulator), tracker or monitor, or
/// several at once (tests). Methods for a role not opened return [`PortError::RoleMissing`] (or
/// `None` / 0). Not `Send`: open it on the thread that uses it. Keep it open until the controller
/// has received what was sent (module docs: samples of a publisher dropped too early are lost).
pub struct ClientPorts {
    names: ServiceNames,
    segments: Option<Outbox<SegmentBatch>>,
    control: Option<Outbox<Control>>,
    joint_state: Option<Outbox<JointState>>,
    base_pose: Option<Outbox<BasePose>>,
    joint_command: Option<Inbox<JointCommand>>,
    extruder_command: Option<Inbox<ExtruderCommand>>,
    base_command: Option<Inbox<BaseCommand>>,
    heater_state: Option<Outbox<HeaterState>>,
    heater_command: Option<Inbox<HeaterCommand>>,
    status: Option<Inbox<Status>>,
    job_progress_out: Option<Outbox<JobProgress>>,
    job_progress_in: Option<Inbox<JobProgress>>,
    joint_state_in: Option<Inbox<JointState>>,
    base_pose_in: Option<Inbox<BasePose>>,
    // Last: every port above is dropped before the node.
    _node: Node<Ipc>,
}

impl ClientPorts {
    /// Creates the node `node_name` and opens the services and ports `roles` need, with the same
    /// fixed QoS as [`ServicePorts`] (so either side may create a service). Start-up code.
    pub fn open(names: &ServiceNames, node_name: &str, roles: ClientRoles) -> Result<Self, PortError> {
        let node = create_node(node_name)?;
        let feeder = roles.feeder;
        let driver = roles.driver;
        let tracker = roles.tracker;
        let monitor = roles.monitor;
        Ok(ClientPorts {
            segments: if feeder { Some(Channel::open(&node, names.segments(), SEGMENTS_QOS)?.publisher()?) } else { None },
            control: if feeder || roles.control { Some(Channel::open(&node, names.control(), CONTROL_QOS)?.publisher()?) } else { None },
            joint_state: if driver { Some(Channel::open(&node, names.joint_state(), MEASUREMENT_QOS)?.publisher()?) } else { None },
            base_pose: if tracker { Some(Channel::open(&node, names.base_pose(), MEASUREMENT_QOS)?.publisher()?) } else { None },
            joint_command: if driver {
                Some(Channel::open(&node, names.joint_command(), OUTPUT_QOS)?.subscriber_with_listener()?)
            } else {
                None
            },
            extruder_command: if monitor { Some(Channel::open(&node, names.extruder_command(), OUTPUT_QOS)?.subscriber()?) } else { None },
            base_command: if roles.base { Some(Channel::open(&node, names.base_command(), OUTPUT_QOS)?.subscriber()?) } else { None },
            heater_state: if roles.heater { Some(Channel::open(&node, names.heater_state(), MEASUREMENT_QOS)?.publisher()?) } else { None },
            heater_command: if roles.heater { Some(Channel::open(&node, names.heater_command(), OUTPUT_QOS)?.subscriber()?) } else { None },
            status: if monitor { Some(Channel::open(&node, names.status(), OUTPUT_QOS)?.subscriber_with_listener()?) } else { None },
            job_progress_out: if feeder { Some(Channel::open(&node, names.job_progress(), JOB_PROGRESS_QOS)?.publisher()?) } else { None },
            job_progress_in: if roles.progress {
                Some(Channel::open(&node, names.job_progress(), JOB_PROGRESS_QOS)?.subscriber()?)
            } else {
                None
            },
            joint_state_in: if roles.measurements {
                Some(Channel::open(&node, names.joint_state(), MEASUREMENT_QOS)?.subscriber()?)
            } else {
                None
            },
            base_pose_in: if roles.measurements {
                Some(Channel::open(&node, names.base_pose(), MEASUREMENT_QOS)?.subscriber()?)
            } else {
                None
            },
            names: names.clone(),
            _node: node,
        })
    }

    fn missing(&self, service: String, role: &'static str) -> PortError {
        PortError::RoleMissing { service, role }
    }

    /// Sends a segment batch and notifies (feeder); returns the number of subscribers reached (0:
    /// no controller is listening, the batch is lost). Respect the credit in `Status` (module docs).
    pub fn send_segments(&self, batch: &SegmentBatch) -> Result<usize, PortError> {
        match &self.segments {
            Some(out) => out.send(batch),
            None => Err(self.missing(self.names.segments(), "feeder")),
        }
    }

    /// Sends a control command and notifies (feeder); returns the number of subscribers reached.
    pub fn send_control(&self, control: &Control) -> Result<usize, PortError> {
        match &self.control {
            Some(out) => out.send(control),
            None => Err(self.missing(self.names.control(), "feeder")),
        }
    }

    /// Sends a joint state and notifies (driver); returns the number of subscribers reached.
    pub fn send_joint_state(&self, state: &JointState) -> Result<usize, PortError> {
        match &self.joint_state {
            Some(out) => out.send(state),
            None => Err(self.missing(self.names.joint_state(), "driver")),
        }
    }

    /// Sends a base pose and notifies (tracker); returns the number of subscribers reached.
    pub fn send_base_pose(&self, pose: &BasePose) -> Result<usize, PortError> {
        match &self.base_pose {
            Some(out) => out.send(pose),
            None => Err(self.missing(self.names.base_pose(), "tracker")),
        }
    }

    /// The oldest queued joint command (driver); `None` when empty.
    pub fn receive_joint_command(&self) -> Result<Option<JointCommand>, PortError> {
        match &self.joint_command {
            Some(inbox) => inbox.receive(),
            None => Err(self.missing(self.names.joint_command(), "driver")),
        }
    }

    /// The oldest queued status (monitor); `None` when empty.
    pub fn receive_status(&self) -> Result<Option<Status>, PortError> {
        match &self.status {
            Some(inbox) => inbox.receive(),
            None => Err(self.missing(self.names.status(), "monitor")),
        }
    }

    /// The oldest queued extruder command (monitor); `None` when empty.
    pub fn receive_extruder_command(&self) -> Result<Option<ExtruderCommand>, PortError> {
        match &self.extruder_command {
            Some(inbox) => inbox.receive(),
            None => Err(self.missing(self.names.extruder_command(), "monitor")),
        }
    }

    /// Sends a heater measurement and notifies (heater); returns the number of subscribers reached.
    pub fn send_heater_state(&self, state: &HeaterState) -> Result<usize, PortError> {
        match &self.heater_state {
            Some(out) => out.send(state),
            None => Err(self.missing(self.names.heater_state(), "heater")),
        }
    }

    /// Drains the heater command queue and returns the newest (heater); `None` if nothing was
    /// queued (or the heater role is not open): the heaters keep their last targets.
    pub fn latest_heater_command(&self) -> Option<HeaterCommand> {
        self.heater_command.as_ref().and_then(Inbox::latest)
    }

    /// Drains the base command queue and returns the newest (base); `None` if nothing was queued
    /// (or the base role is not open, or receiving failed): the base keeps its last setpoint.
    pub fn latest_base_command(&self) -> Option<BaseCommand> {
        self.base_command.as_ref().and_then(Inbox::latest)
    }

    /// Drains the status queue and returns the newest (monitor); `None` if nothing was queued (or
    /// the monitor role is not open, or receiving failed).
    pub fn latest_status(&self) -> Option<Status> {
        self.status.as_ref().and_then(Inbox::latest)
    }

    /// Blocks until a joint command is announced or `timeout_ns` (ns, rounded up to whole µs)
    /// passes, draining every pending announcement (driver). `true` if one arrived.
    pub fn wait_joint_command(&self, timeout_ns: u64) -> Result<bool, PortError> {
        match &self.joint_command {
            Some(inbox) => inbox.wait(timeout_ns),
            None => Err(self.missing(self.names.joint_command(), "driver")),
        }
    }

    /// Blocks until a status is announced or `timeout_ns` (ns, rounded up to whole µs) passes,
    /// draining every pending announcement (monitor). `true` if one arrived.
    pub fn wait_status(&self, timeout_ns: u64) -> Result<bool, PortError> {
        match &self.status {
            Some(inbox) => inbox.wait(timeout_ns),
            None => Err(self.missing(self.names.status(), "monitor")),
        }
    }

    /// Publishes the job's progress (feeder); returns the number of subscribers reached.
    pub fn send_job_progress(&self, progress: &JobProgress) -> Result<usize, PortError> {
        match &self.job_progress_out {
            Some(out) => out.send(progress),
            None => Err(self.missing(self.names.job_progress(), "feeder")),
        }
    }

    /// The newest job progress a feeder published (progress role); `None` if none came.
    pub fn latest_job_progress(&self) -> Option<JobProgress> {
        self.job_progress_in.as_ref().and_then(Inbox::latest)
    }

    /// Drains the joint state queue and returns the newest (measurements); `None` if nothing was
    /// queued (or the role is not open, or receiving failed).
    pub fn latest_joint_state(&self) -> Option<JointState> {
        self.joint_state_in.as_ref().and_then(Inbox::latest)
    }

    /// Drains the base pose queue and returns the newest (measurements); `None` if nothing was
    /// queued (or the role is not open, or receiving failed).
    pub fn latest_base_pose(&self) -> Option<BasePose> {
        self.base_pose_in.as_ref().and_then(Inbox::latest)
    }

    /// Publishers of the status now (count; monitor): 0 means no controller is running. 0 without
    /// the monitor role.
    pub fn status_publishers(&self) -> usize {
        self.status.as_ref().map_or(0, Inbox::publishers)
    }
}

/// Outcome of [`cleanup_dead_nodes`] (counts).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DeadNodeCleanup {
    /// Dead nodes whose stale resources were removed.
    pub removed: usize,
    /// Dead nodes that could not be cleaned (no permission, or another process is cleaning them).
    pub failed: usize,
}

/// Removes the shared-memory files and service registrations left by crashed iceoryx2 processes
/// (any node, not only strand's). Start-up code; node creation also does this by default, this
/// reports it.
pub fn cleanup_dead_nodes() -> Result<DeadNodeCleanup, PortError> {
    quiet_iceoryx2();
    let mut outcome = DeadNodeCleanup::default();
    Node::<Ipc>::list(Config::global_config(), |state| {
        if let NodeState::Dead(view) = state {
            match view.try_remove_stale_resources() {
                Ok(()) => outcome.removed += 1,
                Err(_) => outcome.failed += 1,
            }
        }
        CallbackProgression::Continue
    })
    .map_err(|e| PortError::NodeList { error: format!("{e:?}") })?;
    Ok(outcome)
}
