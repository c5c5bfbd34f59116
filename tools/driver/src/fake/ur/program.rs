//! The URScript program: the primary port's scripts, the `def` program parsed out of one, and the
//! program running the reverse interface's loop (§2.7) it connects back with.

use std::io::Read;
use std::net::{Shutdown, TcpStream, ToSocketAddrs};
use std::os::fd::AsRawFd;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use strand::io::clock::monotonic_ns;

use super::controller::{Motion, State};
use super::{
    JOINT_IGNORE_SPEED, JOINTS, MODE_IDLE, MODE_SERVOJ, MODE_STOPPED, MODE_UNINITIALIZED, MULT_JOINTSTATE, RUNTIME_PLAYING, SAFETY_NORMAL,
    SLICE_NS, Shared, readable,
};

/// Silence that ends a script on the primary port (ns).
const SCRIPT_IDLE_NS: u64 = 100_000_000;
/// The longest script kept (bytes); more is dropped as garbage.
const MAX_SCRIPT_LEN: usize = 1 << 20;
/// The program's attempts to connect back, and the wait between them (s, §2.1).
const CONNECT_ATTEMPTS: u32 = 5;
const CONNECT_RETRY: f64 = 0.2;

impl State {
    /// A script received on the primary port.
    fn script(&mut self, s: &Arc<Shared>, text: String) {
        let program = parse_program(&text);
        self.report.scripts.push(text);
        let program = match program {
            Program::None => return,
            Program::Malformed => return self.report.garbage += 1,
            Program::Def(p) => p,
        };
        if self.program_running {
            self.end_program();
        }
        if self.safety_mode != SAFETY_NORMAL && self.safety_mode != 2 {
            // A controller in a protective stop runs no program.
            return;
        }
        let Some((host, port)) = program.reverse else { return };
        self.program_gen += 1;
        self.program_running = true;
        self.runtime_state = RUNTIME_PLAYING;
        self.control_mode = MODE_UNINITIALIZED;
        self.servo_args = Some((program.lookahead_time, program.gain));
        let generation = self.program_gen;
        let s2 = s.clone();
        match std::thread::Builder::new().name("fake-ur-program".into()).spawn(move || run_program(&s2, generation, &host, port)) {
            Ok(h) => s.threads.lock().unwrap_or_else(|e| e.into_inner()).push(h),
            Err(_) => self.end_program(),
        }
    }

    /// One 8 × i32 message of program `generation`; false when it ends the program.
    pub(super) fn reverse_message(&mut self, f: [i32; 8], timeout_ms: &mut i32) -> bool {
        if f[0] < 0 {
            self.report.garbage += 1;
            return true;
        }
        match f[7] {
            MODE_STOPPED => {
                self.report.clean_stops += 1;
                self.end_program();
                return false;
            }
            MODE_SERVOJ => {
                if self.control_mode != MODE_SERVOJ {
                    // A new mode starts from the actual joints (§2.4).
                    self.control_mode = MODE_SERVOJ;
                    self.target = self.q;
                    self.motion = Motion::Servo;
                }
                let mut q = [0.0; JOINTS];
                for (j, v) in q.iter_mut().enumerate() {
                    *v = f64::from(f[j + 1]) / MULT_JOINTSTATE;
                }
                let dt = self.opts.step;
                if q.iter().zip(&self.target).any(|(n, c)| (n - c).abs() / dt > JOINT_IGNORE_SPEED) {
                    self.report.violations += 1;
                } else {
                    self.target = q;
                    self.fresh = true;
                }
                self.motion = Motion::Servo;
            }
            MODE_IDLE => {
                if self.control_mode != MODE_IDLE {
                    self.control_mode = MODE_IDLE;
                    self.stop_arm();
                }
            }
            _ => {
                self.report.garbage += 1;
                return true;
            }
        }
        *timeout_ms = f[0];
        true
    }
}

/// What a script holds.
pub(super) enum Program {
    /// No `def` program (a `sec` program or single statements): stored only.
    None,
    /// A `def` without its `end` or the final newline.
    Malformed,
    Def(ProgramInfo),
}

