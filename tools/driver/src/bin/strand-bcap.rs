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

use strand::config::Config;
use strand::config::driver::{DriverConfig, DriverProtocol};
use strand_driver::bcap::Bcap;
use strand_driver::bcap::link::BcapLink;
use strand_driver::session::Session;

fn open(cfg: &Config, d: &DriverConfig, session: &mut Session<Bcap>) -> Result<(BcapLink, Vec<u8>), String> {
    let addr = d.robot_address().map_err(|e| e.to_string())?;
    let mut link = BcapLink::connect(addr, d.call_timeout).map_err(|e| e.to_string())?;
    let q0 = match link.start(d.slave_mode, 1.0 / cfg.controller.rate_hz) {
        Ok(q) => q,
        Err(e) => {
            for problem in link.release() {
                eprintln!("strand-bcap: giving the robot back: {problem}");
            }
            return Err(format!("setting the robot up: {e}"));
        }
    };
    eprintln!("strand-bcap: slave mode {:#x}, the arm at {:?} deg", d.slave_mode, &q0[..session.dof()]);
    let dof = session.dof();
    let bcap = session.protocol_mut();
    bcap.set_robot(link.robot().unwrap_or(0), dof);
    // The first command holds the arm where it is, to the bit; its reply starts the session.
    let mut first = Vec::with_capacity(256);
    bcap.encode_wire(&q0, &mut first);
    Ok((link, first))
}

fn main() -> std::process::ExitCode {
    driver_main::main_connecting(DriverProtocol::Bcap, Bcap::new, open)
}
