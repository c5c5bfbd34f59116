//! One client's session: its bytes cut into packets, each request dispatched, and the b-CAP calls
//! themselves (Service, Controller, Robot_Execute and slvMove) answered against the controller.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::Duration;

use strand::io::clock::monotonic_ns;

use super::Inner;
use super::controller::Ctrl;
use super::wire::{Framed, MAX_JOINTS, Packet, Variant, frame, func, hr, vt};
use crate::fake::{real_time, sleep_until};

/// A successful call that matters to the release check.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Step {
    SlaveOff,
    MotorOff,
    GiveArm,
    RobotRelease,
    CtrlDisconnect,
    ServiceStop,
    Other,
}

/// One client's session.
struct Session {
    wdt_ms: u64,
    invoke_timeout_ms: u64,
    ctrl: Option<u32>,
    robot: Option<u32>,
    entered_slave: bool,
    /// Successful calls, consecutive repeats merged, read-only ones left out.
    log: Vec<Step>,
}

impl Session {
    fn step(&mut self, s: Step) {
        if self.log.last() != Some(&s) {
            self.log.push(s);
        }
    }
    fn clean(&self) -> bool {
        use Step::*;
        let n = self.log.len();
        if n < 5 {
            return false;
        }
        let t = &self.log[n - 5..];
        let pair = matches!((t[0], t[1]), (MotorOff, GiveArm) | (GiveArm, MotorOff));
        pair && t[2..] == [RobotRelease, CtrlDisconnect, ServiceStop] && (!self.entered_slave || (n >= 6 && self.log[n - 6] == SlaveOff))
    }
}

pub(super) fn session(inner: &Inner, mut stream: TcpStream) {
    // The replies are the controller's too: a session stalled by the host would make the client late.
    real_time(inner.opts.rt_priority);
    let _ = stream.set_read_timeout(Some(Duration::from_millis(5)));
    let mut s = Session { wdt_ms: 0, invoke_timeout_ms: 180_000, ctrl: None, robot: None, entered_slave: false, log: Vec::new() };
    let mut rx: Vec<u8> = Vec::with_capacity(4096);
    let mut buf = vec![0u8; 65536];
    let mut last_rx = monotonic_ns();
    // Whether the client closed the connection (not the fake stopping).
    let mut closed = false;
    'session: while !inner.stopping() {
        loop {
            match frame(&rx) {
                Framed::Skip(n) => {
                    inner.lock().report.garbage += n as u64;
                    rx.drain(..n);
                }
                Framed::Packet(n) => {
                    let received = monotonic_ns();
                    let bytes: Vec<u8> = rx.drain(..n).collect();
                    if handle(inner, &mut s, &mut stream, &bytes, received).is_err() {
                        closed = true;
                        break 'session;
                    }
                    // A held reply is no stall of what follows it.
                    last_rx = monotonic_ns();
                }
                Framed::Incomplete => {
                    // A length that garbage made up must not stall the session.
                    if !rx.is_empty() && monotonic_ns().saturating_sub(last_rx) > 200_000_000 {
                        inner.lock().report.garbage += 1;
                        rx.drain(..1);
                        continue;
                    }
                    break;
                }
            }
        }
        match stream.read(&mut buf) {
            Ok(0) => {
                closed = true;
                break;
            }
            Ok(n) => {
                rx.extend_from_slice(&buf[..n]);
                last_rx = monotonic_ns();
            }
            Err(e)
                if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut | std::io::ErrorKind::Interrupted) => {}
            Err(_) => {
                closed = true;
                break;
            }
        }
    }
    let mut c = inner.lock();
    c.connected = false;
    c.released = closed && s.clean() && c.slave_mode == 0;
    if c.slave_mode != 0 && !c.streaming {
        c.leave_slave(true);
    }
    c.arm_taken = false;
    drop(c);
    inner.cv.notify_all();
}

