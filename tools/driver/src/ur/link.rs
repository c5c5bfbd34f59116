//! The connections to a UR controller: RTDE (the driver dials 30004: protocol version 2, the
//! controller's version, the output recipe at the controller's rate, the analog-output input
//! recipe, start), the script port (the program sent as text), and the reverse interface (the
//! driver listens; the program connects back and reads the driver's messages).

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::time::Duration;

use strand::io::clock::monotonic_ns;

use super::rtde::{self, kind};
use super::{JOINTS, mode};
use strand::config::Config;
use strand::config::driver::DriverConfig;

use super::Ur;
use crate::paced::{DriverLink, Handshake, LinkError, readable};
use crate::protocol::RobotProtocol;
use crate::session::Session;
use strand_robot::channel::StreamBuffer;

/// How the link is set up (`[driver]`).
#[derive(Clone, Debug)]
pub struct UrSettings {
    /// The controller's RTDE address.
    pub rtde: SocketAddr,
    /// The controller's script port (30002 secondary; 30001 primary).
    pub script_port: u16,
    /// The port the driver listens on for the program (50001).
    pub reverse_port: u16,
    /// The address the program connects back to (empty: the local address of the RTDE
    /// connection, the card facing the robot).
    pub reverse_host: String,
    /// `servoj`'s lookahead time (s, 0.03 to 0.2).
    pub lookahead_time: f64,
    /// `servoj`'s gain (100 to 2000).
    pub servo_gain: f64,
    /// The RTDE rate (Hz; 500 on e-Series, 125 on CB3): `[controller] rate_hz`.
    pub frequency: f64,
    /// The standard analog output the extruder's speed goes to (0 or 1; None: none).
    pub analog_output: Option<u8>,
    /// ratio = offset + scale × the filament's speed (m/s; so s/m), clamped to 0..1.
    pub analog_scale: f64,
    /// See `analog_scale`.
    pub analog_offset: f64,
    /// Longest wait for a setup step (s).
    pub timeout: f64,
}

/// What the setup found.
#[derive(Clone, Debug)]
pub struct UrStarted {
    /// The controller's version (major, minor, bugfix, build).
    pub version: [u32; 4],
    /// The output recipe's id.
    pub recipe: u8,
    /// Where the program connects back.
    pub reverse: SocketAddr,
}

/// The connections.
pub struct UrLink {
    settings: UrSettings,
    rtde: TcpStream,
    framer: StreamBuffer,
    reverse: Option<TcpStream>,
    listener: Option<TcpListener>,
    input_recipe: Option<u8>,
    package_len: Option<usize>,
    last_ratio: Option<f64>,
    out: Vec<u8>,
}

fn io(what: &str) -> impl Fn(std::io::Error) -> LinkError + '_ {
    move |e| LinkError::Io(format!("{what}: {e}"))
}

fn write_all(stream: &mut TcpStream, bytes: &[u8], timeout: f64, what: &str) -> Result<(), LinkError> {
    let deadline = monotonic_ns() + (timeout * 1e9) as u64;
    let mut at = 0;
    while at < bytes.len() {
        match stream.write(&bytes[at..]) {
            Ok(0) => return Err(LinkError::Closed(format!("{what}: the robot closed the connection"))),
            Ok(n) => at += n,
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                if monotonic_ns() > deadline {
                    return Err(LinkError::Io(format!("{what}: the send did not go out in {timeout} s")));
                }
                std::thread::sleep(Duration::from_micros(50));
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(LinkError::Io(format!("{what}: {e}"))),
        }
    }
    Ok(())
}