pub(super) struct ProgramInfo {
    pub(super) reverse: Option<(String, u16)>,
    pub(super) lookahead_time: Option<f64>,
    pub(super) gain: Option<f64>,
}

/// A line without its comment (`#` outside a string).
fn code_of(line: &str) -> &str {
    let mut quoted = false;
    for (i, c) in line.char_indices() {
        match c {
            '"' => quoted = !quoted,
            '#' if !quoted => return &line[..i],
            _ => {}
        }
    }
    line
}

pub(super) fn parse_program(text: &str) -> Program {
    let lines: Vec<&str> = text.lines().map(code_of).collect();
    let Some(def) = lines.iter().position(|l| {
        let t = l.trim();
        t.starts_with("def ") && t.ends_with(':')
    }) else {
        return Program::None;
    };
    if !text.ends_with('\n') || !lines[def + 1..].iter().any(|l| l.trim() == "end") {
        return Program::Malformed;
    }
    let code = lines.join("\n");
    let reverse = lines.iter().enumerate().find_map(|(i, l)| {
        let at = l.find("socket_open(")?;
        Some(socket_target(&l[at + "socket_open(".len()..], &lines[..i]))
    });
    Program::Def(ProgramInfo {
        reverse: reverse.flatten(),
        lookahead_time: number_after(&code, "lookahead_time"),
        gain: number_after(&code, "gain"),
    })
}

/// HOST and PORT of `socket_open(` arguments: literals, or names assigned a literal earlier.
fn socket_target(args: &str, before: &[&str]) -> Option<(String, u16)> {
    let mut parts = Vec::new();
    let (mut cur, mut quoted) = (String::new(), false);
    for c in args.chars() {
        match c {
            '"' => {
                quoted = !quoted;
                cur.push(c);
            }
            ',' | ')' if !quoted => {
                parts.push(cur.trim().to_string());
                cur.clear();
                if c == ')' || parts.len() == 2 {
                    break;
                }
            }
            _ => cur.push(c),
        }
    }
    let resolve = |arg: &str| -> Option<String> {
        if arg.starts_with('"') || arg.parse::<u16>().is_ok() {
            return Some(arg.to_string());
        }
        // The last assignment `name = literal` before the call.
        before.iter().rev().find_map(|l| {
            let t = l.trim();
            let t = t.strip_prefix("global ").or_else(|| t.strip_prefix("local ")).unwrap_or(t);
            let (lhs, rhs) = t.split_once('=')?;
            (lhs.trim() == arg && !rhs.starts_with('=')).then(|| rhs.trim().to_string())
        })
    };
    let host = resolve(parts.first()?)?;
    let host = host.strip_prefix('"')?.strip_suffix('"')?.to_string();
    let port = resolve(parts.get(1)?)?.parse::<u16>().ok()?;
    Some((host, port))
}

/// The number after the first `key=` (spaces allowed around `=`), `key` not part of a longer name.
fn number_after(code: &str, key: &str) -> Option<f64> {
    let mut from = 0;
    while let Some(at) = code[from..].find(key).map(|a| a + from) {
        from = at + key.len();
        let before_ok = code[..at].chars().next_back().is_none_or(|c| !(c.is_alphanumeric() || c == '_'));
        let rest = code[from..].trim_start();
        if before_ok && let Some(rest) = rest.strip_prefix('=') {
            let rest = rest.trim_start();
            let end = rest.find(|c: char| !(c.is_ascii_digit() || matches!(c, '.' | 'e' | 'E' | '+' | '-'))).unwrap_or(rest.len());
            if let Ok(v) = rest[..end].parse() {
                return Some(v);
            }
        }
    }
    None
}