/// Handles one packet's bytes: a reply is written (an error if it is malformed).
fn handle(inner: &Inner, s: &mut Session, stream: &mut TcpStream, bytes: &[u8], received: u64) -> std::io::Result<()> {
    let p = match Packet::decode(bytes) {
        Ok(p) => p,
        Err(serial) => {
            inner.lock().report.garbage += 1;
            return stream.write_all(&Packet { serial: serial.unwrap_or(0), reserved: 0, id: hr::E_INVALIDPACKET, args: vec![] }.encode());
        }
    };
    let slv_move = p.id == func::ROBOT_EXECUTE && p.args.get(1).and_then(Variant::str).is_some_and(|c| c.eq_ignore_ascii_case("slvMove"));
    {
        let mut c = inner.lock();
        if slv_move {
            c.slv_moves += 1;
        } else {
            c.calls.push(call_name(&p));
        }
    }
    let (code, value) = call(inner, s, stream, &p);
    let args = match value {
        Some(v) if code & 0x8000_0000 == 0 => vec![v],
        _ => vec![],
    };
    let out = Packet { serial: p.serial, reserved: 0, id: code, args }.encode();
    let sent = stream.write_all(&out);
    if slv_move {
        inner.lock().report.round_trip.record(monotonic_ns().saturating_sub(received));
    }
    sent
}

fn call_name(p: &Packet) -> String {
    let command = || p.args.get(1).and_then(Variant::str).unwrap_or("?");
    match p.id {
        func::SERVICE_START => "Service_Start".into(),
        func::SERVICE_STOP => "Service_Stop".into(),
        func::CONTROLLER_CONNECT => "Controller_Connect".into(),
        func::CONTROLLER_DISCONNECT => "Controller_Disconnect".into(),
        func::CONTROLLER_GET_ROBOT => "Controller_GetRobot".into(),
        func::CONTROLLER_GET_ROBOT_NAMES => "Controller_GetRobotNames".into(),
        func::CONTROLLER_EXECUTE => format!("Controller_Execute({})", command()),
        func::ROBOT_EXECUTE => format!("Robot_Execute({})", command()),
        func::ROBOT_RELEASE => "Robot_Release".into(),
        id => format!("Function({id})"),
    }
}

type Answer = (u32, Option<Variant>);

fn ok(v: Variant) -> Answer {
    (hr::S_OK, Some(v))
}

fn error(code: u32) -> Answer {
    (code, None)
}

/// Parses `,WDT=400,InvokeTimeout=180000`.
fn service_options(s: &mut Session, option: &str) {
    for part in option.split(',') {
        let Some((k, v)) = part.split_once('=') else { continue };
        let Ok(v) = v.trim().parse::<u64>() else { continue };
        match k.trim().to_ascii_lowercase().as_str() {
            "wdt" => s.wdt_ms = if v == 0 { 0 } else { v.max(80) },
            "invoketimeout" => s.invoke_timeout_ms = v,
            _ => {}
        }
    }
}

