//! The positioner: the cell's external axes, which carry the part (a turntable, a tilt-and-turn
//! table) or the robot (a linear track), and how they move the work relative to the arm.
//!
//! A positioner is a chain of the cell's URDF from the arm's base link B to the plate the part is
//! fixed to (its joints are the cell's external axes, in chain order after the arm's). A job for
//! such a cell is written in the *work frame at home*: where the part's points lie while every
//! external axis is at 0. With the axes at θ the work has moved by
//!
//! M(θ) = T_B,plate(θ) · T_B,plate(0)⁻¹   (in B),
//!
//! so a point p of the job is at M(θ)·p. A track is a chain from its rail to the arm's base link:
//! it carries B, and a point fixed in the cell is seen from the carried base at
//! M(θ) = T_rail,B(θ)⁻¹ · T_rail,B(0) times where it was seen from B at home. Either way a point p
//! of the job (in the work frame at home) is at M(θ)·p in B, and a target moving along the job at ṗ while the axes turn
//! at θ̇ moves at R_M·ṗ + Σᵢ θ̇ᵢ·∂(M p)/∂θᵢ. The path engine runs along the job in the work frame,
//! so its speed is the nozzle's speed over the part ("tool-tip following", RTCP), and the arm's
//! CLIK follows the carried target. Why B and not W: the positioner stands on the arm's base (or
//! beside it on the same floor), and a base that moves carries both.
//!
//! The derivatives ∂M/∂θᵢ are central differences over 1e-6 rad (or m): exact to about 1e-12 for
//! a chain of one or two joints, with no second code path for revolute and prismatic axes.
//! Everything here is allocation-free and deterministic.

use nalgebra::{Matrix3, Point3, UnitQuaternion, Vector3};
use strand_wire::MAX_EXTERNAL_AXES;

use crate::kin::{Frame, JointVector, RobotModel, TcpTarget, geom};

/// The step of the central differences (rad or m).
const DIFFERENCE_STEP: f64 = 1e-6;

/// Why a chain cannot be the cell's positioner.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum PositionerError {
    /// More joints than a segment can carry.
    #[error("the positioner chain \"{root}\" → \"{tip}\" has {count} movable joints; a segment carries at most {max}")]
    TooManyAxes {
        /// Root link.
        root: String,
        /// Tip link.
        tip: String,
        /// Its movable joints.
        count: usize,
        /// [`MAX_EXTERNAL_AXES`].
        max: usize,
    },
    /// The arm's joints and the positioner's together exceed what a joint command carries.
    #[error("the arm's {arm} joints and the positioner's {axes} exceed the {max} a joint command carries")]
    TooManyJoints {
        /// The arm's joints.
        arm: usize,
        /// The positioner's.
        axes: usize,
        /// `MAX_JOINTS`.
        max: usize,
    },
}

/// What a chain of external axes carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Carries {
    /// The part: a positioner under it (a chain from B to the plate).
    Work,
    /// The robot: a track under it (a chain from the rail to B).
    Robot,
}

/// The cell's external axes: their chain and what it carries.
#[derive(Clone, Debug)]
pub struct Positioner {
    model: RobotModel,
    carries: Carries,
    /// The chain's tip at home, T(0), and its inverse.
    home: Frame,
    home_inverse: Frame,
}

impl Positioner {
    /// The positioner of `model`: a chain from the arm's base link B to the plate (`Carries::Work`)
    /// or from a track's rail to B (`Carries::Robot`); its tool, if any, is ignored.
    pub fn new(model: RobotModel, carries: Carries) -> Result<Self, PositionerError> {
        if model.dof() > MAX_EXTERNAL_AXES {
            return Err(PositionerError::TooManyAxes {
                root: model.root_link().to_string(),
                tip: model.tip_link().to_string(),
                count: model.dof(),
                max: MAX_EXTERNAL_AXES,
            });
        }
        let home = model.forward_kinematics(&JointVector::zeros());
        Ok(Positioner { model, carries, home, home_inverse: home.inverse() })
    }

    /// Its chain, with the axes' limits.
    pub fn model(&self) -> &RobotModel {
        &self.model
    }

    /// What it carries.
    pub fn carries(&self) -> Carries {
        self.carries
    }

    /// Its axes (1 or 2).
    pub fn dof(&self) -> usize {
        self.model.dof()
    }

