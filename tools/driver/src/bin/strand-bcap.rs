//! strand-bcap: the bridge between a DENSO RC7/RC8 controller's b-CAP slave mode (the VP6242 of
//! paper 004) and the strand service. The driver connects to the controller (`--robot IP:PORT`,
//! `[driver] robot`, TCP 5007), takes the arm, turns the motor on and enters joint slave mode;
//! each cycle's `slvMove` reply — the arm's position — clocks the service (`[controller] rate_hz`
//! = 125 for the 8 ms cycle), and the next `slvMove` carries the service's command for it, or a
//! hold. On Ctrl-C, on an error the controller reports, or when the controller goes silent, it
//! gives the arm back: slave mode off, motor off, GiveArm, release, disconnect. See the README,
//! "Connecting a robot".

#[path = "common/mod.rs"]
mod driver_main;

use strand::config::driver::DriverProtocol;
use strand_driver::bcap::Bcap;
use strand_driver::bcap::link::BcapLink;

fn main() -> std::process::ExitCode {
    driver_main::main_connecting::<_, BcapLink>(DriverProtocol::Bcap, Bcap::new)
}
