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
//!
//! A cell's external axes (a positioner under the part, a track under the robot: `[positioner]`
//! or `[track]` in the robot file) follow the arm's joints in every joint array, on the service's
//! side and the robot's ([`CellJoints`]): RSI carries them as E1..E6, EGM in `externalJoints` —
//! of the robot's channel, or of their own when the controller runs them as a mechanical unit
//! apart (MultiMove; [`unit_link`], `[driver] external_axes_bind`); the other protocols drive an
//! arm alone and refuse such a cell at start.

pub mod bcap;
pub mod bridge;
pub mod egm;
pub mod fake;
pub mod fri;
pub mod meca;
pub mod paced;
pub mod rsi;
pub mod unit_link;
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
    /// The cell's joints cannot be carried by the protocol: a linear axis where it has none, or
    /// external axes (a positioner, a track) over a protocol that drives the arm alone.
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

/// The joints a driver carries, in the order of every joint array on the wire: the arm's (the
/// robot file's chain), then its positioner's or track's axes (`[positioner]`, `[track]`), in
/// chain order.
#[derive(Clone, Debug)]
pub struct CellJoints {
    /// The arm's joints.
    pub arm: usize,
    /// The section of the external axes (`"positioner"`, `"track"`), if the cell has one.
    pub section: Option<&'static str>,
    /// Every joint, the arm's first.
    pub joints: Vec<CellJoint>,
}

/// One joint a driver carries.
#[derive(Clone, Debug)]
pub struct CellJoint {
    /// Its URDF name.
    pub name: String,
    /// Prismatic: metres here, millimetres on the vendors' wires (else rad and degrees).
    pub linear: bool,
    /// The URDF's position and speed limits, the robot file's acceleration and jerk limits (an
    /// external axis': its own section's).
    pub limits: strand_core::kin::JointLimits,
}

impl CellJoint {
    fn of(j: &strand_core::kin::Joint) -> CellJoint {
        CellJoint { name: j.name.clone(), linear: !j.kind.rotates(), limits: j.limits }
    }
}

impl CellJoints {
    /// The arm's joints, then the external axes, of `cfg`'s robot file.
    pub fn of(cfg: &Config) -> Result<CellJoints, SetupError> {
        let model = cfg.robot.build_model()?;
        let positioner = cfg.robot.build_positioner()?;
        let section = cfg.robot.external_axes().map(|(s, _)| s).filter(|_| positioner.is_some());
        let mut joints: Vec<CellJoint> = model.joints().iter().map(CellJoint::of).collect();
        if let Some(p) = &positioner {
            joints.extend(p.model().joints().iter().map(CellJoint::of));
        }
        if joints.len() > strand_ipc::MAX_JOINTS {
            return Err(SetupError::Section {
                file: cfg.file.display().to_string(),
                why: format!(
                    "the arm's {} joints and the [{}] axes make {}: a joint command carries {}",
                    model.dof(),
                    section.unwrap_or("positioner"),
                    joints.len(),
                    strand_ipc::MAX_JOINTS
                ),
            });
        }
        Ok(CellJoints { arm: model.dof(), section, joints })
    }

    /// All joints: the arm's and the external axes.
    pub fn dof(&self) -> usize {
        self.joints.len()
    }

    /// The external axes.
    pub fn external(&self) -> usize {
        self.joints.len() - self.arm
    }
}

/// The protocols that carry external axes after the arm's: RSI (E1..E6) and EGM
/// (`externalJoints`). FRI, UR RTDE, the Meca500's API and b-CAP's slave mode drive the arm alone.
fn carries_external_axes(p: DriverProtocol) -> bool {
    matches!(p, DriverProtocol::Egm | DriverProtocol::Rsi)
}

/// The protocol's name as its maker writes it, for messages.
fn wire_name(p: DriverProtocol) -> &'static str {
    match p {
        DriverProtocol::Egm => "EGM",
        DriverProtocol::Rsi => "RSI",
        DriverProtocol::Fri => "FRI",
        DriverProtocol::Bcap => "b-CAP",
        DriverProtocol::Meca => "the Meca500's TCP API",
        DriverProtocol::Ur => "UR RTDE",
    }
}

