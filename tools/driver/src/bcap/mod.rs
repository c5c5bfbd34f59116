//! DENSO b-CAP slave mode (RC7/RC8: the VP6242 of paper 004) as the client: the driver opens the
//! b-CAP service on the controller (TCP 5007), takes the arm, turns the motor on, sets the
//! exchange formats and enters joint slave mode; then every controller cycle (8 ms) it sends one
//! `slvMove` with the joints in degrees, and the controller's reply — the arm's position that
//! cycle — is the JointState that clocks the service (`docs/protocols/bcap.md`).
//!
//! Who clocks the cycle: in mode 2 (`0x202`, DENSO's default) the controller holds each reply until
//! its cycle frees a slot of its 3-command buffer, so the replies come once a cycle, on the
//! controller's clock; in mode 1 (`0x102`) the reply is immediate and the driver sends on its own
//! clock. Either way a cycle without a command in the buffer stops the arm with an error
//! (`0x84201482`, command buffer empty), and a commanded step too fast for a joint stops it with
//! another (`0x8420405n`): every answer is the guarded command, and the driver never skips one.
//! Any error the controller answers in slave mode ends the stream: the controller has stopped the
//! arm and left slave mode. The driver names the HRESULT, tells the service, and gives the arm
//! back cleanly (slave mode off, motor off, `GiveArm`, release, disconnect, stop the service) —
//! on Ctrl-C too, after holding the arm to rest.
//!
//! - [`wire`] — the packet, VARIANTs, framing and HRESULT names.
//! - [`Bcap`] — the [`RobotProtocol`]: a `slvMove` reply in, the next `slvMove` out.
//! - [`link`] — the TCP connection: the setup and release calls, and the cycle's exchange.

pub mod link;
pub mod wire;

use crate::protocol::{Channel, Clock, Frame, PacketError, RobotPacket, RobotProtocol};
use strand_ipc::MAX_JOINTS;

/// Values in a J-type `slvMove` (unused joints 0).
pub(crate) const SLAVE_JOINTS: usize = 8;

/// The client's side of slave mode.
pub struct Bcap {
    /// The robot's handle (from `Controller_GetRobot`), once the link has it.
    robot: i32,
    /// The serial of the last `slvMove` sent: its reply must echo it.
    serial: u16,
    /// Replies accepted: the packet sequence.
    cycles: u64,
    /// Which axes are linear (mm on the wire).
    linear: [bool; MAX_JOINTS],
    dof: usize,
}

impl Default for Bcap {
    fn default() -> Self {
        Bcap::new()
    }
}

impl Bcap {
    /// A client with no robot handle yet.
    pub fn new() -> Bcap {
        Bcap { robot: 0, serial: 0, cycles: 0, linear: [false; MAX_JOINTS], dof: 0 }
    }

    /// The robot's handle for every `slvMove` (the link's setup got it).
    pub fn set_robot(&mut self, handle: i32, dof: usize) {
        self.robot = handle;
        self.dof = dof.min(SLAVE_JOINTS);
    }

    /// The wire's values (degrees, mm) for joint-space `axes` (rad, m).
    pub fn to_wire(&self, axes: &[f64]) -> [f64; SLAVE_JOINTS] {
        let mut w = [0.0; SLAVE_JOINTS];
        for (k, (v, a)) in w.iter_mut().zip(axes).enumerate() {
            *v = if self.linear[k] { a * 1e3 } else { a.to_degrees() };
        }
        w
    }

    /// Encodes a `slvMove` to `axes` (rad, m) into `out` with the next serial.
    pub(crate) fn encode_move(&mut self, axes: &[f64], out: &mut Vec<u8>) {
        let w = self.to_wire(axes);
        self.encode_wire(&w, out);
    }

    /// Encodes a `slvMove` to the wire's values (degrees, mm) into `out` with the next serial:
    /// the first one holds the arm where `CurJnt` said it is, to the bit.
    pub(crate) fn encode_wire(&mut self, wire_values: &[f64; SLAVE_JOINTS], out: &mut Vec<u8>) {
        // Below the setup calls' serials (50001…50999), so that no reply passes for the other's.
        self.serial = if self.serial >= 50_000 { 1 } else { self.serial + 1 };
        wire::encode_slv_move(out, self.serial, self.robot, wire_values);
    }
}

impl RobotProtocol for Bcap {
    const NAME: &'static str = "bcap";
    const CLOCK: Clock = Clock::Driver;
    const CHANNEL: Channel = Channel::Stream;

    fn frame(buffered: &[u8]) -> Frame {
        wire::frame(buffered)
    }
    const MAX_PACKET: usize = wire::MAX_PACKET;

