//! The fake RC8 in slave mode in virtual time, for tests that put a missed cycle exactly where it
//! hurts: no sockets, no clock. A `slvMove` is decoded by the fake's own packet and VARIANT code
//! and buffered by the fake's rules; each controller tick ([`FakeProtocol::tick`]) takes the next
//! command through the fake's speed and acceleration checks (0x8420405n, 0x8420404n) and latches
//! `E_BUF_EMPTY` (0x84201482) when the driver left it nothing; the reply to the last `slvMove` is
//! the arm's position, or the latched error. The drives are the caller's: it reports the actual
//! joints each cycle and moves them towards the target the ticks set.

use super::calls::slv_pose;
use super::controller::Ctrl;
use super::{BcapOptions, MAX_JOINTS, Packet, Variant, func, hr};
use crate::fake::{FakeProtocol, InvalidSetup};

/// An RC8 already in J-type slave mode (the connect sequence is not simulated here).
pub struct VirtualRc8 {
    c: Ctrl,
    opts: BcapOptions,
    /// The serial of the last `slvMove` (the reply echoes it).
    serial: u16,
    /// What the last `slvMove` was answered, if it was refused at once (a full buffer, a bad pose).
    refused: Option<u32>,
}

impl VirtualRc8 {
    /// A controller at `opts.start_deg`, motor on, the arm taken, in `slave_mode` (0x002, 0x102 or
    /// 0x202; others are refused, named).
    pub fn new(opts: BcapOptions, slave_mode: u32) -> Result<VirtualRc8, InvalidSetup> {
        if ![0x002, 0x102, 0x202].contains(&slave_mode) {
            return Err(InvalidSetup(format!("slave mode {slave_mode:#x}: the fake takes the J-type modes 0x002, 0x102, 0x202")));
        }
        if opts.start_deg.is_empty() || opts.start_deg.len() > MAX_JOINTS {
            return Err(InvalidSetup(format!("{} joints: 1 to {MAX_JOINTS}", opts.start_deg.len())));
        }
        let mut c = Ctrl::new(&opts.start_deg);
        c.connected = true;
        c.arm_taken = true;
        c.motor_on = true;
        c.enter_slave(slave_mode);
        if slave_mode == 0x202 {
            // Mode 2 holds each reply until a tick frees a slot, so a driver that keeps up runs
            // two commands ahead of the arm: the buffer starts as it stands then (the position).
            let mut hold = [0.0; MAX_JOINTS];
            hold[..opts.start_deg.len()].copy_from_slice(&opts.start_deg);
            c.buffer.extend([hold, hold]);
        }
        Ok(VirtualRc8 { c, opts, serial: 0, refused: None })
    }

    /// The errors latched so far (HRESULTs).
    pub fn errors(&self) -> &[u32] {
        &self.c.errors
    }
}

impl FakeProtocol for VirtualRc8 {
    /// The reply to the last `slvMove`: the actual joints (degrees), or the error latched since.
    fn packet(&mut self, _k: u64, axes_deg: &[f64], out: &mut Vec<u8>) {
        for (a, q) in self.c.actual.iter_mut().zip(axes_deg) {
            *a = *q;
        }
        let reply = match (self.c.latched, self.refused.take()) {
            (Some(code), _) | (None, Some(code)) => Packet { serial: self.serial, reserved: 0, id: code, args: Vec::new() },
            (None, None) => Packet { serial: self.serial, reserved: 0, id: hr::S_OK, args: vec![Variant::r8s(&self.c.joints8())] },
        };
        out.clear();
        out.extend_from_slice(&reply.encode());
    }

