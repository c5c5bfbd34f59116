//! Keys while streaming: `p` pauses or resumes, `+` / `-` change the feed override by 10 points,
//! `s` stops (as a first Ctrl-C does). On a terminal, stdin is put in non-canonical mode without
//! echo (Ctrl-C still interrupts) and restored when the [`Keys`] value is dropped; from a pipe
//! (scripts, tests) the bytes are read as they come.

use std::sync::mpsc::{Receiver, channel};

/// A key pressed while streaming.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Key {
    /// `p`: pause, or resume a paused job.
    PauseResume,
    /// `+` (or `=`): feed override up 10 points.
    Faster,
    /// `-`: feed override down 10 points.
    Slower,
    /// `s`: controlled stop.
    Stop,
}

impl Key {
    fn from_byte(b: u8) -> Option<Key> {
        match b {
            b'p' | b'P' | b' ' => Some(Key::PauseResume),
            b'+' | b'=' => Some(Key::Faster),
            b'-' | b'_' => Some(Key::Slower),
            b's' | b'S' => Some(Key::Stop),
            _ => None,
        }
    }
}

/// The keys from stdin, read on a thread of their own.
pub struct Keys {
    rx: Receiver<Key>,
    saved: Option<libc::termios>,
}

impl Keys {
    /// Starts reading stdin (a terminal, or with `force` any stdin); `None` when stdin is not a
    /// terminal and `force` is off.
    pub fn start(force: bool) -> Option<Keys> {
        // SAFETY: isatty, tcgetpgrp and getpgrp only read.
        let tty = unsafe { libc::isatty(0) } == 1;
        // A terminal we are in the background of (`strand-feed job.gcode &`) is not ours: setting
        // its mode would stop us with SIGTTOU, reading it with SIGTTIN.
        let foreground = tty && unsafe { libc::tcgetpgrp(0) == libc::getpgrp() };
        if (tty && !foreground) || (!tty && !force) {
            return None;
        }
        let saved = if tty { raw_mode() } else { None };
        let (tx, rx) = channel();
        let spawned = std::thread::Builder::new().name("strand-feed-keys".into()).spawn(move || {
            let mut byte = [0u8; 1];
            loop {
                // SAFETY: reads at most one byte into a one-byte buffer.
                let n = unsafe { libc::read(0, byte.as_mut_ptr().cast(), 1) };
                if n <= 0 {
                    if n < 0 && std::io::Error::last_os_error().kind() == std::io::ErrorKind::Interrupted {
                        continue;
                    }
                    return; // end of input, or EIO (the terminal went away)
                }
                if let Some(k) = Key::from_byte(byte[0])
                    && tx.send(k).is_err()
                {
                    return;
                }
            }
        });
        spawned.ok()?;
        Some(Keys { rx, saved })
    }

    /// The next key pressed, if any.
    pub fn next(&self) -> Option<Key> {
        self.rx.try_recv().ok()
    }
}

impl Drop for Keys {
    fn drop(&mut self) {
        if let Some(t) = &self.saved {
            // SAFETY: restores the attributes read from the same descriptor.
            unsafe { libc::tcsetattr(0, libc::TCSANOW, t) };
        }
    }
}

/// Non-canonical, no echo (signals kept); returns the attributes to restore.
fn raw_mode() -> Option<libc::termios> {
    // SAFETY: termios is plain data; tcgetattr fills it or fails.
    let mut t: libc::termios = unsafe { std::mem::zeroed() };
    if unsafe { libc::tcgetattr(0, &mut t) } != 0 {
        return None;
    }
    let saved = t;
    t.c_lflag &= !(libc::ICANON | libc::ECHO);
    t.c_cc[libc::VMIN] = 1;
    t.c_cc[libc::VTIME] = 0;
    // SAFETY: valid attributes for the same descriptor.
    (unsafe { libc::tcsetattr(0, libc::TCSANOW, &t) } == 0).then_some(saved)
}
