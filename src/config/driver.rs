//! `[driver]`: how a robot driver bridge (`strand-egm`, `strand-rsi`, `strand-fri`, `strand-bcap`,
//! `strand-meca`) meets the robot controller — the UDP address it listens on (the robot sends
//! first) or the controller it connects to (the driver sends first), the sender it accepts, the
//! reply deadline inside the robot's cycle, the mapping between the controller's axis angles and
//! the URDF joints, and each interface's own settings. The drivers
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
    /// DENSO b-CAP slave mode, RC7/RC8 (binary request/reply over TCP): `strand-bcap`.
    Bcap,
    /// Mecademic Meca500 TCP API (text commands, monitoring stream): `strand-meca`.
    Meca,
    /// Universal Robots RTDE and a URScript servo program over the reverse interface: `strand-ur`.
    Ur,
}

impl DriverProtocol {
    /// The port the protocol's examples use (EGM 6510, RSI 49152, FRI 30200; the controller's
    /// b-CAP 5007, Meca500 control 10000, UR RTDE 30004).
    pub(crate) fn default_port(self) -> u16 {
        match self {
            DriverProtocol::Egm => 6510,
            DriverProtocol::Rsi => 49152,
            DriverProtocol::Fri => 30200,
            DriverProtocol::Bcap => 5007,
            DriverProtocol::Meca => 10000,
            DriverProtocol::Ur => 30004,
        }
    }

    /// Its name in a config (`egm`, `rsi`, `fri`) and in the driver's name (`strand-fri`).
    pub fn name(self) -> &'static str {
        match self {
            DriverProtocol::Egm => "egm",
            DriverProtocol::Rsi => "rsi",
            DriverProtocol::Fri => "fri",
            DriverProtocol::Bcap => "bcap",
            DriverProtocol::Meca => "meca",
            DriverProtocol::Ur => "ur",
        }
    }

    /// Whether the driver connects to the robot controller (b-CAP, the Meca500, UR: `[driver] robot`
    /// is the controller's address) rather than listening for its packets (EGM, RSI, FRI: `bind`).
    pub fn driver_connects(self) -> bool {
        matches!(self, DriverProtocol::Bcap | DriverProtocol::Meca | DriverProtocol::Ur)
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
    /// The robot sends first (EGM, RSI, FRI): the only sender accepted (`IP` or `IP:PORT`); empty:
    /// the first sender, and no other after it. The driver connects (b-CAP, Meca500): the
    /// controller's address (`IP` with the protocol's port, or `IP:PORT`); empty: 127.0.0.1.
    pub robot: String,
    /// EGM: where the driver listens (`IP:PORT`) for the channel of the cell's external axes when
    /// the controller runs them as a mechanical unit of their own (MultiMove: a positioner in its
    /// own motion task, with its own EGM instance and UDP device); the robot's channel then
    /// carries its six axes only. Empty (the default): the external axes come in the robot's own
    /// channel, as `externalJoints`.
    pub external_axes_bind: String,
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
    /// b-CAP: the slave mode for `slvChangeMode` — 0x202 (joints, mode 2: the controller paces
    /// each `slvMove` to its cycle, buffer of 3; DENSO's default) or 0x102 (joints, mode 1: the
    /// driver paces, the newest command wins).
    pub slave_mode: u32,
    /// Longest wait for one setup or release call, and for the controller's answer to a cycle's
    /// command beyond its cycle (s). Setup calls that take seconds (motor on) are kept alive by
    /// the controller's watchdog packets.
    pub call_timeout: f64,
    /// Meca500: the monitoring port on the controller's address (10001).
    pub monitor_port: u16,
    /// Meca500: the gain on the position error in each velocity command (1/s): velocity =
    /// the command's feed-forward velocity + gain × (commanded − measured position).
    pub velocity_gain: f64,
    /// Meca500: `SetVelTimeout` (s): the arm stops by itself this long after the last velocity
    /// command (strand stopped, the link lost).
    pub velocity_timeout: f64,
    /// UR: the controller's script port the program is sent to (30002 secondary, 30001 primary).
    pub script_port: u16,
    /// UR: the port the driver listens on for the program to connect back (50001; 0: any free).
    pub reverse_port: u16,
    /// UR: the address the program connects back to and the driver listens on; empty: the local
    /// address of the RTDE connection (the card facing the robot).
    pub reverse_host: String,
    /// UR: `servoj`'s lookahead time (s, 0.03 to 0.2): longer smooths more and lags more.
    pub lookahead_time: f64,
    /// UR: `servoj`'s gain (100 to 2000, proportional; higher follows tighter).
    pub servo_gain: f64,
    /// UR: the standard analog output (0 or 1) the extruder's speed goes to; -1: none.
    pub analog_output: i32,
    /// UR: the analog output's ratio (0..1 of its range, voltage domain) = `analog_offset` +
    /// `analog_scale` × the filament's speed into the hot end (`ExtruderCommand::filament_rate`,
    /// m/s; so s/m), clamped: a retraction clamps to the offset.
    pub analog_scale: f64,
    /// UR: see `analog_scale` (a ratio, 0..1).
    pub analog_offset: f64,
    /// RSI: the RECEIVE tag (`Element.Attribute` or `Element`) of the ETHERNET object that carries
    /// the extruder's speed as an analog value in volts, in the same packet as `AK` (the RSI
    /// context maps it to `$ANOUT[n]`); empty (the default): none.
    pub extruder_tag: String,
    /// RSI: the RECEIVE tag of the extruder's enable (1 while extruding, else 0; mapped to
    /// `$OUT[n]`); empty: none.
    pub extruder_enable_tag: String,
    /// RSI: volts per mm³/s of volumetric flow (`ExtruderCommand::volumetric_rate`) on
    /// `extruder_tag` (V·s/mm³).
    pub extruder_volts_per_flow: f64,
    /// RSI: volts at no flow (V); a held robot and a retraction send it (clamped).
    pub extruder_volts_offset: f64,
    /// RSI: the lowest volts sent on `extruder_tag` (V).
    pub extruder_volts_min: f64,
    /// RSI: the highest volts sent on `extruder_tag` (V).
    pub extruder_volts_max: f64,
    /// UR: the read timeout every message announces to the program (s, 0.002 to 0.2): a driver
    /// silent longer (stopped, hung, the link lost) makes it stop the arm (`stopj`) and end.
    pub read_timeout: f64,
}

