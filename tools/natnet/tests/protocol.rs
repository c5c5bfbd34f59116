//! The NatNet reader on packets laid out byte by byte from the public descriptions (not by the
//! crate's writer), the writer and reader against each other in every version, the reader on
//! random, truncated and corrupted packets (errors, never a panic), and the session's handshake
//! deadlines in virtual time.

use std::net::{Ipv4Addr, SocketAddrV4};

use proptest::prelude::*;
use strand::config::tracker::{TrackerConfig, UpAxis};
use strand_natnet::mapping::FrameMapping;
use strand_natnet::protocol::{self, Description, Frame, RigidBodyDescription, RigidBodyPose, Version};
use strand_natnet::session::{Event, Session, SessionConfig, SessionError};

const VERSIONS: [Version; 5] =
    [Version([3, 0, 0, 0]), Version([3, 1, 0, 0]), Version([4, 0, 0, 0]), Version([4, 1, 0, 0]), Version([4, 2, 0, 0])];

fn le(out: &mut Vec<u8>, bytes: &[u8]) {
    out.extend_from_slice(bytes);
}

/// A 3.0 frame as PacketClient.cpp reads it: no marker sets, no other markers, one rigid body
/// (id 7 at (1, 2, 3), identity, error 0.5 mm, tracked), no skeletons, no labeled markers, no
/// force plates, no devices, then the suffix.
fn frame_3_0_by_hand() -> Vec<u8> {
    let mut p = Vec::new();
    le(&mut p, &42i32.to_le_bytes()); // frame number
    le(&mut p, &0i32.to_le_bytes()); // marker sets
    le(&mut p, &0i32.to_le_bytes()); // other markers
    le(&mut p, &1i32.to_le_bytes()); // rigid bodies
    le(&mut p, &7i32.to_le_bytes());
    for v in [1.0f32, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0, 0.0005] {
        le(&mut p, &v.to_le_bytes());
    }
    le(&mut p, &1i16.to_le_bytes()); // params: tracked
    le(&mut p, &0i32.to_le_bytes()); // skeletons
    le(&mut p, &0i32.to_le_bytes()); // labeled markers
    le(&mut p, &0i32.to_le_bytes()); // force plates
    le(&mut p, &0i32.to_le_bytes()); // devices
    le(&mut p, &0u32.to_le_bytes()); // timecode
    le(&mut p, &0u32.to_le_bytes()); // subframe
    le(&mut p, &12.5f64.to_le_bytes()); // timestamp
    le(&mut p, &1_000u64.to_le_bytes()); // mid-exposure
    le(&mut p, &1_020u64.to_le_bytes()); // data received
    le(&mut p, &1_050u64.to_le_bytes()); // transmit
    le(&mut p, &0i16.to_le_bytes()); // params
    le(&mut p, &0i32.to_le_bytes()); // end of data
    p
}

#[test]
fn a_3_0_frame_laid_out_by_hand_reads() {
    let f = protocol::parse_frame(&frame_3_0_by_hand(), Version::new(3, 0)).unwrap();
    assert_eq!(f.number, 42);
    assert_eq!(
        f.rigid_bodies,
        vec![RigidBodyPose { id: 7, position: [1.0, 2.0, 3.0], orientation: [0.0, 0.0, 0.0, 1.0], mean_error: 0.0005, params: 1 }]
    );
    assert_eq!((f.timestamp, f.mid_exposure, f.data_received, f.transmit), (12.5, 1_000, 1_020, 1_050));
    // At 1 kHz ticks the frame's own latency is 50 ms.
    assert_eq!(strand_natnet::session::frame_latency_ns(&f, 1_000), Some(50_000_000));
}

