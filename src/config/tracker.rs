//! `[tracker]`: how `strand-natnet` meets OptiTrack Motive (NatNet 3.x/4.x) — the server's address
//! and ports, unicast or multicast, the rigid body that is the robot's base, and the fixed transforms
//! that turn Motive's pose of that body into the base pose B in the cell's W. The tracker reads it;
//! the config owns the type so that a service config with a `[tracker]` section loads.
//!
//! Why the transforms live here and not in `[base]`: for a tracked base the service takes each
//! `BasePose` as B in W as it is (`[base] mount_xyz/rpy` is only the pose assumed before the first
//! sample), so the tracker must publish B itself, not the marker body.

use std::net::Ipv4Addr;

use serde::{Deserialize, Serialize};
use strand_core::InvalidSetting;

/// Motive's `Up Axis` streaming setting: which of its axes points up.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum UpAxis {
    /// Motive's default: +Y up. Changed to Z-up by +90° about x, (x, y, z) → (x, −z, y), on both the
    /// world and the body's own axes.
    #[default]
    Y,
    /// Motive streams Z-up already: taken as it is.
    Z,
}

/// How Motive sends frames (`Transmission Type` in its streaming settings).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Transmission {
    /// To a multicast group on the data port (Motive's default); any number of clients.
    #[default]
    Multicast,
    /// To each client that connected, at the address it connected from (kept with keep-alives).
    Unicast,
}

/// `[tracker]`: the NatNet client that publishes the base pose.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackerConfig {
    /// Motive's address (IPv4; `--server` overrides it).
    pub server: String,
    /// The local address facing Motive (IPv4): the command socket binds to it and the multicast
    /// group is joined on it. 127.0.0.1 by default: a cell sets its tracking network card.
    pub local_interface: String,
    /// Motive's command port (UDP; Motive's default 1510).
    pub command_port: u16,
    /// Motive's data port (UDP; Motive's default 1511): multicast frames arrive on it.
    pub data_port: u16,
    /// Multicast or unicast; must match Motive's `Transmission Type` (checked at the handshake).
    pub transmission: Transmission,
    /// The multicast group (IPv4; Motive's default 239.255.42.99).
    pub multicast_group: String,
    /// The name of the rigid body that is the base, exactly as in Motive's Assets pane.
    pub rigid_body: String,
    /// Motive's `Up Axis` streaming setting.
    pub up_axis: UpAxis,
    /// Where Motive's world origin (after the up-axis turn) is in W (m).
    pub world_xyz: [f64; 3],
    /// Motive's world orientation in W (after the up-axis turn) as roll, pitch, yaw (rad), fixed
    /// axes x, y, z.
    pub world_rpy: [f64; 3],
    /// The base frame B's origin in the rigid body's frame (its pivot, as Motive defines it) (m).
    pub body_xyz: [f64; 3],
    /// B's orientation in the rigid body's frame as roll, pitch, yaw (rad), fixed axes x, y, z.
    pub body_rpy: [f64; 3],
    /// Longest wait for Motive's answer to the connect and to the model definitions (s).
    pub connect_timeout: f64,
    /// Unicast: how often the client tells Motive it is still there (s).
    pub keepalive_period: f64,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        TrackerConfig {
            server: "127.0.0.1".into(),
            local_interface: "127.0.0.1".into(),
            command_port: 1510,
            data_port: 1511,
            transmission: Transmission::Multicast,
            multicast_group: "239.255.42.99".into(),
            rigid_body: String::new(),
            up_axis: UpAxis::Y,
            world_xyz: [0.0; 3],
            world_rpy: [0.0; 3],
            body_xyz: [0.0; 3],
            body_rpy: [0.0; 3],
            connect_timeout: 3.0,
            keepalive_period: 1.0,
        }
    }
}

impl TrackerConfig {
    /// Checks every key; the message names it and its allowed range.
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        let bad = |m: String| Err(InvalidSetting::new("tracker", m));
        for (key, v) in [("server", &self.server), ("local_interface", &self.local_interface)] {
            if v.parse::<Ipv4Addr>().is_err() {
                return bad(format!("[tracker] {key} = {v:?}: not an IPv4 address"));
            }
        }
        match self.multicast_group.parse::<Ipv4Addr>() {
            Ok(g) if g.is_multicast() => {}
            _ => {
                return bad(format!("[tracker] multicast_group = {:?}: not an IPv4 multicast address (224.0.0.0/4)", self.multicast_group));
            }
        }
        for (key, port) in [("command_port", self.command_port), ("data_port", self.data_port)] {
            if port == 0 {
                return bad(format!("[tracker] {key} = 0: must be Motive's port (1 to 65535)"));
            }
        }
        if self.rigid_body.trim().is_empty() {
            return bad("[tracker] rigid_body is empty: give the name of the base's rigid body in Motive".into());
        }
        for (key, v) in
            [("world_xyz", self.world_xyz), ("world_rpy", self.world_rpy), ("body_xyz", self.body_xyz), ("body_rpy", self.body_rpy)]
        {
            if v.iter().any(|x| !x.is_finite()) {
                return bad(format!("[tracker] {key} = {v:?}: not finite"));
            }
        }
        if !(self.connect_timeout.is_finite() && (0.1..=60.0).contains(&self.connect_timeout)) {
            return bad(format!("[tracker] connect_timeout = {}: must lie in [0.1, 60] s", self.connect_timeout));
        }
        if !(self.keepalive_period.is_finite() && (0.05..=10.0).contains(&self.keepalive_period)) {
            return bad(format!("[tracker] keepalive_period = {}: must lie in [0.05, 10] s", self.keepalive_period));
        }
        Ok(())
    }
}