fn call(inner: &Inner, s: &mut Session, stream: &mut TcpStream, p: &Packet) -> Answer {
    let a = &p.args;
    let handle_is = |i: usize, h: Option<u32>| a.get(i).and_then(Variant::handle).is_some_and(|x| Some(x) == h);
    match p.id {
        func::SERVICE_START => {
            match a.as_slice() {
                [] | [Variant::Empty] => {}
                [Variant::Bstr(o)] => service_options(s, o),
                [_] => return error(hr::DISP_E_TYPEMISMATCH),
                _ => return error(hr::E_INVALIDARG),
            }
            s.step(Step::Other);
            (hr::S_OK, None)
        }
        func::SERVICE_STOP => {
            s.step(Step::ServiceStop);
            (hr::S_OK, None)
        }
        func::CONTROLLER_CONNECT => {
            if a.len() != 4 {
                return error(hr::E_INVALIDARG);
            }
            let Some(provider) = a[1].str() else { return error(hr::DISP_E_TYPEMISMATCH) };
            if !a.iter().all(|v| v.str().is_some()) {
                return error(hr::DISP_E_TYPEMISMATCH);
            }
            if !provider.eq_ignore_ascii_case("CaoProv.DENSO.VRC") {
                return error(hr::E_CAO_OBJECT_NOT_FOUND);
            }
            let h = match s.ctrl {
                Some(h) => h,
                None => {
                    let mut c = inner.lock();
                    c.next_handle += 1;
                    c.next_handle - 1
                }
            };
            s.ctrl = Some(h);
            s.step(Step::Other);
            ok(Variant::I4(h as i32))
        }
        func::CONTROLLER_DISCONNECT => {
            if a.len() != 1 {
                return error(hr::E_INVALIDARG);
            }
            if !handle_is(0, s.ctrl) {
                return error(hr::E_HANDLE);
            }
            let mut c = inner.lock();
            if c.slave_mode != 0 {
                return error(hr::E_IN_SLAVE_MODE);
            }
            if s.robot.take().is_some() {
                c.arm_taken = false;
            }
            s.ctrl = None;
            s.step(Step::CtrlDisconnect);
            (hr::S_OK, None)
        }
        func::CONTROLLER_GET_ROBOT => {
            if a.len() != 3 {
                return error(hr::E_INVALIDARG);
            }
            if !handle_is(0, s.ctrl) {
                return error(hr::E_HANDLE);
            }
            if a[1].str().is_none() || a[2].str().is_none() {
                return error(hr::DISP_E_TYPEMISMATCH);
            }
            let h = match s.robot {
                Some(h) => h,
                None => {
                    let mut c = inner.lock();
                    c.next_handle += 1;
                    c.next_handle - 1
                }
            };
            s.robot = Some(h);
            s.step(Step::Other);
            ok(Variant::I4(h as i32))
        }
        func::CONTROLLER_GET_ROBOT_NAMES => {
            if a.is_empty() || a.len() > 2 {
                return error(hr::E_INVALIDARG);
            }
            if !handle_is(0, s.ctrl) {
                return error(hr::E_HANDLE);
            }
            ok(Variant::Array(vt::BSTR, vec![Variant::Bstr("Arm".into())]))
        }
        func::CONTROLLER_EXECUTE => {
            if a.len() != 2 && a.len() != 3 {
                return error(hr::E_INVALIDARG);
            }
            if !handle_is(0, s.ctrl) {
                return error(hr::E_HANDLE);
            }
            let Some(command) = a[1].str() else { return error(hr::DISP_E_TYPEMISMATCH) };
            let param = a.get(2).unwrap_or(&Variant::Empty);
            controller_execute(inner, command, param)
        }
        func::ROBOT_EXECUTE => {
            if a.len() != 2 && a.len() != 3 {
                return error(hr::E_INVALIDARG);
            }
            if s.ctrl.is_none() || !handle_is(0, s.robot) {
                return error(hr::E_HANDLE);
            }
            let Some(command) = a[1].str() else { return error(hr::DISP_E_TYPEMISMATCH) };
            let param = a.get(2).unwrap_or(&Variant::Empty);
            robot_execute(inner, s, stream, p.serial, command, param)
        }
        func::ROBOT_RELEASE => {
            if a.len() != 1 {
                return error(hr::E_INVALIDARG);
            }
            if !handle_is(0, s.robot) {
                return error(hr::E_HANDLE);
            }
            let mut c = inner.lock();
            if c.slave_mode != 0 {
                return error(hr::E_IN_SLAVE_MODE);
            }
            c.arm_taken = false;
            s.robot = None;
            s.step(Step::RobotRelease);
            (hr::S_OK, None)
        }
        _ => error(hr::E_NOTIMPL),
    }
}

