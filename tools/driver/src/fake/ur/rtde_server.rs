//! The controller's RTDE server: what it does with each package a client sends (version,
//! recipes, start and pause, inputs) and the session thread that reads them.

use std::io::Read;
use std::net::{Shutdown, TcpStream};
use std::os::fd::AsRawFd;
use std::sync::atomic::Ordering;

use super::controller::State;
use super::rtde::*;
use super::{CB3_MAX_FREQUENCY, MAX_NAMES_LEN, RTDE_PROTOCOL_VERSION, SLICE_NS, Shared, URE_MAX_FREQUENCY, peer_gone, readable};

impl State {
    fn session(&mut self, id: u64) -> Option<&mut Session> {
        self.sessions.iter_mut().find(|s| s.id == id)
    }

    fn reply(&mut self, id: u64, bytes: &[u8]) {
        if let Some(s) = self.session(id) {
            s.conn.push(bytes);
        }
    }

    /// One RTDE package from session `id`.
    fn rtde_package(&mut self, id: u64, ty: u8, payload: &[u8]) {
        match ty {
            V => {
                let Ok(v) = <[u8; 2]>::try_from(payload) else { return self.report.garbage += 1 };
                let accepted = u16::from_be_bytes(v) == RTDE_PROTOCOL_VERSION;
                self.reply(id, &package(V, &[u8::from(accepted)]));
            }
            VERSION => {
                if !payload.is_empty() {
                    return self.report.garbage += 1;
                }
                let mut p = Vec::with_capacity(16);
                for v in self.opts.version {
                    p.extend_from_slice(&v.to_be_bytes());
                }
                self.reply(id, &package(VERSION, &p));
            }
            SETUP_OUTPUTS => self.setup_outputs(id, payload),
            SETUP_INPUTS => self.setup_inputs(id, payload),
            START => {
                if !payload.is_empty() {
                    return self.report.garbage += 1;
                }
                let step = self.opts.step;
                let Some(s) = self.session(id) else { return };
                let accepted = match s.outputs {
                    Outputs::Valid(_) => true,
                    Outputs::None => !s.inputs.is_empty(),
                    Outputs::Invalid => false,
                };
                s.conn.push(&package(START, &[u8::from(accepted)]));
                if accepted {
                    if !s.started {
                        s.phase = 1.0 - s.frequency * step;
                    }
                    s.started = true;
                    if !s.told {
                        s.told = true;
                        s.conn.push(&text_message("RTDE started", "strand fake UR", 3));
                    }
                    self.report.rtde_sessions += 1;
                }
            }
            PAUSE => {
                if !payload.is_empty() {
                    return self.report.garbage += 1;
                }
                if let Some(s) = self.session(id) {
                    s.started = false;
                    s.conn.push(&package(PAUSE, &[1]));
                }
            }
            DATA => self.input_data(id, payload),
            TEXT => {
                // v2: u8 len, message, u8 len, source, u8 level; read and dropped.
                let ok = (|| {
                    let m = usize::from(*payload.first()?);
                    let s = usize::from(*payload.get(1 + m)?);
                    (payload.len() == 1 + m + 1 + s + 1).then_some(())
                })();
                if ok.is_none() {
                    self.report.garbage += 1;
                }
            }
            _ => self.report.garbage += 1,
        }
    }

    /// The names of a setup package, or `None` (garbage: not ASCII, empty or too long).
    fn names(&mut self, bytes: &[u8]) -> Option<Vec<String>> {
        let text = std::str::from_utf8(bytes).ok().filter(|t| t.is_ascii() && !t.is_empty() && t.len() <= MAX_NAMES_LEN);
        if text.is_none() {
            self.report.garbage += 1;
        }
        Some(text?.split(',').map(str::to_string).collect())
    }