/// The same frame in 4.1: each section's size after its count, assets between skeletons and
/// labeled markers, the precision timestamp before the params. The rigid body section's size
/// says 42 bytes: 4 more than the 38 this reader knows (a later field), which it skips.
#[test]
fn a_4_1_frame_laid_out_by_hand_reads_and_its_sizes_win() {
    let mut p = Vec::new();
    le(&mut p, &43i32.to_le_bytes());
    for _ in 0..2 {
        le(&mut p, &0i32.to_le_bytes()); // count
        le(&mut p, &0i32.to_le_bytes()); // size
    }
    le(&mut p, &1i32.to_le_bytes());
    le(&mut p, &42i32.to_le_bytes());
    le(&mut p, &7i32.to_le_bytes());
    for v in [1.0f32, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0, 0.0005] {
        le(&mut p, &v.to_le_bytes());
    }
    le(&mut p, &1i16.to_le_bytes());
    le(&mut p, &[0xAB; 4]); // a field from the future
    for _ in 0..5 {
        // skeletons, assets, labeled markers, force plates, devices
        le(&mut p, &0i32.to_le_bytes());
        le(&mut p, &0i32.to_le_bytes());
    }
    le(&mut p, &0u32.to_le_bytes());
    le(&mut p, &0u32.to_le_bytes());
    le(&mut p, &12.5f64.to_le_bytes());
    le(&mut p, &1_000u64.to_le_bytes());
    le(&mut p, &1_020u64.to_le_bytes());
    le(&mut p, &1_050u64.to_le_bytes());
    le(&mut p, &1_700_000_000u32.to_le_bytes()); // precision seconds
    le(&mut p, &123u32.to_le_bytes()); // fraction
    le(&mut p, &2i16.to_le_bytes()); // params: models changed
    le(&mut p, &0i32.to_le_bytes());
    let f = protocol::parse_frame(&p, Version::new(4, 1)).unwrap();
    assert_eq!(f.number, 43);
    assert_eq!(f.rigid_bodies[0].position, [1.0, 2.0, 3.0]);
    assert!(f.rigid_bodies[0].tracked());
    assert_eq!(f.precision, (1_700_000_000, 123));
    assert_eq!(f.params, protocol::FRAME_MODELS_CHANGED);
}

/// Server info as Motive 3 sends it: name[256], versions, clock, data port, multicast, group.
#[test]
fn server_info_laid_out_by_hand_reads() {
    let mut p = vec![0u8; 256];
    p[..6].copy_from_slice(b"Motive");
    le(&mut p, &[3, 1, 0, 0]);
    le(&mut p, &[4, 1, 0, 0]);
    le(&mut p, &10_000_000u64.to_le_bytes());
    le(&mut p, &1511u16.to_le_bytes());
    p.push(1);
    le(&mut p, &[239, 255, 42, 99]);
    let packet = protocol::packet(protocol::NAT_SERVERINFO, &p);
    let (id, payload) = protocol::split(&packet).unwrap();
    assert_eq!(id, protocol::NAT_SERVERINFO);
    let info = protocol::parse_server_info(payload).unwrap();
    assert_eq!(info.app_name, "Motive");
    assert_eq!(info.natnet_version, Version::new(4, 1));
    assert_eq!(info.clock_hz, 10_000_000);
    let c = info.connection.unwrap();
    assert_eq!((c.data_port, c.multicast, c.multicast_group), (1511, true, [239, 255, 42, 99]));
    // A 2.x server's short info: no clock, no connection.
    let short = protocol::parse_server_info(&p[..264]).unwrap();
    assert_eq!((short.clock_hz, short.connection), (0, None));
}

#[test]
fn the_connect_packet_is_a_named_sender_asking_for_the_servers_own_version() {
    let c = protocol::connect_packet();
    let (id, payload) = protocol::split(&c).unwrap();
    assert_eq!(id, protocol::NAT_CONNECT);
    assert_eq!(payload.len(), 270);
    assert!(payload.starts_with(b"strand-natnet\0"));
    assert_eq!(&payload[264..269], &[0, 0, 0, 0, 0]);
}

fn body(name: &str, id: i32, markers: usize) -> RigidBodyDescription {
    RigidBodyDescription {
        name: name.into(),
        id,
        parent_id: -1,
        offset: [0.0, 0.1, 0.0],
        orientation_offset: [0.0, 0.0, 0.0, 1.0],
        markers: (0..markers).map(|i| ([i as f32, 0.0, 0.0], i as i32, format!("{name}{i}"))).collect(),
    }
}