/// A description of the codes the fake knows.
fn describe(code: u32) -> String {
    let known = match code {
        hr::E_BUF_EMPTY => "Command buffer empty (command value generation delay)",
        hr::E_BUF_FULL => "Command buffer full",
        hr::E_SLAVE_OFF => "Slave move while slave mode off",
        hr::E_IN_SLAVE_MODE => "Invalid command in slave mode",
        hr::E_MOTOR_OFF => "Motor is off",
        hr::E_ERROR_PENDING => "Cannot execute while an error is pending",
        c if (hr::E_SPEED + 1..=hr::E_SPEED + 8).contains(&c) => return format!("Command speed too large (J{})", c - hr::E_SPEED),
        c if (hr::E_ACCEL + 1..=hr::E_ACCEL + 8).contains(&c) => return format!("Command acceleration too large (J{})", c - hr::E_ACCEL),
        c => return format!("Error 0x{c:08X}"),
    };
    known.into()
}

fn controller_execute(inner: &Inner, command: &str, param: &Variant) -> Answer {
    let mut c = inner.lock();
    match command.to_ascii_lowercase().as_str() {
        "clearerror" => {
            if c.slave_mode != 0 {
                return error(hr::E_IN_SLAVE_MODE);
            }
            c.latched = None;
            ok(Variant::Empty)
        }
        "geterrordescription" => {
            if c.slave_mode != 0 {
                return error(hr::E_IN_SLAVE_MODE);
            }
            match param.int() {
                Some(code) => ok(Variant::Bstr(describe(code as u32))),
                None => error(hr::DISP_E_TYPEMISMATCH),
            }
        }
        _ => error(hr::E_INVALID_CMD_NAME),
    }
}

/// `[state, noWait]` or a scalar state.
fn motor_param(param: &Variant) -> Option<(bool, bool)> {
    match param {
        Variant::Array(_, items) if !items.is_empty() && items.len() <= 2 => {
            Some((items[0].int()? != 0, items.get(1).map(Variant::int).unwrap_or(Some(0))? != 0))
        }
        v => Some((v.int()? != 0, false)),
    }
}

/// An integer format, or `[format, tsUnit]`.
fn format_param(param: &Variant) -> Option<(u32, Option<i64>)> {
    match param {
        Variant::Array(_, items) if !items.is_empty() && items.len() <= 2 => {
            Some((items[0].int()? as u32, items.get(1).map(Variant::int).unwrap_or(Some(0)).map(Some)?))
        }
        v => Some((v.int()? as u32, None)),
    }
}

