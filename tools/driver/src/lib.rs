//! strand's robot drivers: bridges between a robot controller's streaming interface and the
//! service. Each robot state becomes the JointState that clocks the service; each answer carries
//! the service's JointCommand for it, checked against the joint limits, or a hold when the command
//! is late.
//!
//! - [`protocol`], [`session`], [`guard`], [`axes`] — what every driver shares, from the
//!   `strand-robot` crate (re-exported here): the protocol trait, the sans-IO session, the limits
//!   every answer keeps and the catch-up after a missed cycle, the axis mapping.
//! - [`egm`] (ABB), [`rsi`] (KUKA KR C4), [`fri`] (KUKA LBR iiwa), [`bcap`] (DENSO RC7/RC8),
//!   [`meca`] (Mecademic Meca500) and [`ur`] (Universal Robots) implement the protocol trait. A new interface is one more module.
//! - [`bridge`] — the process loop where the robot sends first (EGM, RSI, FRI): UDP socket,
//!   service ports, deadlines.
//! - [`paced`] — the process loop where the driver connects and sends first (b-CAP, the
//!   Meca500): a link carries the cycle's exchange, on the robot's clock (b-CAP mode 2) or the
//!   driver's.
//! - [`fake`] — fake robot controllers speaking the real wire formats, for tests and benchmarks.

pub mod bcap;
pub mod bridge;
pub mod egm;
pub mod fake;
pub mod fri;
pub mod meca;
pub mod paced;
pub mod rsi;
pub mod ur;

pub use strand_robot::{axes, guard, protocol, session};

use strand::config::Config;
use strand::config::driver::{DriverConfig, DriverProtocol};

use axes::AxisMap;
use guard::ReplyGuard;
use protocol::RobotProtocol;
use session::{Session, SessionRules};

/// A driver that cannot start: the message names the file and key.
#[derive(Debug, thiserror::Error)]
pub enum SetupError {
    /// The service config.
    #[error(transparent)]
    Config(#[from] strand::config::ConfigError),
    /// A `[driver]` value.
    #[error("{file}: {source}")]
    Setting {
        /// The config file.
        file: String,
        /// What is wrong.
        source: strand_core::InvalidSetting,
    },
    /// The robot's joints cannot be carried by the protocol (a linear axis where it has none).
    #[error("{file}: the robot cannot be driven over {protocol}: {why}")]
    Robot {
        /// The config file.
        file: String,
        /// The protocol (`egm`, `rsi`).
        protocol: &'static str,
        /// Which joint, and why.
        why: String,
    },
    /// No `[driver]` section, or one for another protocol.
    #[error("{file}: {why}")]
    Section {
        /// The config file.
        file: String,
        /// What is missing.
        why: String,
    },
}

/// The `[driver]` section of `cfg` for `protocol`, checked against the robot.
pub fn driver_config(cfg: &Config, protocol: DriverProtocol) -> Result<DriverConfig, SetupError> {
    let file = cfg.file.display().to_string();
    let d = cfg.driver.clone().ok_or_else(|| SetupError::Section {
        file: file.clone(),
        why: format!("no [driver] section (protocol = \"{}\"): see the README, \"Connecting a robot\"", name(protocol)),
    })?;
    if d.protocol != protocol {
        return Err(SetupError::Section { file, why: format!("[driver] protocol = \"{}\", not \"{}\"", name(d.protocol), name(protocol)) });
    }
    let model = cfg.robot.build_model()?;
    d.validate(model.dof()).map_err(|source| SetupError::Setting { file: file.clone(), source })?;
    // The answer must leave inside the robot's cycle, with room for the answer itself.
    let period = 1.0 / cfg.controller.rate_hz;
    if d.reply_deadline > 0.75 * period {
        return Err(SetupError::Section {
            file,
            why: format!(
                "[driver] reply_deadline = {} s does not fit the robot's cycle ([controller] rate_hz = {} Hz: {} s); at most 0.75 of it",
                d.reply_deadline, cfg.controller.rate_hz, period
            ),
        });
    }
    if protocol == DriverProtocol::Fri {
        // The robot sends every send period, a whole number of ms from 1 to 5 set in the Sunrise
        // application; the service runs at that rate.
        let ms = 1000.0 / cfg.controller.rate_hz;
        if !((1.0..=5.0).contains(&ms) && (ms - ms.round()).abs() < 1e-9) {
            return Err(SetupError::Section {
                file,
                why: format!(
                    "[controller] rate_hz = {} Hz: FRI's send period is a whole number of ms, 1 to 5, the one the Sunrise application sets (rate_hz 1000, 500, 333.333…, 250, 200)",
                    cfg.controller.rate_hz
                ),
            });
        }
    }
    if protocol == DriverProtocol::Bcap {
        // The controller's cycle (8 ms on RC8; DENSO's own driver accepts nothing else): one
        // slvMove a cycle, and the service ticks once per reply.
        let ms = 1000.0 / cfg.controller.rate_hz;
        if !((2.0..=16.0).contains(&ms) && (ms - ms.round()).abs() < 1e-9) {
            return Err(SetupError::Section {
                file,
                why: format!(
                    "[controller] rate_hz = {} Hz: b-CAP slave mode runs on the controller's cycle, a whole number of ms (RC8: 8 ms, rate_hz = 125); run the service and strand-bcap with --set controller.rate_hz=125",
                    cfg.controller.rate_hz
                ),
            });
        }
    }
    if protocol == DriverProtocol::Ur && !(100.0..=500.0).contains(&cfg.controller.rate_hz) {
        // RTDE streams at the rate asked, at most 500 Hz (e-Series; CB3 125 Hz): one tick each.
        return Err(SetupError::Section {
            file,
            why: format!(
                "[controller] rate_hz = {} Hz: RTDE streams at most 500 Hz (e-Series; 125 Hz on a CB3); run the service and strand-ur with --set controller.rate_hz=500",
                cfg.controller.rate_hz
            ),
        });
    }
    Ok(d)
}

fn name(p: DriverProtocol) -> &'static str {
    p.name()
}

/// A session for the robot of `cfg` with its `[driver]` section `d`: the axis mapping, and the
/// guard with the URDF's position and velocity limits, the robot file's acceleration limits and
/// the robot's cycle (`[controller] rate_hz`).
pub fn session<P: RobotProtocol>(cfg: &Config, d: &DriverConfig, mut protocol: P) -> Result<Session<P>, SetupError> {
    let model = cfg.robot.build_model()?;
    let linear: Vec<bool> = model.joints().iter().map(|j| !j.kind.rotates()).collect();
    protocol.set_linear_axes(&linear).map_err(|why| SetupError::Robot { file: cfg.file.display().to_string(), protocol: P::NAME, why })?;
    protocol.set_period(1.0 / cfg.controller.rate_hz);
    let bounds = model.joints().iter().map(|j| j.limits).collect();
    let guard = ReplyGuard::new(bounds, 1.0 / cfg.controller.rate_hz);
    let map = AxisMap::new(model.dof(), &d.axis_sign, &d.axis_offset);
    let robot = match d.robot.as_str() {
        "" => None,
        text => Some(text.parse().map_err(|e: strand_robot::BadRobotAddress| SetupError::Setting {
            file: cfg.file.display().to_string(),
            source: strand_core::InvalidSetting::new("driver", e.to_string()),
        })?),
    };
    Ok(Session::new(
        protocol,
        map,
        guard,
        SessionRules { robot, max_late_cycles: d.max_late_cycles, recover_cycles: d.recover_cycles, reply_deadline: d.reply_deadline },
    ))
}
