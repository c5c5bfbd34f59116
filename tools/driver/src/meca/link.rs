//! The two TCP connections to a Meca500 — control (commands, replies, events) and monitoring (the
//! joints every interval) — the setup (`docs/protocols/meca500.md` §6: errors reset, activated,
//! homed, motion cleared and resumed, velocity timeout, acceleration, monitoring interval and
//! real-time joints set), the driver's tick, and the stop.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::time::Duration;

use strand::io::clock::monotonic_ns;

use super::{FROM_CONTROL, FROM_MONITOR, describe, parse_message, parse_numbers};
use strand::config::Config;
use strand::config::driver::DriverConfig;

use super::Meca;
use crate::paced::{DriverLink, Handshake, LinkError, readable, sleep_until};
use crate::protocol::RobotProtocol;
use crate::session::Session;
use strand_robot::channel::StreamBuffer;

/// One connection's bytes, split at NUL (or a newline) into messages ([`Meca::frame`]).
struct Socket {
    stream: TcpStream,
    buf: StreamBuffer,
    what: &'static str,
}

impl Socket {
    fn connect(addr: SocketAddr, what: &'static str, timeout: f64) -> Result<Socket, LinkError> {
        let io = |e: std::io::Error| LinkError::Io(format!("{what} port {addr}: {e}"));
        let stream = TcpStream::connect_timeout(&addr, Duration::from_secs_f64(timeout)).map_err(io)?;
        stream.set_nodelay(true).map_err(io)?;
        stream.set_nonblocking(true).map_err(io)?;
        let mut s = Socket { stream, buf: StreamBuffer::with_capacity(8192), what };
        // A lone NUL: the robot then knows this is no WebSocket and sends its banner at once.
        s.write_all(b"\0", timeout)?;
        Ok(s)
    }

    fn write_all(&mut self, bytes: &[u8], timeout: f64) -> Result<(), LinkError> {
        let deadline = monotonic_ns() + (timeout * 1e9) as u64;
        let mut at = 0;
        while at < bytes.len() {
            match self.stream.write(&bytes[at..]) {
                Ok(0) => return Err(LinkError::Closed(format!("the robot closed its {} port", self.what))),
                Ok(n) => at += n,
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                    if monotonic_ns() > deadline {
                        return Err(LinkError::Io(format!("{} port: the send did not go out in {timeout} s", self.what)));
                    }
                    std::thread::sleep(Duration::from_micros(50));
                }
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(LinkError::Io(format!("{} port: {e}", self.what))),
            }
        }
        Ok(())
    }

    /// Reads what is there (waiting until `deadline_ns` for something); false if nothing came.
    fn fill(&mut self, deadline_ns: u64) -> Result<bool, LinkError> {
        if !readable(&self.stream, deadline_ns.saturating_sub(monotonic_ns())) {
            return Ok(false);
        }
        const CHUNK: usize = 4096;
        let mut any = false;
        loop {
            let r = self.stream.read(self.buf.spare(CHUNK));
            self.buf.filled(CHUNK, *r.as_ref().unwrap_or(&0));
            match r {
                Ok(0) => return Err(LinkError::Closed(format!("the robot closed its {} port", self.what))),
                Ok(n) => {
                    any = true;
                    if n < CHUNK {
                        return Ok(true);
                    }
                }
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => return Ok(any),
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(LinkError::Io(format!("{} port: {e}", self.what))),
            }
        }
    }

    /// The next whole message (without its terminator), if one is buffered.
    fn next(&mut self) -> Option<String> {
        loop {
            let n = self.buf.next_len(Meca::frame).ok().flatten()?;
            let text = String::from_utf8_lossy(&self.buf.packet(n)[..n - 1]).trim().to_string();
            self.buf.consume(n);
            if !text.is_empty() {
                return Some(text);
            }
        }
    }
}

/// What the setup found.
#[derive(Clone, Debug, PartialEq)]
pub struct Started {
    /// The banner (`Connected to Meca500 R3 v9.3.0`).
    pub banner: String,
    /// Steps it had to take (error reset, activation, homing, motion resumed).
    pub steps: Vec<String>,
}

/// The Meca500's connections, and the driver's tick.
pub struct MecaLink {
    control: Socket,
    monitor: Socket,
    peer: SocketAddr,
    timeout: f64,
    banner: String,
    /// The tick (ns) and the next one.
    period_ns: u64,
    next_tick: u64,
    /// Ticks that went by without running before the last one (the driver stalled).
    lapsed: u64,
    /// The tick's messages, tagged by socket, NUL-terminated (the packet [`super::Meca`] reads).
    packet: Vec<u8>,
}

