//! The TCP connection to the controller's b-CAP service: the setup calls (service, controller,
//! arm, motor, exchange formats, slave mode), the cycle's exchange of a `slvMove` for the arm's
//! position, and the release. One call is outstanding at a time, as b-CAP requires; a reply is the
//! packet that echoes the call's serial and is not an interim `S_EXECUTING` (the controller's
//! watchdog packets during a long call, such as turning the motor on).

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::time::Duration;

use strand::io::clock::monotonic_ns;

use super::wire::{self, Variant, func};
use crate::protocol::RobotProtocol;
use strand::config::Config;
use strand::config::driver::DriverConfig;
use strand_robot::channel::StreamBuffer;

use super::Bcap;
use crate::paced::{DriverLink, Handshake, LinkError, readable, sleep_until};
use crate::session::Session;

/// Controller_Connect's provider for RC8 / RC8A / COBOTTA (RC9: `CaoProv.DENSO.VRC9`).
pub(crate) const PROVIDER: &str = "CaoProv.DENSO.VRC";
/// The exchange formats strand sets: the command is a bare joint array, the reply a bare joint
/// array (`slvSendFormat` 0x0000, `slvRecvFormat` 0x0002).
pub(crate) const SEND_FORMAT: i32 = 0x0000;
/// See [`SEND_FORMAT`].
pub(crate) const RECV_FORMAT: i32 = 0x0002;

/// The connection and what the setup got.
pub struct BcapLink {
    stream: TcpStream,
    peer: SocketAddr,
    framer: StreamBuffer,
    /// The serial of setup and release calls (the cycle's `slvMove`s have their own).
    serial: u16,
    out: Vec<u8>,
    call_timeout: f64,
    controller: Option<i32>,
    robot: Option<i32>,
    arm_taken: bool,
    motor_on: bool,
    slave: bool,
    service: bool,
    /// Mode 1: the driver's cycle (ns) and its next tick; the answer waits for it.
    paced: Option<(u64, u64)>,
    pending: Vec<u8>,
    packet_len: Option<usize>,
}

impl BcapLink {
    /// Connects to the controller's b-CAP port.
    pub fn connect(addr: SocketAddr, call_timeout: f64) -> Result<BcapLink, LinkError> {
        let io = |e: std::io::Error| LinkError::Io(format!("{addr}: {e}"));
        let stream = TcpStream::connect_timeout(&addr, Duration::from_secs_f64(call_timeout)).map_err(io)?;
        stream.set_nodelay(true).map_err(io)?;
        stream.set_nonblocking(true).map_err(io)?;
        Ok(BcapLink {
            stream,
            peer: addr,
            framer: StreamBuffer::with_capacity(4096),
            serial: 0,
            out: Vec::with_capacity(512),
            call_timeout,
            controller: None,
            robot: None,
            arm_taken: false,
            motor_on: false,
            slave: false,
            service: false,
            paced: None,
            pending: Vec::with_capacity(512),
            packet_len: None,
        })
    }

    /// The robot's handle (after [`BcapLink::start`]).
    pub fn robot(&self) -> Option<i32> {
        self.robot
    }

    /// The next whole packet's length, if one came (b-CAP resynchronises on its SOH: it never
    /// loses the framing).
    fn next_len(&mut self) -> Option<usize> {
        self.framer.next_len(Bcap::frame).ok().flatten()
    }

    fn next_serial(&mut self) -> u16 {
        // Far from the cycle's serials, so that a stray reply cannot pass for the other's.
        self.serial = if self.serial >= 999 { 1 } else { self.serial + 1 };
        self.serial + 50_000
    }

