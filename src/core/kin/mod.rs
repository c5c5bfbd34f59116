//! Kinematics of a serial arm: the chain from URDF, FK, the geometric Jacobian and its derivative,
//! task manipulability with its analytic gradient, and the per-tick CLIK solver.
//!
//! Frames: B is the chain's root link (the robot base), T the TCP at the nozzle tip with z along the
//! nozzle. Everything here is in B; mapping world targets into B is the base correction's job.

mod clik;
mod fk;
pub mod geom;
mod model;
pub mod svd;
mod task;

pub use clik::{Clik, ClikConfig, ClikStatus, ClikStep, InvalidClikConfig, PathVelocity, Priority, TcpTarget};
pub use fk::{ChainState, Jacobian};
pub use model::{Frame, Joint, JointKind, JointLimits, JointVector, MAX_JOINTS, ModelError, RobotModel};
pub use svd::Svd;
pub use task::{Task, TaskJacobian, manipulability, manipulability_gradient};
