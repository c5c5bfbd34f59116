//! A fake Klipper micro-controller on a pseudo-terminal, for tests without a board.
//!
//! Written from the public protocol description (Klipper's docs/Protocol.md, docs/MCU_Commands.md
//! and the firmware's command/stepper/pwm/adc behaviour), deliberately *not* from this crate's host
//! code: it has its own CRC, VLQ and block handling, so a misunderstanding shared by both sides
//! would have to be made twice. It runs in a thread and serves the slave side of a pty that the
//! host opens like a serial port.
//!
//! What it does: answers `identify` with its own zlib-compressed dictionary (ids deliberately
//! scrambled), keeps a simulated 32-bit clock that drifts from the host's and wraps during tests,
//! answers `get_clock`/`get_uptime`/`get_config`, accepts `allocate_oids`, `config_stepper`,
//! `config_pwm_out`, `config_analog_in`, `finalize_config`, executes `queue_step`,
//! `set_next_step_dir`, `reset_step_clock` into a recorded step list with the firmware's
//! arithmetic, drives a first-order hot-end model from `queue_pwm_out` and reports it through
//! `query_analog_in`/`analog_in_state` as a thermistor ADC would. It shuts down like the firmware:
//! "Timer too close" for an event scheduled in the past, "Missed scheduling of next hard pwm
//! event" when a heater is not refreshed within max_duration, "ADC out of range" past the host's
//! limits. It acks every block, NAKs out-of-order ones, and can inject faults.

use std::collections::{HashMap, VecDeque};
use std::ffi::CStr;
use std::io::Write;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Faults to inject, each every N-th occurrence (`0` = never).
#[derive(Debug, Clone, Copy, Default)]
pub struct Faults {
    /// Ignore every N-th valid block from the host, as if lost on the wire (no ack).
    pub drop_rx_every: u32,
    /// Flip a CRC byte of every N-th block sent to the host.
    pub corrupt_tx_every: u32,
    /// Write random garbage bytes before every N-th block sent to the host.
    pub garbage_tx_every: u32,
}

/// How the fake behaves on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Personality {
    /// A Klipper MCU.
    Klipper,
    /// Never answers (a board without firmware, or the wrong port).
    Silent,
    /// Answers every write with random binary bytes (wrong baud rate).
    Garbage,
    /// Answers like a G-code firmware (Marlin/RepRapFirmware: "start", "ok" lines).
    GcodeFirmware,
}

/// The fake's configuration.
#[derive(Debug, Clone)]
pub struct FakeConfig {
    /// Nominal clock frequency announced as CLOCK_FREQ, Hz.
    pub clock_freq: f64,
    /// True clock rate error relative to the host's monotonic clock, parts per million.
    pub drift_ppm: f64,
    /// The 32-bit clock's value when the fake starts, ticks (set near 2^32 to test wrapping).
    pub clock_start: u32,
    /// The MCU constant ("rp2040", "stm32f446xx", "atmega2560").
    pub mcu: String,
    /// Injected faults.
    pub faults: Faults,
    /// Wire behaviour.
    pub personality: Personality,
    /// Hot end: heater power at full duty, W.
    pub heater_power: f64,
    /// Hot end: heat capacity, J/K.
    pub heat_capacity: f64,
    /// Hot end: loss to ambient, W/K.
    pub heat_loss: f64,
    /// Thermistor's lag behind the block (first order), s.
    pub sensor_lag: f64,
    /// Ambient temperature, °C.
    pub ambient: f64,
    /// Thermistor model: resistance at 25 °C, Ω.
    pub thermistor_r25: f64,
    /// Thermistor model: beta, K.
    pub thermistor_beta: f64,
    /// Pull-up resistor of the ADC divider, Ω.
    pub pullup: f64,
}

impl Default for FakeConfig {
    fn default() -> Self {
        Self {
            clock_freq: 12_000_000.0,
            drift_ppm: 50.0,
            clock_start: 0xffff_ffff - 12_000_000, // wraps 1 s after start
            mcu: "rp2040".into(),
            faults: Faults::default(),
            personality: Personality::Klipper,
            heater_power: 40.0,
            heat_capacity: 0.5,
            heat_loss: 0.1,
            sensor_lag: 0.3,
            ambient: 25.0,
            thermistor_r25: 100_000.0,
            thermistor_beta: 3950.0,
            pullup: 4700.0,
        }
    }
}

