//! strand-meca: the bridge between a Mecademic Meca500 (its TCP API: the arm of paper 000) and the
//! strand service. The driver connects to the robot's control port (`--robot IP:PORT`, `[driver]
//! robot`, 10000) and its monitoring port (`[driver] monitor_port`, 10001), resets an error,
//! activates, homes and resumes the robot as needed, and then on its own clock (`[controller]
//! rate_hz`) publishes the newest joints as the JointState that clocks the service and answers
//! with `MoveJointsVel` towards the service's command. The robot stops by itself `[driver]
//! velocity_timeout` after the last command. See the README, "Connecting a robot".

#[path = "common/mod.rs"]
mod driver_main;

use strand::config::driver::DriverProtocol;
use strand_driver::meca::Meca;
use strand_driver::meca::link::MecaLink;

fn make() -> Meca {
    // The cycle and gain are set from the config before the first tick (session, open).
    Meca::new(0.004, 0.0)
}

fn main() -> std::process::ExitCode {
    driver_main::main_connecting::<_, MecaLink>(DriverProtocol::Meca, make)
}
