//! The iceoryx2 ports end to end, both sides in one process (a crashed feeder in a child process):
//! every message type crosses with identical bytes, waits block and time out, publisher counts follow
//! peers coming and going (including a crash, after dead-node cleanup), 100 batches arrive in order,
//! a second controller is refused, and the steady-state tick path does not allocate.

use std::time::{Duration, Instant};

use strand_ipc::ports::{ClientPorts, ClientRoles, PortError, ServicePorts, cleanup_dead_nodes};
use strand_ipc::*;

// The service's counting allocator, compiled in: this crate does not depend on the service.
#[path = "../../src/io/alloc_count.rs"]
#[allow(unreachable_pub, reason = "the service's public allocator, included here as a private module")]
mod alloc_count;
use alloc_count::allocations;

#[global_allocator]
static GLOBAL: alloc_count::Counting = alloc_count::Counting;

/// Heap allocations `f` makes on this thread.
fn allocations_in(f: impl FnOnce()) -> usize {
    let before = allocations();
    f();
    allocations() - before
}

/// Service names unique to this process and test.
fn names(test: &str) -> ServiceNames {
    ServiceNames::new(&format!("strand/test-{}-{}", std::process::id(), test))
}

const ALL_ROLES: ClientRoles = ClientRoles {
    feeder: true,
    driver: true,
    tracker: true,
    monitor: true,
    control: true,
    progress: true,
    base: true,
    measurements: false,
    heater: true,
};

#[test]
fn a_calibration_reads_the_newest_joint_state_and_base_pose() {
    // `strand calibrate` live: the measurements role subscribes to what the driver and the tracker publish.
    let n = names("measurements");
    let reader = ClientPorts::open(&n, "test-calibrate", ClientRoles { measurements: true, ..Default::default() }).unwrap();
    let driver = ClientPorts::open(&n, "test-driver", ClientRoles { driver: true, tracker: true, ..Default::default() }).unwrap();
    assert!(reader.latest_joint_state().is_none() && reader.latest_base_pose().is_none());
    for seq in 1..=3 {
        assert_eq!(driver.send_joint_state(&joint_state(seq)).unwrap(), 1);
        let pose = BasePose { seq, stamp_ns: seq, position: [seq as f64, 0.0, 0.0], orientation: [1.0, 0.0, 0.0, 0.0] };
        assert_eq!(driver.send_base_pose(&pose).unwrap(), 1);
    }
    assert_eq!(bytes(&reader.latest_joint_state().unwrap()), bytes(&joint_state(3)));
    assert_eq!(reader.latest_base_pose().map(|p| (p.seq, p.position[0])), Some((3, 3.0)));
    assert!(reader.latest_joint_state().is_none(), "drained");
    // Without the role: nothing, no error.
    let other = ClientPorts::open(&n, "test-other", ClientRoles { monitor: true, ..Default::default() }).unwrap();
    assert!(other.latest_joint_state().is_none() && other.latest_base_pose().is_none());
}

/// The bytes of a wire message (the contract types have no implicit padding).
fn bytes<T: Copy>(v: &T) -> &[u8] {
    // SAFETY: T is a #[repr(C)] wire type whose every byte is a field (no padding).
    unsafe { std::slice::from_raw_parts(v as *const T as *const u8, std::mem::size_of::<T>()) }
}

fn segment(seq: u64, x: f64) -> Segment {
    Segment {
        seq,
        stamp_ns: 1_000 + seq,
        kind: SegmentKind::Arc as u32,
        flags: segment_flags::EXTRUDE | segment_flags::LAYER_START | segment_flags::PRESSURE_ADVANCE | segment_flags::AXES,
        end: [x, 0.25, -0.125],
        centre: [x / 2.0, 0.5, 0.0],
        normal: [0.0, 0.0, 1.0],
        sweep: 1.25,
        orientation: [0.0, 1.0, 0.0, 0.0],
        feed: 0.02,
        filament: 1e-3 * x,
        duration: 0.0,
        source_line: 40 + seq as u32,
        _reserved: 0,
        pressure_advance: 0.03 + 1e-3 * x,
        axes: [0.5 * x, -0.25],
        heater: 1,
        heat_wait: 2,
        temperature: 200.0 + x,
        temperature_range: [190.0, 210.0 + x],
    }
}