    fn write_all(&mut self, bytes: &[u8]) -> Result<(), LinkError> {
        let deadline = monotonic_ns() + (self.call_timeout * 1e9) as u64;
        let mut at = 0;
        while at < bytes.len() {
            match self.stream.write(&bytes[at..]) {
                Ok(0) => return Err(LinkError::Closed("the controller closed the connection".into())),
                Ok(n) => at += n,
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                    if monotonic_ns() > deadline {
                        return Err(LinkError::Io(format!("{}: the send did not go out in {} s", self.peer, self.call_timeout)));
                    }
                    std::thread::sleep(Duration::from_micros(50));
                }
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(LinkError::Io(format!("{}: {e}", self.peer))),
            }
        }
        Ok(())
    }

    /// Reads what the socket has into the framer; false if nothing came by `deadline_ns`.
    fn fill(&mut self, deadline_ns: u64) -> Result<bool, LinkError> {
        let now = monotonic_ns();
        if !readable(&self.stream, deadline_ns.saturating_sub(now)) {
            // One look more: a driver descheduled past its deadline still takes what came.
            if now < deadline_ns {
                return Ok(false);
            }
        }
        let spare = self.framer.spare(4096);
        match self.stream.read(spare) {
            Ok(0) => {
                self.framer.filled(4096, 0);
                Err(LinkError::Closed("the controller closed the connection".into()))
            }
            Ok(n) => {
                self.framer.filled(4096, n);
                Ok(true)
            }
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::Interrupted) => {
                self.framer.filled(4096, 0);
                Ok(false)
            }
            Err(e) => {
                self.framer.filled(4096, 0);
                Err(LinkError::Io(format!("{}: {e}", self.peer)))
            }
        }
    }

    /// One call: its reply's value, or the HRESULT named with what was called.
    fn call(&mut self, what: &str, id: i32, args: &[Variant]) -> Result<Option<Variant>, LinkError> {
        let serial = self.next_serial();
        let mut out = std::mem::take(&mut self.out);
        wire::encode_call(&mut out, serial, id, args);
        let sent = self.write_all(&out);
        self.out = out;
        sent?;
        // Interim packets restart the wait (the controller says it is still working).
        let mut deadline = monotonic_ns() + (self.call_timeout * 1e9) as u64;
        loop {
            if let Some(n) = self.next_len() {
                let packet = self.framer.packet(n).to_vec();
                self.framer.consume(n);
                let Ok(h) = wire::read_header(&packet) else { continue };
                if h.serial != serial {
                    continue;
                }
                if h.hresult == wire::hr::S_EXECUTING {
                    deadline = monotonic_ns() + (self.call_timeout * 1e9) as u64;
                    continue;
                }
                if h.hresult & 0x8000_0000 != 0 {
                    return Err(LinkError::Refused(format!("{what} answered {}", wire::describe(h.hresult))));
                }
                return wire::read_value(&packet).map_err(|e| LinkError::Io(format!("{what}: the reply: {}", e.0)));
            }
            if monotonic_ns() >= deadline {
                return Err(LinkError::Io(format!("{what}: no reply in {} s ([driver] call_timeout)", self.call_timeout)));
            }
            self.fill(deadline)?;
        }
    }

    fn robot_execute(&mut self, command: &str, param: Variant) -> Result<Option<Variant>, LinkError> {
        let robot = self.robot.unwrap_or(0);
        self.call(&format!("Robot_Execute({command})"), func::ROBOT_EXECUTE, &[Variant::I4(robot), Variant::Bstr(command.into()), param])
    }

    /// The connect sequence (`docs/protocols/bcap.md` §3.7): the service (with a 400 ms watchdog,
    /// so that the motor's seconds do not time out), the controller, its errors cleared, the arm
    /// taken, the motor on, the formats set, joint slave mode `slave_mode` entered. Returns the
    /// arm's joints before the first command (degrees or mm, eight values). `period` is the
    /// controller's cycle (s): in mode 1 the driver sends on it.
    pub fn start(&mut self, slave_mode: u32, period: f64) -> Result<[f64; 8], LinkError> {
        self.call("Service_Start", func::SERVICE_START, &[Variant::Bstr(",WDT=400,InvokeTimeout=180000".into())])?;
        self.service = true;
        let handle = |v: Option<Variant>, what: &str| {
            v.as_ref().and_then(Variant::as_i32).ok_or_else(|| LinkError::Io(format!("{what}: no handle in the reply ({v:?})")))
        };
        let c = self.call(
            "Controller_Connect",
            func::CONTROLLER_CONNECT,
            &[
                Variant::Bstr("strand".into()),
                Variant::Bstr(PROVIDER.into()),
                Variant::Bstr("localhost".into()),
                Variant::Bstr(String::new()),
            ],
        )?;
        let c = handle(c, "Controller_Connect")?;
        self.controller = Some(c);
        self.call(
            "Controller_Execute(ClearError)",
            func::CONTROLLER_EXECUTE,
            &[Variant::I4(c), Variant::Bstr("ClearError".into()), Variant::Empty],
        )?;
        let r = self.call(
            "Controller_GetRobot",
            func::CONTROLLER_GET_ROBOT,
            &[Variant::I4(c), Variant::Bstr("Arm".into()), Variant::Bstr(String::new())],
        )?;
        self.robot = Some(handle(r, "Controller_GetRobot")?);
        self.robot_execute("TakeArm", Variant::I4Array(vec![0, 1]))?;
        self.arm_taken = true;
        self.robot_execute("Motor", Variant::I4Array(vec![1, 0]))?;
        self.motor_on = true;
        let q = match self.robot_execute("CurJnt", Variant::Empty)? {
            Some(Variant::R8Array(v)) if !v.is_empty() && v.len() <= 8 && v.iter().all(|x| x.is_finite()) => {
                let mut q = [0.0; 8];
                q[..v.len()].copy_from_slice(&v);
                q
            }
            other => return Err(LinkError::Io(format!("Robot_Execute(CurJnt): not the joints ({other:?})"))),
        };
        self.robot_execute("slvSendFormat", Variant::I4(SEND_FORMAT))?;
        self.robot_execute("slvRecvFormat", Variant::I4(RECV_FORMAT))?;
        self.robot_execute("slvChangeMode", Variant::I4(slave_mode as i32))?;
        self.slave = true;
        if slave_mode & 0xF00 == 0x100 {
            let p = (period * 1e9).round() as u64;
            self.paced = Some((p, monotonic_ns() + p));
        }
        Ok(q)
    }

    /// Gives the arm back: slave mode off, motor off, the arm given, the robot released, the
    /// controller disconnected, the service stopped — each step that applies, each tried even if
    /// one before failed (a controller that stopped after an error refuses some). Returns what
    /// failed.
    pub fn release(&mut self) -> Vec<String> {
        let mut failed = Vec::new();
        // The reply to the cycle's last slvMove may still be held (mode 2, until the next cycle):
        // take it, and leave slave mode at once after it, while the buffer still holds commands —
        // a cycle that finds it empty stops the arm with an error.
        if let Some(n) = self.packet_len.take() {
            self.framer.consume(n);
        }
        let end = monotonic_ns() + 20_000_000;
        while self.next_len().is_none() && monotonic_ns() < end {
            if self.fill(end).is_err() {
                break;
            }
        }
        self.framer.clear();
        let mut step = |r: Result<Option<Variant>, LinkError>| {
            if let Err(e) = r {
                failed.push(e.to_string());
            }
        };
        if self.slave {
            step(self.robot_execute("slvChangeMode", Variant::I4(0)));
            self.slave = false;
        }
        if self.motor_on {
            step(self.robot_execute("Motor", Variant::I4Array(vec![0, 0])));
            self.motor_on = false;
        }
        if self.arm_taken {
            step(self.robot_execute("GiveArm", Variant::Empty));
            self.arm_taken = false;
        }
        if let Some(r) = self.robot.take() {
            step(self.call("Robot_Release", func::ROBOT_RELEASE, &[Variant::I4(r)]));
        }
        if let Some(c) = self.controller.take() {
            step(self.call("Controller_Disconnect", func::CONTROLLER_DISCONNECT, &[Variant::I4(c)]));
        }
        if self.service {
            step(self.call("Service_Stop", func::SERVICE_STOP, &[]));
            self.service = false;
        }
        let _ = self.stream.shutdown(std::net::Shutdown::Both);
        failed
    }
}

