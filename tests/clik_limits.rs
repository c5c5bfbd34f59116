//! The CLIK step at its limits and under bad input: scaling that keeps the direction, braking on a
//! NaN target, repairing a NaN or out-of-range joint input, saturation at lower limits and on a
//! prismatic rail, and a configuration that is refused.

mod common;
#[path = "common/paths.rs"]
mod paths;

use common::{jv, rail_arm, robot};
use nalgebra::{UnitQuaternion, Vector3};
use paths::{Shape, track};
use strand_core::kin::{Clik, ClikConfig, ClikStep, JointVector, PathVelocity, RobotModel, Task, TcpTarget};

fn clik(task: Task) -> Clik {
    Clik::new(ClikConfig { task, ..ClikConfig::default() }).unwrap()
}

fn check_limits(model: &RobotModel, steps: &[ClikStep], dt: f64) {
    let mut prev = JointVector::zeros();
    for (k, s) in steps.iter().enumerate() {
        common::assert_within_limits(model, s, &prev, dt, &format!("tick {k}"));
        prev = s.qd;
    }
}

#[test]
fn too_fast_a_path_is_slowed_by_one_factor_and_keeps_its_direction() {
    // VP6242 (1 rad/s on every joint): a 50 mm circle in 0.6 s needs more than the joints can give.
    let model = robot("vp6242");
    let mut solver = clik(Task::Print5);
    let q0 = common::start("vp6242");
    let r = track(&model, &mut solver, q0, Shape::Circle { a: Vector3::x(), b: Vector3::y(), radius: 0.05 }, 0.6, 1000.0);
    check_limits(&model, &r.steps, 1e-3);
    let scaled: Vec<&ClikStep> = r.steps.iter().filter(|s| s.status.scaled && !s.status.at_limit && !s.status.invalid_input).collect();
    assert!(scaled.len() > 50, "only {} scaled steps", scaled.len());
    for s in &scaled {
        assert!(s.scale < 1.0 && s.scale >= 0.0);
        let expect = s.requested * s.scale;
        assert!((s.qd - expect).norm() <= 1e-9 * (1.0 + s.requested.norm()), "direction changed: {:?} vs {:?}", s.qd, expect);
    }
    // Every scaled step has a joint at a limit: its speed limit, or the edge of its acceleration step.
    for w in r.steps.windows(2) {
        let (prev, s) = (&w[0], &w[1]);
        if s.status.scaled && !s.status.at_limit && !s.status.invalid_input {
            let binding = (0..6).any(|i| {
                let l = model.limits(i);
                (s.qd[i].abs() - l.velocity).abs() < 1e-9 || ((s.qd[i] - prev.qd[i]).abs() - l.acceleration * 1e-3).abs() < 1e-9
            });
            assert!(binding, "scaled with no joint at a limit: {s:?}");
        }
    }
    assert!(r.min_scale < 0.9, "min scale {}", r.min_scale);
}