/// A primary-port connection: each stretch of text up to 100 ms of silence or the close is a script.
pub(super) fn read_scripts(s: &Arc<Shared>, mut stream: TcpStream) {
    let fd = stream.as_raw_fd();
    let mut text: Vec<u8> = Vec::new();
    let mut buf = [0u8; 4096];
    let mut last = monotonic_ns();
    let mut overflow = false;
    let mut open = true;
    while open && !s.stop.load(Ordering::Relaxed) {
        let idle = last + SCRIPT_IDLE_NS;
        let now = monotonic_ns();
        let mut done = now >= idle;
        if !done && readable(fd, (idle - now).min(SLICE_NS)) {
            match stream.read(&mut buf) {
                Ok(0) => (done, open) = (true, false),
                Ok(n) => {
                    last = monotonic_ns();
                    if text.len() + n > MAX_SCRIPT_LEN {
                        overflow = true;
                    } else {
                        text.extend_from_slice(&buf[..n]);
                    }
                }
                Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::Interrupted) => {}
                Err(_) => (done, open) = (true, false),
            }
        }
        if done {
            if overflow {
                s.lock().report.garbage += 1;
            } else if !text.is_empty() {
                let t = String::from_utf8_lossy(&text).into_owned();
                s.lock().script(s, t);
            }
            text.clear();
            overflow = false;
            last = monotonic_ns();
        }
    }
    let _ = stream.shutdown(Shutdown::Both);
}

/// The program's reverse-interface side: connect back, then the §2.7 loop.
fn run_program(s: &Shared, generation: u64, host: &str, port: u16) {
    let ended = |s: &Shared| s.stop.load(Ordering::Relaxed) || s.lock().program_gen != generation;
    let retry = Duration::from_secs_f64(CONNECT_RETRY);
    let mut stream = None;
    'attempts: for attempt in 0..CONNECT_ATTEMPTS {
        if ended(s) {
            return;
        }
        if attempt > 0 {
            std::thread::sleep(retry);
        }
        for addr in (host, port).to_socket_addrs().into_iter().flatten() {
            if let Ok(c) = TcpStream::connect_timeout(&addr, retry) {
                stream = Some(c);
                break 'attempts;
            }
        }
    }
    let Some(mut stream) = stream else {
        let mut st = s.lock();
        if st.program_gen == generation {
            st.end_program();
        }
        return;
    };
    let _ = stream.set_nodelay(true);
    {
        let mut st = s.lock();
        if st.program_gen != generation {
            return;
        }
        st.reverse = stream.try_clone().ok();
    }
    let fd = stream.as_raw_fd();
    let step_ns = (s.lock().opts.step * 1e9).round().max(1.0) as u64;
    let t0 = s.lock().t0;
    let mut timeout_ms: i32 = 0; // the first read blocks
    loop {
        let start = monotonic_ns();
        let deadline = (timeout_ms > 0).then(|| {
            // The first controller step at or after the timeout.
            let d = start + timeout_ms as u64 * 1_000_000 - t0;
            t0 + d.div_ceil(step_ns) * step_ns
        });
        let mut msg = [0u8; 32];
        let mut have = 0;
        let complete = loop {
            if ended(s) {
                return;
            }
            let now = monotonic_ns();
            let wait = match deadline {
                Some(d) if now >= d => break false,
                Some(d) => (d - now).min(SLICE_NS),
                None => SLICE_NS,
            };
            if !readable(fd, wait) {
                continue;
            }
            match stream.read(&mut msg[have..]) {
                Ok(0) => break false,
                Ok(n) => {
                    have += n;
                    if have == msg.len() {
                        break true;
                    }
                }
                Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::Interrupted) => {}
                Err(_) => break false,
            }
        };
        let mut st = s.lock();
        if st.program_gen != generation {
            return;
        }
        if !complete {
            st.report.timeouts += 1;
            st.end_program();
            return;
        }
        let mut f = [0i32; 8];
        for (i, v) in f.iter_mut().enumerate() {
            *v = i32::from_be_bytes([msg[4 * i], msg[4 * i + 1], msg[4 * i + 2], msg[4 * i + 3]]);
        }
        if !st.reverse_message(f, &mut timeout_ms) {
            return;
        }
    }
}
