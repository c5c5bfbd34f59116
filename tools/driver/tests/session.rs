//! The session (`strand_robot::session`) driven with a real protocol's packets: KUKA RSI's XML, as
//! the driver sends and reads them. (The session's own crate knows no protocol; these tests live
//! with the drivers.)

use std::net::SocketAddr;

use strand_driver::rsi::Rsi;
use strand_ipc::JointCommand;
use strand_robot::axes::AxisMap;
use strand_robot::guard::{JointLimits, ReplyGuard};
use strand_robot::protocol::PacketError;
use strand_robot::session::{DriverState, Dropped, Due, ReplyKind, Session, SessionRules};

fn rob(ipoc: u64, a1: f64) -> Vec<u8> {
    format!(
        "<Rob TYPE=\"KUKA\"><AIPos A1=\"{a1}\" A2=\"-90.0\" A3=\"90.0\" A4=\"0.0\" A5=\"90.0\" A6=\"0.0\"/><Delay D=\"0\"/><IPOC>{ipoc}</IPOC></Rob>"
    )
    .into_bytes()
}

fn session() -> Session<Rsi> {
    let b = JointLimits { lower: -3.0, upper: 3.0, velocity: 2.0, acceleration: 10.0, jerk: f64::INFINITY };
    let rules = SessionRules { robot: None, max_late_cycles: 3, recover_cycles: 5, reply_deadline: 0.002 };
    Session::new(Rsi::new(), AxisMap::identity(6), ReplyGuard::new(vec![b; 6], 0.004), rules)
}

fn command(seq: u64, a1: f64) -> JointCommand {
    let mut c = JointCommand { state_seq: seq, dof: 6, valid: 1, ..Default::default() };
    c.position[..6].copy_from_slice(&[
        a1,
        -std::f64::consts::FRAC_PI_2,
        std::f64::consts::FRAC_PI_2,
        0.0,
        std::f64::consts::FRAC_PI_2,
        0.0,
    ]);
    c
}

#[test]
fn every_bad_packet_kind_is_dropped_and_counted() {
    let mut s = session();
    let robot: SocketAddr = "127.0.0.1:5000".parse().unwrap();
    let other: SocketAddr = "127.0.0.2:5000".parse().unwrap();
    assert!(s.on_packet(&rob(100, 0.0), robot).is_ok());
    let good = rob(104, 0.0);
    assert!(matches!(s.on_packet(&good, other), Err(Dropped::Foreign(_))));
    assert!(matches!(s.on_packet(&good[..good.len() - 12], robot), Err(Dropped::Packet(_))));
    assert!(matches!(s.on_packet(b"\x00\x01\x02", robot), Err(Dropped::Packet(PacketError::Malformed(_)))));
    assert!(matches!(s.on_packet(&vec![b'<'; 5000], robot), Err(Dropped::Packet(PacketError::Oversized(_)))));
    assert!(matches!(s.on_packet(&rob(100, 0.0), robot), Err(Dropped::Order { .. })));
    assert!(matches!(s.on_packet(&rob(96, 0.0), robot), Err(Dropped::Order { .. })));
    assert!(s.on_packet(&good, robot).is_ok());
    let c = s.counters;
    assert_eq!((c.packets, c.foreign, c.malformed, c.oversized, c.duplicate, c.out_of_order), (2, 1, 2, 1, 1, 1), "{c:?}");
}

#[test]
fn late_commands_hold_then_fault_then_recover_without_a_jump() {
    let mut s = session();
    let robot: SocketAddr = "127.0.0.1:5000".parse().unwrap();
    let mut out = Vec::new();
    let mut ipoc = 1000;
    let mut next = |s: &mut Session<Rsi>| {
        ipoc += 4;
        s.on_packet(&rob(ipoc, 0.0), robot).unwrap().0
    };
    // Following, A1 speeding up at 5 rad/s² (inside the 10 rad/s² limit).
    let (mut a1, mut v) = (0.0, 0.0);
    for _ in 0..50 {
        let seq = next(&mut s);
        v += 5.0 * 0.004;
        a1 += v * 0.004;
        assert_eq!(s.reply(Some(&command(seq, a1)), &mut out).0, ReplyKind::Command);
    }
    assert_eq!(s.state(), DriverState::Following);
    // Three late: holds, then the latched fault.
    let mut transitions = Vec::new();
    for _ in 0..3 {
        next(&mut s);
        let (kind, t) = s.reply(None, &mut out);
        assert_eq!(kind, ReplyKind::Late);
        transitions.extend(t);
    }
    assert_eq!(transitions.last().map(|t| t.to), Some(DriverState::HeldAfterFault));
    assert_eq!(s.counters.faults, 1);
    // The service answers again: five cycles in time release it.
    let mut released = None;
    for k in 0..5 {
        next(&mut s);
        released = released.or(s.note_service(true).map(|t| (k, t)));
    }
    assert_eq!(released.map(|(k, t)| (k, t.to)), Some((4, DriverState::Following)));
    // The guard never let a step pass the limits (the hold braked within 10 rad/s²).
    assert_eq!(s.guard().clamps, 0, "holds brake, they do not clamp");
}