#[test]
fn a_nan_target_makes_the_arm_brake_at_its_acceleration_limits_and_stop() {
    let model = robot("iiwa7");
    let mut solver = clik(Task::Print5);
    let q0 = common::start("iiwa7");
    let start = model.forward_kinematics(&q0);
    let orient = UnitQuaternion::from_rotation_matrix(&start.rotation);
    let dt = 1e-3;
    let v = Vector3::new(0.0, 0.08, 0.0);
    let mut q = q0;
    let mut steps = Vec::new();
    // Accelerate along +y (smoothly), then 1.5 s of NaN targets, then the path again.
    let mut p = start.translation.vector;
    for k in 0..6000 {
        // The path runs on during the NaN stretch and stops at tick 2500; the arm must catch up after.
        let ramp = if k < 2500 { (k as f64 / 300.0).min(1.0) } else { 0.0 };
        p += v * ramp * dt;
        let mut target = TcpTarget { position: p, orientation: orient, linear_velocity: v * ramp, angular_velocity: Vector3::zeros() };
        let invalid = (1000..2500).contains(&k);
        if invalid {
            target.position.x = f64::NAN;
        }
        let s = solver.step(&model, &q, &target, dt);
        assert_eq!(s.status.invalid_input, invalid, "tick {k}");
        q = s.q;
        steps.push(s);
    }
    check_limits(&model, &steps, dt);
    // While invalid, no joint speeds up, and the arm comes to rest.
    for k in 1001..2500 {
        for i in 0..7 {
            assert!(steps[k].qd[i].abs() <= steps[k - 1].qd[i].abs() + 1e-15, "tick {k} joint {i} sped up");
        }
    }
    assert!(steps[1000].qd.norm() > 0.01, "was moving before");
    assert_eq!(steps[2499].qd.norm(), 0.0, "at rest after braking");
    let held = steps[2499].q;
    assert!(
        (model.forward_kinematics(&held).translation.vector - model.forward_kinematics(&steps[1400].q).translation.vector).norm() < 1e-12
    );
    // Valid targets again: the error (the path moved on) is closed and tracking resumes.
    let last = steps.last().unwrap();
    assert!(last.position_error < 1e-6 && !last.status.invalid_input, "error {}", last.position_error);
}

#[test]
fn a_nan_joint_input_is_replaced_by_the_last_command() {
    let model = robot("vp6242");
    let mut solver = clik(Task::Print5);
    let q0 = common::start("vp6242");
    let pose = model.forward_kinematics(&q0);
    let target =
        TcpTarget::at_rest(pose.translation.vector + Vector3::new(0.0, 0.0, 0.01), UnitQuaternion::from_rotation_matrix(&pose.rotation));
    let first = solver.step(&model, &q0, &target, 1e-3);
    let mut bad = first.q;
    bad[3] = f64::NAN;
    let second = solver.step(&model, &bad, &target, 1e-3);
    assert!(second.status.invalid_input);
    assert!(second.q.iter().all(|x| x.is_finite()));
    assert!((second.q[3] - first.q[3]).abs() < 1e-3, "jumped: {} → {}", first.q[3], second.q[3]);
    // A fresh solver with nothing to fall back on uses the middle of the range, and says so.
    let mut fresh = clik(Task::Print5);
    let s = fresh.step(&model, &bad, &target, 1e-3);
    assert!(s.status.invalid_input && s.q.iter().all(|x| x.is_finite()) && model.within_limits(&s.q));
}

#[test]
fn a_joint_input_past_its_limit_comes_back_within_speed_and_acceleration_limits() {
    let model = robot("vp6242");
    let upper = model.limits(0).upper;
    let mut solver = clik(Task::Print5);
    let mut q = jv(&[upper + 0.05, 0.0, 2.1, 0.3, 0.9, 0.2]);
    let pose = model.forward_kinematics(&jv(&[upper - 0.2, 0.0, 2.1, 0.3, 0.9, 0.2]));
    let target = TcpTarget::at_rest(pose.translation.vector, UnitQuaternion::from_rotation_matrix(&pose.rotation));
    let mut steps = Vec::new();
    let mut worst = q[0];
    for _ in 0..3000 {
        let s = solver.step(&model, &q, &target, 1e-3);
        assert!(s.q[0] <= worst + 1e-15, "moved further out: {}", s.q[0]);
        worst = worst.min(s.q[0].max(upper));
        if s.q[0] > upper {
            assert!(s.status.at_limit);
        }
        q = s.q;
        steps.push(s);
    }
    check_limits(&model, &steps, 1e-3);
    assert!(model.within_limits(&q), "still outside: {:?}", q);
    assert!(steps.last().unwrap().position_error < 1e-6);
}