fn batch(seq: u64, len: u32) -> SegmentBatch {
    let mut b = SegmentBatch { seq, stamp_ns: 5_000 + seq, len, ..SegmentBatch::default() };
    for i in 0..len as usize {
        b.segments[i] = segment(seq * 100 + i as u64, 0.1 * (i + 1) as f64);
    }
    b
}

fn joint_state(seq: u64) -> JointState {
    let mut s = JointState { seq, stamp_ns: 7_000 + seq, dof: 7, ..JointState::default() };
    for i in 0..7 {
        s.position[i] = 0.1 * i as f64 + seq as f64;
        s.velocity[i] = -0.01 * i as f64;
        s.effort[i] = 2.5 * i as f64;
    }
    s
}

#[test]
fn every_message_crosses_both_ways_with_equal_bytes() {
    let n = names("roundtrip");
    let client = ClientPorts::open(&n, "test-client", ALL_ROLES).expect("client ports");
    let service = ServicePorts::open(&n, "test-service").expect("service ports");

    // Client → service.
    let b = batch(1, 3);
    let control = Control { seq: 9, stamp_ns: 123, command: Command::FeedOverride as u32, _reserved: 0, value: 0.75 };
    let state = joint_state(4);
    let pose = BasePose { seq: 2, stamp_ns: 456, position: [1.0, 2.0, 3.0], orientation: [0.5, 0.5, 0.5, 0.5] };
    assert_eq!(client.send_segments(&b).unwrap(), 1);
    assert_eq!(client.send_control(&control).unwrap(), 1);
    assert_eq!(client.send_joint_state(&state).unwrap(), 1);
    assert_eq!(client.send_base_pose(&pose).unwrap(), 1);

    let got = service.receive_segments().unwrap().expect("a segment batch");
    assert_eq!(bytes(&got), bytes(&b));
    assert_eq!(got.as_slice().len(), 3);
    assert_eq!(got.as_slice()[2], b.segments[2]);
    assert_eq!(bytes(&service.receive_control().unwrap().expect("a control")), bytes(&control));
    assert_eq!(bytes(&service.receive_joint_state().unwrap().expect("a joint state")), bytes(&state));
    assert_eq!(bytes(&service.receive_base_pose().unwrap().expect("a base pose")), bytes(&pose));
    assert!(service.receive_segments().unwrap().is_none());
    assert!(service.receive_control().unwrap().is_none());
    assert!(service.receive_joint_state().unwrap().is_none());
    assert!(service.receive_base_pose().unwrap().is_none());

    // Service → client.
    let mut cmd =
        JointCommand { seq: 11, stamp_ns: 99, tick: 11, state_seq: 4, state_stamp_ns: 7_004, dof: 7, valid: 1, ..Default::default() };
    cmd.position[6] = 1.5;
    cmd.velocity[0] = -0.5;
    let ext = ExtruderCommand { seq: 11, stamp_ns: 99, tick: 11, motor_speed: 3.0, flags: extruder_flags::EXTRUDING, ..Default::default() };
    let status =
        Status { seq: 11, tick: 11, contract_version: CONTRACT_VERSION, queue_free: 64, last_received_seq: 102, ..Default::default() };
    assert_eq!(service.publish_joint_command(&cmd).unwrap(), 1);
    assert_eq!(service.publish_extruder_command(&ext).unwrap(), 1);
    assert_eq!(service.publish_status(&status).unwrap(), 1);
    assert!(client.wait_joint_command(5_000_000).unwrap());
    assert!(client.wait_status(5_000_000).unwrap());
    assert_eq!(bytes(&client.receive_joint_command().unwrap().expect("a joint command")), bytes(&cmd));
    assert_eq!(bytes(&client.receive_extruder_command().unwrap().expect("an extruder command")), bytes(&ext));
    assert_eq!(bytes(&client.receive_status().unwrap().expect("a status")), bytes(&status));
    assert!(client.receive_joint_command().unwrap().is_none());

    // latest_status drains and keeps the newest.
    for seq in 12..15 {
        service.publish_status(&Status { seq, ..status }).unwrap();
    }
    assert_eq!(client.latest_status().map(|s| s.seq), Some(14));
    assert_eq!(client.latest_status(), None);
    assert_eq!(client.status_publishers(), 1);
}

