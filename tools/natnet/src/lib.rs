//! strand-natnet: the robot base's pose from OptiTrack Motive over NatNet 3.x/4.x, published as
//! `BasePose` for a tracked base (`[base] mode = "tracked"`, `[tracker]`).
//!
//! - [`protocol`]: the wire format, read and written, by version;
//! - [`session`]: the handshake and the frames as a state machine without I/O;
//! - [`mapping`]: Motive's pose of the rigid body → the base B in W;
//! - [`client`]: the sockets and the publishing loop;
//! - [`fake`]: a fake Motive for tests.

pub mod client;
pub mod fake;
pub mod mapping;
pub mod protocol;
pub mod session;
