//! strand-rsi: the bridge between a KUKA robot controller's RSI (Robot Sensor Interface, an
//! ETHERNET object and `RSI_MOVECORR`) and the strand service. The robot's `<Rob>` packets clock the
//! service (robot clock, the RSI cycle as `rate_hz`); each is answered with a `<Sen>` carrying the
//! service's command as an axis correction from the start, inside `[driver] reply_deadline`, or a
//! hold. See the README, "Connecting a robot".

#[path = "common/mod.rs"]
mod driver_main;

fn main() -> std::process::ExitCode {
    driver_main::main_for(strand::config::driver::DriverProtocol::Rsi, strand_driver::rsi::Rsi::new)
}
