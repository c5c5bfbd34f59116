//! strand-fri: the bridge between a KUKA LBR iiwa's FRI (Fast Robot Interface, a Sunrise
//! application with a joint-position overlay: `config/drivers/fri/`) and the strand service. The
//! robot's monitoring messages clock the service (robot clock, the FRI send period as `rate_hz`);
//! in `COMMANDING_ACTIVE` each is answered with the service's command for it, inside `[driver]
//! reply_deadline`, or a hold. See the README, "Connecting a robot".

#[path = "common/mod.rs"]
mod driver_main;

fn main() -> std::process::ExitCode {
    driver_main::main_for(strand::config::driver::DriverProtocol::Fri, strand_driver::fri::Fri::new)
}
