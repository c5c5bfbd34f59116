//! strand-mcu as a process: the service's extruder and heater commands in, the board's steps and
//! heater duty out, the hot end's temperature back as `HeaterState` — what the simulator's thermal
//! model does for a cell without hardware, done by a stock-Klipper board.
//!
//! - **Steps.** Every `ExtruderCommand` carries the filament position the service commands at its
//!   tick (m, integrated by the service, so a lost sample costs resolution, never position). The
//!   position is a sample of the motor's trajectory at the tick's time plus `step_lead_time`, in
//!   `CLOCK_MONOTONIC` (the service's clock) mapped onto the MCU's clock ([`crate::clock`]):
//!   the steps run that lead after their command, whatever the host's scheduling does meanwhile.
//!   The service's `[extruder] motion_delay` then aligns the bead with the arm: the nozzle's motor
//!   follows the controller by `motion_delay + step_lead_time`, which a cell sets to the arm's
//!   command-to-motion delay.
//! - **The hot end.** The latest `HeaterCommand`'s hot-end target drives the board's PID
//!   ([`crate::board`]); every temperature report is published at once, stamped with the time the
//!   MCU sampled it. A target above `max_temp` is held at `max_temp` (said once).
//! - **Faults.** Klipper's `verify_heater` failing, a thermistor out of range, or the MCU shutting
//!   down (a step scheduled in the past, "Timer too close") switches the heater off and is published
//!   as [`heater_flags::FAULT`] until the process stops: the service faults `HeaterFault` and stops
//!   the job. The board keeps its heater off by itself too if this process dies (`max_duration`).
//!
//! The bed is not this board's: a cell's bed heater is its own (or another owner's).

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use strand::io::clock::monotonic_ns;
use strand_ipc::ports::{ClientPorts, ClientRoles, PortError};
use strand_ipc::{self as ipc, ServiceNames, heater_flags};

use crate::board::ExtruderBoard;
use crate::config::BoardConfig;
use crate::mcu::{ConnectOptions, McuError};

/// How often a fault is re-published while it stands (s).
const FAULT_REPEAT: f64 = 0.1;

/// What [`run`] needs beside the board's config.
pub struct RunOptions<'a> {
    /// The service prefix.
    pub prefix: String,
    /// Set to stop (a signal handler).
    pub stop: &'a AtomicBool,
    /// Connecting to the board.
    pub connect: ConnectOptions,
}

/// What a run did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct Report {
    /// Extruder commands taken.
    pub commands: u64,
    /// Extruder commands dropped: stamped at or before one already taken.
    pub out_of_order: u64,
    /// Steps sent to the board.
    pub steps: u64,
    /// Temperatures published.
    pub readings: u64,
    /// The fault that switched the heater off, if one did.
    pub fault: Option<String>,
}

/// Why the process could not run.
#[derive(Debug, thiserror::Error)]
pub enum ProcessError {
    /// The board: not there, not Klipper, a pin it lacks, a configuration it refuses.
    #[error("board: {0}")]
    Board(#[from] McuError),
    /// The service's ports.
    #[error("service ports: {0}")]
    Port(#[from] PortError),
}

/// Connects to the board of `cfg`, then serves the service under `opts.prefix` until
/// `opts.stop` is set. `say` gets one line per notable event (the start, a fault).
pub fn run(cfg: &BoardConfig, opts: &RunOptions, say: &mut dyn FnMut(&str)) -> Result<Report, ProcessError> {
    let mut board = ExtruderBoard::connect(cfg.clone(), opts.connect)?;
    // The board counts host time from its connection; the service stamps CLOCK_MONOTONIC.
    let offset = monotonic_ns() as f64 * 1e-9 - board.mcu.now();
    let ports = ClientPorts::open(
        &ServiceNames::new(&opts.prefix),
        &format!("strand-mcu-{}", std::process::id()),
        ClientRoles { monitor: true, heater: true, ..Default::default() },
    )?;
    say(&format!(
        "board {} on {}: steps run {:.0} ms after their command (the extruder follows the controller by [extruder] \
         motion_delay + {:.0} ms; set motion_delay to the arm's delay minus it)",
        board.mcu.dict.constant_str("MCU").unwrap_or_else(|_| "?".into()),
        cfg.serial.display(),
        cfg.step_lead_time * 1e3,
        cfg.step_lead_time * 1e3
    ));
    let mut report = Report::default();
    let mut last_t = f64::NEG_INFINITY;
    let mut seq = 0u64;
    let mut clamped_said = false;
    let mut last_fault_sent: Option<Instant> = None;
    let mut last_temp = f64::NAN;
    while !opts.stop.load(Ordering::Relaxed) {
        while let Some(e) = ports.receive_extruder_command()? {
            let t = e.stamp_ns as f64 * 1e-9 - offset + cfg.step_lead_time;
            if t <= last_t {
                report.out_of_order += 1;
                continue;
            }
            last_t = t;
            report.commands += 1;
            if report.fault.is_none() {
                board.sample(t, e.filament_position);
            }
        }
        if report.fault.is_none() {
            if let Some(h) = ports.latest_heater_command() {
                let target = if h.hot_end_target.is_finite() { h.hot_end_target.max(0.0) } else { 0.0 };
                if target > cfg.max_temp && !clamped_said {
                    say(&format!("hot end target {target:.1} °C is above [extruder.board] max_temp: held at {:.1} °C", cfg.max_temp));
                    clamped_said = true;
                }
                board.target = target.min(cfg.max_temp);
            }
            if let Err(e) = board.poll(0.002) {
                board.target = 0.0;
                let why = board.fault.clone().unwrap_or_else(|| e.to_string());
                say(&format!("FAULT, heater off: {why}"));
                report.fault = Some(why);
            }
            for r in board.take_readings() {
                seq += 1;
                last_temp = r.temp;
                report.readings += 1;
                let flags = heater_flags::HOT_END | if report.fault.is_some() { heater_flags::FAULT } else { 0 };
                ports.send_heater_state(&state(seq, r.time + offset, r.temp, r.duty, flags))?;
            }
            report.steps = board.steps_sent;
        } else {
            // The board is off (by us, or shut down): say so until stopped, never go quiet.
            if last_fault_sent.is_none_or(|t| t.elapsed().as_secs_f64() >= FAULT_REPEAT) {
                seq += 1;
                let hot_end = if last_temp.is_finite() { heater_flags::HOT_END } else { 0 };
                let now = monotonic_ns() as f64 * 1e-9;
                ports.send_heater_state(&state(seq, now, last_temp, 0.0, hot_end | heater_flags::FAULT))?;
                last_fault_sent = Some(Instant::now());
            }
            // Whatever the board still sends (a shut-down MCU answers nothing useful).
            let _ = board.mcu.poll(0.0);
            std::thread::sleep(Duration::from_millis(2));
        }
    }
    if report.fault.is_none() {
        // Off on the way out; the board's max_duration would do it a few seconds later anyway.
        let _ = board.heater_off();
    }
    Ok(report)
}

fn state(seq: u64, time_s: f64, hot_end: f64, power: f64, flags: u32) -> ipc::HeaterState {
    ipc::HeaterState {
        seq,
        stamp_ns: (time_s.max(0.0) * 1e9) as u64,
        hot_end: if hot_end.is_finite() { hot_end } else { 0.0 },
        hot_end_power: power,
        flags,
        ..Default::default()
    }
}
