//! The CLIK step on real robots: tracking accuracy, the wrist singularity, joint limits, determinism.

mod common;
#[path = "common/paths.rs"]
mod paths;

use common::{assert_within_limits, jv, robot, start};
use nalgebra::{UnitQuaternion, Vector3};
use paths::{Shape, track};
use strand_core::kin::{Clik, ClikConfig, JointVector, RobotModel, Task, TcpTarget};

fn clik(task: Task) -> Clik {
    Clik::new(ClikConfig { task, ..ClikConfig::default() }).unwrap()
}

/// A line and a circle sized to the arm: 100 mm and r = 30 mm on the iiwa, 60 mm and r = 20 mm on the
/// small arms, the line heading inwards and up, away from the stretched-arm boundary.
fn shapes(model: &RobotModel, q0: &JointVector) -> [(&'static str, Shape, f64); 2] {
    let p0 = model.forward_kinematics(q0).translation.vector;
    let big = model.dof() == 7;
    let (length, radius) = if big { (0.10, 0.03) } else { (0.06, 0.02) };
    let inward = Vector3::new(-p0.x, -p0.y, 0.0).normalize();
    let d = (inward + Vector3::new(0.0, 0.0, 0.4) + inward.cross(&Vector3::z()) * 0.5).normalize();
    [("line", Shape::Line { dir: d, length }, 3.0), ("circle", Shape::Circle { a: Vector3::x(), b: Vector3::y(), radius }, 4.0)]
}

#[test]
fn tracks_lines_and_circles_to_a_micrometre_at_1khz() {
    use strand_core::kin::Priority::{None as Flat, PositionFirst};
    let cases = [
        ("iiwa7", Task::Pose6, Flat),
        ("iiwa7", Task::Print5, Flat),
        ("vp6242", Task::Print5, Flat),
        ("meca500", Task::Print5, Flat),
        ("iiwa7", Task::Pose6, PositionFirst),
        ("vp6242", Task::Print5, PositionFirst),
    ];
    for (name, task, priority) in cases {
        let model = robot(name);
        for (shape_name, shape, total) in shapes(&model, &start(name)) {
            let mut solver = Clik::new(ClikConfig { task, priority, ..ClikConfig::default() }).unwrap();
            let r = track(&model, &mut solver, start(name), shape, total, 1000.0);
            let label = format!("{name} {task:?} {priority:?} {shape_name}");
            eprintln!(
                "{label}: max position error {:.2e} m, nozzle axis {:.2e} rad, orientation {:.2e} rad",
                r.max_pos_err, r.max_axis_err, r.max_rot_err
            );
            assert!(r.max_pos_err < 1e-6, "{label}: position error {:e} m", r.max_pos_err);
            assert!(r.max_axis_err < 1e-6, "{label}: nozzle axis error {:e} rad", r.max_axis_err);
            if task == Task::Pose6 {
                assert!(r.max_rot_err < 1e-6, "{label}: orientation error {:e} rad", r.max_rot_err);
            }
            if let Some(bad) = r.steps.iter().find(|s| !s.status.is_ok()) {
                panic!("{label}: {} steps flagged, first {bad:?}", r.flagged);
            }
            assert!(
                r.max_speed_ratio <= 1.0 && r.max_accel_ratio <= 1.0 + 1e-9,
                "{label}: limits {} {}",
                r.max_speed_ratio,
                r.max_accel_ratio
            );
        }
    }
}

#[test]
fn print5_uses_the_free_roll_to_raise_manipulability() {
    // Holding a point in the 5-D task, the null space climbs the manipulability gradient while the TCP
    // and the nozzle axis stay put. On the iiwa7 the null space is 2-D (elbow self-motion and roll). On a
    // 6-axis arm whose nozzle lies along J6 the free roll is J6 alone, which leaves w unchanged; a
    // nozzle mounted at an angle makes the roll a motion of the whole wrist, and then it pays off.
    let tilted = robot("vp6242").with_tool(strand_core::kin::Frame::from_parts(
        nalgebra::Translation3::new(0.05, 0.0, 0.03),
        strand_core::kin::geom::rpy(0.0, std::f64::consts::FRAC_PI_2 - 0.6, 0.0),
    ));
    let cases = [
        ("iiwa7", robot("iiwa7"), jv(&[0.2, 0.6, 1.4, -1.3, 0.2, 0.9, 0.3])),
        ("vp6242 tilted nozzle", tilted.unwrap(), jv(&[0.1, 0.3, 1.7, 0.6, 0.5, 0.2])),
    ];
    for (label, model, q0) in cases {
        let mut solver = clik(Task::Print5);
        let r = track(&model, &mut solver, q0, Shape::Line { dir: Vector3::x(), length: 0.0 }, 4.0, 1000.0);
        let first = r.steps.first().unwrap().manipulability;
        let last = r.steps.last().unwrap().manipulability;
        assert!(last > first * 1.02, "{label}: manipulability {first} → {last}");
        assert!(r.steps.windows(2).all(|w| w[1].manipulability >= w[0].manipulability - 1e-12), "{label}: w must not fall");
        assert!(r.max_pos_err < 1e-6 && r.max_axis_err < 1e-6, "{label}: {:e} {:e}", r.max_pos_err, r.max_axis_err);
    }
}

#[test]
fn through_the_vp6242_wrist_singularity_speeds_stay_in_limits_and_error_is_bounded() {
    let model = robot("vp6242");
    for task in [Task::Pose6, Task::Print5] {
        // Joint-space path that crosses q5 = 0 (J4 and J6 collinear); the target is its FK.
        let (qa, qb) = (jv(&[0.0, 0.3, 1.6, 0.0, 0.35, 0.0]), jv(&[0.0, 0.3, 1.6, 0.0, -0.35, 0.0]));
        let rate = 1000.0;
        let dt = 1.0 / rate;
        let total = 3.0;
        let mut solver = clik(task);
        let mut q = qa;
        let (mut max_err, mut near, mut qd_prev) = (0.0f64, 0usize, JointVector::zeros());
        let mut min_sigma = f64::INFINITY;
        let ticks = (total * rate) as usize + 500;
        let mut final_err = 0.0;
        let mut max_reported = 0.0f64;
        let mut max_rot = 0.0f64;
        for k in 0..ticks {
            let t = (k + 1) as f64 * dt;
            let (s, ds) = paths::quintic(t, total);
            let qt = qa + (qb - qa) * s;
            let qtd = (qb - qa) * ds;
            let pose = model.forward_kinematics(&qt);
            let mut st = strand_core::kin::ChainState::new(6);
            model.kinematics(&qt, &mut st);
            let twist = st.jacobian * qtd;
            let target = TcpTarget {
                position: pose.translation.vector,
                orientation: UnitQuaternion::from_rotation_matrix(&pose.rotation),
                linear_velocity: twist.fixed_rows::<3>(0).into_owned(),
                angular_velocity: twist.fixed_rows::<3>(3).into_owned(),
            };
            let step = solver.step(&model, &q, &target, dt);
            assert_within_limits(&model, &step, &qd_prev, dt, &format!("{task:?} tick {k}"));
            qd_prev = step.qd;
            q = step.q;
            let err = (model.forward_kinematics(&q).translation.vector - pose.translation.vector).norm();
            max_err = max_err.max(err);
            final_err = err;
            min_sigma = min_sigma.min(step.sigma_min);
            // The error the step reports is the one it measured before moving: bounded the same way.
            assert!(step.position_error < 5e-3, "{task:?} tick {k}: reported error {}", step.position_error);
            max_reported = max_reported.max(step.position_error).max(step.orientation_error);
            max_rot = max_rot.max(step.orientation_error);
            if step.status.near_singular {
                near += 1;
                assert!(step.damping > 0.0);
            }
        }
        assert!(near > 0, "{task:?}: the singular stretch was never reported (σ_min reached {min_sigma:e})");
        assert!(max_err < 5e-3, "{task:?}: error through the singularity {max_err:e} m");
        assert!(final_err < 1e-6, "{task:?}: error after the singularity {final_err:e} m");
        assert!(max_reported > 1e-7, "{task:?}: the damped stretch must show up in the reported error ({max_reported:e})");
        assert!(max_rot < 0.1, "{task:?}: orientation error through the singularity {max_rot} rad");
        eprintln!(
            "{task:?}: max position error {max_err:e} m, max reported orientation error {max_rot:e} rad, min σ {min_sigma:e}, {near} near-singular ticks"
        );
    }
}

fn hold(model: &RobotModel, solver: &mut Clik, q0: JointVector, target: TcpTarget, ticks: usize) -> Vec<strand_core::kin::ClikStep> {
    let mut q = q0;
    let mut out = Vec::with_capacity(ticks);
    let mut qd_prev = JointVector::zeros();
    for k in 0..ticks {
        let step = solver.step(model, &q, &target, 1e-3);
        assert!(model.within_limits(&step.q), "tick {k}: {:?} left the limits", step.q);
        assert_within_limits(model, &step, &qd_prev, 1e-3, &format!("tick {k}"));
        qd_prev = step.qd;
        q = step.q;
        out.push(step);
    }
    out
}

#[test]
fn a_target_outside_the_workspace_is_approached_and_held() {
    for (name, task) in [("iiwa7", Task::Pose6), ("vp6242", Task::Print5)] {
        let model = robot(name);
        let q0 = start(name);
        let start_pose = model.forward_kinematics(&q0);
        let far = start_pose.translation.vector.normalize() * 3.0; // 3 m out: beyond either arm
        let target = TcpTarget::at_rest(far, UnitQuaternion::from_rotation_matrix(&start_pose.rotation));
        let mut solver = clik(task);
        let steps = hold(&model, &mut solver, q0, target, 8000);
        let tail = &steps[steps.len() - 500..];
        let errs: Vec<f64> = tail.iter().map(|s| s.position_error).collect();
        let spread = errs.iter().cloned().fold(f64::NEG_INFINITY, f64::max) - errs.iter().cloned().fold(f64::INFINITY, f64::min);
        assert!(errs[0] > 1.5 && spread < 1e-3, "{name}: error {} settles (spread {spread:e})", errs[0]);
        // Held: the residual motion (the arm slowly turning to face the far target) dies away.
        let (early, late) = (tail[0].qd.norm(), tail.last().unwrap().qd.norm());
        assert!(late < 2e-2 && late < early, "{name}: joint speed {early} → {late} rad/s");
        assert!(tail.iter().all(|s| s.status.near_singular || s.status.at_limit), "{name}: a stretched arm must be reported");
    }
}

#[test]
fn a_target_past_a_joint_limit_drives_the_joint_to_its_limit_and_holds_it_there() {
    let model = robot("vp6242");
    let upper = model.limits(0).upper;
    let q0 = jv(&[upper - 0.3, 0.3, 1.7, 0.3, 0.9, 0.2]);
    let mut qt = q0;
    qt[0] = upper + 0.25; // the same pose turned past J1's limit
    let pose = model.forward_kinematics(&qt);
    let target = TcpTarget::at_rest(pose.translation.vector, UnitQuaternion::from_rotation_matrix(&pose.rotation));
    let mut solver = clik(Task::Pose6);
    let steps = hold(&model, &mut solver, q0, target, 4000);
    let last = steps.last().unwrap();
    assert!((last.q[0] - upper).abs() < 1e-9, "J1 at {} (limit {upper})", last.q[0]);
    assert!(last.status.at_limit && last.saturated & 1 == 1, "{last:?}");
    assert!(last.qd.norm() < 1e-2, "still moving: {:?}", last.qd);
    assert!(steps.iter().all(|s| s.q[0] <= upper));
}

#[test]
fn identical_inputs_give_bit_identical_commands() {
    let model = robot("iiwa7");
    let run = || {
        let mut solver = clik(Task::Print5);
        let r = track(&model, &mut solver, start("iiwa7"), shapes(&model, &start("iiwa7"))[1].1, 2.0, 1000.0);
        r.steps.iter().flat_map(|s| s.q.iter().chain(s.qd.iter()).map(|x| x.to_bits()).collect::<Vec<_>>()).collect::<Vec<u64>>()
    };
    let (a, b) = (run(), run());
    assert_eq!(a.len(), b.len());
    assert!(a == b, "two identical runs differ");
}

/// The nozzle axis (= J6 axis on this arm) sweeps past the forearm (J4) axis at 0.01 rad: following it
/// exactly would swing J4 and J6 by ~π within a few milliseconds (tens of rad/s against 1 rad/s). Path
/// time advances at the rate each step achieved (its `scale`), as the path engine will do. Returns the
/// largest nozzle-axis error (rad), position error (m), the smallest scale, and the near-singular ticks.
fn grazing_sweep(priority: strand_core::kin::Priority) -> (f64, f64, f64, usize) {
    let model = robot("vp6242");
    let qa = jv(&[0.0, 0.3, 1.6, 0.0, 0.35, 0.0]);
    let mut st = strand_core::kin::ChainState::new(6);
    model.kinematics(&qa, &mut st);
    let forearm = st.ang(3).normalize();
    let a0 = st.tcp.rotation * Vector3::z();
    let side = (a0 - forearm * a0.dot(&forearm)).normalize();
    let normal = forearm.cross(&side);
    let theta0 = a0.dot(&forearm).acos();
    let delta0 = 0.01;
    let axis_at = |t: f64, total: f64| {
        let (s, _) = paths::quintic(t, total);
        let th = theta0 * (1.0 - 2.0 * s);
        let d = delta0 * (1.0 - (th / theta0).powi(2));
        (forearm * th.cos() + side * th.sin() + normal * d).normalize()
    };
    let p0 = st.tcp.translation.vector;
    let (rate, total) = (1000.0, 3.0);
    let dt = 1.0 / rate;
    let mut solver = Clik::new(ClikConfig { task: Task::Print5, priority, ..ClikConfig::default() }).unwrap();
    let mut q = qa;
    let mut qd_prev = JointVector::zeros();
    let (mut max_axis_err, mut max_pos_err, mut min_scale, mut near) = (0.0f64, 0.0f64, 1.0f64, 0);
    let mut last_axis_err = 0.0;
    let (mut tau, mut rate_factor) = (0.0f64, 1.0f64);
    for k in 0..(total * rate) as usize + 6000 {
        tau += rate_factor * dt;
        let a = axis_at(tau, total);
        let a_dot = (axis_at(tau + 1e-6, total) - axis_at(tau - 1e-6, total)) / 2e-6 * rate_factor;
        let orientation = UnitQuaternion::rotation_between(&Vector3::z(), &a).unwrap();
        let target = TcpTarget { position: p0, orientation, linear_velocity: Vector3::zeros(), angular_velocity: a.cross(&a_dot) };
        let step = solver.step(&model, &q, &target, dt);
        assert_within_limits(&model, &step, &qd_prev, dt, &format!("{priority:?} tick {k}"));
        qd_prev = step.qd;
        q = step.q;
        let reached = model.forward_kinematics(&q);
        let axis_err = (reached.rotation * Vector3::z()).cross(&a).norm();
        max_axis_err = max_axis_err.max(axis_err);
        max_pos_err = max_pos_err.max((reached.translation.vector - p0).norm());
        min_scale = min_scale.min(step.scale);
        near += usize::from(step.status.near_singular);
        last_axis_err = axis_err;
        // Recover the rate gently (at most 1 % a tick), never faster than the step allowed.
        rate_factor = step.scale.min(rate_factor + 0.01).max(0.01);
    }
    assert!(tau >= total, "{priority:?}: the sweep did not finish: path time {tau} of {total} s");
    assert!(last_axis_err < 1e-6 && near > 0 && min_scale < 1.0, "{priority:?}: not recovered ({last_axis_err}) or not reported");
    (max_axis_err, max_pos_err, min_scale, near)
}

#[test]
fn a_nozzle_sweep_grazing_the_vp6242_wrist_singularity_is_slowed_and_damped_not_flipped() {
    use strand_core::kin::Priority;
    let (axis_first, pos_first, _, near_first) = grazing_sweep(Priority::PositionFirst);
    let (axis_flat, pos_flat, _, _) = grazing_sweep(Priority::None);
    eprintln!(
        "grazing sweep, position-first: nozzle axis {axis_first:.3e} rad, position {pos_first:.3e} m, {near_first} near-singular ticks"
    );
    eprintln!("grazing sweep, one damped inverse: nozzle axis {axis_flat:.3e} rad, position {pos_flat:.3e} m");
    assert!(axis_first < 0.1 && pos_first < 3e-3, "position-first: {axis_first} rad, {pos_first} m");
    assert!(axis_flat < 0.3 && pos_flat < 2e-2, "single inverse: {axis_flat} rad, {pos_flat} m");
    assert!(pos_first < 0.5 * pos_flat, "position-first must hold the tip better: {pos_first} vs {pos_flat} m");
}