impl MecaLink {
    /// Connects to the control port `control` and the monitoring port on the same address.
    pub fn connect(control: SocketAddr, monitor_port: u16, timeout: f64) -> Result<MecaLink, LinkError> {
        let monitor = SocketAddr::new(control.ip(), monitor_port);
        let mut link = MecaLink {
            control: Socket::connect(control, "control", timeout)?,
            monitor: Socket::connect(monitor, "monitoring", timeout)?,
            peer: control,
            timeout,
            banner: String::new(),
            period_ns: 0,
            next_tick: 0,
            lapsed: 0,
            packet: Vec::with_capacity(8192),
        };
        // The banners: [3000] (the monitoring port of old firmware may send a 2007 first).
        let banner = link.expect_control(&[3000], "the banner")?;
        link.banner = banner;
        Ok(link)
    }

    fn deadline(&self) -> u64 {
        monotonic_ns() + (self.timeout * 1e9) as u64
    }

    /// Sends `command` and waits for one of the `ok` codes on the control port; an error code
    /// that comes first is the error, named with the command.
    fn command(&mut self, command: &str, ok: &[u32]) -> Result<String, LinkError> {
        let mut bytes = command.as_bytes().to_vec();
        bytes.push(0);
        self.control.write_all(&bytes, self.timeout)?;
        if ok.is_empty() {
            return Ok(String::new());
        }
        self.expect_control(ok, command)
    }

    fn expect_control(&mut self, ok: &[u32], what: &str) -> Result<String, LinkError> {
        let deadline = self.deadline();
        loop {
            while let Some(text) = self.control.next() {
                let Some(m) = parse_message(&text) else { continue };
                if ok.contains(&m.code) {
                    return Ok(m.payload.to_string());
                }
                if (1000..2000).contains(&m.code) || (3001..=3003).contains(&m.code) {
                    return Err(LinkError::Refused(format!("{what}: the robot answered {}: {}", describe(m.code), m.payload)));
                }
            }
            if monotonic_ns() >= deadline {
                return Err(LinkError::Io(format!("{what}: no answer in {} s ([driver] call_timeout)", self.timeout)));
            }
            self.control.fill(deadline)?;
        }
    }

    /// The robot's status: activated, homed, simulation, error, paused, eob, eom.
    fn status(&mut self) -> Result<[bool; 7], LinkError> {
        let payload = self.command("GetStatusRobot", &[2007])?;
        let mut v = [0.0; 7];
        match parse_numbers(&payload, &mut v) {
            Some(n) if n >= 5 => Ok(v.map(|x| x != 0.0)),
            _ => Err(LinkError::Io(format!("GetStatusRobot: unreadable status [{payload}]"))),
        }
    }

    /// Makes the robot ready to stream and starts the driver's tick of `period` (s): errors
    /// reset, activated, homed, motion cleared and resumed, the velocity timeout and the
    /// acceleration set, the monitoring interval half the tick (at least 1 ms: every tick finds a
    /// fresh one), the encoders' joints streamed.
    pub fn start(&mut self, period: f64, velocity_timeout: f64) -> Result<Started, LinkError> {
        let mut steps = Vec::new();
        let s = self.status()?;
        if s[3] {
            self.command("ResetError", &[2005, 2006])?;
            steps.push("error reset".to_string());
        }
        if !s[0] {
            self.command("ActivateRobot", &[2000, 2001])?;
            steps.push("activated".to_string());
        }
        if !s[1] {
            self.command("Home", &[2002, 2003])?;
            steps.push("homed".to_string());
        }
        let s = self.status()?;
        if s[4] {
            self.command("ClearMotion", &[2044])?;
            self.command("ResumeMotion", &[2043])?;
            steps.push("motion cleared and resumed".to_string());
        }
        self.command(&format!("SetVelTimeout({velocity_timeout:.3})"), &[])?;
        self.command("SetJointAcc(100)", &[])?;
        let interval = (period / 2.0).max(0.001);
        self.command(&format!("SetMonitoringInterval({interval:.4})"), &[])?;
        self.command("SetRealTimeMonitoring(2210,2212)", &[2117])?;
        let s = self.status()?;
        if !(s[0] && s[1]) || s[3] || s[4] {
            return Err(LinkError::Refused(format!(
                "the robot is not ready to move (status {s:?}: activated, homed, sim, error, paused, eob, eom)"
            )));
        }
        // Drop what the monitoring port said before the robot was ready (its status pushes of
        // every step above): the stream starts after the push that says ready — the last change,
        // or the snapshot at connection if nothing changed — and the interval after it.
        let deadline = self.deadline();
        let mut ready = false;
        'fresh: loop {
            while let Some(text) = self.monitor.next() {
                match parse_message(&text) {
                    Some(m) if m.code == 2007 => {
                        let mut v = [0.0; 7];
                        ready = parse_numbers(m.payload, &mut v).is_some_and(|n| n >= 5)
                            && v[0] != 0.0
                            && v[1] != 0.0
                            && v[3] == 0.0
                            && v[4] == 0.0;
                    }
                    Some(m) if m.code == 2230 && ready => break 'fresh,
                    _ => {}
                }
            }
            if monotonic_ns() >= deadline {
                return Err(LinkError::Io(format!("the monitoring port did not say the robot is ready in {} s", self.timeout)));
            }
            self.monitor.fill(deadline)?;
        }
        while self.control.next().is_some() {}
        self.period_ns = (period * 1e9).round() as u64;
        self.next_tick = monotonic_ns() + self.period_ns;
        Ok(Started { banner: self.banner.clone(), steps })
    }

    /// Stops the arm: zero velocity (it decelerates at its joint acceleration), and the links
    /// closed; the robot stays activated and homed for the next job. Returns what failed.
    pub fn release(&mut self) -> Vec<String> {
        let mut failed = Vec::new();
        if let Err(e) = self.command("MoveJointsVel(0,0,0,0,0,0)", &[]) {
            failed.push(e.to_string());
        }
        let _ = self.control.stream.shutdown(std::net::Shutdown::Both);
        let _ = self.monitor.stream.shutdown(std::net::Shutdown::Both);
        failed
    }
}

