//! strand-egm: the bridge between an ABB robot controller's EGM (Externally Guided Motion, joint
//! mode) and the strand service. The robot's `EgmRobot` packets clock the service (robot clock, the
//! EGM cycle as `rate_hz`); each is answered with an `EgmSensor` carrying the service's command for
//! it, inside `[driver] reply_deadline`, or a hold. See the README, "Connecting a robot".

#[path = "common/mod.rs"]
mod driver_main;

fn main() -> std::process::ExitCode {
    driver_main::main_for(strand::config::driver::DriverProtocol::Egm, strand_driver::egm::Egm::new)
}