fn descriptions() -> Vec<Description> {
    vec![
        Description::MarkerSet("all".into(), vec!["a".into(), "b".into()]),
        Description::RigidBody(body("flyer", 3, 4)),
        Description::Skeleton("walker".into(), 9, vec![body("hip", 10, 2)]),
        Description::ForcePlate(1, "FP".into(), vec!["Fz".into()]),
        Description::Device(2, "daq".into(), "S1".into(), vec!["ai0".into(), "ai1".into()]),
        Description::Camera("cam".into(), [1.0, 2.0, 3.0], [0.0, 0.0, 0.0, 1.0]),
        Description::Asset("glove".into(), 1, 20, vec![body("palm", 21, 1)], vec![("tip".into(), 22)]),
        Description::RigidBody(body("bed", 5, 0)),
    ]
}

fn rb(id: i32) -> RigidBodyPose {
    RigidBodyPose { id, position: [0.1, 0.2, 0.3], orientation: [0.0, 0.0, 0.0, 1.0], mean_error: 0.0, params: 1 }
}

fn frame() -> Frame {
    Frame {
        number: 7,
        marker_sets: vec![("all".into(), vec![[1.0, 2.0, 3.0]])],
        other_markers: vec![[4.0, 5.0, 6.0]],
        rigid_bodies: vec![rb(3), rb(5)],
        skeletons: vec![(9, vec![rb(10)])],
        assets: vec![(20, vec![rb(21)], vec![(22, [0.0; 3], 0.01, 0, 0.0)])],
        labeled_markers: vec![(1, [0.0; 3], 0.01, 0, 0.0)],
        force_plates: vec![(1, vec![vec![1.0, 2.0]])],
        devices: vec![(2, vec![vec![3.0], vec![]])],
        timecode: (1, 2),
        timestamp: 3.5,
        mid_exposure: 100,
        data_received: 110,
        transmit: 120,
        precision: (5, 6),
        params: 0,
    }
}

/// What a version carries of a written frame or description list.
fn as_sent(v: Version) -> (Frame, Vec<Description>) {
    let mut f = frame();
    if !v.at_least(4, 1) {
        f.assets.clear();
        f.precision = (0, 0);
    }
    let defs = descriptions()
        .into_iter()
        .filter(|d| v.at_least(4, 1) || !matches!(d, Description::Asset(..)))
        .map(|d| {
            let strip = |mut b: RigidBodyDescription| {
                if !v.at_least(4, 0) {
                    b.markers.iter_mut().for_each(|m| m.2.clear());
                }
                b
            };
            match d {
                Description::RigidBody(b) => Description::RigidBody(strip(b)),
                Description::Skeleton(n, i, bs) => Description::Skeleton(n, i, bs.into_iter().map(strip).collect()),
                Description::Asset(n, k, i, bs, m) => Description::Asset(n, k, i, bs.into_iter().map(strip).collect(), m),
                d => d,
            }
        })
        .collect();
    (f, defs)
}

#[test]
fn every_version_reads_back_what_it_wrote() {
    for v in VERSIONS {
        let (f, defs) = as_sent(v);
        let packet = protocol::frame_packet(&frame(), v);
        let (id, payload) = protocol::split(&packet).unwrap();
        assert_eq!(id, protocol::NAT_FRAMEOFDATA);
        assert_eq!(protocol::parse_frame(payload, v).unwrap(), f, "frame, NatNet {v}");
        let packet = protocol::model_definitions_packet(&descriptions(), v);
        let (_, payload) = protocol::split(&packet).unwrap();
        assert_eq!(protocol::parse_model_definitions(payload, v).unwrap(), defs, "descriptions, NatNet {v}");
    }
}