#[test]
fn joint_state_wait_blocks_times_out_and_drains() {
    let n = names("wait");
    let client = ClientPorts::open(&n, "test-client", ClientRoles { driver: true, ..Default::default() }).unwrap();
    let service = ServicePorts::open(&n, "test-service").unwrap();

    // Nothing sent: times out, after blocking for its timeout (a wait that returns early spins).
    // Only lower bounds here: how fast a wait wakes is a measurement, strand-bench latency's.
    let t = Instant::now();
    assert!(!service.wait_joint_state(5_000_000).unwrap());
    let waited = t.elapsed();
    assert!(waited >= Duration::from_millis(4), "{waited:?}");
    assert!(!service.wait_joint_state(0).unwrap());
    // Below one microsecond: rounded up, not "block forever" (SO_RCVTIMEO 0): it returns.
    assert!(!service.wait_joint_state(500).unwrap());

    // Several sends before the wait: one wake-up, and every announcement drained.
    for seq in 1..=3 {
        client.send_joint_state(&joint_state(seq)).unwrap();
    }
    assert!(service.wait_joint_state(1_000_000_000).unwrap());
    let t = Instant::now();
    assert!(!service.wait_joint_state(5_000_000).unwrap(), "announcements were not drained");
    assert!(t.elapsed() >= Duration::from_millis(4));
    let seqs: Vec<u64> = std::iter::from_fn(|| service.receive_joint_state().unwrap()).map(|s| s.seq).collect();
    assert_eq!(seqs, [1, 2, 3]);

    // A send from another thread wakes a blocked wait. (The ports are neither Send nor Sync: each
    // thread opens its own. The sender stays open until the sample is received: a publisher dropped
    // before the subscriber's next receive takes its unread samples with it.)
    let (done_tx, done_rx) = std::sync::mpsc::channel::<()>();
    let names = &n;
    std::thread::scope(|s| {
        s.spawn(move || {
            let other = ClientPorts::open(names, "test-client-2", ClientRoles { driver: true, ..Default::default() }).unwrap();
            std::thread::sleep(Duration::from_millis(20));
            other.send_joint_state(&joint_state(4)).unwrap();
            done_rx.recv().unwrap();
        });
        assert!(service.wait_joint_state(5_000_000_000).unwrap());
        assert_eq!(service.receive_joint_state().unwrap().map(|s| s.seq), Some(4));
        done_tx.send(()).unwrap();
    });
}

/// Documents an iceoryx2 0.10 behaviour the clients must respect: a sample sent by a publisher
/// that is dropped before the subscriber's next `receive()` (which is when the subscriber maps the
/// publisher's memory) is lost, although `send` reported it delivered. Once connected, samples
/// outlive their publisher.
#[test]
fn samples_of_a_publisher_dropped_before_the_first_receive_are_lost() {
    let n = names("dropped");
    let service = ServicePorts::open(&n, "test-service").unwrap();
    let control = Control { seq: 1, command: Command::Stop as u32, ..Default::default() };
    {
        let feeder = ClientPorts::open(&n, "test-feeder", ClientRoles { feeder: true, ..Default::default() }).unwrap();
        assert_eq!(feeder.send_control(&control).unwrap(), 1);
    }
    assert_eq!(service.receive_control().unwrap(), None);
    {
        let feeder = ClientPorts::open(&n, "test-feeder", ClientRoles { feeder: true, ..Default::default() }).unwrap();
        feeder.send_control(&control).unwrap();
        assert_eq!(service.receive_control().unwrap(), Some(control));
        feeder.send_control(&Control { seq: 2, ..control }).unwrap();
    }
    assert_eq!(service.receive_control().unwrap().map(|c| c.seq), Some(2));
}

#[test]
fn publisher_counts_follow_the_peers() {
    let n = names("peers");
    let service = ServicePorts::open(&n, "test-service").unwrap();
    assert_eq!((service.segment_publishers(), service.joint_state_publishers(), service.base_pose_publishers()), (0, 0, 0));
    let client =
        ClientPorts::open(&n, "test-client", ClientRoles { feeder: true, driver: true, monitor: true, ..Default::default() }).unwrap();
    assert_eq!(service.segment_publishers(), 1);
    assert_eq!(service.joint_state_publishers(), 1);
    assert_eq!(service.base_pose_publishers(), 0);
    drop(client);
    assert_eq!(service.segment_publishers(), 0);
    assert_eq!(service.joint_state_publishers(), 0);

    // A role not opened is an error naming the service and the role.
    let tracker = ClientPorts::open(&n, "test-tracker", ClientRoles { tracker: true, ..Default::default() }).unwrap();
    match tracker.send_segments(&batch(1, 1)) {
        Err(e @ PortError::RoleMissing { role: "feeder", .. }) => assert!(e.to_string().contains("-peers/segments"), "{e}"),
        other => panic!("{other:?}"),
    }
    assert_eq!(tracker.latest_status(), None);
    assert_eq!(tracker.status_publishers(), 0);
}