impl UrLink {
    /// Connects RTDE and runs its setup up to the start of the stream; sends the program and
    /// waits for it to connect back.
    pub fn start(settings: UrSettings) -> Result<(UrLink, UrStarted), LinkError> {
        let s = &settings;
        let rtde = TcpStream::connect_timeout(&s.rtde, Duration::from_secs_f64(s.timeout)).map_err(io("RTDE"))?;
        rtde.set_nodelay(true).map_err(io("RTDE"))?;
        rtde.set_nonblocking(true).map_err(io("RTDE"))?;
        let local = rtde.local_addr().map_err(io("RTDE"))?;
        let mut link = UrLink {
            settings: settings.clone(),
            rtde,
            framer: StreamBuffer::with_capacity(8192),
            reverse: None,
            listener: None,
            input_recipe: None,
            package_len: None,
            last_ratio: None,
            out: Vec::with_capacity(64),
        };
        // 1. Protocol version 2.
        let accepted = link.ask(kind::PROTOCOL_VERSION, &2u16.to_be_bytes(), "RTDE protocol version 2")?;
        if accepted.first() != Some(&1) {
            return Err(LinkError::Refused("the controller does not speak RTDE protocol version 2 (software older than 3.2?)".into()));
        }
        // 2. The controller's version: CB3 (major < 5) streams at most 125 Hz.
        let v = link.ask(kind::URCONTROL_VERSION, &[], "the controller's version")?;
        if v.len() < 16 {
            return Err(LinkError::Io(format!("the controller's version: {} bytes", v.len())));
        }
        let version: [u32; 4] = std::array::from_fn(|k| u32::from_be_bytes(v[4 * k..4 * k + 4].try_into().unwrap_or_default()));
        let max = if version[0] < 5 { 125.0 } else { 500.0 };
        if settings.frequency > max {
            return Err(LinkError::Refused(format!(
                "[controller] rate_hz = {} Hz: this controller ({}.{}.{}) streams RTDE at most at {max} Hz",
                settings.frequency, version[0], version[1], version[2]
            )));
        }
        // 3. The outputs.
        let mut out = Vec::new();
        rtde::setup_outputs(&mut out, settings.frequency);
        let answer = link.ask_raw(&out, kind::SETUP_OUTPUTS, "the output recipe")?;
        let recipe = rtde::recipe(&answer, &rtde::OUTPUTS, &rtde::OUTPUT_TYPES).map_err(|e| LinkError::Refused(e.0))?;
        // 4. The inputs: the extruder's analog output.
        if settings.analog_output.is_some() {
            rtde::setup_inputs(&mut out);
            let answer = link.ask_raw(&out, kind::SETUP_INPUTS, "the input recipe")?;
            link.input_recipe = Some(rtde::recipe(&answer, &rtde::INPUTS, &rtde::INPUT_TYPES).map_err(|e| LinkError::Refused(e.0))?);
        }
        // 5. The reverse interface: listen where the robot reaches this PC.
        let host: std::net::IpAddr = if settings.reverse_host.is_empty() {
            local.ip()
        } else {
            settings
                .reverse_host
                .parse()
                .map_err(|_| LinkError::Refused(format!("[driver] reverse_host = {:?}: not an IP address", settings.reverse_host)))?
        };
        let listener = TcpListener::bind((host, settings.reverse_port)).map_err(io("the reverse interface"))?;
        let reverse = listener.local_addr().map_err(io("the reverse interface"))?;
        listener.set_nonblocking(true).map_err(io("the reverse interface"))?;
        link.listener = Some(listener);
        // 6. Start the stream (a data package may come before the answer: that is a start too).
        link.write(kind::START, &[])?;
        let deadline = monotonic_ns() + (settings.timeout * 1e9) as u64;
        loop {
            let Some(n) = link.next_package(deadline)? else {
                return Err(LinkError::Io(format!("RTDE start: no answer in {} s", settings.timeout)));
            };
            let (k, p) = rtde::split(link.framer.packet(n));
            let started = match k {
                kind::START if p.first() == Some(&1) => true,
                kind::START => return Err(LinkError::Refused("the controller refused to start the RTDE stream".into())),
                kind::DATA => {
                    // Keep it: it is the first state.
                    link.package_len = None;
                    break;
                }
                _ => false,
            };
            link.framer.consume(n);
            if started {
                break;
            }
        }
        // 7. The program, to the script port; it connects back.
        let program = super::script(&reverse.ip().to_string(), reverse.port(), settings.lookahead_time, settings.servo_gain);
        let script_addr = SocketAddr::new(settings.rtde.ip(), settings.script_port);
        let mut script =
            TcpStream::connect_timeout(&script_addr, Duration::from_secs_f64(settings.timeout)).map_err(io("the script port"))?;
        script.write_all(program.as_bytes()).map_err(io("the script port"))?;
        script.flush().map_err(io("the script port"))?;
        drop(script);
        let deadline = monotonic_ns() + (settings.timeout * 1e9) as u64;
        let stream = loop {
            match link.listener.as_ref().map(TcpListener::accept) {
                Some(Ok((stream, from))) if from.ip() == settings.rtde.ip() || settings.rtde.ip().is_loopback() => break stream,
                Some(Ok((_, from))) => eprintln!("strand-ur: the reverse interface refused {from}: not the robot"),
                Some(Err(e)) if e.kind() == std::io::ErrorKind::WouldBlock => {}
                Some(Err(e)) => return Err(LinkError::Io(format!("the reverse interface: {e}"))),
                None => unreachable!("listening"),
            }
            if monotonic_ns() > deadline {
                return Err(LinkError::Io(format!(
                    "the program did not connect back to {reverse} in {} s: is the robot in remote control, and {reverse} reachable from it?",
                    settings.timeout
                )));
            }
            // Keep the RTDE stream drained meanwhile (it never backlogs, but the socket would).
            let _ = link.fill(monotonic_ns() + 2_000_000);
            link.drop_old_data();
        };
        stream.set_nodelay(true).map_err(io("the reverse interface"))?;
        stream.set_nonblocking(true).map_err(io("the reverse interface"))?;
        link.reverse = Some(stream);
        // The RTDE stream from now on: older packages are stale.
        link.drop_old_data();
        Ok((link, UrStarted { version, recipe, reverse }))
    }