impl Default for DriverConfig {
    fn default() -> Self {
        DriverConfig {
            protocol: DriverProtocol::Egm,
            bind: String::new(),
            robot: String::new(),
            external_axes_bind: String::new(),
            reply_deadline: 0.002,
            max_late_cycles: 3,
            recover_cycles: 25,
            axis_sign: Vec::new(),
            axis_offset: Vec::new(),
            slave_mode: 0x202,
            call_timeout: 5.0,
            monitor_port: 10001,
            velocity_gain: 20.0,
            velocity_timeout: 0.05,
            script_port: 30002,
            reverse_port: 50001,
            reverse_host: String::new(),
            lookahead_time: 0.03,
            servo_gain: 2000.0,
            analog_output: -1,
            analog_scale: 0.0,
            analog_offset: 0.0,
            extruder_tag: String::new(),
            extruder_enable_tag: String::new(),
            extruder_volts_per_flow: 0.0,
            extruder_volts_offset: 0.0,
            extruder_volts_min: 0.0,
            extruder_volts_max: 10.0,
            read_timeout: 0.02,
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

    /// The external axes' own channel (`external_axes_bind`), if they have one.
    pub fn unit_address(&self) -> Result<Option<SocketAddr>, InvalidSetting> {
        if self.external_axes_bind.is_empty() {
            return Ok(None);
        }
        let addr = self.external_axes_bind.parse::<SocketAddr>().map_err(|_| {
            InvalidSetting::new("driver", format!("[driver] external_axes_bind = {:?}: not an IP:PORT address", self.external_axes_bind))
        })?;
        let robot = self.bind_address()?;
        if addr == robot && addr.port() != 0 {
            return Err(InvalidSetting::new(
                "driver",
                format!(
                    "[driver] external_axes_bind = {:?} is the robot's channel (bind): the unit needs a port of its own",
                    self.external_axes_bind
                ),
            ));
        }
        Ok(Some(addr))
    }

    /// The controller to connect to (the driver sends first): `robot`, with the protocol's port if
    /// it names none, or 127.0.0.1 with the protocol's port.
    pub fn robot_address(&self) -> Result<SocketAddr, InvalidSetting> {
        let port = self.protocol.default_port();
        if self.robot.is_empty() {
            return Ok(SocketAddr::from(([127, 0, 0, 1], port)));
        }
        self.robot
            .parse::<SocketAddr>()
            .or_else(|_| self.robot.parse::<IpAddr>().map(|ip| SocketAddr::new(ip, port)))
            .map_err(|_| InvalidSetting::new("driver", format!("[driver] robot = {:?}: not an IP or IP:PORT address", self.robot)))
    }

    /// Checks every key; `dof` is the robot's joint count (for the per-joint lists).
    pub fn validate(&self, dof: usize) -> Result<(), InvalidSetting> {
        let bad = |m: String| Err(InvalidSetting::new("driver", m));
        self.bind_address()?;
        if self.unit_address()?.is_some() && self.protocol != DriverProtocol::Egm {
            return bad(format!(
                "[driver] external_axes_bind = {:?}: a channel of their own for the external axes is EGM's (MultiMove); {} carries them with the robot's",
                self.external_axes_bind,
                self.protocol.name()
            ));
        }
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
        if ![0x202, 0x102].contains(&self.slave_mode) {
            return bad(format!(
                "[driver] slave_mode = {:#x}: strand drives joints in mode 2 (0x202, the controller paces) or mode 1 (0x102, the driver paces)",
                self.slave_mode
            ));
        }
        if !(self.call_timeout.is_finite() && (0.1..=600.0).contains(&self.call_timeout)) {
            return bad(format!("[driver] call_timeout = {}: must lie in [0.1, 600] s", self.call_timeout));
        }
        if !(self.velocity_gain.is_finite() && (0.0..=500.0).contains(&self.velocity_gain)) {
            return bad(format!("[driver] velocity_gain = {}: must lie in [0, 500] 1/s", self.velocity_gain));
        }
        if !(self.velocity_timeout.is_finite() && (0.001..=1.0).contains(&self.velocity_timeout)) {
            return bad(format!("[driver] velocity_timeout = {}: must lie in [0.001, 1] s (SetVelTimeout's range)", self.velocity_timeout));
        }
        if self.monitor_port == 0 {
            return bad("[driver] monitor_port = 0: not a port".to_string());
        }
        if self.script_port == 0 {
            return bad("[driver] script_port = 0: not a port".to_string());
        }
        if !self.reverse_host.is_empty() && self.reverse_host.parse::<IpAddr>().is_err() {
            return bad(format!("[driver] reverse_host = {:?}: not an IP address", self.reverse_host));
        }
        if !(self.read_timeout.is_finite() && (0.002..=0.2).contains(&self.read_timeout)) {
            return bad(format!("[driver] read_timeout = {}: the program takes 0.002 to 0.2 s", self.read_timeout));
        }
        if !(self.lookahead_time.is_finite() && (0.03..=0.2).contains(&self.lookahead_time)) {
            return bad(format!("[driver] lookahead_time = {}: servoj takes 0.03 to 0.2 s", self.lookahead_time));
        }
        if !(self.servo_gain.is_finite() && (100.0..=2000.0).contains(&self.servo_gain)) {
            return bad(format!("[driver] servo_gain = {}: servoj takes 100 to 2000", self.servo_gain));
        }
        if !(-1..=1).contains(&self.analog_output) {
            return bad(format!("[driver] analog_output = {}: 0 or 1 (a standard analog output), or -1 for none", self.analog_output));
        }
        if !(self.analog_scale.is_finite() && self.analog_offset.is_finite() && (0.0..=1.0).contains(&self.analog_offset)) {
            return bad(format!(
                "[driver] analog_scale = {}, analog_offset = {}: finite, the offset a ratio in [0, 1]",
                self.analog_scale, self.analog_offset
            ));
        }
        if (!self.extruder_tag.is_empty() || !self.extruder_enable_tag.is_empty()) && self.protocol != DriverProtocol::Rsi {
            return bad(format!(
                "[driver] extruder_tag / extruder_enable_tag: RSI's outputs; {} carries the extruder otherwise (UR: analog_output)",
                self.protocol.name()
            ));
        }
        if self.extruder_tag.is_empty() && !self.extruder_enable_tag.is_empty() {
            return bad("[driver] extruder_enable_tag without extruder_tag: the enable goes with the analog value".to_string());
        }
        let volts = [self.extruder_volts_per_flow, self.extruder_volts_offset, self.extruder_volts_min, self.extruder_volts_max];
        if volts.iter().any(|v| !v.is_finite())
            || self.extruder_volts_per_flow < 0.0
            || self.extruder_volts_min >= self.extruder_volts_max
            || !(-10.0..=10.0).contains(&self.extruder_volts_min)
            || !(-10.0..=10.0).contains(&self.extruder_volts_max)
        {
            return bad(format!(
                "[driver] extruder_volts_per_flow = {}, extruder_volts_offset = {}, extruder_volts_min = {}, extruder_volts_max = {}: finite, the gain ≥ 0 V·s/mm³, min < max within ±10 V (KUKA's analog outputs)",
                self.extruder_volts_per_flow, self.extruder_volts_offset, self.extruder_volts_min, self.extruder_volts_max
            ));
        }
        self.robot_address()?;
        Ok(())
    }

    /// The extruder's outputs in the robot's packet (`extruder_tag`, RSI), if any.
    pub fn extruder_output(&self) -> Option<(String, String, [f64; 4])> {
        (!self.extruder_tag.is_empty()).then(|| {
            (
                self.extruder_tag.clone(),
                self.extruder_enable_tag.clone(),
                [self.extruder_volts_per_flow, self.extruder_volts_offset, self.extruder_volts_min, self.extruder_volts_max],
            )
        })
    }
}