    /// How the work has moved relative to the arm from home with the axes at `axes` (rad or m),
    /// in B: M(θ) = T(θ) · T(0)⁻¹ for a positioner, T(θ)⁻¹ · T(0) for a track.
    pub fn work_motion(&self, axes: &[f64; MAX_EXTERNAL_AXES]) -> Frame {
        let mut q = JointVector::zeros();
        for i in 0..self.dof() {
            q[i] = axes[i];
        }
        let t = self.model.forward_kinematics(&q);
        match self.carries {
            Carries::Work => t * self.home_inverse,
            Carries::Robot => t.inverse() * self.home,
        }
    }

    /// The work's motion with the axes at `axes` turning at `rates` (rad/s or m/s): M(θ), and its
    /// rate of change Ṁ = Σᵢ θ̇ᵢ·∂M/∂θᵢ as the rotation's rate Ṙ, the translation's ṫ and the angular
    /// velocity ω (rad/s, B).
    fn motion(&self, axes: &[f64; MAX_EXTERNAL_AXES], rates: &[f64; MAX_EXTERNAL_AXES]) -> WorkMotion {
        let m = self.work_motion(axes);
        let mut motion = WorkMotion { m, r_dot: Matrix3::zeros(), t_dot: Vector3::zeros(), w: Vector3::zeros() };
        for i in 0..self.dof() {
            if rates[i] == 0.0 {
                continue;
            }
            let mut up = *axes;
            let mut down = *axes;
            up[i] += DIFFERENCE_STEP;
            down[i] -= DIFFERENCE_STEP;
            let (m_up, m_down) = (self.work_motion(&up), self.work_motion(&down));
            let scale = rates[i] / (2.0 * DIFFERENCE_STEP);
            motion.r_dot += (m_up.rotation.matrix() - m_down.rotation.matrix()) * scale;
            motion.t_dot += (m_up.translation.vector - m_down.translation.vector) * scale;
            let turn = UnitQuaternion::from_rotation_matrix(&(m_up.rotation * m_down.rotation.inverse()));
            motion.w += geom::quaternion_log(&turn) * scale;
        }
        motion
    }

    /// The target `home` (B, in the work frame at home, with its velocities along the job) where
    /// the work is with the axes at `axes` turning at `rates` (rad/s or m/s): its pose moved by
    /// M(θ), its velocities turned by M's rotation plus what the axes' motion adds.
    pub fn carry(&self, home: &TcpTarget, axes: &[f64; MAX_EXTERNAL_AXES], rates: &[f64; MAX_EXTERNAL_AXES]) -> TcpTarget {
        self.motion(axes, rates).carry(home)
    }

    /// [`carry`](Self::carry) of two targets at one point (the target with all its velocities, and
    /// the same with the path's own): the work's motion is computed once.
    pub fn carry_both(
        &self,
        a: &TcpTarget,
        b: &TcpTarget,
        axes: &[f64; MAX_EXTERNAL_AXES],
        rates: &[f64; MAX_EXTERNAL_AXES],
    ) -> (TcpTarget, TcpTarget) {
        let motion = self.motion(axes, rates);
        (motion.carry(a), motion.carry(b))
    }

    /// A pose (B) on the moved work brought back to the work frame at home: M(θ)⁻¹ applied.
    pub fn to_home(
        &self,
        position: &Vector3<f64>,
        orientation: &UnitQuaternion<f64>,
        axes: &[f64; MAX_EXTERNAL_AXES],
    ) -> (Vector3<f64>, UnitQuaternion<f64>) {
        let back = self.work_motion(axes).inverse();
        let r = UnitQuaternion::from_rotation_matrix(&back.rotation);
        ((back * Point3::from(*position)).coords, r * orientation)
    }
}

/// M(θ) and its rate of change at one tick ([`Positioner::motion`]).
struct WorkMotion {
    m: Frame,
    /// dR/dt (1/s), dt/dt (m/s), and the angular velocity (rad/s), in B.
    r_dot: Matrix3<f64>,
    t_dot: Vector3<f64>,
    w: Vector3<f64>,
}