#[test]
fn a_robot_starting_outside_its_limits_is_refused_and_a_restart_is_a_new_session() {
    let mut s = session();
    let robot: SocketAddr = "127.0.0.1:5000".parse().unwrap();
    // A1 at 200°: outside ±3 rad (a wrong mapping would look like this).
    assert!(matches!(s.on_packet(&rob(100, 200.0), robot), Err(Dropped::OutsideLimits { joint: 1, .. })));
    assert_eq!((s.counters.outside_limits, s.state()), (1, DriverState::WaitingForRobot));
    assert!(s.on_packet(&rob(104, 10.0), robot).is_ok(), "a later good packet starts the session");
    // RSI off and on again at another pose, the controller's IPOC lower after a reboot.
    let t = s.reset().unwrap();
    assert_eq!(t.to, DriverState::WaitingForRobot);
    let other: SocketAddr = "127.0.0.1:5001".parse().unwrap();
    let (_, q, t) = s.on_packet(&rob(8, 20.0), other).expect("a new session: new sender, new sequence");
    assert_eq!(t.map(|t| t.to), Some(DriverState::Holding));
    let mut out = Vec::new();
    s.reply(None, &mut out);
    let text = String::from_utf8(out).unwrap();
    assert!(text.contains("A1=\"0.000000\""), "the new reference is the new pose (no jump): {text}");
    assert!((q[0] - 20f64.to_radians()).abs() < 1e-12);
}

#[test]
fn the_robot_is_held_until_the_first_valid_command() {
    let mut s = session();
    let robot: SocketAddr = "127.0.0.1:5000".parse().unwrap();
    let mut out = Vec::new();
    let (seq, _, t) = s.on_packet(&rob(8, 5.0), robot).unwrap();
    assert_eq!(t.map(|t| t.to), Some(DriverState::Holding));
    let mut invalid = command(seq, 1.0);
    invalid.valid = 0;
    assert_eq!(s.reply(Some(&invalid), &mut out).0, ReplyKind::Hold);
    let text = String::from_utf8(out.clone()).unwrap();
    assert!(text.contains("A1=\"0.000000\""), "a hold is a zero correction: {text}");
}

#[test]
fn cycles_without_a_packet_are_counted_and_the_next_answer_starts_from_rest() {
    let mut s = session();
    let robot: SocketAddr = "127.0.0.1:5000".parse().unwrap();
    let mut out = Vec::new();
    // Following at 0.5 rad/s on A1 (reached at 5 rad/s²).
    let (mut ipoc, mut a1, mut v) = (1000u64, 0.0f64, 0.0f64);
    for _ in 0..100 {
        ipoc += 4;
        let seq = s.on_packet(&rob(ipoc, a1.to_degrees()), robot).unwrap().0;
        v = (v + 5.0 * 0.004).min(0.5);
        a1 += v * 0.004;
        s.reply(Some(&command(seq, a1)), &mut out);
    }
    assert!((s.guard().velocity()[0] - 0.5).abs() < 1e-9, "in step at 0.5 rad/s");
    // Two packets lost: IPOC steps by three cycles. The robot held its target through them.
    ipoc += 12;
    let seq = s.on_packet(&rob(ipoc, a1.to_degrees()), robot).unwrap().0;
    assert_eq!(s.counters.lost_cycles, 2);
    let held = s.guard().last().unwrap()[0];
    a1 += 3.0 * 0.5 * 0.004;
    s.reply(Some(&command(seq, a1)), &mut out);
    let step = s.guard().last().unwrap()[0] - held;
    assert!(step >= 0.0 && step / 0.004 <= 10.0 * 0.004 + 1e-12, "from rest, within the acceleration limit: {} rad/s", step / 0.004);
}