/// One step the fake "took".
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RecordedStep {
    /// The step's time, MCU clock ticks since the fake's clock_start, extended to 64 bits.
    pub clock: u64,
    /// Direction pin level at that step (0 or 1).
    pub dir: u8,
}

/// What the fake observed; shared with the test.
#[derive(Debug, Default, Clone)]
pub struct FakeState {
    /// Steps per stepper oid.
    pub steps: HashMap<u8, Vec<RecordedStep>>,
    /// Shutdown reason, once shut down.
    pub shutdown: Option<String>,
    /// Hot-end block temperature, °C.
    pub block_temp: f64,
    /// Thermistor temperature, °C.
    pub sensor_temp: f64,
    /// Current heater duty, 0..=1.
    pub heater_duty: f64,
    /// Host blocks dropped by fault injection (count).
    pub dropped_rx: u64,
    /// Blocks corrupted by fault injection (count).
    pub corrupted_tx: u64,
    /// NAKs sent (count).
    pub naks: u64,
    /// Whether finalize_config was received.
    pub finalized: bool,
}

/// A running fake MCU; dropping it stops the thread.
#[derive(Debug)]
pub struct FakeMcu {
    /// The pty slave's path; open it as the serial port.
    pub path: PathBuf,
    /// Observed state.
    pub state: Arc<Mutex<FakeState>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    /// When the fake's clock was at `clock_start`, for converting recorded clocks to host time.
    pub epoch: Instant,
    /// The fake's true clock rate, ticks per host second.
    pub true_freq: f64,
}

impl Drop for FakeMcu {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl FakeMcu {
    /// Opens a pty and starts serving it.
    pub fn start(cfg: FakeConfig) -> std::io::Result<Self> {
        let mut master: libc::c_int = -1;
        let mut slave: libc::c_int = -1;
        let mut name = [0 as libc::c_char; 128];
        // SAFETY: openpty writes two fds and a NUL-terminated name into buffers we own; termios
        // and winsize may be null.
        let r = unsafe { libc::openpty(&mut master, &mut slave, name.as_mut_ptr(), std::ptr::null(), std::ptr::null()) };
        if r != 0 {
            return Err(std::io::Error::last_os_error());
        }
        // SAFETY: openpty returned two fresh fds that we now own.
        let master = unsafe { OwnedFd::from_raw_fd(master) };
        // SAFETY: as above.
        let slave = unsafe { OwnedFd::from_raw_fd(slave) };
        // SAFETY: name is NUL-terminated by openpty.
        let path = PathBuf::from(unsafe { CStr::from_ptr(name.as_ptr()) }.to_string_lossy().into_owned());
        // Raw mode on the slave so the line discipline passes bytes through untouched both ways.
        // SAFETY: termios is plain data; tcgetattr fills it.
        unsafe {
            let mut t: libc::termios = std::mem::zeroed();
            libc::tcgetattr(slave.as_raw_fd(), &mut t);
            libc::cfmakeraw(&mut t);
            libc::tcsetattr(slave.as_raw_fd(), libc::TCSANOW, &t);
        }
        let state = Arc::new(Mutex::new(FakeState { block_temp: cfg.ambient, sensor_temp: cfg.ambient, ..Default::default() }));
        let stop = Arc::new(AtomicBool::new(false));
        let epoch = Instant::now();
        let true_freq = cfg.clock_freq * (1.0 + cfg.drift_ppm * 1e-6);
        let (st, sp) = (state.clone(), stop.clone());
        let thread = std::thread::Builder::new().name("fake-mcu".into()).spawn(move || {
            // The slave stays open in this thread so the pty never hangs up between host
            // connections.
            let _slave = slave;
            let mut f = Fake::new(cfg, master, st, epoch);
            f.run(&sp);
        })?;
        Ok(Self { path, state, stop, thread: Some(thread), epoch, true_freq })
    }