fn robot_execute(inner: &Inner, s: &mut Session, stream: &mut TcpStream, serial: u16, command: &str, param: &Variant) -> Answer {
    let cmd = command.to_ascii_lowercase();
    if cmd == "slvmove" {
        return slv_move(inner, param);
    }
    if cmd == "motor" {
        return motor(inner, s, stream, serial, param);
    }
    let mut c = inner.lock();
    let answer = match cmd.as_str() {
        "takearm" | "givearm" | "slvsendformat" | "slvrecvformat" if c.slave_mode != 0 => error(hr::E_IN_SLAVE_MODE),
        "takearm" => {
            c.arm_taken = true;
            ok(Variant::Empty)
        }
        "givearm" => {
            c.arm_taken = false;
            s.step(Step::GiveArm);
            return ok(Variant::Empty);
        }
        "curjnt" => return ok(Variant::r8s(&c.joints8())),
        "highcurjntex" => {
            let mut v = vec![f64::from(inner.stamp(false))];
            v.extend_from_slice(&c.joints8());
            return ok(Variant::r8s(&v));
        }
        "slvsendformat" => match param {
            Variant::Empty => return ok(Variant::I4(c.send_fmt as i32)),
            v => match v.int() {
                Some(f) if f >= 0 && f & !(0x20 | 0x100 | 0x200) == 0 => {
                    c.send_fmt = f as u32;
                    ok(Variant::Empty)
                }
                Some(_) => error(hr::E_INVALIDARG),
                None => error(hr::DISP_E_TYPEMISMATCH),
            },
        },
        "slvrecvformat" => match param {
            Variant::Empty => return ok(Variant::I4(c.recv_fmt as i32)),
            v => match format_param(v) {
                Some((f, unit))
                    if f & 0xF == 2 && f & !(0xF | 0x10 | 0x20 | 0x40 | 0x100) == 0 && unit.is_none_or(|u| u == 0 || u == 1) =>
                {
                    c.recv_fmt = f;
                    c.ts_us = unit == Some(1);
                    ok(Variant::Empty)
                }
                Some(_) => error(hr::E_INVALIDARG),
                None => error(hr::DISP_E_TYPEMISMATCH),
            },
        },
        "slvchangemode" => {
            let Some(mode) = param.int() else { return error(hr::DISP_E_TYPEMISMATCH) };
            match mode {
                0 => {
                    if c.slave_mode != 0 {
                        c.leave_slave(false);
                    }
                    s.step(Step::SlaveOff);
                    drop(c);
                    inner.cv.notify_all();
                    return ok(Variant::Empty);
                }
                0x002 | 0x102 | 0x202 => {
                    c.resolve_motor(monotonic_ns());
                    if c.latched.is_some() {
                        error(hr::E_ERROR_PENDING)
                    } else if !c.arm_taken {
                        error(hr::E_ACCESSDENIED)
                    } else if !c.motor_on {
                        error(hr::E_MOTOR_OFF)
                    } else {
                        c.enter_slave(mode as u32);
                        s.entered_slave = true;
                        ok(Variant::Empty)
                    }
                }
                _ => error(hr::E_INVALIDARG),
            }
        }
        "slvgetmode" => return ok(Variant::I4(c.slave_mode as i32)),
        _ => return error(hr::E_INVALID_CMD_NAME),
    };
    if answer.0 & 0x8000_0000 == 0 {
        s.step(Step::Other);
    }
    answer
}

fn motor(inner: &Inner, s: &mut Session, stream: &mut TcpStream, serial: u16, param: &Variant) -> Answer {
    let Some((on, no_wait)) = motor_param(param) else { return error(hr::DISP_E_TYPEMISMATCH) };
    let now = monotonic_ns();
    let on_ns = (inner.opts.motor_on_time.max(0.0) * 1e9) as u64;
    {
        let mut c = inner.lock();
        c.resolve_motor(now);
        if !on {
            if c.slave_mode != 0 {
                c.leave_slave(true);
                s.step(Step::Other);
            }
            c.motor_on = false;
            c.motor_on_at = None;
            s.step(Step::MotorOff);
            drop(c);
            inner.cv.notify_all();
            return ok(Variant::Empty);
        }
        if c.latched.is_some() {
            return error(hr::E_ERROR_PENDING);
        }
        s.step(Step::Other);
        if c.motor_on {
            return ok(Variant::Empty);
        }
        let at = *c.motor_on_at.get_or_insert(now + on_ns);
        if no_wait {
            return ok(Variant::Empty);
        }
        drop(c);
        // Held until the motor is on or InvokeTimeout, S_EXECUTING every WDT ms meanwhile.
        let timeout = now.saturating_add(s.invoke_timeout_ms.saturating_mul(1_000_000));
        let end = at.min(timeout);
        let wdt_ns = s.wdt_ms * 1_000_000;
        let mut next_wdt = if wdt_ns > 0 { now + wdt_ns } else { u64::MAX };
        let executing = Packet { serial, reserved: 0, id: hr::S_EXECUTING, args: vec![] }.encode();
        loop {
            let t = monotonic_ns();
            if t >= end || inner.stopping() {
                break;
            }
            if t >= next_wdt {
                if stream.write_all(&executing).is_err() {
                    break;
                }
                next_wdt += wdt_ns;
            }
            sleep_until(end.min(next_wdt).min(t + 5_000_000));
        }
        if end < at {
            return error(hr::E_TIMEOUT);
        }
    }
    let mut c = inner.lock();
    let done = monotonic_ns().max(c.motor_on_at.unwrap_or(0));
    c.resolve_motor(done);
    if c.latched.is_some() && !c.motor_on {
        return error(hr::E_ERROR_PENDING);
    }
    c.motor_on = true;
    ok(Variant::Empty)
}