impl WorkMotion {
    fn carry(&self, home: &TcpTarget) -> TcpTarget {
        let r = UnitQuaternion::from_rotation_matrix(&self.m.rotation);
        TcpTarget {
            position: (self.m * Point3::from(home.position)).coords,
            orientation: r * home.orientation,
            linear_velocity: r * home.linear_velocity + self.r_dot * home.position + self.t_dot,
            angular_velocity: r * home.angular_velocity + self.w,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TABLE: &str = r#"<robot name="table">
      <link name="base_link"/><link name="plate_base"/><link name="plate"/>
      <joint name="mount" type="fixed"><parent link="base_link"/><child link="plate_base"/><origin xyz="0.6 0.1 0.2"/></joint>
      <joint name="c" type="revolute"><parent link="plate_base"/><child link="plate"/><axis xyz="0 0 1"/>
        <limit lower="-6.3" upper="6.3" velocity="1.0" effort="1"/></joint>
    </robot>"#;

    fn table() -> Positioner {
        Positioner::new(RobotModel::from_urdf_str(TABLE, "table.urdf", "base_link", "plate").unwrap(), Carries::Work).unwrap()
    }

    #[test]
    fn a_turntable_turns_the_work_about_its_axis_and_the_velocity_is_the_turn_s() {
        let t = table();
        // A point 0.1 m out from the table's axis, at home.
        let home = TcpTarget::at_rest(Vector3::new(0.7, 0.1, 0.25), UnitQuaternion::identity());
        let quarter = std::f64::consts::FRAC_PI_2;
        let moved = t.carry(&home, &[quarter, 0.0], &[2.0, 0.0]);
        let (again, _) = t.carry_both(&home, &home, &[quarter, 0.0], &[2.0, 0.0]);
        assert_eq!(again.linear_velocity, moved.linear_velocity);
        assert!((moved.position - Vector3::new(0.6, 0.2, 0.25)).norm() < 1e-12, "{:?}", moved.position);
        // ω × r: 2 rad/s about z at 0.1 m from the axis, the point on +y of it: −x at 0.2 m/s.
        assert!((moved.linear_velocity - Vector3::new(-0.2, 0.0, 0.0)).norm() < 1e-8, "{:?}", moved.linear_velocity);
        assert!((moved.angular_velocity - Vector3::new(0.0, 0.0, 2.0)).norm() < 1e-8);
        assert!(moved.orientation.angle_to(&UnitQuaternion::from_axis_angle(&Vector3::z_axis(), quarter)) < 1e-12);
        let (back, q) = t.to_home(&moved.position, &moved.orientation, &[quarter, 0.0]);
        assert!((back - home.position).norm() < 1e-12);
        assert!(q.angle_to(&UnitQuaternion::identity()) < 1e-12);
    }

    #[test]
    fn a_chain_of_three_axes_is_refused() {
        let urdf = r#"<robot name="p"><link name="a"/><link name="b"/><link name="c"/><link name="d"/>
          <joint name="1" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" velocity="1" effort="1"/></joint>
          <joint name="2" type="revolute"><parent link="b"/><child link="c"/><axis xyz="0 1 0"/><limit lower="-1" upper="1" velocity="1" effort="1"/></joint>
          <joint name="3" type="revolute"><parent link="c"/><child link="d"/><axis xyz="1 0 0"/><limit lower="-1" upper="1" velocity="1" effort="1"/></joint>
        </robot>"#;
        let model = RobotModel::from_urdf_str(urdf, "p.urdf", "a", "d").unwrap();
        assert!(matches!(Positioner::new(model, Carries::Work), Err(PositionerError::TooManyAxes { count: 3, .. })));
    }

    #[test]
    fn a_track_carries_the_robot_and_the_work_moves_back_relative_to_it() {
        let urdf = r#"<robot name="track"><link name="rail"/><link name="carriage"/><link name="base_link"/>
          <joint name="x" type="prismatic"><parent link="rail"/><child link="carriage"/><axis xyz="1 0 0"/>
            <limit lower="0" upper="2" velocity="0.5" effort="1"/></joint>
          <joint name="mount" type="fixed"><parent link="carriage"/><child link="base_link"/><origin xyz="0 0 0.3" rpy="0 0 1.5707963267948966"/></joint>
        </robot>"#;
        let track = Positioner::new(RobotModel::from_urdf_str(urdf, "track.urdf", "rail", "base_link").unwrap(), Carries::Robot).unwrap();
        // The base moved 0.4 m along the rail's x, which is B's −y (B turned 90° on the carriage):
        // a point fixed in the cell is 0.4 m further along B's +y, and moves at +0.1 m/s in B when
        // the track runs at 0.1 m/s.
        let home = TcpTarget::at_rest(Vector3::new(0.5, 0.0, 0.0), UnitQuaternion::identity());
        let seen = track.carry(&home, &[0.4, 0.0], &[0.1, 0.0]);
        assert!((seen.position - Vector3::new(0.5, 0.4, 0.0)).norm() < 1e-12, "{:?}", seen.position);
        assert!((seen.linear_velocity - Vector3::new(0.0, 0.1, 0.0)).norm() < 1e-9, "{:?}", seen.linear_velocity);
        assert!(seen.angular_velocity.norm() < 1e-9);
        assert!((track.to_home(&seen.position, &seen.orientation, &[0.4, 0.0]).0 - home.position).norm() < 1e-12);
    }
}