    /// A copy of the observed state.
    pub fn snapshot(&self) -> FakeState {
        self.state.lock().expect("fake state").clone()
    }
}

// ---- the fake's own wire code (independent of crate::transport) ----

fn fake_crc(data: &[u8]) -> [u8; 2] {
    // CRC16-CCITT as Protocol.md specifies, bit-by-bit reflected form (poly 0x8408, init 0xffff).
    let mut crc: u16 = 0xffff;
    for &b in data {
        crc ^= u16::from(b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 { (crc >> 1) ^ 0x8408 } else { crc >> 1 };
        }
    }
    [(crc >> 8) as u8, crc as u8]
}

fn put_int(out: &mut Vec<u8>, v: u32) {
    // Protocol.md's VLQ: 7 bits a byte, high bit = more; the first byte's 0x60 bits sign-extend.
    let sv = v as i32;
    let n = if (-32..96).contains(&sv) {
        1
    } else if (-4096..12288).contains(&sv) {
        2
    } else if (-(1 << 19)..(3 << 19)).contains(&sv) {
        3
    } else if (-(1 << 26)..(3 << 26)).contains(&sv) {
        4
    } else {
        5
    };
    for i in (1..n).rev() {
        out.push(((v >> (7 * i)) & 0x7f) as u8 | 0x80);
    }
    out.push((v & 0x7f) as u8);
}

fn get_int(buf: &[u8], pos: &mut usize) -> Option<u32> {
    let first = *buf.get(*pos)?;
    *pos += 1;
    let mut v: u32 = if first & 0x60 == 0x60 { 0xffff_ffe0 | u32::from(first & 0x1f) } else { u32::from(first & 0x7f) };
    let mut c = first;
    let mut n = 0;
    while c & 0x80 != 0 && n < 4 {
        c = *buf.get(*pos)?;
        *pos += 1;
        n += 1;
        v = (v << 7) | u32::from(c & 0x7f);
    }
    Some(v)
}

/// The fake's commands and responses; ids are scrambled on purpose.
const COMMANDS: &[(&str, u32)] = &[
    ("identify offset=%u count=%c", 1),
    ("get_uptime", 17),
    ("get_clock", 9),
    ("get_config", 33),
    ("allocate_oids count=%c", 41),
    ("finalize_config crc=%u", 12),
    ("emergency_stop", 55),
    ("clear_shutdown", 56),
    ("config_stepper oid=%c step_pin=%c dir_pin=%c invert_step=%c step_pulse_ticks=%u", 70),
    ("queue_step oid=%c interval=%u count=%hu add=%hi", 130),
    ("set_next_step_dir oid=%c dir=%c", 131),
    ("reset_step_clock oid=%c clock=%u", 132),
    ("stepper_get_position oid=%c", 133),
    ("config_pwm_out oid=%c pin=%u cycle_ticks=%u value=%hu default_value=%hu max_duration=%u", 90),
    ("queue_pwm_out oid=%c clock=%u value=%hu", 91),
    ("config_analog_in oid=%c pin=%u", 95),
    ("config_digital_out oid=%c pin=%u value=%c default_value=%c max_duration=%u", 97),
    (
        "query_analog_in oid=%c clock=%u sample_ticks=%u sample_count=%c rest_ticks=%u bytes_per_report=%c min_value=%hu max_value=%hu range_check_count=%c",
        96,
    ),
];

const RESPONSES: &[(&str, u32)] = &[
    ("identify_response offset=%u data=%.*s", 0),
    ("uptime high=%u clock=%u", 80),
    ("clock clock=%u", 81),
    ("config is_config=%c crc=%u is_shutdown=%c move_count=%hu", 83),
    ("shutdown clock=%u static_string_id=%hu", 84),
    ("is_shutdown static_string_id=%hu", 85),
    ("stepper_position oid=%c pos=%i", 86),
    ("analog_in_state oid=%c next_clock=%u values=%*s", 87),
    ("starting", 88),
];

/// Commands still accepted in shutdown (the firmware's HF_IN_SHUTDOWN).
const IN_SHUTDOWN: &[&str] = &["identify", "get_uptime", "get_clock", "get_config", "emergency_stop", "clear_shutdown"];

const STATIC_STRINGS: &[&str] = &[
    "Timer too close",
    "Missed scheduling of next hard pwm event",
    "Scheduled pwm event will exceed max_duration",
    "ADC out of range",
    "Invalid count parameter",
    "Can't reset time when stepper active",
    "Move queue overflow",
    "Command request",
    "oids already allocated",
    "Invalid oid type",
];
const STATIC_STRING_MIN: usize = 2;
const MOVE_COUNT: usize = 1024;

fn dictionary_bytes(cfg: &FakeConfig) -> Vec<u8> {
    let cmds: serde_json::Map<String, serde_json::Value> = COMMANDS.iter().map(|(f, i)| (f.to_string(), (*i).into())).collect();
    let resps: serde_json::Map<String, serde_json::Value> = RESPONSES.iter().map(|(f, i)| (f.to_string(), (*i).into())).collect();
    let statics: serde_json::Map<String, serde_json::Value> =
        STATIC_STRINGS.iter().enumerate().map(|(i, s)| (s.to_string(), (i + STATIC_STRING_MIN).into())).collect();
    let json = serde_json::json!({
        "app": "Klipper",
        "version": "v0.12.0-fake-strand",
        "build_versions": "fake",
        "license": "GNU GPLv3",
        "commands": cmds,
        "responses": resps,
        "output": {},
        "enumerations": {
            "pin": {"PA0": [0, 16], "PB0": [16, 16], "PC0": [32, 16], "gpio0": [64, 30]},
            "static_string_id": statics,
        },
        "config": {
            "CLOCK_FREQ": cfg.clock_freq as u64,
            "MCU": cfg.mcu,
            "ADC_MAX": 4095,
            "PWM_MAX": 255,
            "RECEIVE_WINDOW": 192,
            "STEPPER_STEP_BOTH_EDGE": 1,
            "STATS_SUMSQ_BASE": 256,
        },
    });
    let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::best());
    z.write_all(json.to_string().as_bytes()).expect("in-memory write");
    z.finish().expect("in-memory write")
}