    fn setup_outputs(&mut self, id: u64, payload: &[u8]) {
        let max = if self.opts.version[0] < 5 { CB3_MAX_FREQUENCY } else { URE_MAX_FREQUENCY };
        let Some(f) = payload.get(..8).and_then(|b| b.try_into().ok()).map(f64::from_be_bytes) else {
            return self.report.garbage += 1;
        };
        let names = self.names(&payload[8..]);
        let Some(s) = self.session(id) else { return };
        let Some(names) = names else {
            s.outputs = Outputs::Invalid;
            return s.conn.push(&package(SETUP_OUTPUTS, &[0]));
        };
        if s.started {
            // A recipe cannot change while the stream runs: refused, the old one kept.
            s.conn.push(&text_message("Cannot set up outputs while started; pause first", "strand fake UR", 1));
            return s.conn.push(&package(SETUP_OUTPUTS, &[0]));
        }
        if !(f > 0.0 && f <= max) {
            s.outputs = Outputs::Invalid;
            s.conn.push(&text_message(&format!("RTDE frequency {f} Hz out of range (0, {max}]"), "strand fake UR", 1));
            return s.conn.push(&package(SETUP_OUTPUTS, &[0]));
        }
        let fields: Vec<Option<OutField>> = names.iter().map(|n| OutField::of(n)).collect();
        let types: Vec<&str> = fields.iter().map(|f| f.map_or("NOT_FOUND", OutField::type_name)).collect();
        let valid = fields.iter().all(Option::is_some);
        let mut p = vec![u8::from(valid)];
        p.extend_from_slice(types.join(",").as_bytes());
        s.frequency = f;
        s.outputs = if valid { Outputs::Valid(fields.into_iter().flatten().collect()) } else { Outputs::Invalid };
        s.conn.push(&package(SETUP_OUTPUTS, &p));
    }

    fn setup_inputs(&mut self, id: u64, payload: &[u8]) {
        let names = self.names(payload);
        // Owners whose client has gone (its reader not yet noticed) give their inputs up.
        let gone: Vec<u64> = self.sessions.iter().filter(|s| s.id != id && peer_gone(&s.conn.stream)).map(|s| s.id).collect();
        self.owners.retain(|(_, o)| !gone.contains(o));
        let in_use: Vec<bool> = names.iter().flatten().map(|n| self.owners.iter().any(|(name, owner)| name == n && *owner != id)).collect();
        let Some(s) = self.sessions.iter_mut().find(|s| s.id == id) else { return };
        let Some(names) = names else { return s.conn.push(&package(SETUP_INPUTS, &[0])) };
        if s.started {
            s.conn.push(&text_message("Cannot set up inputs while started; pause first", "strand fake UR", 1));
            return s.conn.push(&package(SETUP_INPUTS, &[0]));
        }
        let fields: Vec<Option<InField>> = names.iter().map(|n| InField::of(n)).collect();
        let types: Vec<&str> = fields
            .iter()
            .zip(&in_use)
            .map(|(f, used)| match f {
                None => "NOT_FOUND",
                Some(_) if *used => "IN_USE",
                Some(f) => f.type_name(),
            })
            .collect();
        let valid = fields.iter().all(Option::is_some) && !in_use.iter().any(|u| *u);
        let rid = if valid && s.next_input_id < 255 {
            s.next_input_id += 1;
            s.inputs.push((s.next_input_id, fields.into_iter().flatten().collect()));
            s.next_input_id
        } else {
            0
        };
        let mut p = vec![rid];
        p.extend_from_slice(types.join(",").as_bytes());
        s.conn.push(&package(SETUP_INPUTS, &p));
        if rid != 0 {
            for n in names {
                if !self.owners.iter().any(|(name, _)| *name == n) {
                    self.owners.push((n, id));
                }
            }
        }
    }

