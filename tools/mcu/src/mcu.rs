//! A connection to one Klipper MCU over a serial port (or a pty).
//!
//! Single-threaded and poll-driven: the caller calls [`Mcu::poll`] often (every control tick);
//! it writes what the send window releases (including retransmissions), reads what arrived,
//! feeds acks to the window and `clock` answers to the clock estimate, and returns the other
//! messages. Nothing blocks longer than the timeout given.

use std::collections::VecDeque;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::path::Path;
use std::time::{Duration, Instant};

use crate::clock::ClockSync;
use crate::dictionary::{DictError, Dictionary, Message, Value};
use crate::transport::{BlockParser, SendWindow};

/// What can go wrong talking to the MCU.
#[derive(Debug, thiserror::Error)]
pub enum McuError {
    /// The serial port cannot be opened or configured.
    #[error("serial port {path}: {err}")]
    Open {
        /// The port.
        path: String,
        /// The OS error.
        err: std::io::Error,
    },
    /// Reading or writing failed.
    #[error("serial I/O: {0}")]
    Io(#[from] std::io::Error),
    /// Nothing at all came back.
    #[error("no answer from the MCU within {0:.1} s (not powered, wrong port, or no firmware)")]
    NoAnswer(f64),
    /// Bytes came back but never a valid Klipper block.
    #[error("the MCU answers but not in Klipper's protocol ({0} bytes of garbage; wrong baud rate?)")]
    Garbage(u64),
    /// Text came back: a G-code firmware.
    #[error("the board runs other firmware, not Klipper: it answered {0:?}")]
    OtherFirmware(String),
    /// The dictionary says it is not Klipper.
    #[error("the board's firmware is '{0}', not Klipper")]
    NotKlipper(String),
    /// A dictionary lookup or message problem (names the command or pin).
    #[error(transparent)]
    Dict(#[from] DictError),
    /// A request was not answered in time.
    #[error("no '{0}' answer within {1:.1} s")]
    Timeout(String, f64),
    /// The MCU shut down.
    #[error("MCU shutdown: {0}")]
    Shutdown(String),
    /// The MCU holds a different configuration (a firmware restart is needed).
    #[error("the MCU is configured differently (crc {theirs:#x}, ours {ours:#x}); restart its firmware")]
    ConfigMismatch {
        /// The MCU's config CRC.
        theirs: u32,
        /// The host's config CRC.
        ours: u32,
    },
}

/// One received message with its timing.
#[derive(Debug, Clone)]
pub struct Received {
    /// The decoded message.
    pub msg: Message,
    /// Host monotonic time it was read, s.
    pub receive_time: f64,
    /// Host time the block that this message acknowledged was first sent, s (None if unknown).
    pub sent_time: Option<f64>,
}

fn baud_const(baud: u32) -> Option<libc::speed_t> {
    Some(match baud {
        9600 => libc::B9600,
        19200 => libc::B19200,
        38400 => libc::B38400,
        57600 => libc::B57600,
        115200 => libc::B115200,
        230400 => libc::B230400,
        460800 => libc::B460800,
        500000 => libc::B500000,
        576000 => libc::B576000,
        921600 => libc::B921600,
        1000000 => libc::B1000000,
        _ => return None,
    })
}

/// Opens `path` non-blocking in raw mode at `baud` (ignored by USB CDC and ptys).
pub fn open_serial(path: &Path, baud: u32) -> Result<OwnedFd, McuError> {
    let open_err = |err| McuError::Open { path: path.display().to_string(), err };
    let c = std::ffi::CString::new(path.as_os_str().as_encoded_bytes())
        .map_err(|_| open_err(std::io::Error::from(std::io::ErrorKind::InvalidInput)))?;
    // SAFETY: a valid NUL-terminated path.
    let fd = unsafe { libc::open(c.as_ptr(), libc::O_RDWR | libc::O_NOCTTY | libc::O_NONBLOCK | libc::O_CLOEXEC) };
    if fd < 0 {
        return Err(open_err(std::io::Error::last_os_error()));
    }
    // SAFETY: a fresh fd we own.
    let fd = unsafe { OwnedFd::from_raw_fd(fd) };
    // SAFETY: termios is plain data filled by tcgetattr.
    unsafe {
        let mut t: libc::termios = std::mem::zeroed();
        if libc::tcgetattr(fd.as_raw_fd(), &mut t) != 0 {
            return Err(open_err(std::io::Error::last_os_error()));
        }
        libc::cfmakeraw(&mut t);
        let b = baud_const(baud).unwrap_or(libc::B230400);
        libc::cfsetispeed(&mut t, b);
        libc::cfsetospeed(&mut t, b);
        t.c_cflag |= libc::CLOCAL | libc::CREAD;
        if libc::tcsetattr(fd.as_raw_fd(), libc::TCSANOW, &t) != 0 {
            return Err(open_err(std::io::Error::last_os_error()));
        }
        if baud_const(baud).is_none() {
            // A rate without a Bxxx constant (250000, Klipper's AVR default): termios2 with
            // BOTHER, as pyserial does. A pty refuses it harmlessly; the rate means nothing there.
            let mut t2: libc::termios2 = std::mem::zeroed();
            if libc::ioctl(fd.as_raw_fd(), libc::TCGETS2, &mut t2) == 0 {
                t2.c_cflag &= !libc::CBAUD;
                t2.c_cflag |= libc::BOTHER;
                t2.c_ispeed = baud;
                t2.c_ospeed = baud;
                libc::ioctl(fd.as_raw_fd(), libc::TCSETS2, &t2);
            }
        }
        libc::tcflush(fd.as_raw_fd(), libc::TCIOFLUSH);
    }
    Ok(fd)
}

/// Connection tuning.
#[derive(Debug, Clone, Copy)]
pub struct ConnectOptions {
    /// Give up on a silent or foreign board after this long, s.
    pub timeout: f64,
    /// Interval of the initial get_clock samples, s (Klipper: 0.05).
    pub sync_interval: f64,
    /// Number of initial get_clock samples (Klipper: 8).
    pub sync_samples: usize,
    /// Interval of periodic get_clock while running, s (Klipper: 0.9839).
    pub clock_interval: f64,
}

impl Default for ConnectOptions {
    fn default() -> Self {
        Self { timeout: 3.0, sync_interval: 0.05, sync_samples: 8, clock_interval: 0.9839 }
    }
}

/// A connected Klipper MCU.
#[derive(Debug)]
pub struct Mcu {
    fd: OwnedFd,
    epoch: Instant,
    parser: BlockParser,
    window: SendWindow,
    /// The MCU's data dictionary.
    pub dict: Dictionary,
    /// The clock estimate (None until the first get_uptime).
    pub clock: Option<ClockSync>,
    inbox: VecDeque<Received>,
    /// Bytes received in total.
    pub bytes_read: u64,
    text: Vec<u8>,
    /// The shutdown reason, once the MCU reported one.
    pub shutdown: Option<String>,
    opts: ConnectOptions,
    next_clock_query: f64,
    clock_query_pending: bool,
}

impl Mcu {
    /// The instant [`Mcu::now`] counts from.
    pub fn epoch(&self) -> Instant {
        self.epoch
    }

    /// Host monotonic time since this connection was opened, s.
    pub fn now(&self) -> f64 {
        self.epoch.elapsed().as_secs_f64()
    }

    /// Opens the port, reads the dictionary and synchronises the clock.
    pub fn connect(path: &Path, baud: u32, opts: ConnectOptions) -> Result<Self, McuError> {
        let fd = open_serial(path, baud)?;
        let mut m = Self {
            fd,
            epoch: Instant::now(),
            parser: BlockParser::new(),
            window: SendWindow::new(192),
            dict: Dictionary::bootstrap(),
            clock: None,
            inbox: VecDeque::new(),
            bytes_read: 0,
            text: Vec::new(),
            shutdown: None,
            opts,
            next_clock_query: f64::MAX,
            clock_query_pending: false,
        };
        m.identify()?;
        m.sync_clock()?;
        Ok(m)
    }

    fn identify(&mut self) -> Result<(), McuError> {
        // The timeout counts from the last progress: a slow link that delivers is not an error.
        let mut deadline = self.now() + self.opts.timeout;
        let mut data = Vec::new();
        let mut sent_at = -1.0;
        loop {
            let now = self.now();
            if now > deadline {
                return Err(self.classify_silence());
            }
            if now - sent_at > 0.2 {
                // (Re)ask for the chunk at the current offset; a board that boots late or lost
                // the first request gets asked again.
                if !self.window.busy() {
                    let cmd = self
                        .dict
                        .encode(crate::dictionary::IDENTIFY, &[("offset", Value::Int(data.len() as i64)), ("count", Value::Int(40))])?;
                    self.window.queue(cmd);
                }
                sent_at = now;
            }
            self.pump(0.01)?;
            while let Some(r) = self.inbox.pop_front() {
                if r.msg.name != "identify_response" {
                    continue;
                }
                if r.msg.int("offset")? as usize != data.len() {
                    continue;
                }
                let chunk = r.msg.bytes("data")?.to_vec();
                if chunk.is_empty() {
                    self.dict = Dictionary::from_identify_data(&data)?;
                    if !self.dict.app.is_empty() && self.dict.app != "Klipper" {
                        return Err(McuError::NotKlipper(self.dict.app.clone()));
                    }
                    let rw = self.dict.constant_f64("RECEIVE_WINDOW").unwrap_or(192.0);
                    self.window.receive_window = rw as usize;
                    return Ok(());
                }
                data.extend_from_slice(&chunk);
                deadline = self.now() + self.opts.timeout;
                let cmd = self
                    .dict
                    .encode(crate::dictionary::IDENTIFY, &[("offset", Value::Int(data.len() as i64)), ("count", Value::Int(40))])?;
                self.window.queue(cmd);
                sent_at = self.now();
            }
        }
    }

    fn classify_silence(&self) -> McuError {
        if self.bytes_read == 0 {
            return McuError::NoAnswer(self.opts.timeout);
        }
        let printable = self.text.iter().filter(|&&b| b == b'\n' || b == b'\r' || (0x20..0x7f).contains(&b)).count();
        if !self.text.is_empty() && printable * 10 >= self.text.len() * 9 {
            let s = String::from_utf8_lossy(&self.text);
            let s: String = s.split_whitespace().collect::<Vec<_>>().join(" ");
            return McuError::OtherFirmware(s.chars().take(60).collect());
        }
        McuError::Garbage(self.parser.bytes_invalid.max(self.bytes_read))
    }

    fn sync_clock(&mut self) -> Result<(), McuError> {
        let freq = self.dict.constant_f64("CLOCK_FREQ")?;
        let r = self.request("get_uptime", &[], "uptime", 2.0)?;
        let clock64 = ((r.msg.int("high")? as u64) << 32) | r.msg.int("clock")? as u64;
        let sent = r.sent_time.unwrap_or(r.receive_time);
        self.clock = Some(ClockSync::new(freq, clock64, sent));
        for _ in 0..self.opts.sync_samples {
            let until = self.now() + self.opts.sync_interval;
            while self.now() < until {
                self.pump(until - self.now())?;
            }
            let r = self.request("get_clock", &[], "clock", 2.0)?;
            self.on_clock(&r);
        }
        self.next_clock_query = self.now() + self.opts.clock_interval;
        Ok(())
    }

    fn on_clock(&mut self, r: &Received) {
        self.clock_query_pending = false;
        if let (Some(cs), Some(sent), Ok(c)) = (self.clock.as_mut(), r.sent_time, r.msg.int("clock")) {
            cs.handle_clock(c as u32, sent, r.receive_time);
        }
    }

    /// Queues a command by format and parameters.
    pub fn send(&mut self, format: &str, args: &[(&str, Value)]) -> Result<(), McuError> {
        let cmd = self.dict.encode(format, args)?;
        self.window.queue(cmd);
        Ok(())
    }

    /// Sends a query and waits for the named response. The query is sent again when its answer is
    /// lost (a corrupted response block is never retransmitted by the MCU), so use it only for
    /// idempotent queries (get_clock, get_uptime, get_config, identify...), as Klipper does.
    pub fn request(&mut self, format: &str, args: &[(&str, Value)], response: &str, timeout: f64) -> Result<Received, McuError> {
        let cmd = self.dict.encode(format, args)?;
        // A stale answer to an earlier, retried query must not answer this one.
        self.inbox.retain(|r| r.msg.name != response);
        self.window.queue(cmd.clone());
        let deadline = self.now() + timeout;
        let mut last_send = self.now();
        loop {
            self.pump(0.005)?;
            if !self.window.busy() && self.now() - last_send > 0.1 {
                self.window.queue(cmd.clone());
                last_send = self.now();
            }
            if let Some(i) = self.inbox.iter().position(|r| r.msg.name == response) {
                return Ok(self.inbox.remove(i).expect("index valid"));
            }
            if self.now() > deadline {
                return Err(McuError::Timeout(response.into(), timeout));
            }
        }
    }

    /// Writes, reads (waiting up to `timeout` s for input) and returns the messages received
    /// since the last call (clock answers are consumed here).
    pub fn poll(&mut self, timeout: f64) -> Result<Vec<Received>, McuError> {
        if self.clock.is_some() && self.now() >= self.next_clock_query {
            // A lost get_clock is not retried by itself: the next period asks again.
            let cmd = self.dict.encode("get_clock", &[])?;
            self.window.queue(cmd);
            self.clock_query_pending = true;
            self.next_clock_query = self.now() + self.opts.clock_interval;
        }
        self.pump(timeout)?;
        Ok(self.inbox.drain(..).collect())
    }

    fn pump(&mut self, timeout: f64) -> Result<(), McuError> {
        let now = self.now();
        let out = self.window.poll_output(now);
        if !out.is_empty() {
            self.write_all(&out)?;
        }
        let wait = match self.window.next_deadline() {
            Some(d) => (d - now).clamp(0.0, timeout),
            None => timeout,
        };
        let mut pfd = libc::pollfd { fd: self.fd.as_raw_fd(), events: libc::POLLIN, revents: 0 };
        // SAFETY: one valid pollfd.
        let r = unsafe { libc::poll(&mut pfd, 1, (wait * 1000.0).ceil() as i32) };
        if r > 0 && pfd.revents & libc::POLLIN != 0 {
            let mut buf = [0u8; 4096];
            // SAFETY: reading into our buffer.
            let n = unsafe { libc::read(self.fd.as_raw_fd(), buf.as_mut_ptr().cast(), buf.len()) };
            if n > 0 {
                let data = &buf[..n as usize];
                self.bytes_read += n as u64;
                if self.text.len() < 256 {
                    self.text.extend_from_slice(data);
                }
                let t = self.now();
                for b in self.parser.push(data) {
                    let advanced = self.window.on_block(b.seq, b.content.is_empty(), t);
                    if b.content.is_empty() {
                        continue;
                    }
                    let sent_time = if advanced { self.window.last_acked_sent_time } else { None };
                    match self.dict.decode_all(&b.content) {
                        Ok(msgs) => {
                            for msg in msgs {
                                if msg.name == "shutdown" || msg.name == "is_shutdown" {
                                    let reason = match msg.params.get("static_string_id") {
                                        Some(Value::Enum(s)) => s.clone(),
                                        Some(v) => format!("{v:?}"),
                                        None => "unknown".into(),
                                    };
                                    self.shutdown.get_or_insert(reason);
                                }
                                let r = Received { msg, receive_time: t, sent_time };
                                if r.msg.name == "clock" && self.clock.is_some() && self.clock_query_pending {
                                    self.on_clock(&r);
                                } else {
                                    self.inbox.push_back(r);
                                }
                            }
                        }
                        Err(_) => continue,
                    }
                }
            }
        }
        let now = self.now();
        let out = self.window.poll_output(now);
        if !out.is_empty() {
            self.write_all(&out)?;
        }
        Ok(())
    }

    fn write_all(&mut self, data: &[u8]) -> Result<(), McuError> {
        let mut off = 0;
        let deadline = self.now() + 1.0;
        while off < data.len() {
            // SAFETY: writing from our slice.
            let n = unsafe { libc::write(self.fd.as_raw_fd(), data[off..].as_ptr().cast(), data.len() - off) };
            if n < 0 {
                let e = std::io::Error::last_os_error();
                if e.kind() == std::io::ErrorKind::WouldBlock || e.kind() == std::io::ErrorKind::Interrupted {
                    if self.now() > deadline {
                        return Err(McuError::Io(e));
                    }
                    std::thread::sleep(Duration::from_micros(200));
                    continue;
                }
                return Err(McuError::Io(e));
            }
            off += n as usize;
        }
        Ok(())
    }

    /// The estimated MCU clock now (64-bit ticks).
    pub fn clock_now(&self) -> u64 {
        self.clock.as_ref().map(|c| c.clock_at(self.now()) as u64).unwrap_or(0)
    }

    /// The MCU clock frequency (nominal, from the dictionary), Hz.
    pub fn clock_freq(&self) -> f64 {
        self.clock.as_ref().map(|c| c.mcu_freq).unwrap_or(0.0)
    }

    /// Blocks retransmitted so far (count).
    pub fn retransmits(&self) -> u64 {
        self.window.retransmits
    }

    /// Whether everything sent has been acknowledged.
    pub fn idle(&self) -> bool {
        !self.window.busy()
    }
}

/// CRC-32 (IEEE, as zlib.crc32) of the configuration text, for finalize_config.
pub fn crc32(data: &[u8]) -> u32 {
    let mut crc = 0xffff_ffffu32;
    for &b in data {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 { (crc >> 1) ^ 0xedb8_8320 } else { crc >> 1 };
        }
    }
    !crc
}

#[cfg(test)]
mod tests {
    #[test]
    fn crc32_check_value() {
        assert_eq!(super::crc32(b"123456789"), 0xcbf4_3926);
    }
}