/// The slvMove reply value per the recv format: bare R8×8, or a VARIANT array.
fn position(inner: &Inner, c: &Ctrl) -> Variant {
    let pose = Variant::r8s(&c.joints8());
    let f = c.recv_fmt;
    if f & !0xF == 0 {
        return pose;
    }
    let mut v = Vec::new();
    if f & 0x10 != 0 {
        v.push(Variant::I4(inner.stamp(c.ts_us)));
    }
    v.push(pose);
    if f & 0x100 != 0 {
        v.push(Variant::I4(0));
    }
    if f & 0x20 != 0 {
        v.push(Variant::I4(0));
    }
    if f & 0x40 != 0 {
        v.push(Variant::r8s(&[0.0; MAX_JOINTS]));
    }
    Variant::Array(vt::VARIANT, v)
}

/// The 8 joint values (degrees) of a `slvMove` parameter under `slvSendFormat` `send_fmt`, or the
/// HRESULT that refuses it.
pub(super) fn slv_pose(send_fmt: u32, param: &Variant) -> Result<[f64; MAX_JOINTS], u32> {
    let pose = match (send_fmt, param) {
        (0, Variant::Array(vt::R8, q)) => q,
        (f, Variant::Array(vt::VARIANT, items)) if f != 0 => match items.first() {
            Some(Variant::Array(vt::R8, q)) => q,
            _ => return Err(hr::DISP_E_TYPEMISMATCH),
        },
        _ => return Err(hr::DISP_E_TYPEMISMATCH),
    };
    if pose.len() != MAX_JOINTS && pose.len() != MAX_JOINTS + 1 {
        return Err(hr::E_INVALIDARG);
    }
    let mut cmd = [0.0; MAX_JOINTS];
    for (x, v) in cmd.iter_mut().zip(pose) {
        match v {
            Variant::R8(v) if v.is_finite() => *x = *v,
            _ => return Err(hr::E_INVALIDARG),
        }
    }
    Ok(cmd)
}

fn slv_move(inner: &Inner, param: &Variant) -> Answer {
    let mut c = inner.lock();
    if c.latched.is_some() || c.slave_mode == 0 {
        return error(hr::E_SLAVE_OFF);
    }
    let cmd = match slv_pose(c.send_fmt, param) {
        Ok(cmd) => cmd,
        Err(code) => return error(code),
    };
    let code = match (c.slave_mode >> 8) & 0xF {
        1 => {
            c.buffer.clear();
            c.buffer.push_back(cmd);
            hr::S_OK
        }
        mode => {
            if c.buffer.len() >= 3 {
                c.buffer_full += 1;
                return error(hr::E_BUF_FULL);
            }
            c.buffer.push_back(cmd);
            if c.buffer.len() < 3 {
                hr::S_OK
            } else if mode == 0 {
                hr::S_BUF_FULL
            } else {
                // Mode 2: held until a tick frees a slot.
                let pops = c.pops;
                while c.pops == pops && c.slave_mode != 0 && !inner.stopping() {
                    c = inner.cv.wait_timeout(c, Duration::from_millis(5)).map_or_else(|e| e.into_inner().0, |r| r.0);
                }
                match c.latched {
                    Some(code) => return error(code),
                    None if c.slave_mode == 0 => return error(hr::E_SLAVE_OFF),
                    None => hr::S_OK,
                }
            }
        }
    };
    (code, Some(position(inner, &c)))
}
