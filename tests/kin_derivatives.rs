//! The Jacobian, the Hessian slices and the manipulability gradients against central finite
//! differences, on all five bundled robots at random configurations.

mod common;

use common::{ROBOTS, Rng, rail_arm, robot};
use strand_core::kin::{ChainState, JointVector, RobotModel, Task, TaskJacobian, geom, manipulability, manipulability_gradient};

const H: f64 = 1e-6;

/// The five bundled robots and the synthetic rail-mounted arm (prismatic and continuous joints).
fn models() -> Vec<(String, RobotModel)> {
    let mut v: Vec<(String, RobotModel)> = ROBOTS.iter().map(|n| (n.to_string(), robot(n))).collect();
    v.push(("rail_arm".into(), rail_arm()));
    v
}
const CONFIGS: usize = 40;

fn perturbed(q: &JointVector, i: usize, h: f64) -> JointVector {
    let mut p = *q;
    p[i] += h;
    p
}

fn state(model: &RobotModel, q: &JointVector) -> ChainState {
    let mut s = ChainState::new(model.dof());
    model.kinematics(q, &mut s);
    s
}

#[test]
fn jacobian_matches_finite_differences() {
    let mut rng = Rng(1);
    for (name, model) in models() {
        let mut worst: f64 = 0.0;
        for _ in 0..CONFIGS {
            let q = rng.config(&model, 0.02);
            let s = state(&model, &q);
            assert!((s.tcp.translation.vector - model.forward_kinematics(&q).translation.vector).norm() < 1e-15);
            for i in 0..model.dof() {
                let (a, b) = (model.forward_kinematics(&perturbed(&q, i, H)), model.forward_kinematics(&perturbed(&q, i, -H)));
                let lin = (a.translation.vector - b.translation.vector) / (2.0 * H);
                let ang = geom::rotation_vector(&(a.rotation * b.rotation.inverse())) / (2.0 * H);
                worst = worst.max((lin - s.lin(i)).norm()).max((ang - s.ang(i)).norm());
            }
        }
        assert!(worst < 1e-8, "{name}: Jacobian vs finite differences: worst column error {worst:e}");
    }
}

#[test]
fn hessian_slices_match_finite_differences() {
    let mut rng = Rng(2);
    for (name, model) in models() {
        let mut worst: f64 = 0.0;
        for _ in 0..CONFIGS {
            let q = rng.config(&model, 0.02);
            let s = state(&model, &q);
            for i in 0..model.dof() {
                let fd = (state(&model, &perturbed(&q, i, H)).jacobian - state(&model, &perturbed(&q, i, -H)).jacobian) / (2.0 * H);
                worst = worst.max((fd - s.jacobian_derivative(i)).abs().max());
            }
        }
        assert!(worst < 1e-8, "{name}: dJ/dq vs finite differences: worst entry error {worst:e}");
    }
}

#[test]
fn manipulability_gradient_matches_finite_differences_for_both_tasks() {
    let mut rng = Rng(3);
    for (name, model) in models() {
        for task in [Task::Pose6, Task::Print5] {
            let mut worst: f64 = 0.0;
            for _ in 0..CONFIGS {
                let q = rng.config(&model, 0.02);
                let s = state(&model, &q);
                let tj = TaskJacobian::new(&s, task);
                let svd = tj.svd();
                let w = svd.manipulability();
                assert!((w - manipulability(&s, task)).abs() < 1e-15);
                // w² = det(JJᵀ), checked against nalgebra's determinant.
                let mut j = nalgebra::DMatrix::<f64>::zeros(tj.m, model.dof());
                for r in 0..tj.m {
                    for c in 0..model.dof() {
                        j[(r, c)] = tj.rows[r][c];
                    }
                }
                let det = (&j * j.transpose()).determinant();
                assert!((w * w - det).abs() < 1e-12 * (1.0 + det.abs()), "{name} {task:?}: w² {} vs det {det}", w * w);
                let grad = manipulability_gradient(&s, &tj, &svd);
                for i in 0..model.dof() {
                    let wp = manipulability(&state(&model, &perturbed(&q, i, H)), task);
                    let wm = manipulability(&state(&model, &perturbed(&q, i, -H)), task);
                    let fd = (wp - wm) / (2.0 * H);
                    worst = worst.max((fd - grad[i]).abs());
                }
            }
            assert!(worst < 1e-8, "{name} {task:?}: grad w vs finite differences: worst {worst:e}");
        }
    }
}

#[test]
fn five_d_manipulability_does_not_depend_on_the_nozzle_roll() {
    // Turning the tool about its own nozzle axis must not change the 5-D manipulability.
    let model = robot("vp6242");
    let q = common::jv(&[0.3, 0.2, 1.9, 0.4, 0.9, 0.0]);
    let w0 = manipulability(&state(&model, &q), Task::Print5);
    for roll in [0.5, 1.5, -2.5] {
        let mut q2 = q;
        q2[5] = roll; // joint 6 turns about the nozzle axis on this arm
        let w = manipulability(&state(&model, &q2), Task::Print5);
        assert!((w - w0).abs() < 1e-14, "roll {roll}: {w} vs {w0}");
    }
}

#[test]
fn at_and_near_singularities_everything_stays_finite() {
    // Stretched iiwa (q = 0: shoulder, elbow and wrist all singular), VP6242 wrist at q5 = 0 exactly,
    // and configurations approaching them.
    let cases: [(&str, Vec<f64>); 3] =
        [("iiwa7", vec![0.0; 7]), ("vp6242", vec![0.0, 0.3, 1.6, 0.0, 0.0, 0.0]), ("meca500", vec![0.0, 0.0, 0.0, 0.0, 0.0, 0.0])];
    for (name, q) in cases {
        let model = robot(name);
        for eps in [0.0, 1e-12, 1e-9, 1e-6, 1e-3] {
            let mut q = common::jv(&q);
            for i in 0..model.dof() {
                q[i] += eps * (i as f64 + 1.0);
            }
            let s = state(&model, &q);
            for task in [Task::Pose6, Task::Print5] {
                let tj = TaskJacobian::new(&s, task);
                let svd = tj.svd();
                let g = manipulability_gradient(&s, &tj, &svd);
                assert!(svd.manipulability().is_finite() && g.iter().all(|x| x.is_finite()), "{name} {task:?} eps {eps}");
                if eps == 0.0 {
                    assert!(svd.sigma_min() < 1e-6, "{name} {task:?}: expected a singularity, σ_min = {}", svd.sigma_min());
                }
            }
        }
    }
}
