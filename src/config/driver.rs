//! `[driver]`: how a robot driver bridge (`strand-egm`, `strand-rsi`, `strand-fri`) meets the robot controller —
//! the UDP address it listens on, the sender it accepts, the reply deadline inside the robot's
//! cycle, and the mapping between the controller's axis angles and the URDF joints. The drivers
//! read it; the config owns the type so that a service config with a `[driver]` section loads.

use std::net::{IpAddr, SocketAddr};

use serde::{Deserialize, Serialize};
use strand_core::InvalidSetting;

/// The robot controller's interface.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum DriverProtocol {
    /// ABB Externally Guided Motion (protobuf over UDP): `strand-egm`.
    #[default]
    Egm,
    /// KUKA Robot Sensor Interface (XML over UDP): `strand-rsi`.
    Rsi,
    /// KUKA Sunrise Fast Robot Interface, LBR iiwa (protobuf over UDP): `strand-fri`.
    Fri,
}

impl DriverProtocol {
    /// The port the protocol's examples use (EGM 6510, RSI 49152, FRI 30200).
    pub fn default_port(self) -> u16 {
        match self {
            DriverProtocol::Egm => 6510,
            DriverProtocol::Rsi => 49152,
            DriverProtocol::Fri => 30200,
        }
    }

    /// Its name in a config (`egm`, `rsi`, `fri`) and in the driver's name (`strand-fri`).
    pub fn name(self) -> &'static str {
        match self {
            DriverProtocol::Egm => "egm",
            DriverProtocol::Rsi => "rsi",
            DriverProtocol::Fri => "fri",
        }
    }
}

/// `[driver]`: the bridge between the robot controller and the service.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct DriverConfig {
    /// The robot controller's interface.
    pub protocol: DriverProtocol,
    /// Address and port the driver listens on (`IP:PORT`). 127.0.0.1 by default: a cell sets the
    /// address of the network card that faces the robot controller.
    pub bind: String,
    /// The only sender accepted (`IP` or `IP:PORT`); empty: the first sender, and no other after it.
    pub robot: String,
    /// Longest wait for the service's command after a robot packet arrives (s); then the driver
    /// answers with a hold (the last target, braked within the acceleration limits). At most
    /// 0.75 of the robot's cycle (the driver checks it against `[controller] rate_hz`).
    pub reply_deadline: f64,
    /// Replies in a row without the service's command before the driver holds for good and raises
    /// a fault the service sees (an emergency stop from the driver).
    pub max_late_cycles: u32,
    /// Cycles in a row answered in time by the service before a held driver follows it again.
    pub recover_cycles: u32,
    /// Per joint in chain order: +1 or −1, the direction of the controller's axis against the URDF
    /// joint's (1: robot axis angle = +joint angle + offset).
    pub axis_sign: Vec<f64>,
    /// Per joint in chain order: the controller's axis angle when the URDF joint is at 0 (rad or m).
    pub axis_offset: Vec<f64>,
}

impl Default for DriverConfig {
    fn default() -> Self {
        DriverConfig {
            protocol: DriverProtocol::Egm,
            bind: String::new(),
            robot: String::new(),
            reply_deadline: 0.002,
            max_late_cycles: 3,
            recover_cycles: 25,
            axis_sign: Vec::new(),
            axis_offset: Vec::new(),
        }
    }
}

impl DriverConfig {
    /// The address to bind: `bind`, or 127.0.0.1 with the protocol's port.
    pub fn bind_address(&self) -> Result<SocketAddr, InvalidSetting> {
        if self.bind.is_empty() {
            return Ok(SocketAddr::from(([127, 0, 0, 1], self.protocol.default_port())));
        }
        self.bind.parse().map_err(|_| InvalidSetting::new("driver", format!("[driver] bind = {:?}: not an IP:PORT address", self.bind)))
    }

    /// Checks every key; `dof` is the robot's joint count (for the per-joint lists).
    pub fn validate(&self, dof: usize) -> Result<(), InvalidSetting> {
        let bad = |m: String| Err(InvalidSetting::new("driver", m));
        self.bind_address()?;
        // The sender to accept: an address, or an IP with any port (the driver parses it again).
        if !self.robot.is_empty() && self.robot.parse::<SocketAddr>().is_err() && self.robot.parse::<IpAddr>().is_err() {
            return bad(format!("[driver] robot = {:?}: not an IP or IP:PORT address", self.robot));
        }
        if !(self.reply_deadline.is_finite() && (0.0001..=0.1).contains(&self.reply_deadline)) {
            return bad(format!("[driver] reply_deadline = {}: must lie in [0.0001, 0.1] s", self.reply_deadline));
        }
        if !(1..=1000).contains(&self.max_late_cycles) {
            return bad(format!("[driver] max_late_cycles = {}: must lie in [1, 1000]", self.max_late_cycles));
        }
        if !(1..=100_000).contains(&self.recover_cycles) {
            return bad(format!("[driver] recover_cycles = {}: must lie in [1, 100000]", self.recover_cycles));
        }
        for (key, list) in [("axis_sign", &self.axis_sign), ("axis_offset", &self.axis_offset)] {
            if !list.is_empty() && list.len() != dof {
                return bad(format!("[driver] {key} has {} values; the robot has {dof} joints", list.len()));
            }
        }
        if let Some(s) = self.axis_sign.iter().find(|s| **s != 1.0 && **s != -1.0) {
            return bad(format!("[driver] axis_sign: {s} is neither 1 nor -1"));
        }
        if let Some(o) = self.axis_offset.iter().find(|o| !o.is_finite()) {
            return bad(format!("[driver] axis_offset: {o} is not finite"));
        }
        Ok(())
    }
}