#[derive(Debug, Default)]
struct Stepper {
    next_step_time: u32,
    last_step: u64,
    dir: u8,
    next_dir: u8,
    queued_until: u64,
}

#[derive(Debug)]
struct Pwm {
    max_duration: u32,
    default_value: u16,
    value: u16,
    queue: VecDeque<(u64, u16)>,
    /// 64-bit clock by which a new value must arrive (max_duration after a non-default value).
    deadline: Option<u64>,
}

#[derive(Debug)]
struct Adc {
    next: u64,
    sample_count: u32,
    rest_ticks: u32,
    min_value: u16,
    max_value: u16,
    range_check_count: u8,
    invalid: u8,
    bytes_per_report: u8,
    data: Vec<u8>,
}

struct Fake {
    cfg: FakeConfig,
    fd: OwnedFd,
    state: Arc<Mutex<FakeState>>,
    epoch: Instant,
    true_freq: f64,
    dict: Vec<u8>,
    ids: HashMap<u32, &'static str>,
    resp_ids: HashMap<&'static str, u32>,
    rx: Vec<u8>,
    next_seq: u8,
    need_sync: bool,
    rx_blocks: u32,
    tx_blocks: u32,
    rng: u64,
    shutdown: Option<usize>,
    oid_count: Option<u8>,
    config_crc: Option<u32>,
    steppers: HashMap<u8, Stepper>,
    pwms: HashMap<u8, Pwm>,
    adcs: HashMap<u8, Adc>,
    adc_pending: HashMap<u8, ()>,
    last_model: f64,
    /// End clocks of queued moves (steps and pwm updates) not yet executed: the firmware's shared
    /// move pool of MOVE_COUNT entries.
    moves: Vec<u64>,
}

impl Fake {
    fn new(cfg: FakeConfig, fd: OwnedFd, state: Arc<Mutex<FakeState>>, epoch: Instant) -> Self {
        let dict = dictionary_bytes(&cfg);
        let true_freq = cfg.clock_freq * (1.0 + cfg.drift_ppm * 1e-6);
        Self {
            ids: COMMANDS.iter().map(|(f, i)| (*i, *f)).collect(),
            resp_ids: RESPONSES.iter().map(|(f, i)| (f.split(' ').next().unwrap_or(""), *i)).collect(),
            cfg,
            fd,
            state,
            epoch,
            true_freq,
            dict,
            rx: Vec::new(),
            next_seq: 0,
            need_sync: false,
            rx_blocks: 0,
            tx_blocks: 0,
            rng: 0x9e37_79b9_7f4a_7c15,
            shutdown: None,
            oid_count: None,
            config_crc: None,
            steppers: HashMap::new(),
            pwms: HashMap::new(),
            adcs: HashMap::new(),
            adc_pending: HashMap::new(),
            last_model: 0.0,
            moves: Vec::new(),
        }
    }

    fn rand(&mut self) -> u64 {
        self.rng ^= self.rng << 13;
        self.rng ^= self.rng >> 7;
        self.rng ^= self.rng << 17;
        self.rng
    }

    /// Ticks since clock_start (64-bit, never wraps).
    fn now64(&self) -> u64 {
        (self.epoch.elapsed().as_secs_f64() * self.true_freq) as u64
    }

