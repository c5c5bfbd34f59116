//! Cost of the per-tick kinematics: FK, FK + Jacobian, the manipulability gradient, and one full CLIK
//! step (FK, Jacobian, SVD, gradient, null space, limits), for the 7-axis iiwa7 and the 6-axis VP6242
//! in the 5-D printing task. `svd/*` compares our warm-started Jacobi SVD with nalgebra's.
//!
//! Run: `cargo bench -p strand --bench kin`.

use std::path::PathBuf;

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::SMatrix;
use strand::config::RobotConfig;
use strand_core::kin::{ChainState, Clik, ClikConfig, JointVector, Priority, RobotModel, Task, TaskJacobian, manipulability_gradient, svd};

// The targets `strand-bench clik` and the Pinocchio bench track too: one table.
#[path = "../tools/bench/src/circle.rs"]
mod circle;
use circle::{IIWA_Q0, circle};

fn robot(name: &str) -> RobotModel {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/robots").join(format!("{name}.toml"));
    RobotConfig::load(&path).unwrap().build_model().unwrap()
}

fn start(name: &str) -> JointVector {
    let v: &[f64] = match name {
        "iiwa7" => &IIWA_Q0,
        _ => &[0.1, 0.0, 2.1, 0.3, 0.9, 0.2],
    };
    let mut q = JointVector::zeros();
    q.as_mut_slice()[..v.len()].copy_from_slice(v);
    q
}

fn kinematics(c: &mut Criterion) {
    for (name, task) in [("iiwa7", Task::Pose6), ("iiwa7", Task::Print5), ("vp6242", Task::Print5)] {
        let model = robot(name);
        let q = start(name);
        let label = format!("{name}/{task:?}");
        let mut state = ChainState::new(model.dof());
        if task == Task::Pose6 || name == "vp6242" {
            c.bench_function(&format!("fk/{name}"), |b| {
                b.iter(|| std::hint::black_box(model.forward_kinematics(std::hint::black_box(&q))))
            });
            c.bench_function(&format!("fk_jacobian/{name}"), |b| b.iter(|| model.kinematics(std::hint::black_box(&q), &mut state)));
        }
        model.kinematics(&q, &mut state);
        let tj = TaskJacobian::new(&state, task);
        let s = tj.svd();
        c.bench_function(&format!("gradient/{label}"), |b| b.iter(|| std::hint::black_box(manipulability_gradient(&state, &tj, &s))));
        c.bench_function(&format!("svd_cold/{label}"), |b| {
            b.iter(|| std::hint::black_box(svd::svd(&tj.rows, tj.m, tj.n, &svd::identity_start())))
        });
        c.bench_function(&format!("svd_warm/{label}"), |b| b.iter(|| std::hint::black_box(svd::svd(&tj.rows, tj.m, tj.n, &s.u))));
        if task == Task::Pose6 {
            let j: SMatrix<f64, 6, 7> = SMatrix::from_fn(|r, col| tj.rows[r][col]);
            c.bench_function(&format!("svd_nalgebra/{label}"), |b| {
                b.iter(|| std::hint::black_box(std::hint::black_box(j).svd(true, true)))
            });
        }
        let targets = circle(&model, &q);
        for (suffix, priority) in [("", Priority::None), ("/position-first", Priority::PositionFirst)] {
            let mut solver = Clik::new(ClikConfig { task, priority, ..ClikConfig::default() }).unwrap();
            let mut qk = q;
            let mut k = 0usize;
            c.bench_function(&format!("clik_step/{label}{suffix}"), |b| {
                b.iter(|| {
                    let step = solver.step(&model, &qk, &targets[k], 1e-3);
                    qk = step.q;
                    k = (k + 1) % targets.len();
                    std::hint::black_box(step.scale)
                })
            });
        }
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().warm_up_time(std::time::Duration::from_millis(500)).measurement_time(std::time::Duration::from_secs(2)).sample_size(50);
    targets = kinematics
}
criterion_main!(benches);
