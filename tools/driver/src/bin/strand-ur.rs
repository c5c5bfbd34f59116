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

use strand::config::driver::DriverProtocol;
use strand_driver::ur::Ur;
use strand_driver::ur::link::UrLink;

fn main() -> std::process::ExitCode {
    driver_main::main_connecting::<_, UrLink>(DriverProtocol::Ur, Ur::new)
}