    fn to32(&self, c: u64) -> u32 {
        (c as u32).wrapping_add(self.cfg.clock_start)
    }

    /// Extends a 32-bit clock from the host to 64 bits near now (±2^31 ticks).
    fn to64(&self, c: u32) -> u64 {
        let now = self.now64();
        let diff = c.wrapping_sub(self.to32(now)) as i32;
        (now as i64 + i64::from(diff)).max(0) as u64
    }

    fn run(&mut self, stop: &AtomicBool) {
        let mut buf = [0u8; 4096];
        while !stop.load(Ordering::Relaxed) {
            let mut pfd = libc::pollfd { fd: self.fd.as_raw_fd(), events: libc::POLLIN, revents: 0 };
            // SAFETY: one valid pollfd.
            let r = unsafe { libc::poll(&mut pfd, 1, 1) };
            if r > 0 && pfd.revents & libc::POLLIN != 0 {
                // SAFETY: reading into a buffer we own.
                let n = unsafe { libc::read(self.fd.as_raw_fd(), buf.as_mut_ptr().cast(), buf.len()) };
                if n > 0 {
                    let data = buf[..n as usize].to_vec();
                    self.on_bytes(&data);
                }
            } else if r > 0 && pfd.revents & (libc::POLLHUP | libc::POLLERR) != 0 {
                std::thread::sleep(Duration::from_millis(1));
            }
            self.tick();
        }
    }

    fn write_raw(&self, data: &[u8]) {
        let mut off = 0;
        while off < data.len() {
            // SAFETY: writing from a slice we own.
            let n = unsafe { libc::write(self.fd.as_raw_fd(), data[off..].as_ptr().cast(), data.len() - off) };
            if n <= 0 {
                let e = std::io::Error::last_os_error();
                if e.kind() == std::io::ErrorKind::WouldBlock || e.kind() == std::io::ErrorKind::Interrupted {
                    std::thread::sleep(Duration::from_micros(200));
                    continue;
                }
                return;
            }
            off += n as usize;
        }
    }

    fn send_block(&mut self, content: &[u8]) {
        self.tx_blocks += 1;
        let f = self.cfg.faults;
        let mut out = Vec::new();
        if f.garbage_tx_every > 0 && self.tx_blocks.is_multiple_of(f.garbage_tx_every) {
            for _ in 0..(self.rand() % 10 + 1) {
                let b = self.rand() as u8;
                out.push(if b == 0x7e { 0 } else { b });
            }
            // Real firmware would not send a sync here; a host must resync on the next block's
            // end. We add none, so the garbage merges with the block and both are lost.
        }
        let mut block = vec![(content.len() + 5) as u8, 0x10 | self.next_seq];
        block.extend_from_slice(content);
        let crc = fake_crc(&block);
        block.extend_from_slice(&crc);
        block.push(0x7e);
        if f.corrupt_tx_every > 0 && self.tx_blocks.is_multiple_of(f.corrupt_tx_every) {
            let i = block.len() - 2;
            block[i] ^= 0x5a;
            self.state.lock().expect("fake state").corrupted_tx += 1;
        }
        out.extend_from_slice(&block);
        self.write_raw(&out);
    }

    fn respond(&mut self, name: &str, args: &[u32], data: Option<&[u8]>) {
        let Some(&id) = self.resp_ids.get(name) else { return };
        let mut c = Vec::new();
        put_int(&mut c, id);
        for &a in args {
            put_int(&mut c, a);
        }
        if let Some(d) = data {
            c.push(d.len() as u8);
            c.extend_from_slice(d);
        }
        self.send_block(&c);
    }

