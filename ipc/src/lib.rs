//! strand's client crate: the iceoryx2 ports of both sides over the wire contract of
//! [`strand_wire`], re-exported here whole (`strand_ipc::Segment` is `strand_wire::Segment`).
//!
//! [`ports`] opens the services: the controller's [`ports::ServicePorts`] and every client's
//! [`ports::ClientPorts`] (feeder, robot driver, base tracker, monitor), with the quality of service
//! fixed in one place; [`recycling`] is the allocation-free iceoryx2 service flavour they use.
//!
//! It depends on iceoryx2 (and thiserror) only, nothing of the controller, so a feeder, a robot
//! driver or a live view links it alone. The controller's core and the offline crates depend on
//! `strand-wire` instead, and link no transport.

pub use strand_wire::*;

pub mod ports;
pub mod recycling;
