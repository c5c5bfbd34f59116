//! strand-ur: the bridge between a Universal Robots arm (e-Series or CB3) and the strand service.
//! The driver connects to the controller's RTDE port (`--robot IP:PORT`, `[driver] robot`, 30004),
//! sets up its output recipe at `[controller] rate_hz` (500 Hz) and the extruder's analog output,
//! listens on `[driver] reverse_port`, and sends strand's URScript program to the script port
//! (`[driver] script_port`, 30002): the program connects back and servos the arm with `servoj` to
//! each message. Each RTDE data package clocks the service; the answer is the service's command
//! for it, or a hold. The robot's speed slider slows the service's path. On Ctrl-C it holds the arm
//! to rest and ends the program. See the README, "Connecting a robot".

#[path = "common/mod.rs"]
mod driver_main;

use strand::config::Config;
use strand::config::driver::{DriverConfig, DriverProtocol};
use strand_driver::session::Session;
use strand_driver::ur::Ur;
use strand_driver::ur::link::{UrLink, UrSettings};

fn open(cfg: &Config, d: &DriverConfig, session: &mut Session<Ur>) -> Result<(UrLink, Vec<u8>), String> {
    let settings = UrSettings {
        rtde: d.robot_address().map_err(|e| e.to_string())?,
        script_port: d.script_port,
        reverse_port: d.reverse_port,
        reverse_host: d.reverse_host.clone(),
        lookahead_time: d.lookahead_time,
        servo_gain: d.servo_gain,
        frequency: cfg.controller.rate_hz,
        analog_output: u8::try_from(d.analog_output).ok(),
        analog_scale: d.analog_scale,
        analog_offset: d.analog_offset,
        timeout: d.call_timeout,
    };
    let (link, started) = UrLink::start(settings).map_err(|e| format!("setting the robot up: {e}"))?;
    let v = started.version;
    eprintln!(
        "strand-ur: URControl {}.{}.{}.{}; RTDE at {} Hz; the program connected back to {}",
        v[0], v[1], v[2], v[3], cfg.controller.rate_hz, started.reverse
    );
    session.protocol_mut().set_recipe(started.recipe);
    session.protocol_mut().set_read_timeout(d.read_timeout);
    Ok((link, Vec::new()))
}

fn main() -> std::process::ExitCode {
    driver_main::main_connecting(DriverProtocol::Ur, Ur::new, open)
}