impl DriverLink for BcapLink {
    fn peer(&self) -> SocketAddr {
        self.peer
    }

    fn finish(&mut self) -> Vec<String> {
        self.release()
    }

    fn send(&mut self, answer: &[u8]) -> Result<(), LinkError> {
        if self.paced.is_some() {
            // Mode 1: the answer goes at the driver's next tick.
            self.pending.clear();
            self.pending.extend_from_slice(answer);
            return Ok(());
        }
        self.write_all(answer)
    }

    fn receive(&mut self, deadline_ns: u64) -> Result<Option<&[u8]>, LinkError> {
        if let Some(n) = self.packet_len.take() {
            self.framer.consume(n);
        }
        if let Some((period, next)) = self.paced
            && !self.pending.is_empty()
        {
            sleep_until(next);
            let pending = std::mem::take(&mut self.pending);
            let sent = self.write_all(&pending);
            self.pending = pending;
            self.pending.clear();
            sent?;
            // On absolute ticks; a driver that fell more than a tick behind starts again from now.
            let now = monotonic_ns();
            let mut next = next + period;
            if next < now {
                next = now + period;
            }
            self.paced = Some((period, next));
        }
        loop {
            if let Some(n) = self.next_len() {
                self.packet_len = Some(n);
                return Ok(Some(self.framer.packet(n)));
            }
            // Nothing by the deadline (a signal that cut the wait short is no deadline).
            if !self.fill(deadline_ns)? && monotonic_ns() >= deadline_ns && self.next_len().is_none() {
                return Ok(None);
            }
        }
    }
}

impl Handshake<Bcap> for BcapLink {
    /// Connects, takes the arm into slave mode (`[driver] slave_mode`, the cycle from
    /// `[controller] rate_hz`), and gives the session the robot's handle; the first answer holds
    /// the arm where `CurJnt` says it is, to the bit (its reply starts the session).
    fn handshake(cfg: &Config, d: &DriverConfig, session: &mut Session<Bcap>) -> Result<(BcapLink, Vec<u8>), LinkError> {
        let addr = d.robot_address().map_err(|e| LinkError::Setup(e.to_string()))?;
        let mut link = BcapLink::connect(addr, d.call_timeout)?;
        let q0 = match link.start(d.slave_mode, 1.0 / cfg.controller.rate_hz) {
            Ok(q) => q,
            Err(e) => {
                for problem in link.release() {
                    eprintln!("strand-bcap: giving the robot back: {problem}");
                }
                return Err(LinkError::Setup(e.to_string()));
            }
        };
        eprintln!("strand-bcap: slave mode {:#x}, the arm at {:?} deg", d.slave_mode, &q0[..session.dof()]);
        let dof = session.dof();
        let bcap = session.protocol_mut();
        bcap.set_robot(link.robot().unwrap_or(0), dof);
        let mut first = Vec::with_capacity(256);
        bcap.encode_wire(&q0, &mut first);
        Ok((link, first))
    }
}