#[test]
fn hundred_batches_arrive_in_order() {
    let n = names("order");
    let client = ClientPorts::open(&n, "test-client", ClientRoles { feeder: true, ..Default::default() }).unwrap();
    let service = ServicePorts::open(&n, "test-service").unwrap();
    for seq in 0..100 {
        assert_eq!(client.send_segments(&batch(seq, (seq % 32) as u32 + 1)).unwrap(), 1, "batch {seq}");
    }
    let mut got = Vec::new();
    while let Some(b) = service.receive_segments().unwrap() {
        got.push(b);
    }
    assert_eq!(got.len(), 100);
    for (seq, b) in got.iter().enumerate() {
        assert_eq!(bytes(b), bytes(&batch(seq as u64, (seq % 32) as u32 + 1)), "batch {seq}");
    }
}

#[test]
fn a_second_controller_is_refused() {
    let n = names("second");
    let _first = ServicePorts::open(&n, "test-service-1").unwrap();
    match ServicePorts::open(&n, "test-service-2") {
        Err(e @ PortError::CreatePort { port: "publisher", .. }) => assert!(e.to_string().contains("-second/joint_command"), "{e}"),
        Err(e) => panic!("wrong error: {e}"),
        Ok(_) => panic!("a second controller opened the same services"),
    }
}

/// Nothing on either side's tick allocates in steady state: receiving, waiting, the publisher counts,
/// and publishing too (iceoryx2 0.10's per-loan shared state is recycled by `strand_ipc::recycling`;
/// with plain `ipc::Service` this count is one per publish).
#[test]
fn steady_state_ports_allocate_nothing() {
    let n = names("alloc");
    let client = ClientPorts::open(&n, "test-client", ALL_ROLES).unwrap();
    let service = ServicePorts::open(&n, "test-service").unwrap();
    let b = batch(1, 32);
    let state = joint_state(1);
    let pose = BasePose::default();
    let control = Control::default();
    let probe = allocations();
    std::hint::black_box(vec![1u8; 16]);
    assert!(allocations() > probe, "the counting allocator must see a Vec");
    let (mut publish, mut other) = (0, 0);
    for round in 0..1010 {
        if round == 10 {
            // Warm-up done (connections are set up lazily on first use).
            (publish, other) = (0, 0);
        }
        publish += allocations_in(|| {
            client.send_segments(&b).unwrap();
            client.send_control(&control).unwrap();
            client.send_joint_state(&state).unwrap();
            client.send_base_pose(&pose).unwrap();
        });
        // The controller's tick.
        other += allocations_in(|| {
            assert!(service.wait_joint_state(1_000_000_000).unwrap());
            assert!(service.receive_segments().unwrap().is_some());
            assert!(service.receive_control().unwrap().is_some());
            assert!(service.receive_joint_state().unwrap().is_some());
            assert!(service.receive_base_pose().unwrap().is_some());
            assert!(service.receive_segments().unwrap().is_none());
            assert!(!service.wait_joint_state(0).unwrap());
            std::hint::black_box(service.segment_publishers() + service.joint_state_publishers() + service.base_pose_publishers());
        });
        publish += allocations_in(|| {
            service.publish_joint_command(&JointCommand::default()).unwrap();
            service.publish_extruder_command(&ExtruderCommand::default()).unwrap();
            service.publish_status(&Status::default()).unwrap();
        });
        // The driver's and monitor's side.
        other += allocations_in(|| {
            assert!(client.wait_joint_command(1_000_000_000).unwrap());
            assert!(client.receive_joint_command().unwrap().is_some());
            assert!(client.receive_extruder_command().unwrap().is_some());
            assert!(client.latest_status().is_some());
        });
    }
    assert_eq!(other, 0, "receive/wait/publisher counts allocated {other} times in 1000 rounds");
    assert_eq!(publish, 0, "allocations in 7000 publishes");
}

