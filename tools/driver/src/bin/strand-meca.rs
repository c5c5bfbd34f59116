//! strand-meca: the bridge between a Mecademic Meca500 (its TCP API: the arm of paper 000) and the
//! strand service. The driver connects to the robot's control port (`--robot IP:PORT`, `[driver]
//! robot`, 10000) and its monitoring port (`[driver] monitor_port`, 10001), resets an error,
//! activates, homes and resumes the robot as needed, and then on its own clock (`[controller]
//! rate_hz`) publishes the newest joints as the JointState that clocks the service and answers
//! with `MoveJointsVel` towards the service's command. The robot stops by itself `[driver]
//! velocity_timeout` after the last command. See the README, "Connecting a robot".

#[path = "common/mod.rs"]
mod driver_main;

use strand::config::Config;
use strand::config::driver::{DriverConfig, DriverProtocol};
use strand_driver::meca::Meca;
use strand_driver::meca::link::MecaLink;
use strand_driver::session::Session;

fn open(cfg: &Config, d: &DriverConfig, session: &mut Session<Meca>) -> Result<(MecaLink, Vec<u8>), String> {
    let addr = d.robot_address().map_err(|e| e.to_string())?;
    let mut link = MecaLink::connect(addr, d.monitor_port, d.call_timeout).map_err(|e| e.to_string())?;
    let started = link.start(1.0 / cfg.controller.rate_hz, d.velocity_timeout).map_err(|e| format!("setting the robot up: {e}"))?;
    eprintln!("strand-meca: {}; {}", started.banner, if started.steps.is_empty() { "ready".to_string() } else { started.steps.join(", ") });
    let model = cfg.robot.build_model().map_err(|e| e.to_string())?;
    let speed: Vec<f64> = model.joints().iter().map(|j| j.limits.velocity).collect();
    let meca = session.protocol_mut();
    meca.set_speed_limits(&speed);
    meca.set_gain(d.velocity_gain);
    Ok((link, Vec::new()))
}

fn make() -> Meca {
    // The cycle and gain are set from the config before the first tick (session, open).
    Meca::new(0.004, 0.0)
}

fn main() -> std::process::ExitCode {
    driver_main::main_connecting(DriverProtocol::Meca, make, open)
}