    /// A client's `U`: decoded with its input recipe and applied.
    fn input_data(&mut self, id: u64, payload: &[u8]) {
        let Some(s) = self.sessions.iter().find(|s| s.id == id) else { return };
        let Some(&rid) = payload.first() else { return self.report.garbage += 1 };
        let Some((_, fields)) = s.inputs.iter().find(|(r, _)| *r == rid) else { return self.report.garbage += 1 };
        if !s.started || 1 + fields.iter().map(|f| f.size()).sum::<usize>() != payload.len() {
            return self.report.garbage += 1;
        }
        let mut values = Vec::with_capacity(fields.len());
        let mut at = 1;
        for f in fields {
            let Some(v) = payload.get(at..).and_then(|b| f.decode(b)) else { return self.report.garbage += 1 };
            values.push((*f, v));
            at += f.size();
        }
        let get = |want: InField| values.iter().rev().find(|(f, _)| *f == want).map(|(_, v)| *v);
        let (mut bad, mut wrote) = (false, false);
        if let Some(Value::U8(mask)) = get(InField::AnalogMask) {
            let domain = match get(InField::AnalogType) {
                Some(Value::U8(t)) => Some(t),
                _ => None,
            };
            for pin in 0..2 {
                if mask & (1 << pin) == 0 {
                    continue;
                }
                let ratio = match get(InField::Analog(pin)) {
                    Some(Value::F64(r)) if (0.0..=1.0).contains(&r) => Some(r),
                    Some(_) => {
                        bad = true;
                        continue;
                    }
                    None => None,
                };
                if domain.is_none() && ratio.is_none() {
                    continue;
                }
                if let Some(t) = domain {
                    self.analog[pin].0 = (t >> pin) & 1;
                }
                if let Some(r) = ratio {
                    self.analog[pin].1 = r;
                }
                wrote = true;
            }
        }
        if let (Some(Value::U32(mask)), Some(Value::F64(f))) = (get(InField::SliderMask), get(InField::SliderFraction))
            && mask & 1 != 0
        {
            if (0.0..=1.0).contains(&f) {
                self.speed_fraction = f;
            } else {
                bad = true;
            }
        }
        if let (Some(Value::U8(mask)), Some(Value::U8(d))) = (get(InField::DigitalMask), get(InField::Digital)) {
            self.digital = (self.digital & !mask) | (d & mask);
        }
        for (f, v) in &values {
            match (f, v) {
                (InField::BitRegister(n), Value::U8(b)) => {
                    let bit = 1u64 << (n - 64);
                    self.bit_registers = if *b != 0 { self.bit_registers | bit } else { self.bit_registers & !bit };
                }
                (InField::IntRegister(n), Value::I32(i)) => self.int_registers[*n] = *i,
                (InField::DoubleRegister(n), Value::F64(d)) => self.double_registers[*n] = *d,
                _ => {}
            }
        }
        if wrote {
            self.report.analog_writes += 1;
        }
        if bad {
            self.report.garbage += 1;
        }
    }
}

/// One RTDE client: packages split or merged across reads.
pub(super) fn rtde_session(s: &Shared, mut stream: TcpStream, id: u64) {
    let fd = stream.as_raw_fd();
    let mut acc: Vec<u8> = Vec::with_capacity(4096);
    let mut buf = [0u8; 4096];
    'conn: while !s.stop.load(Ordering::Relaxed) {
        if !readable(fd, SLICE_NS) {
            if s.lock().session(id).is_none_or(|x| x.conn.dead) {
                break;
            }
            continue;
        }
        let n = match stream.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::Interrupted) => continue,
            Err(_) => break,
        };
        acc.extend_from_slice(&buf[..n]);
        let mut at = 0;
        let mut st = s.lock();
        while acc.len() - at >= 3 {
            let size = usize::from(u16::from_be_bytes([acc[at], acc[at + 1]]));
            if size < 3 {
                st.report.garbage += 1;
                break 'conn;
            }
            if acc.len() - at < size {
                break;
            }
            st.rtde_package(id, acc[at + 2], &acc[at + 3..at + size]);
            at += size;
        }
        drop(st);
        acc.drain(..at);
    }
    let mut st = s.lock();
    if let Some(i) = st.sessions.iter().position(|x| x.id == id) {
        let x = st.sessions.remove(i);
        let _ = x.conn.stream.shutdown(Shutdown::Both);
    }
    st.owners.retain(|(_, o)| *o != id);
}