impl DriverLink for MecaLink {
    fn peer(&self) -> SocketAddr {
        self.peer
    }

    fn finish(&mut self) -> Vec<String> {
        self.release()
    }

    fn lapsed(&mut self) -> u64 {
        std::mem::take(&mut self.lapsed)
    }

    fn send(&mut self, answer: &[u8]) -> Result<(), LinkError> {
        if answer.is_empty() {
            return Ok(());
        }
        self.control.write_all(answer, self.timeout)
    }

    /// At the driver's tick: every message both ports sent since the last one.
    fn receive(&mut self, deadline_ns: u64) -> Result<Option<&[u8]>, LinkError> {
        if self.next_tick > deadline_ns {
            return Ok(None);
        }
        sleep_until(self.next_tick);
        let now = monotonic_ns();
        self.next_tick += self.period_ns;
        if self.next_tick < now {
            // More than a tick behind (the machine stalled): the ticks that went by are told to the
            // loop, and the clock goes on from now.
            self.lapsed += (now - self.next_tick) / self.period_ns + 1;
            self.next_tick = now + self.period_ns;
        }
        self.packet.clear();
        self.control.fill(0)?;
        self.monitor.fill(0)?;
        for (tag, socket) in [(FROM_CONTROL, &mut self.control), (FROM_MONITOR, &mut self.monitor)] {
            while let Some(text) = socket.next() {
                self.packet.push(tag);
                self.packet.extend_from_slice(text.as_bytes());
                self.packet.push(0);
            }
        }
        Ok(Some(&self.packet))
    }
}

impl Handshake<Meca> for MecaLink {
    /// Connects both ports, activates and homes the arm as needed, sets velocity mode up
    /// (`[driver] velocity_timeout`, monitoring at half the cycle), and gives the session the
    /// URDF's speed limits and `[driver] velocity_gain`. No first answer: the robot streams.
    fn handshake(cfg: &Config, d: &DriverConfig, session: &mut Session<Meca>) -> Result<(MecaLink, Vec<u8>), LinkError> {
        let addr = d.robot_address().map_err(|e| LinkError::Setup(e.to_string()))?;
        let model = cfg.robot.build_model().map_err(|e| LinkError::Setup(e.to_string()))?;
        let mut link = MecaLink::connect(addr, d.monitor_port, d.call_timeout)?;
        let started = link.start(1.0 / cfg.controller.rate_hz, d.velocity_timeout).map_err(|e| LinkError::Setup(e.to_string()))?;
        eprintln!(
            "strand-meca: {}; {}",
            started.banner,
            if started.steps.is_empty() { "ready".to_string() } else { started.steps.join(", ") }
        );
        let speed: Vec<f64> = model.joints().iter().map(|j| j.limits.velocity).collect();
        let meca = session.protocol_mut();
        meca.set_speed_limits(&speed);
        meca.set_gain(d.velocity_gain);
        meca.set_velocity_timeout(d.velocity_timeout);
        Ok((link, Vec::new()))
    }
}