/// The JointState's report of what the robot was told: the target (the last answer) and its
/// velocity always; `HELD` once after a cycle the robot kept its target (late, missed, lost);
/// `CATCHING_UP` while the answers are not the command.
#[test]
fn the_report_says_what_the_robot_was_told_and_that_it_held() {
    use strand_ipc::joint_state_flags::{CATCHING_UP, HELD, TARGET_KNOWN};
    let mut s = session();
    let robot: SocketAddr = "127.0.0.1:5000".parse().unwrap();
    let mut out = Vec::new();
    let (mut ipoc, mut a1, mut v) = (1000, 0.0, 0.0);
    for _ in 0..40 {
        // Up to 0.5 rad/s at 5 rad/s² (half the limit).
        ipoc += 4;
        let seq = s.on_packet(&rob(ipoc, 0.0), robot).unwrap().0;
        v = (v + 5.0 * 0.004f64).min(0.5);
        a1 += v * 0.004;
        let mut c = command(seq, a1);
        c.velocity[0] = v;
        assert_eq!(s.reply(Some(&c), &mut out).0, ReplyKind::Command);
    }
    assert_eq!(s.counters.clamped, 0);
    let r = s.robot_report();
    assert_eq!(r.flags, TARGET_KNOWN);
    assert_eq!(r.target[0], a1);
    assert!((r.target_velocity[0] - v).abs() < 1e-9);
    // A late service: the driver holds (braking at the acceleration limit).
    ipoc += 4;
    s.on_packet(&rob(ipoc, 0.0), robot).unwrap();
    assert_eq!(s.reply(None, &mut out).0, ReplyKind::Late);
    let r = s.robot_report();
    assert_eq!(r.flags, TARGET_KNOWN | HELD | CATCHING_UP);
    assert!((r.target_velocity[0] - (v - 10.0 * 0.004)).abs() < 1e-9, "{:?}", r.target_velocity);
    assert!((r.target[0] - (a1 + r.target_velocity[0] * 0.004)).abs() < 1e-12);
    // Told once.
    assert_eq!(s.robot_report().flags & HELD, 0);
    // A lost packet (IPOC skips a cycle): held again, at rest.
    ipoc += 8;
    s.on_packet(&rob(ipoc, 0.0), robot).unwrap();
    let r = s.robot_report();
    assert_eq!(r.flags & HELD, HELD);
    assert_eq!(r.target_velocity[0], 0.0);
}

#[test]
fn the_session_owns_the_reply_the_silence_and_the_stop_deadlines() {
    // 4 ms cycles: the answer is due 2 ms after its packet ([driver] reply_deadline); 25 silent
    // cycles = 100 ms end the robot's session; a stop holds until at rest.
    let mut s = session();
    let robot: SocketAddr = "127.0.0.1:5000".parse().unwrap();
    let ms = 1_000_000u64;
    assert_eq!((s.poll_timeout(), s.reply_deadline()), (None, None), "nothing pending before the robot");
    s.on_packet_at(1000 * ms, &rob(100, 0.0), robot).unwrap();
    assert_eq!((s.reply_deadline(), s.poll_timeout()), (Some(1002 * ms), Some(1002 * ms)));
    assert_eq!(s.poll(1002 * ms - 1), Due::Nothing);
    assert_eq!(s.poll(1002 * ms), Due::Reply, "the answer is due: a hold, since no command came");
    let mut out = Vec::new();
    assert_eq!(s.reply(None, &mut out).0, ReplyKind::Late);
    assert_eq!(s.reply_deadline(), None, "answered");
    assert_eq!(s.poll_timeout(), Some(1100 * ms));
    assert_eq!(s.poll(1099 * ms), Due::Nothing);
    match s.poll(1101 * ms) {
        Due::SessionEnded(t) => assert_eq!(t.to, DriverState::WaitingForRobot),
        other => panic!("{other:?}"),
    }
    // A new session; the service moves A1, then a stop: the answers hold, braking, and the stop is
    // done once the target has been at rest for a few polls.
    let mut t = 2000 * ms;
    s.on_packet_at(t, &rob(200, 0.0), robot).unwrap();
    for k in 1..=50u64 {
        t += 4 * ms;
        s.on_packet_at(t, &rob(200 + 4 * k, 0.0), robot).unwrap();
        s.reply(Some(&command(k, 0.004 * k as f64)), &mut out);
    }
    assert!(s.request_stop(t) && !s.request_stop(t) && s.stopping());
    let mut polls = 0;
    loop {
        t += 4 * ms;
        polls += 1;
        s.on_packet_at(t, &rob(400 + 4 * polls, 0.0), robot).unwrap();
        s.reply_hold(&mut out);
        if s.poll(t) == Due::StopDone {
            break;
        }
        assert!(polls < 200, "the stop never ended");
    }
    // From 1 rad/s at 10 rad/s² the hold brakes in 0.1 s (25 cycles), then 5 polls at rest.
    assert!((20..=40).contains(&polls), "{polls} polls");
    // A stop with no robot streaming is done at once.
    let mut quiet = session();
    quiet.request_stop(0);
    assert_eq!(quiet.poll(0), Due::StopDone);
}

