//! `[view]`: the live view — a Foxglove WebSocket server fed from the log writer thread — and what
//! the log itself records for a 3D view (`/tf`, the path and the bead, decimated). The service and
//! the log read it; the config owns the type so that config, log and view do not import each other.

use std::collections::BTreeMap;
use std::net::{IpAddr, SocketAddr};

use serde::{Deserialize, Serialize};
use strand_core::InvalidSetting;

/// `[view]`: the live Foxglove server and the scene channels.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct ViewConfig {
    /// Serve the live view (`strand run`; `strand-demo --view` turns it on).
    pub enabled: bool,
    /// Address and port of the WebSocket server (`IP:PORT`). 127.0.0.1 by default: any other
    /// address exposes the controller's state to the network and is warned about at start.
    pub address: String,
    /// Let a connected client send control requests (pause, resume, stop, overrides) on the
    /// `/strand/control` client channel. Off: the view is read-only.
    pub allow_control: bool,
    /// Messages per second sent to a client on each channel unless `rates` names it (Hz, > 0).
    pub default_rate_hz: f64,
    /// Per topic: messages per second sent to a client (Hz; 0: every message). Topics not listed
    /// use `default_rate_hz`. Not for `/robot_description` (sent whole, once per subscription) nor
    /// the trails `/bead` and `/path/executed` (each message holds only what is new: never thinned).
    pub rates: BTreeMap<String, f64>,
    /// `/tf` and `/joints/normalized` in the MCAP log and the live view (Hz, 1 to 1000).
    pub tf_rate_hz: f64,
    /// The path markers (`/path/ahead`, `/path/executed`, `/bead`) in the MCAP log and the live
    /// view (Hz, 0.5 to 100).
    pub marker_rate_hz: f64,
    /// Segments shown ahead of the one executing (`/path/ahead`), 1 to 10000.
    pub path_ahead_segments: usize,
    /// TCP error drawn fully red on the bead (m, > 0); 0 errors are green.
    pub bead_error_scale: f64,
    /// Points of the bead and of the executed path (each) kept for viewers that connect
    /// mid-print, who get the whole of it when they subscribe (about 40 bytes a point; the oldest
    /// go first), 0 to 10,000,000.
    pub history_points: usize,
}

impl Default for ViewConfig {
    fn default() -> Self {
        let rates =
            [("/segments", 0.0), ("/status", 10.0), ("/strand/tick", 2.0), ("/path/ahead", 2.0), ("/path/executed", 0.0), ("/bead", 0.0)]
                .into_iter()
                .map(|(t, r)| (t.to_string(), r))
                .collect();
        ViewConfig {
            enabled: false,
            address: "127.0.0.1:8765".to_string(),
            allow_control: false,
            default_rate_hz: 30.0,
            rates,
            tf_rate_hz: 30.0,
            marker_rate_hz: 4.0,
            path_ahead_segments: 200,
            bead_error_scale: 0.001,
            history_points: 1_000_000,
        }
    }
}

impl ViewConfig {
    /// The server's socket address.
    pub fn socket_addr(&self) -> Result<SocketAddr, InvalidSetting> {
        self.address.parse().map_err(|e| {
            InvalidSetting::new("view", format!("[view] address = {:?}: {e} (expected IP:PORT, e.g. 127.0.0.1:8765)", self.address))
        })
    }

    /// True when the server listens beyond this machine (any address but a loopback one).
    pub fn exposed(&self) -> bool {
        self.socket_addr().is_ok_and(|a| !match a.ip() {
            IpAddr::V4(ip) => ip.is_loopback(),
            IpAddr::V6(ip) => ip.is_loopback(),
        })
    }

    /// The rate for `topic` (Hz; 0: every message).
    pub(crate) fn rate_for(&self, topic: &str) -> f64 {
        self.rates.get(topic).copied().unwrap_or(self.default_rate_hz)
    }

    /// Checks every key; the message names it and its allowed range.
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        self.socket_addr()?;
        let bad = |m: String| Err(InvalidSetting::new("view", m));
        if !(self.default_rate_hz.is_finite() && self.default_rate_hz > 0.0) {
            return bad(format!("[view] default_rate_hz = {}: must be > 0 Hz", self.default_rate_hz));
        }
        for (topic, r) in &self.rates {
            if !(r.is_finite() && *r >= 0.0) {
                return bad(format!("[view] rates.{topic:?} = {r}: must be ≥ 0 Hz (0: every message)"));
            }
        }
        if !(self.tf_rate_hz.is_finite() && (1.0..=1000.0).contains(&self.tf_rate_hz)) {
            return bad(format!("[view] tf_rate_hz = {}: must lie in [1, 1000] Hz", self.tf_rate_hz));
        }
        if !(self.marker_rate_hz.is_finite() && (0.5..=100.0).contains(&self.marker_rate_hz)) {
            return bad(format!("[view] marker_rate_hz = {}: must lie in [0.5, 100] Hz", self.marker_rate_hz));
        }
        if !(1..=10_000).contains(&self.path_ahead_segments) {
            return bad(format!("[view] path_ahead_segments = {}: must lie in [1, 10000]", self.path_ahead_segments));
        }
        if self.history_points > 10_000_000 {
            return bad(format!("[view] history_points = {}: must lie in [0, 10000000]", self.history_points));
        }
        if !(self.bead_error_scale.is_finite() && self.bead_error_scale > 0.0) {
            return bad(format!("[view] bead_error_scale = {}: must be > 0 m", self.bead_error_scale));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// default.toml documents every key with its default value.
    #[test]
    fn default_toml_documents_the_defaults() {
        let table: toml::Table = toml::from_str(include_str!("../../config/default.toml")).unwrap();
        let documented: ViewConfig = table["view"].clone().try_into().unwrap();
        assert_eq!(documented, ViewConfig::default());
    }

    #[test]
    fn loopback_by_default_and_bad_values_named() {
        let v = ViewConfig::default();
        v.validate().unwrap();
        assert!(!v.exposed());
        assert!(ViewConfig { address: "0.0.0.0:8765".into(), ..v.clone() }.exposed());
        let e = ViewConfig { address: "localhost".into(), ..v.clone() }.validate().unwrap_err();
        assert!(e.to_string().contains("[view] address"), "{e}");
        let e = ViewConfig { tf_rate_hz: 0.0, ..v.clone() }.validate().unwrap_err();
        assert!(e.to_string().contains("tf_rate_hz"), "{e}");
        assert_eq!(v.rate_for("/segments"), 0.0);
        assert_eq!(v.rate_for("/tf"), 30.0);
    }
}
