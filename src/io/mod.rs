//! The I/O shell around the deterministic core: the cycle runner over the iceoryx2 ports of
//! `strand_ipc::ports`, cycle clock, real-time set-up.
//!
//! Nothing in here decides anything about motion; it moves bytes between shared memory and the
//! controller, waits for ticks and measures how late they were. `core` never imports this module.
//! Functions documented as *tick-path safe* do not allocate, lock a mutex, print or use `tracing`;
//! everything else runs at start-up, shutdown or on an error path.

pub mod alloc_count;
pub mod clock;
pub mod histogram;
pub mod rt;
pub mod runner;
