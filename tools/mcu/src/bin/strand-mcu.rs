//! `strand-mcu --serial PATH [--baud N] --identify`: connect to a Klipper board and print what it
//! is (MCU, firmware version, clock frequency), to check the wiring of a cell.

use std::path::PathBuf;
use std::process::ExitCode;

use strand_mcu::mcu::{ConnectOptions, Mcu};

fn main() -> ExitCode {
    let mut serial = None;
    let mut baud = 250_000u32;
    let mut identify = false;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--serial" => serial = args.next().map(PathBuf::from),
            "--baud" => baud = args.next().and_then(|b| b.parse().ok()).unwrap_or(baud),
            "--identify" => identify = true,
            _ => {
                eprintln!("usage: strand-mcu --serial PATH [--baud N] --identify");
                return ExitCode::from(2);
            }
        }
    }
    let (Some(serial), true) = (serial, identify) else {
        eprintln!("usage: strand-mcu --serial PATH [--baud N] --identify");
        return ExitCode::from(2);
    };
    match Mcu::connect(&serial, baud, ConnectOptions::default()) {
        Ok(m) => {
            let c = |k: &str| m.dict.constant_str(k).unwrap_or_else(|_| "?".into());
            println!("mcu: {}", c("MCU"));
            println!("version: {}", m.dict.version);
            println!("build: {}", m.dict.build_versions);
            println!("clock_freq: {} Hz", c("CLOCK_FREQ"));
            if let Some(cs) = &m.clock {
                println!("measured clock: {:.0} Hz", cs.freq());
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("strand-mcu: {e}");
            ExitCode::FAILURE
        }
    }
}