    /// A `slvMove` into the buffer (the tick takes it).
    fn answer(&mut self, _k: u64, bytes: &[u8], _axes_deg: &mut [f64]) -> Result<(), Option<u64>> {
        let p = Packet::decode(bytes).map_err(|_| None)?;
        let is_move =
            p.id == func::ROBOT_EXECUTE && p.args.get(1).and_then(Variant::str).is_some_and(|c| c.eq_ignore_ascii_case("slvMove"));
        if !is_move {
            return Err(None);
        }
        self.serial = p.serial;
        self.c.slv_moves += 1;
        if self.c.latched.is_some() || self.c.slave_mode == 0 {
            self.refused = Some(hr::E_SLAVE_OFF);
            return Ok(());
        }
        let cmd = match p.args.get(2).map(|param| slv_pose(self.c.send_fmt, param)) {
            Some(Ok(cmd)) => cmd,
            Some(Err(code)) => {
                self.refused = Some(code);
                return Ok(());
            }
            None => {
                self.refused = Some(hr::E_INVALIDARG);
                return Ok(());
            }
        };
        if (self.c.slave_mode >> 8) & 0xF == 1 {
            self.c.buffer.clear();
        } else if self.c.buffer.len() >= 3 {
            self.c.buffer_full += 1;
            self.refused = Some(hr::E_BUF_FULL);
            return Ok(());
        }
        self.c.buffer.push_back(cmd);
        Ok(())
    }

    /// The controller's tick: the next buffered command becomes the drives' target.
    fn tick(&mut self, _k: u64, axes_deg: &mut [f64]) {
        // The drives are the caller's: the tick only moves the target (no lag here).
        self.c.tick(0.0, &self.opts);
        for (a, t) in axes_deg.iter_mut().zip(&self.c.target) {
            *a = *t;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn slv_move(serial: u16, deg: &[f64]) -> Vec<u8> {
        let mut q = [0.0; MAX_JOINTS];
        q[..deg.len()].copy_from_slice(deg);
        Packet {
            serial,
            reserved: 0,
            id: func::ROBOT_EXECUTE,
            args: vec![Variant::I4(1), Variant::Bstr("slvMove".into()), Variant::r8s(&q)],
        }
        .encode()
    }

    #[test]
    fn mode_2_runs_two_ahead_checks_each_command_and_latches_an_empty_buffer() {
        let opts = BcapOptions { start_deg: vec![0.0; 6], cycle: 0.008, speed_limit_deg: vec![100.0; 6], ..Default::default() };
        let mut rc8 = VirtualRc8::new(opts, 0x202).unwrap();
        let (mut target, mut out) = (vec![0.0; 6], Vec::new());
        // Two buffered holds, then the commands: a step of 0.2° per 8 ms (25 deg/s, 3125 deg/s²
        // from rest) is taken two ticks after it was sent.
        for k in 0..4u64 {
            rc8.packet(k, &target.clone(), &mut out);
            rc8.answer(k, &slv_move(k as u16 + 1, &[0.2 * (k + 1) as f64, 0.0, 0.0, 0.0, 0.0, 0.0]), &mut target).unwrap();
            rc8.tick(k, &mut target);
        }
        assert!((target[0] - 0.4).abs() < 1e-12, "{target:?}");
        // Two stalled ticks run the buffer; the third finds it empty.
        for k in 4..7 {
            rc8.tick(k, &mut target);
        }
        assert_eq!(rc8.errors(), &[hr::E_BUF_EMPTY]);
        rc8.packet(7, &target.clone(), &mut out);
        let reply = Packet::decode(&out).unwrap();
        assert_eq!((reply.serial, reply.id, reply.args.len()), (4, hr::E_BUF_EMPTY, 0));
        // A command faster than the limit latches the joint's speed error.
        let opts = BcapOptions { start_deg: vec![0.0; 6], cycle: 0.008, speed_limit_deg: vec![100.0; 6], ..Default::default() };
        let mut rc8 = VirtualRc8::new(opts, 0x102).unwrap();
        rc8.answer(0, &slv_move(1, &[0.0, 1.0, 0.0, 0.0, 0.0, 0.0]), &mut target).unwrap();
        rc8.tick(0, &mut target);
        assert_eq!(rc8.errors(), &[hr::E_SPEED + 2]);
    }
}