#[test]
fn a_4_1_description_of_an_unknown_type_is_skipped_by_its_size() {
    let mut p = Vec::new();
    le(&mut p, &2i32.to_le_bytes());
    le(&mut p, &99i32.to_le_bytes()); // a type from the future
    le(&mut p, &3i32.to_le_bytes());
    le(&mut p, &[1, 2, 3]);
    le(&mut p, &1i32.to_le_bytes());
    let rb = protocol::model_definitions_packet(&[Description::RigidBody(body("flyer", 3, 1))], Version::new(4, 1));
    le(&mut p, &rb[4 + 4 + 4..]); // its size and body, after its own count and type
    let defs = protocol::parse_model_definitions(&p, Version::new(4, 1)).unwrap();
    assert_eq!(defs[0], Description::Other(99));
    assert!(matches!(&defs[1], Description::RigidBody(b) if b.name == "flyer"));
    // Before 4.1 there is no size to skip it by: an error naming the type.
    let e = protocol::parse_model_definitions(&[1, 0, 0, 0, 99, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0], Version::new(4, 0)).unwrap_err();
    assert!(e.to_string().contains("unknown description type 99"), "{e}");
}

#[test]
fn every_truncation_of_a_valid_packet_is_an_error() {
    for v in VERSIONS {
        let packet = protocol::frame_packet(&frame(), v);
        let payload = &packet[4..];
        // Everything up to the frame params is needed; the end tag is not read.
        for n in 0..payload.len() - 4 {
            assert!(protocol::parse_frame(&payload[..n], v).is_err(), "NatNet {v}: {n} of {} bytes read", payload.len());
        }
        let packet = protocol::model_definitions_packet(&descriptions(), v);
        let payload = &packet[4..];
        for n in 0..payload.len() {
            assert!(protocol::parse_model_definitions(&payload[..n], v).is_err(), "NatNet {v}: {n} of {} bytes read", payload.len());
        }
    }
    assert!(protocol::split(&[7, 0, 10, 0, 1, 2]).is_err(), "a payload shorter than declared");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    /// Random bytes: an error or a frame, never a panic (and never a huge allocation).
    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..600), v in 0usize..5) {
        let v = VERSIONS[v];
        let _ = protocol::parse_frame(&bytes, v);
        let _ = protocol::parse_model_definitions(&bytes, v);
        let _ = protocol::parse_server_info(&bytes);
        let _ = protocol::split(&bytes);
    }

    /// Valid packets with bytes changed and cut: an error or a frame, never a panic; and the
    /// session takes them without failing once streaming.
    #[test]
    fn corrupted_packets_never_panic(flips in proptest::collection::vec((any::<usize>(), any::<u8>()), 1..8), cut in any::<usize>(), v in 0usize..5) {
        let v = VERSIONS[v];
        for mut packet in [protocol::frame_packet(&frame(), v), protocol::model_definitions_packet(&descriptions(), v)] {
            for (at, b) in &flips {
                let i = at % packet.len();
                packet[i] = *b;
            }
            packet.truncate(4 + cut % (packet.len() - 3));
            if let Ok((_, payload)) = protocol::split(&packet) {
                let _ = protocol::parse_frame(payload, v);
                let _ = protocol::parse_model_definitions(payload, v);
            }
            let (mut s, now) = streaming_session(v);
            let _ = s.handle(now, &packet);
        }
    }
}

fn session_config(timeout_ns: u64) -> SessionConfig {
    SessionConfig {
        server: SocketAddrV4::new(Ipv4Addr::LOCALHOST, 1510),
        rigid_body: "flyer".into(),
        multicast: false,
        connect_timeout_ns: timeout_ns,
        keepalive_ns: 1_000_000_000,
    }
}

fn mapping() -> FrameMapping {
    FrameMapping::new(&TrackerConfig { rigid_body: "flyer".into(), up_axis: UpAxis::Z, ..TrackerConfig::default() })
}