/// The recycling flavour is `ipc::Service` on the wire: a peer built on iceoryx2's own
/// `ipc::Service` (as every non-strand client is, the Python one included) receives the controller's
/// commands bit for bit and its joint states reach the controller.
#[test]
fn a_plain_ipc_service_peer_talks_to_the_ports() {
    use iceoryx2::prelude::*;
    let n = names("plain");
    let service = ServicePorts::open(&n, "test-service").unwrap();
    let node = NodeBuilder::new().create::<ipc::Service>().unwrap();
    let open = |name: &str, history: usize| {
        node.service_builder(&ServiceName::new(name).unwrap())
            .publish_subscribe::<JointCommand>()
            .subscriber_max_buffer_size(16)
            .history_size(history)
            .max_publishers(1)
            .max_subscribers(8)
            .max_nodes(20)
            .enable_safe_overflow(true)
            .open()
            .unwrap()
    };
    let commands = open(&n.joint_command(), 1).subscriber_builder().create().unwrap();
    let states = node
        .service_builder(&ServiceName::new(&n.joint_state()).unwrap())
        .publish_subscribe::<JointState>()
        .open()
        .unwrap()
        .publisher_builder()
        .create()
        .unwrap();
    for i in 0..20u64 {
        let mut command = JointCommand { seq: i, stamp_ns: 7 * i, dof: 7, ..JointCommand::default() };
        command.position[3] = 0.25 * i as f64;
        service.publish_joint_command(&command).unwrap();
        let got = commands.receive().unwrap().expect("the plain peer received the command");
        assert_eq!(bytes(got.payload()), bytes(&command));
        let state = joint_state(i);
        states.send_copy(state).unwrap();
        let back = service.receive_joint_state().unwrap().expect("the controller received the plain peer's state");
        assert_eq!(bytes(&back), bytes(&state));
    }
}

/// Run as a child process by `a_crashed_feeder_is_cleaned_up`: opens a feeder, says READY, waits
/// for a line on stdin, sends one batch and exits without dropping anything, as a crash would.
#[test]
#[ignore = "child process of a_crashed_feeder_is_cleaned_up"]
fn crash_child() {
    let Ok(prefix) = std::env::var("STRAND_CRASH_PREFIX") else { return };
    let client =
        ClientPorts::open(&ServiceNames::new(&prefix), "test-crashing-feeder", ClientRoles { feeder: true, ..Default::default() }).unwrap();
    println!("READY");
    std::io::stdin().read_line(&mut String::new()).unwrap();
    assert_eq!(client.send_segments(&batch(7, 2)).unwrap(), 1);
    std::process::exit(17);
}

#[test]
fn a_crashed_feeder_is_cleaned_up() {
    use std::io::{BufRead, Write};
    use std::process::{Command, Stdio};
    let n = names("crash");
    let service = ServicePorts::open(&n, "test-service").unwrap();
    let mut child = Command::new(std::env::current_exe().unwrap())
        .args(["--exact", "crash_child", "--ignored", "--nocapture", "--test-threads=1"])
        .env("STRAND_CRASH_PREFIX", &n.prefix)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    // Read the child's output on a thread, so a child that never gets ready fails the test instead
    // of hanging it. libtest prints "test crash_child ... " on the same line as READY.
    let stdout = child.stdout.take().unwrap();
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let ready = std::io::BufReader::new(stdout).lines().any(|l| l.is_ok_and(|l| l.ends_with("READY")));
        let _ = ready_tx.send(ready);
    });
    if ready_rx.recv_timeout(Duration::from_secs(60)) != Ok(true) {
        let _ = child.kill();
        panic!("the child never got ready");
    }
    assert_eq!(service.segment_publishers(), 1);
    // Connect to the child's publisher before it sends (a receive does that), so its batch
    // outlives it.
    assert!(service.receive_segments().unwrap().is_none());
    writeln!(child.stdin.take().unwrap(), "go").unwrap();
    assert_eq!(child.wait().unwrap().code(), Some(17));
    assert_eq!(service.receive_segments().unwrap().map(|b| b.seq), Some(7));
    // The dead feeder counts as a publisher until its resources are cleaned up (node creation
    // elsewhere may do that first, so 0 or 1 here).
    assert!(service.segment_publishers() <= 1);
    // The clean-up races with the other tests of this binary (their nodes come and go, and a
    // node another process is cleaning up counts as "failed" here): retry for up to a second.
    let mut cleanups = Vec::new();
    for _ in 0..50 {
        cleanups.push(cleanup_dead_nodes().unwrap());
        if service.segment_publishers() == 0 {
            break;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(service.segment_publishers(), 0, "{cleanups:?}");
    assert!(service.receive_segments().unwrap().is_none());
}