    /// Drops every whole package read so far: the stream's next one is fresh (the controller
    /// sends its newest data every cycle).
    fn drop_old_data(&mut self) {
        while let Ok(Some(n)) = self.framer.next_len(Ur::frame) {
            self.framer.consume(n);
        }
    }

    fn write(&mut self, k: u8, payload: &[u8]) -> Result<(), LinkError> {
        let mut out = std::mem::take(&mut self.out);
        rtde::encode(&mut out, k, payload);
        let r = write_all(&mut self.rtde, &out, self.settings.timeout, "RTDE");
        self.out = out;
        r
    }

    fn fill(&mut self, deadline_ns: u64) -> Result<bool, LinkError> {
        if !readable(&self.rtde, deadline_ns.saturating_sub(monotonic_ns())) {
            return Ok(false);
        }
        let r = self.rtde.read(self.framer.spare(4096));
        self.framer.filled(4096, *r.as_ref().unwrap_or(&0));
        match r {
            Ok(0) => Err(LinkError::Closed("RTDE: the controller closed the connection".into())),
            Ok(_) => Ok(true),
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::Interrupted) => Ok(false),
            Err(e) => Err(LinkError::Io(format!("RTDE: {e}"))),
        }
    }

    /// The next whole package's length (left at the front), by `deadline_ns`.
    fn next_package(&mut self, deadline_ns: u64) -> Result<Option<usize>, LinkError> {
        loop {
            if let Some(n) = self.framer.next_len(Ur::frame).map_err(|e| LinkError::Io(format!("RTDE: {e}")))? {
                return Ok(Some(n));
            }
            if !self.fill(deadline_ns)? && monotonic_ns() >= deadline_ns {
                return Ok(None);
            }
        }
    }

    /// Sends a setup package and returns the payload of the answer of the same type (text
    /// messages and data packages in between are skipped).
    fn ask(&mut self, k: u8, payload: &[u8], what: &str) -> Result<Vec<u8>, LinkError> {
        let mut out = Vec::new();
        rtde::encode(&mut out, k, payload);
        self.ask_raw(&out, k, what)
    }

    fn ask_raw(&mut self, package: &[u8], k: u8, what: &str) -> Result<Vec<u8>, LinkError> {
        write_all(&mut self.rtde, package, self.settings.timeout, "RTDE")?;
        let deadline = monotonic_ns() + (self.settings.timeout * 1e9) as u64;
        loop {
            let Some(n) = self.next_package(deadline)? else {
                return Err(LinkError::Io(format!("{what}: no answer in {} s", self.settings.timeout)));
            };
            let (got, p) = rtde::split(self.framer.packet(n));
            let (got, p) = (got, p.to_vec());
            self.framer.consume(n);
            if got == k {
                return Ok(p);
            }
            if got == kind::TEXT_MESSAGE {
                eprintln!("strand-ur: robot: {}", text_message(&p));
            }
        }
    }

    /// Sends the STOPPED mode (the program ends cleanly), pauses RTDE and closes everything.
    pub fn release(&mut self) -> Vec<String> {
        let mut failed = Vec::new();
        if let Some(mut r) = self.reverse.take() {
            let mut out = Vec::new();
            super::message(&mut out, 100, &[0.0; JOINTS], mode::STOPPED);
            if let Err(e) = write_all(&mut r, &out, self.settings.timeout, "the reverse interface") {
                failed.push(e.to_string());
            }
            let _ = r.shutdown(std::net::Shutdown::Write);
        }
        if let Err(e) = self.write(kind::PAUSE, &[]) {
            failed.push(e.to_string());
        }
        let _ = self.rtde.shutdown(std::net::Shutdown::Both);
        failed
    }
}