    fn on_bytes(&mut self, data: &[u8]) {
        match self.cfg.personality {
            Personality::Klipper => {}
            Personality::Silent => return,
            Personality::Garbage => {
                let g: Vec<u8> = (0..data.len().max(8)).map(|_| self.rand() as u8).collect();
                self.write_raw(&g);
                return;
            }
            Personality::GcodeFirmware => {
                self.write_raw(b"start\necho:Unknown command: \"\x07\"\nok\n");
                return;
            }
        }
        self.rx.extend_from_slice(data);
        loop {
            if self.rx.is_empty() {
                return;
            }
            if self.need_sync {
                match self.rx.iter().position(|&b| b == 0x7e) {
                    Some(i) => {
                        self.rx.drain(..=i);
                        self.need_sync = false;
                        continue;
                    }
                    None => {
                        self.rx.clear();
                        return;
                    }
                }
            }
            let len = self.rx[0] as usize;
            let bad = !(5..=64).contains(&len) || (self.rx.len() > 1 && self.rx[1] & 0xf0 != 0x10);
            if !bad && self.rx.len() < len {
                return;
            }
            let good = !bad && self.rx[len - 1] == 0x7e && fake_crc(&self.rx[..len - 3]) == [self.rx[len - 3], self.rx[len - 2]];
            if !good {
                if self.rx[0] == 0x7e {
                    self.rx.remove(0);
                } else {
                    self.need_sync = true;
                    self.nak();
                }
                continue;
            }
            let block: Vec<u8> = self.rx.drain(..len).collect();
            self.rx_blocks += 1;
            let f = self.cfg.faults;
            if f.drop_rx_every > 0 && self.rx_blocks.is_multiple_of(f.drop_rx_every) {
                self.state.lock().expect("fake state").dropped_rx += 1;
                continue;
            }
            let seq = block[1] & 0x0f;
            if seq != self.next_seq {
                self.nak();
                continue;
            }
            self.next_seq = (self.next_seq + 1) & 0x0f;
            self.dispatch(&block[2..len - 3]);
            self.send_block(&[]);
        }
    }

    fn nak(&mut self) {
        self.state.lock().expect("fake state").naks += 1;
        self.send_block(&[]);
    }

    fn dispatch(&mut self, mut content: &[u8]) {
        while !content.is_empty() {
            let mut pos = 0;
            let Some(id) = get_int(content, &mut pos) else { return };
            let Some(&fmt) = self.ids.get(&id) else { return };
            let mut args = Vec::new();
            for p in fmt.split(' ').skip(1) {
                if p.ends_with("%*s") || p.ends_with("%.*s") || p.ends_with("%s") {
                    let l = content.get(pos).copied().unwrap_or(0) as usize;
                    pos += 1 + l;
                    args.push(0);
                } else {
                    let Some(v) = get_int(content, &mut pos) else { return };
                    args.push(v);
                }
            }
            content = content.get(pos..).unwrap_or(&[]);
            let name = fmt.split(' ').next().unwrap_or("");
            if let Some(reason) = self.shutdown
                && !IN_SHUTDOWN.contains(&name)
            {
                self.respond("is_shutdown", &[(reason + STATIC_STRING_MIN) as u32], None);
                continue;
            }
            self.command(name, &args);
        }
    }

    fn do_shutdown(&mut self, reason: &str) {
        if self.shutdown.is_some() {
            return;
        }
        let idx = STATIC_STRINGS.iter().position(|s| *s == reason).unwrap_or(0);
        self.shutdown = Some(idx);
        for p in self.pwms.values_mut() {
            p.value = 0;
            p.queue.clear();
            p.deadline = None;
        }
        self.adcs.clear();
        {
            let mut st = self.state.lock().expect("fake state");
            st.shutdown = Some(reason.to_string());
            st.heater_duty = 0.0;
        }
        let now = self.to32(self.now64());
        self.respond("shutdown", &[now, (idx + STATIC_STRING_MIN) as u32], None);
    }

    /// Takes one entry of the move pool until `end`; false (after shutting down) when full.
    fn alloc_move(&mut self, now: u64, end: u64) -> bool {
        self.moves.retain(|&e| e > now);
        if self.moves.len() >= MOVE_COUNT {
            self.do_shutdown("Move queue overflow");
            return false;
        }
        self.moves.push(end);
        true
    }