#[test]
fn lower_limits_and_a_prismatic_rail_saturate_and_hold() {
    // The rail (lower limit 0 m) and j3 (lower limit −2.5 rad) are both asked past their lower limits;
    // the rail so far that the target stays out of reach.
    let model = rail_arm();
    let q0 = jv(&[0.15, 0.3, 0.4, -2.3, 0.2, 0.5, 0.1]);
    let mut qt = q0;
    qt[0] = -1.0; // 1 m past the rail's end: no other joint can make that up
    qt[3] = -2.8;
    let pose = model.forward_kinematics(&qt);
    let target = TcpTarget::at_rest(pose.translation.vector, UnitQuaternion::from_rotation_matrix(&pose.rotation));
    let mut solver = clik(Task::Pose6);
    let mut q = q0;
    let mut steps = Vec::new();
    for k in 0..12000 {
        let s = solver.step(&model, &q, &target, 1e-3);
        assert!(model.within_limits(&s.q), "tick {k}: {:?}", s.q);
        q = s.q;
        steps.push(s);
    }
    check_limits(&model, &steps, 1e-3);
    let last = steps.last().unwrap();
    assert!(last.q[0].abs() < 1e-9, "rail at {}", last.q[0]);
    assert!(last.saturated & 1 == 1 && last.status.at_limit, "{last:?}");
    assert!(steps.iter().any(|s| s.saturated.count_ones() >= 2), "two joints were never saturated together");
    // The other joints keep closing what error they can: it falls, and their motion dies away.
    let (mid, end) = (&steps[6000], last);
    assert!(end.position_error < mid.position_error, "error {} → {}", mid.position_error, end.position_error);
    let tail = &steps[steps.len() - 1000..];
    assert!(tail.last().unwrap().qd.norm() < tail[0].qd.norm(), "joint motion does not die away");
}

#[test]
fn a_configuration_it_cannot_use_is_refused_naming_the_key() {
    for (cfg, key) in [
        (ClikConfig { nullspace_speed_fraction: -0.1, ..ClikConfig::default() }, "clik.nullspace_speed_fraction"),
        (ClikConfig { sigma_threshold: 0.0, ..ClikConfig::default() }, "clik.sigma_threshold"),
        (ClikConfig { gains: [1.0, 1.0, f64::NAN, 1.0, 1.0, 1.0], ..ClikConfig::default() }, "clik.gains[2]"),
        (ClikConfig { max_correction_speed: 0.0, ..ClikConfig::default() }, "clik.max_correction_speed"),
    ] {
        let msg = Clik::new(cfg).unwrap_err().to_string();
        assert!(msg.contains(key), "{msg}");
    }
}

#[test]
fn a_tick_length_that_is_not_positive_holds_the_arm() {
    let model = robot("iiwa7");
    let mut solver = clik(Task::Print5);
    let q0 = common::start("iiwa7");
    let pose = model.forward_kinematics(&q0);
    let target = TcpTarget::at_rest(pose.translation.vector, UnitQuaternion::from_rotation_matrix(&pose.rotation));
    for dt in [0.0, -1e-3, f64::NAN, f64::INFINITY] {
        let s = solver.step(&model, &q0, &target, dt);
        assert!(s.status.invalid_input && s.q == q0 && s.qd == JointVector::zeros(), "dt {dt}");
    }
}