/// The `[driver]` section of `cfg` for `protocol`, checked against the cell: the arm and its
/// positioner's (or track's) axes. `axis_sign` and `axis_offset` list either the arm's joints (the
/// external axes then map one to one) or every joint of the cell, arm first.
pub fn driver_config(cfg: &Config, protocol: DriverProtocol) -> Result<DriverConfig, SetupError> {
    let file = cfg.file.display().to_string();
    let d = cfg.driver.clone().ok_or_else(|| SetupError::Section {
        file: file.clone(),
        why: format!("no [driver] section (protocol = \"{}\"): see the README, \"Connecting a robot\"", name(protocol)),
    })?;
    if d.protocol != protocol {
        return Err(SetupError::Section { file, why: format!("[driver] protocol = \"{}\", not \"{}\"", name(d.protocol), name(protocol)) });
    }
    let cell = CellJoints::of(cfg)?;
    if cell.external() > 0 && !carries_external_axes(protocol) {
        let names: Vec<&str> = cell.joints[cell.arm..].iter().map(|j| j.name.as_str()).collect();
        return Err(SetupError::Robot {
            file,
            protocol: name(protocol),
            why: format!(
                "{} carries no external axes: the robot file's [{}] has {} ({}); drive this cell with strand-rsi (KUKA) or strand-egm (ABB), or use a robot file without it",
                wire_name(protocol),
                cell.section.unwrap_or("positioner"),
                names.len(),
                names.join(", ")
            ),
        });
    }
    // The per-joint lists: the arm's joints, or the whole cell's.
    let mapped = if [&d.axis_sign, &d.axis_offset].iter().all(|l| l.is_empty() || l.len() == cell.arm) { cell.arm } else { cell.dof() };
    if let Some((key, list)) = [("axis_sign", &d.axis_sign), ("axis_offset", &d.axis_offset)]
        .into_iter()
        .find(|(_, l)| !l.is_empty() && l.len() != mapped)
        .filter(|_| cell.external() > 0)
    {
        return Err(SetupError::Section {
            file,
            why: format!(
                "[driver] {key} has {} values; the cell has the arm's {} joints and {} [{}] axes: give {} (the arm's; the axes map one to one) or {} (arm first), and the same count in axis_sign and axis_offset",
                list.len(),
                cell.arm,
                cell.external(),
                cell.section.unwrap_or("positioner"),
                cell.arm,
                cell.dof()
            ),
        });
    }
    d.validate(mapped).map_err(|source| SetupError::Setting { file: file.clone(), source })?;
    if !d.external_axes_bind.is_empty() && cell.external() == 0 {
        return Err(SetupError::Section {
            file,
            why: format!(
                "[driver] external_axes_bind = {:?}, but the robot file has no external axes ([positioner] or [track]) to stream on a channel of their own",
                d.external_axes_bind
            ),
        });
    }
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

/// A session for the cell of `cfg` with its `[driver]` section `d`: the axis mapping and the
/// guard over every joint the driver carries ([`CellJoints`]: the arm's, then its positioner's or
/// track's axes), with the URDF's position and velocity limits, the robot file's acceleration
/// limits (the external axes' from their own section) and the robot's cycle (`[controller]
/// rate_hz`).
pub fn session<P: RobotProtocol>(cfg: &Config, d: &DriverConfig, mut protocol: P) -> Result<Session<P>, SetupError> {
    let cell = CellJoints::of(cfg)?;
    let linear: Vec<bool> = cell.joints.iter().map(|j| j.linear).collect();
    protocol.set_linear_axes(&linear).map_err(|why| SetupError::Robot { file: cfg.file.display().to_string(), protocol: P::NAME, why })?;
    let unit = d.unit_address().map_err(|source| SetupError::Setting { file: cfg.file.display().to_string(), source })?;
    if unit.is_some() {
        // The external axes on a channel of their own (EGM MultiMove).
        protocol.split_unit_channel(cell.arm).map_err(|why| SetupError::Robot {
            file: cfg.file.display().to_string(),
            protocol: P::NAME,
            why,
        })?;
    }
    if let Some((tag, enable_tag, [volts_per_flow, volts_offset, volts_min, volts_max])) = d.extruder_output() {
        // The extruder's command in the robot's packet (RSI: analog and digital outputs).
        let output = protocol::ExtruderOutput { tag, enable_tag, volts_per_flow, volts_offset, volts_min, volts_max };
        protocol.set_extruder_output(output).map_err(|why| SetupError::Robot {
            file: cfg.file.display().to_string(),
            protocol: P::NAME,
            why,
        })?;
    }
    protocol.set_period(1.0 / cfg.controller.rate_hz);
    let bounds = cell.joints.iter().map(|j| j.limits).collect();
    let guard = ReplyGuard::new(bounds, 1.0 / cfg.controller.rate_hz);
    // Lists of the arm's length leave the external axes one to one (`driver_config` checked them).
    let map = AxisMap::new(cell.dof(), &d.axis_sign, &d.axis_offset);
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