    fn command(&mut self, name: &str, a: &[u32]) {
        let now = self.now64();
        match name {
            "identify" => {
                let off = a[0] as usize;
                let count = (a[1] as usize).min(40);
                let end = (off + count).min(self.dict.len());
                let chunk = self.dict.get(off.min(end)..end).unwrap_or(&[]).to_vec();
                self.respond("identify_response", &[a[0]], Some(&chunk));
            }
            "get_uptime" => {
                let c = (now + u64::from(self.cfg.clock_start)) as u128;
                self.respond("uptime", &[(c >> 32) as u32, c as u32], None);
            }
            "get_clock" => {
                let c = self.to32(now);
                self.respond("clock", &[c], None);
            }
            "get_config" => {
                let sd = u32::from(self.shutdown.is_some());
                let (isc, crc) = match self.config_crc {
                    Some(c) => (1, c),
                    None => (0, 0),
                };
                self.respond("config", &[isc, crc, sd, MOVE_COUNT as u32], None);
            }
            "allocate_oids" => {
                if self.oid_count.is_some() {
                    self.do_shutdown("oids already allocated");
                }
                self.oid_count = Some(a[0] as u8);
            }
            "finalize_config" => {
                self.config_crc = Some(a[0]);
                self.state.lock().expect("fake state").finalized = true;
            }
            "emergency_stop" => self.do_shutdown("Command request"),
            "clear_shutdown" => {
                self.shutdown = None;
                self.state.lock().expect("fake state").shutdown = None;
            }
            "config_stepper" => {
                self.steppers.insert(a[0] as u8, Stepper::default());
            }
            "config_pwm_out" => {
                self.pwms.insert(
                    a[0] as u8,
                    Pwm { max_duration: a[5], default_value: a[4] as u16, value: a[3] as u16, queue: VecDeque::new(), deadline: None },
                );
            }
            "config_analog_in" => {
                self.adc_pending.insert(a[0] as u8, ());
            }
            "query_analog_in" => {
                let oid = a[0] as u8;
                if !self.adc_pending.contains_key(&oid) {
                    return self.do_shutdown("Invalid oid type");
                }
                let t = self.to64(a[1]);
                if t < now {
                    return self.do_shutdown("Timer too close");
                }
                self.adcs.insert(
                    oid,
                    Adc {
                        next: t + u64::from(a[2]) * u64::from(a[3]),
                        sample_count: a[3],
                        rest_ticks: a[4],
                        bytes_per_report: a[5] as u8,
                        min_value: a[6] as u16,
                        max_value: a[7] as u16,
                        range_check_count: a[8] as u8,
                        invalid: 0,
                        data: Vec::new(),
                    },
                );
            }
            "queue_pwm_out" => {
                let oid = a[0] as u8;
                let t = self.to64(a[1]);
                let Some(p) = self.pwms.get_mut(&oid) else {
                    return self.do_shutdown("Invalid oid type");
                };
                if p.queue.is_empty() {
                    if let Some(d) = p.deadline
                        && d < t
                    {
                        return self.do_shutdown("Scheduled pwm event will exceed max_duration");
                    }
                    if t < now {
                        return self.do_shutdown("Timer too close");
                    }
                }
                p.queue.push_back((t, a[2] as u16));
                self.alloc_move(now, t);
            }
            "set_next_step_dir" => {
                if let Some(s) = self.steppers.get_mut(&(a[0] as u8)) {
                    s.next_dir = a[1] as u8;
                }
            }
            "reset_step_clock" => {
                let t = self.to64(a[1]);
                if let Some(s) = self.steppers.get_mut(&(a[0] as u8)) {
                    if s.queued_until > now {
                        return self.do_shutdown("Can't reset time when stepper active");
                    }
                    s.next_step_time = a[1];
                    s.last_step = t;
                }
            }
            "queue_step" => self.queue_step(now, a),
            "stepper_get_position" => {}
            _ => {}
        }
    }

    /// The firmware's arithmetic: the first step at next_step_time + interval, then the interval
    /// grows by add after each step (32-bit wrapping clock, 16-bit signed add).
    fn queue_step(&mut self, now: u64, a: &[u32]) {
        let oid = a[0] as u8;
        let (interval, count, add) = (a[1], a[2] as u16, a[3] as u16 as i16);
        if count == 0 {
            return self.do_shutdown("Invalid count parameter");
        }
        let start = self.to32(0);
        let Some(s) = self.steppers.get_mut(&oid) else {
            return self.do_shutdown("Invalid oid type");
        };
        let idle = s.queued_until <= now;
        let mut t32 = s.next_step_time;
        let mut iv = interval;
        let mut steps = Vec::with_capacity(count as usize);
        let mut t64 = s.last_step;
        for _ in 0..count {
            let nt = t32.wrapping_add(iv);
            t64 = t64.wrapping_add(u64::from(nt.wrapping_sub(t32)));
            t32 = nt;
            iv = iv.wrapping_add(add as i32 as u32);
            steps.push(t64);
        }
        if idle && steps[0] < now {
            return self.do_shutdown("Timer too close");
        }
        let end = *steps.last().expect("count > 0");
        if s.next_dir != s.dir {
            s.dir = s.next_dir;
        }
        let dir = s.dir;
        s.next_step_time = t32;
        s.last_step = t64;
        s.queued_until = t64;
        let _ = start;
        if !self.alloc_move(now, end) {
            return;
        }
        let mut st = self.state.lock().expect("fake state");
        let rec = st.steps.entry(oid).or_default();
        rec.extend(steps.into_iter().map(|clock| RecordedStep { clock, dir }));
    }