/// Where the driver clocks the cycle and its own loop lapsed (the process stalled), a robot that
/// runs on at its last command — the Meca500 keeps its last velocity until `SetVelTimeout` — is
/// owed the service's ticks it ran on for, up to that timeout; a robot that holds owes none. The
/// owed ticks' commands pass the guard (the robot ran on along them) but are not answers sent, and
/// the packet's own answer is still due.
#[test]
fn a_lapse_of_the_drivers_loop_owes_the_ticks_a_robot_ran_on_for() {
    use strand_driver::meca::{FROM_MONITOR, Meca};
    let b = JointLimits { lower: -3.0, upper: 3.0, velocity: 2.0, acceleration: 10.0, jerk: f64::INFINITY };
    let rules = SessionRules { robot: None, max_late_cycles: 3, recover_cycles: 5, reply_deadline: 0.002 };
    let mut meca = Meca::new(0.004, 20.0);
    meca.set_velocity_timeout(0.02);
    let mut s = Session::new(meca, AxisMap::identity(6), ReplyGuard::new(vec![b; 6], 0.004), rules);
    let robot: SocketAddr = "127.0.0.1:10000".parse().unwrap();
    let packet = |t: u64| {
        let mut p = Vec::new();
        for m in [format!("[2210][{t},0,0,0,0,0,0]"), format!("[2230][{t}]")] {
            p.push(FROM_MONITOR);
            p.extend_from_slice(m.as_bytes());
            p.push(0);
        }
        p
    };
    let mut c = JointCommand { state_seq: 1, dof: 6, valid: 1, ..Default::default() };
    let mut out = Vec::new();
    s.on_packet_at(0, &packet(0), robot).unwrap();
    s.reply(Some(&c), &mut out);
    // Three ticks lapsed, within the 20 ms the arm runs on for at 4 ms a tick: three owed, once.
    s.on_packet_at(16_000_000, &packet(16_000), robot).unwrap();
    s.driver_lapsed(3);
    assert_eq!((s.take_owed_ticks(), s.take_owed_ticks()), (3, 0));
    let replies = s.counters.replies;
    for k in 1..=3 {
        c.position[0] = 0.001 * k as f64;
        assert_eq!(s.reply_owed(Some(&c), &mut out).0, ReplyKind::Command);
        assert!(out.starts_with(b"MoveJointsVel("), "{}", String::from_utf8_lossy(&out));
    }
    assert_eq!(s.counters.replies, replies, "owed answers are not sent");
    // An owed command that did not come in time is skipped: nothing written, nothing counted late.
    let late = s.counters.late;
    assert_eq!(s.reply_owed(None, &mut out).0, ReplyKind::Late);
    assert!(out.is_empty());
    assert_eq!((s.late_run(), s.counters.late), (0, late));
    assert_eq!(s.reply_deadline(), Some(16_000_000 + 2_000_000), "the packet's answer is still due");
    // The guard went along the owed commands (within its acceleration limit: 10 rad/s²).
    let went = s.guard().last().unwrap()[0];
    assert!((0.0007..=0.003).contains(&went), "{went}");
    s.reply(Some(&c), &mut out);
    assert_eq!((s.counters.replies, s.reply_deadline()), (replies + 1, None));
    // Twelve lapsed: the arm stopped itself after five (20 ms); five are owed.
    s.on_packet_at(68_000_000, &packet(68_000), robot).unwrap();
    s.driver_lapsed(12);
    assert_eq!(s.take_owed_ticks(), 5);
    assert_eq!((s.counters.lost_cycles, s.counters.owed_ticks), (15, 8));
    // A robot that holds its target (RSI) owes nothing: its next answer catches up.
    let mut rsi = session();
    rsi.on_packet(&rob(100, 0.0), robot).unwrap();
    rsi.driver_lapsed(3);
    assert_eq!((rsi.take_owed_ticks(), rsi.counters.lost_cycles), (0, 3));
}