#[test]
fn a_bad_tick_length_while_moving_brakes_within_the_acceleration_limits() {
    let model = robot("iiwa7");
    let mut solver = clik(Task::Print5);
    let q0 = common::start("iiwa7");
    let pose = model.forward_kinematics(&q0);
    let orient = UnitQuaternion::from_rotation_matrix(&pose.rotation);
    let v = Vector3::new(0.0, 0.05, 0.0);
    let mut q = q0;
    let mut steps = Vec::new();
    for k in 0..1500 {
        let ramp = (k as f64 / 200.0).min(1.0);
        let p = pose.translation.vector + v * (k as f64 * 1e-3);
        let target = TcpTarget { position: p, orientation: orient, linear_velocity: v * ramp, angular_velocity: Vector3::zeros() };
        let dt = if (1000..1010).contains(&k) { f64::NAN } else { 1e-3 };
        let s = solver.step(&model, &q, &target, dt);
        assert_eq!(s.status.invalid_input, dt.is_nan(), "tick {k}");
        q = s.q;
        steps.push(s);
    }
    check_limits(&model, &steps, 1e-3);
    assert!(steps[1009].qd.norm() < steps[999].qd.norm(), "did not slow down");
    // And a solver reset with a speed past the limit slows down at the acceleration limit, no panic.
    let mut fast = clik(Task::Print5);
    let mut over = JointVector::zeros();
    over[0] = model.limits(0).velocity * 1.5;
    over[1] = f64::NAN;
    fast.reset(over);
    let s = fast.step(&model, &q0, &TcpTarget::at_rest(pose.translation.vector, orient), 1e-3);
    assert!(s.q.iter().all(|x| x.is_finite()));
    assert!(((over[0] - s.qd[0]) - model.limits(0).acceleration * 1e-3).abs() < 1e-9, "{}", s.qd[0]);
    // Spare entries past the chain's joints carry nothing through.
    let mut spare = q0;
    spare[7] = f64::NAN;
    let s = clik(Task::Print5).step(&model, &spare, &TcpTarget::at_rest(pose.translation.vector, orient), 1e-3);
    assert!(s.q.iter().all(|x| x.is_finite()) && s.q[7] == 0.0);
}

#[test]
fn only_the_paths_own_velocity_slows_the_path() {
    // VP6242 (1 rad/s on every joint) asked for 0.6 m/s along x: more than its joints can give.
    let model = robot("vp6242");
    let q0 = common::start("vp6242");
    let start = model.forward_kinematics(&q0);
    let fast = Vector3::new(0.6, 0.0, 0.0);
    let dt = 1e-3;
    let target = |k: usize| TcpTarget {
        position: start.translation.vector + fast * (k as f64 + 1.0) * dt,
        orientation: UnitQuaternion::from_rotation_matrix(&start.rotation),
        linear_velocity: fast,
        angular_velocity: Vector3::zeros(),
    };
    let zero = PathVelocity { linear: Vector3::zeros(), angular: Vector3::zeros() };
    let all_path = PathVelocity { linear: fast, angular: Vector3::zeros() };
    // The velocity is the base's (the path stands still): the step is scaled, the path is not slowed.
    let (mut base_driven, mut path_driven) = (clik(Task::Print5), clik(Task::Print5));
    let (mut q_b, mut q_p) = (q0, q0);
    let (mut scaled_b, mut scaled_p, mut path_slowed) = (0, 0, 0);
    for k in 0..200 {
        let b = base_driven.step_on_path(&model, &q_b, &target(k), &zero, dt);
        let p = path_driven.step_on_path(&model, &q_p, &target(k), &all_path, dt);
        q_b = b.q;
        q_p = p.q;
        if b.scale < 1.0 {
            scaled_b += 1;
            assert_eq!(b.path_scale, 1.0, "tick {k}: the base's motion slowed the path ({b:?})");
        }
        if p.scale < 1.0 {
            scaled_p += 1;
            assert!(p.path_scale >= 0.0 && p.path_scale <= 1.0);
            if p.path_scale < 1.0 {
                path_slowed += 1;
            }
        }
        assert!(p.path_scale.is_finite() && b.path_scale.is_finite());
    }
    assert!(scaled_b > 100 && scaled_p > 100, "scaled ticks: base {scaled_b}, path {scaled_p}");
    assert!(path_slowed * 10 >= scaled_p * 9, "the path's own speed slowed it on only {path_slowed} of {scaled_p} scaled ticks");
    // Unscaled steps report 1 for both.
    let mut calm = clik(Task::Print5);
    let s =
        calm.step(&model, &q0, &TcpTarget::at_rest(start.translation.vector, UnitQuaternion::from_rotation_matrix(&start.rotation)), dt);
    assert_eq!((s.scale, s.path_scale), (1.0, 1.0));
}
