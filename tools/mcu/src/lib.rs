//! Drive a stock-Klipper micro-controller from strand.
//!
//! Any printer board with stock Klipper firmware (RP2040, STM32, AVR) becomes the extruder's
//! stepper driver and hot-end controller, with no firmware of ours: this crate speaks Klipper's
//! MCU protocol over the board's serial port. One module per job:
//!
//! - [`transport`]: message blocks, VLQ integers, CRC, the reliable send window (acks, NAK,
//!   retransmission).
//! - [`dictionary`]: the MCU's self-description (commands, responses, pins, constants) and
//!   encoding/decoding by format string.
//! - [`clock`]: the MCU clock in host time, with drift.
//! - [`stepcompress`]: step times → `queue_step` commands within a max error, and step times from
//!   a sampled position trajectory.
//! - [`thermal`]: thermistor conversion, Klipper's PID and heater verification.
//! - [`mcu`]: the connection: open, identify, clock sync, send/receive.
//! - [`board`]: the extruder board: configuration, stepper and heater over an [`mcu::Mcu`].
//! - [`config`]: the board's configuration section (`[extruder.board]`, owned by the service config).
//! - [`process`]: strand-mcu's process: the service's extruder and heater commands to the board,
//!   its temperatures (and faults) back.
//! - [`fake`]: a fake Klipper MCU on a pty for tests.

pub mod board;
pub mod clock;
pub mod config;
pub mod dictionary;
pub mod fake;
pub mod mcu;
pub mod process;
pub mod stepcompress;
pub mod thermal;
pub mod transport;