    fn set_linear_axes(&mut self, linear: &[bool]) -> Result<(), String> {
        if linear.len() > SLAVE_JOINTS {
            return Err(format!("{} joints; a J-type slvMove carries {SLAVE_JOINTS}", linear.len()));
        }
        self.linear = [false; MAX_JOINTS];
        self.linear[..linear.len()].copy_from_slice(linear);
        self.dof = linear.len();
        Ok(())
    }

    /// A `slvMove` reply: the arm's position this cycle. An interim packet, or a reply to another
    /// serial, is not a state; an error the controller answers is [`PacketError::RobotError`]
    /// (the arm stopped), except a full buffer, which is dropped (the next command goes again).
    fn read(&mut self, packet: &[u8]) -> Result<RobotPacket, PacketError> {
        let h = wire::read_header(packet).map_err(|e| PacketError::Malformed(e.0))?;
        if h.hresult == wire::hr::S_EXECUTING {
            return Err(PacketError::Malformed("an interim S_EXECUTING packet, not a reply".into()));
        }
        if h.serial != self.serial {
            return Err(PacketError::Malformed(format!("a reply to serial {}, the last slvMove was {}", h.serial, self.serial)));
        }
        if !wire::keeps_streaming(h.hresult) {
            return Err(PacketError::RobotError(format!("slvMove answered {}", wire::describe(h.hresult))));
        }
        if h.hresult == wire::hr::E_BUF_FULL {
            return Err(PacketError::Malformed(wire::describe(h.hresult)));
        }
        let mut w = [0.0; SLAVE_JOINTS];
        let n = wire::read_joints(packet, &mut w).map_err(|e| PacketError::Truncated(e.0))?;
        if n < self.dof {
            return Err(PacketError::Truncated(format!("{n} joint values; the robot has {}", self.dof)));
        }
        let mut axes = [0.0; MAX_JOINTS];
        for k in 0..self.dof {
            if !w[k].is_finite() {
                return Err(PacketError::BadValue(format!("J{} is {}", k + 1, w[k])));
            }
            axes[k] = if self.linear[k] { w[k] * 1e-3 } else { w[k].to_radians() };
        }
        self.cycles += 1;
        Ok(RobotPacket { seq: self.cycles, axes, dof: self.dof, following: true })
    }

    fn reset(&mut self) {
        // A new connection: the sequence goes on (it only has to increase).
    }

    /// The cycle's `slvMove`, with the next serial.
    fn write(&mut self, axes: &[f64], out: &mut Vec<u8>) {
        self.encode_move(axes, out);
    }
}

#[cfg(test)]
mod tests {
    use super::wire::{Variant, encode_call};
    use super::*;

    fn reply(serial: u16, hresult: u32, value: Option<Variant>) -> Vec<u8> {
        // A reply is a call's layout with the HRESULT where the function id goes.
        let mut out = Vec::new();
        encode_call(&mut out, serial, hresult as i32, value.as_slice());
        out
    }

    #[test]
    fn a_reply_to_the_last_move_is_the_arms_position_and_errors_are_named() {
        let mut b = Bcap::new();
        b.set_linear_axes(&[false; 6]).unwrap();
        b.set_robot(7, 6);
        let mut out = Vec::new();
        b.encode_move(&[0.1, 0.2, 0.3, 0.0, 0.0, 0.0], &mut out);
        assert_eq!(wire::read_header(&out).unwrap().serial, 1);
        let deg = vec![10.0, 20.0, 30.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let p = b.read(&reply(1, 0, Some(Variant::R8Array(deg)))).unwrap();
        assert_eq!((p.seq, p.dof), (1, 6));
        assert!((p.axes[2] - 30f64.to_radians()).abs() < 1e-15);
        // The buffer full (success), then an old serial, then the controller's error.
        b.encode_move(&[0.0; 6], &mut out);
        assert!(b.read(&reply(2, wire::hr::S_BUF_FULL, Some(Variant::R8Array(vec![0.0; 8])))).is_ok());
        b.encode_move(&[0.0; 6], &mut out);
        assert!(matches!(b.read(&reply(2, 0, Some(Variant::R8Array(vec![0.0; 8])))), Err(PacketError::Malformed(_))));
        match b.read(&reply(3, 0x8420_1482, None)) {
            Err(PacketError::RobotError(why)) => assert!(why.contains("0x84201482") && why.contains("too late"), "{why}"),
            other => panic!("{other:?}"),
        }
        assert!(matches!(b.read(&reply(3, wire::hr::E_BUF_FULL, None)), Err(PacketError::Malformed(_))));
        assert!(matches!(b.read(&reply(3, 0, Some(Variant::R8Array(vec![f64::NAN; 8])))), Err(PacketError::BadValue(_))));
        assert!(matches!(b.read(&reply(3, 0, Some(Variant::R8Array(vec![0.0; 4])))), Err(PacketError::Truncated(_))));
    }
}
