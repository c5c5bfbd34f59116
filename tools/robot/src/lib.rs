//! What every robot driver shares, whatever its wire format and transport: the decisions of a
//! driver, without its I/O. It depends on the wire types (`strand-wire`) only, so a driver's
//! logic is unit-tested here and each driver binary keeps only its transport's loop.
//!
//! - [`protocol`] — the one small trait a robot interface implements (read the robot's state,
//!   write a command; its channel and who clocks the cycle); the interfaces themselves live with
//!   their drivers.
//! - [`channel`] — a datagram, or a stream cut into packets by the protocol's framing.
//! - [`session`] — one connection as a state machine without I/O: senders, order, holds, faults.
//! - [`guard`] — the limits every answer keeps, and the catch-up after a missed or held cycle.
//! - [`axes`] — the controller's axes ↔ the URDF's joints.
//! - [`RobotAddress`] — which sender a driver accepts.

pub mod axes;
pub mod channel;
pub mod guard;
pub mod protocol;
pub mod session;

use std::net::{IpAddr, SocketAddr};

/// Which sender a driver accepts (`[driver] robot`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RobotAddress {
    /// This address and port only.
    Exact(SocketAddr),
    /// This address, any port.
    Ip(IpAddr),
}

impl RobotAddress {
    /// Whether `from` is this sender.
    pub fn matches(&self, from: SocketAddr) -> bool {
        match self {
            RobotAddress::Exact(a) => *a == from,
            RobotAddress::Ip(ip) => *ip == from.ip(),
        }
    }
}

/// `[driver] robot` that is neither an IP nor an IP:PORT address.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("[driver] robot = {0:?}: not an IP or IP:PORT address")]
pub struct BadRobotAddress(pub String);

impl std::str::FromStr for RobotAddress {
    type Err = BadRobotAddress;

    /// `IP:PORT` (that sender only) or `IP` (any port).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if let Ok(a) = s.parse::<SocketAddr>() {
            return Ok(RobotAddress::Exact(a));
        }
        s.parse::<IpAddr>().map(RobotAddress::Ip).map_err(|_| BadRobotAddress(s.to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_robot_address_is_an_ip_with_or_without_its_port() {
        let exact: RobotAddress = "192.168.1.5:6510".parse().unwrap();
        let ip: RobotAddress = "192.168.1.5".parse().unwrap();
        assert!(exact.matches("192.168.1.5:6510".parse().unwrap()) && !exact.matches("192.168.1.5:6511".parse().unwrap()));
        assert!(ip.matches("192.168.1.5:6511".parse().unwrap()) && !ip.matches("192.168.1.6:6511".parse().unwrap()));
        assert_eq!("robot".parse::<RobotAddress>(), Err(BadRobotAddress("robot".into())));
    }
}