fn server_info(v: Version) -> Vec<u8> {
    protocol::server_info_packet(&protocol::ServerInfo {
        app_name: "Motive".into(),
        app_version: Version::new(3, 1),
        natnet_version: v,
        clock_hz: 1_000_000_000,
        connection: Some(protocol::DataConnection { data_port: 1511, multicast: false, multicast_group: [239, 255, 42, 99] }),
    })
}

fn streaming_session(v: Version) -> (Session, u64) {
    let mut s = Session::new(session_config(3_000_000_000), mapping());
    s.start(1_000);
    s.handle(2_000, &server_info(v)).unwrap();
    let ready = s.handle(3_000, &protocol::model_definitions_packet(&descriptions(), v)).unwrap();
    assert!(matches!(ready, Event::Ready(r) if r.body_id == 3));
    (s, 4_000)
}

#[test]
fn the_handshake_retries_and_times_out_in_virtual_time() {
    let mut s = Session::new(session_config(1_000_000_000), mapping());
    s.start(0);
    let mut sent = 1;
    let mut t;
    let e = loop {
        t = s.next_deadline();
        match s.poll(t) {
            Ok(Event::Send(p)) => {
                assert_eq!(protocol::split(&p).unwrap().0, protocol::NAT_CONNECT);
                sent += 1;
            }
            Ok(_) => {}
            Err(e) => break e,
        }
    };
    assert_eq!(t, 1_000_000_000, "the error comes at the timeout, not later");
    assert!(matches!(e, SessionError::NoAnswer { tries, .. } if tries == sent), "{e}");
    assert_eq!(sent, 4, "a connect every 0.25 s");
}

#[test]
fn the_session_publishes_tracked_frames_only_and_stamps_capture_time() {
    let v = Version::new(4, 2);
    let (mut s, now) = streaming_session(v);
    let mut f = frame();
    f.mid_exposure = 1_000_000;
    f.transmit = 6_000_000; // 5 ms at the 1 GHz clock of server_info
    let pose = s.handle(now + 100_000_000, &protocol::frame_packet(&f, v)).unwrap();
    let Event::Pose(p) = pose else { panic!("{pose:?}") };
    assert_eq!(p.stamp_ns, now + 95_000_000);
    assert_eq!(p.seq, 7);
    assert_eq!(p.position, [0.1f32 as f64, 0.2f32 as f64, 0.3f32 as f64]);
    // Untracked: nothing, said once.
    f.number = 8;
    f.rigid_bodies[0].params = 0;
    assert_eq!(s.handle(now + 200_000_000, &protocol::frame_packet(&f, v)).unwrap(), Event::Lost);
    f.number = 9;
    assert_eq!(s.handle(now + 300_000_000, &protocol::frame_packet(&f, v)).unwrap(), Event::Nothing);
    // A duplicate is dropped; the body absent is not tracked either.
    f.rigid_bodies[0].params = 1;
    assert_eq!(s.handle(now + 400_000_000, &protocol::frame_packet(&f, v)).unwrap(), Event::Nothing);
    f.number = 10;
    f.rigid_bodies.remove(0);
    assert_eq!(s.handle(now + 500_000_000, &protocol::frame_packet(&f, v)).unwrap(), Event::Nothing);
    let c = s.counters();
    assert_eq!((c.published, c.untracked, c.missing, c.out_of_order), (1, 2, 1, 1));
    // A frame saying the models changed asks for them again.
    f.number = 11;
    f.params = protocol::FRAME_MODELS_CHANGED;
    let e = s.handle(now + 600_000_000, &protocol::frame_packet(&f, v)).unwrap();
    assert!(matches!(e, Event::Send(p) if protocol::split(&p).unwrap().0 == protocol::NAT_REQUEST_MODELDEF));
}

#[test]
fn a_natnet_2_server_is_refused_by_version() {
    let mut s = Session::new(session_config(1_000_000_000), mapping());
    s.start(0);
    let e = s.handle(1, &server_info(Version::new(2, 10))).unwrap_err();
    assert!(e.to_string().contains("NatNet 2.10.0.0; strand-natnet reads NatNet 3.0 to 4.2"), "{e}");
}