    fn tick(&mut self) {
        let now = self.now64();
        let t = now as f64 / self.true_freq;
        // Hot-end model: first order block, first order sensor lag.
        let dt = (t - self.last_model).clamp(0.0, 0.05);
        self.last_model = t;
        let mut duty = 0.0;
        let mut expired = false;
        for p in self.pwms.values_mut() {
            while let Some(&(when, v)) = p.queue.front() {
                if when > now {
                    break;
                }
                p.queue.pop_front();
                p.value = v;
                p.deadline = if v != p.default_value && p.max_duration > 0 { Some(when + u64::from(p.max_duration)) } else { None };
            }
            if p.queue.is_empty()
                && let Some(d) = p.deadline
                && now > d
            {
                expired = true;
            }
            duty = f64::from(p.value) / 255.0;
        }
        if expired {
            self.do_shutdown("Missed scheduling of next hard pwm event");
            duty = 0.0;
        }
        let (block, sensor) = {
            let mut st = self.state.lock().expect("fake state");
            let c = &self.cfg;
            let dtemp = (duty * c.heater_power - c.heat_loss * (st.block_temp - c.ambient)) / c.heat_capacity;
            st.block_temp += dtemp * dt;
            st.sensor_temp += (st.block_temp - st.sensor_temp) * (dt / c.sensor_lag.max(1e-3)).min(1.0);
            st.heater_duty = duty;
            (st.block_temp, st.sensor_temp)
        };
        let _ = block;
        // ADC reports.
        let adc = self.adc_value(sensor);
        let mut reports = Vec::new();
        let mut out_of_range = false;
        for (&oid, a) in self.adcs.iter_mut() {
            if now < a.next {
                continue;
            }
            let value = (adc * a.sample_count).min(u32::from(u16::MAX)) as u16;
            if value < a.min_value || value > a.max_value {
                a.invalid = a.invalid.saturating_add(1);
                if a.invalid >= a.range_check_count.max(1) {
                    out_of_range = true;
                }
            } else {
                a.invalid = 0;
            }
            let next = a.next + u64::from(a.rest_ticks);
            a.data.extend_from_slice(&value.to_le_bytes());
            if a.data.len() + 2 > usize::from(a.bytes_per_report.max(2)) {
                reports.push((oid, next, std::mem::take(&mut a.data)));
            }
            a.next = next;
        }
        for (oid, next, data) in reports {
            let n = self.to32(next);
            self.respond("analog_in_state", &[u32::from(oid), n], Some(&data));
        }
        if out_of_range {
            self.do_shutdown("ADC out of range");
        }
    }

    /// One ADC sample (0..=4095) of the thermistor divider at `temp` °C.
    fn adc_value(&self, temp: f64) -> u32 {
        let c = &self.cfg;
        let tk = temp + 273.15;
        let r = c.thermistor_r25 * (c.thermistor_beta * (1.0 / tk - 1.0 / 298.15)).exp();
        let frac = r / (r + c.pullup);
        (frac * 4095.0).round().clamp(0.0, 4095.0) as u32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fake_crc_equals_transport_crc() {
        // The two CRC implementations were written independently (byte-wise and bit-wise).
        let mut s = 1u32;
        for n in 0..200 {
            let data: Vec<u8> = (0..n % 64)
                .map(|_| {
                    s = s.wrapping_mul(1_103_515_245).wrapping_add(12345);
                    (s >> 16) as u8
                })
                .collect();
            let c = crate::transport::crc16_ccitt(&data);
            assert_eq!(fake_crc(&data), [(c >> 8) as u8, c as u8]);
        }
    }

    #[test]
    fn fake_vlq_equals_transport_vlq() {
        for v in [
            0u32,
            1,
            95,
            96,
            4095,
            12287,
            12288,
            1 << 20,
            0xbff_ffff,
            0xc00_0000,
            u32::MAX,
            0x8000_0000,
            (-33i32) as u32,
            (-4097i32) as u32,
        ] {
            let mut a = Vec::new();
            let mut b = Vec::new();
            put_int(&mut a, v);
            crate::transport::encode_vlq(&mut b, v);
            assert_eq!(a, b, "{v:#x}");
            let mut pos = 0;
            assert_eq!(get_int(&a, &mut pos), Some(v));
        }
    }
}