/// A text message's words (protocol version 2: length-prefixed message and source, then level).
fn text_message(p: &[u8]) -> String {
    let Some((&n, rest)) = p.split_first() else { return String::new() };
    let text = rest.get(..n as usize).map(String::from_utf8_lossy).unwrap_or_default();
    text.to_string()
}

impl DriverLink for UrLink {
    fn peer(&self) -> SocketAddr {
        self.settings.rtde
    }

    fn send(&mut self, answer: &[u8]) -> Result<(), LinkError> {
        match self.reverse.as_mut() {
            Some(r) if !answer.is_empty() => write_all(r, answer, self.settings.timeout, "the reverse interface"),
            _ => Ok(()),
        }
    }

    /// The next RTDE data package (text messages are logged; a program that closed the reverse
    /// interface shows in the robot's runtime state).
    fn receive(&mut self, deadline_ns: u64) -> Result<Option<&[u8]>, LinkError> {
        if let Some(n) = self.package_len.take() {
            self.framer.consume(n);
        }
        loop {
            let Some(n) = self.next_package(deadline_ns)? else { return Ok(None) };
            let (k, p) = rtde::split(self.framer.packet(n));
            match k {
                kind::DATA => {
                    self.package_len = Some(n);
                    return Ok(Some(self.framer.packet(n)));
                }
                kind::TEXT_MESSAGE => eprintln!("strand-ur: robot: {}", text_message(p)),
                _ => {}
            }
            self.framer.consume(n);
        }
    }

    fn finish(&mut self) -> Vec<String> {
        self.release()
    }

    fn wants_extruder(&self) -> bool {
        self.input_recipe.is_some()
    }

    /// The filament's speed onto the standard analog output (only when the ratio changes).
    fn extruder(&mut self, filament_rate: f64) -> Result<(), LinkError> {
        let (Some(id), Some(pin)) = (self.input_recipe, self.settings.analog_output) else { return Ok(()) };
        let ratio = (self.settings.analog_offset + self.settings.analog_scale * filament_rate).clamp(0.0, 1.0);
        let ratio = if ratio.is_finite() { ratio } else { 0.0 };
        if self.last_ratio.is_some_and(|r| (r - ratio).abs() < 1e-4) {
            return Ok(());
        }
        self.last_ratio = Some(ratio);
        let mut out = std::mem::take(&mut self.out);
        rtde::analog_output(&mut out, id, pin, true, ratio);
        let r = write_all(&mut self.rtde, &out, self.settings.timeout, "RTDE");
        self.out = out;
        r
    }
}

impl Handshake<Ur> for UrLink {
    /// Sets RTDE up at `[controller] rate_hz`, sends strand's servo program to
    /// `[driver] script_port`, waits for it to connect back to `reverse_port`, and gives the
    /// session the output recipe and the read timeout. No first answer: the robot streams.
    fn handshake(cfg: &Config, d: &DriverConfig, session: &mut Session<Ur>) -> Result<(UrLink, Vec<u8>), LinkError> {
        let settings = UrSettings {
            rtde: d.robot_address().map_err(|e| LinkError::Setup(e.to_string()))?,
            script_port: d.script_port,
            reverse_port: d.reverse_port,
            reverse_host: d.reverse_host.clone(),
            lookahead_time: d.lookahead_time,
            servo_gain: d.servo_gain,
            frequency: cfg.controller.rate_hz,
            analog_output: u8::try_from(d.analog_output).ok(),
            analog_scale: d.analog_scale,
            analog_offset: d.analog_offset,
            timeout: d.call_timeout,
        };
        let (link, started) = UrLink::start(settings).map_err(|e| LinkError::Setup(e.to_string()))?;
        let v = started.version;
        eprintln!(
            "strand-ur: URControl {}.{}.{}.{}; RTDE at {} Hz; the program connected back to {}",
            v[0], v[1], v[2], v[3], cfg.controller.rate_hz, started.reverse
        );
        session.protocol_mut().set_recipe(started.recipe);
        session.protocol_mut().set_read_timeout(d.read_timeout);
        Ok((link, Vec::new()))
    }
}
