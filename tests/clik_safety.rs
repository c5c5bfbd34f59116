//! Safety of the CLIK step under arbitrary targets (property-based): whatever is asked — far away,
//! spinning, fast, or NaN — a step that starts from rest within the limits keeps every command finite,
//! within the position and velocity limits, and changes velocity by at most the acceleration limit.

mod common;

use nalgebra::{UnitQuaternion, Vector3};
use proptest::prelude::*;
use strand_core::kin::{Clik, ClikConfig, JointVector, Priority, RobotModel, Task, TcpTarget};

fn models() -> Vec<RobotModel> {
    let mut v: Vec<RobotModel> = common::ROBOTS.iter().map(|n| common::robot(n)).collect();
    v.push(common::rail_arm());
    v
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn any_target_gives_commands_within_all_limits(
        robot_index in 0usize..6,
        seed in any::<u64>(),
        pose6 in any::<bool>(),
        position_first in any::<bool>(),
        rate in prop_oneof![Just(250.0), Just(1000.0), Just(4000.0), Just(8000.0)],
        offset in prop::array::uniform3(-2.0f64..2.0),
        spin in prop::array::uniform3(-3.0f64..3.0),
        speed in prop::array::uniform3(-1.0f64..1.0),
        nan_every in 0usize..7,
    ) {
        let models = models();
        let model = &models[robot_index];
        let mut rng = common::Rng(seed);
        let q0 = rng.config(model, 0.0);
        let dt = 1.0 / rate;
        let task = if pose6 { Task::Pose6 } else { Task::Print5 };
        let priority = if position_first { Priority::PositionFirst } else { Priority::None };
        let mut solver = Clik::new(ClikConfig { task, priority, ..ClikConfig::default() }).unwrap();
        let start = model.forward_kinematics(&q0);
        let mut q = q0;
        let mut qd_prev = JointVector::zeros();
        for k in 0..60 {
            let position = start.translation.vector + Vector3::from(offset) * (k as f64 / 60.0);
            let mut target = TcpTarget {
                position,
                orientation: UnitQuaternion::from_scaled_axis(Vector3::from(spin) * (k as f64 * dt)),
                linear_velocity: Vector3::from(speed),
                angular_velocity: Vector3::from(spin),
            };
            if nan_every > 0 && k % nan_every == 0 {
                target.position.y = f64::NAN;
            }
            let step = solver.step(model, &q, &target, dt);
            prop_assert!(step.q.iter().chain(step.qd.iter()).all(|x| x.is_finite()));
            prop_assert!(model.within_limits(&step.q), "tick {}: {:?}", k, step.q);
            prop_assert_eq!(step.status.invalid_input, nan_every > 0 && k % nan_every == 0);
            for i in 0..model.dof() {
                let l = model.limits(i);
                prop_assert!(step.qd[i].abs() <= l.velocity * (1.0 + 1e-9), "tick {} joint {}: speed {}", k, i, step.qd[i]);
                let acc = (step.qd[i] - qd_prev[i]).abs() / dt;
                prop_assert!(acc <= l.acceleration * (1.0 + 1e-6), "tick {} joint {}: accel {} > {}", k, i, acc, l.acceleration);
            }
            qd_prev = step.qd;
            q = step.q;
        }
    }
}
