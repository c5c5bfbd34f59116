//! A child process that is never left behind: the one guard the tools (the demo's service, sim and
//! feeder; the benchmarks' service, drivers and ping-pong) and their tests hold their children in.
//!
//! Dropped while the child still runs, it kills (SIGKILL) and reaps it, so a panicking test or a
//! tool that returns early leaves no service holding the shared-memory ports. Asked to, it stops the
//! child politely first: SIGTERM, so a service writes its report and closes its log, then SIGKILL
//! after a grace period. Waiting polls every [`POLL`]: `std::process::Child` has no timed wait.

use std::process::Child;
use std::time::{Duration, Instant};

/// How often a wait looks at the child.
pub(crate) const POLL: Duration = Duration::from_millis(20);

/// A running child, killed and reaped on drop. See the module documentation.
#[derive(Debug)]
pub struct Reaped(pub Child);

impl Reaped {
    /// Its exit code if it has exited (-1: ended by a signal).
    pub fn exited(&mut self) -> Option<i32> {
        match self.0.try_wait() {
            Ok(Some(s)) => Some(s.code().unwrap_or(-1)),
            _ => None,
        }
    }

    /// Waits for it to exit until `deadline`: its exit code, or None if it still runs.
    pub fn wait_until(&mut self, deadline: Instant) -> Option<i32> {
        loop {
            if let Some(c) = self.exited() {
                return Some(c);
            }
            if Instant::now() >= deadline {
                return None;
            }
            std::thread::sleep(POLL);
        }
    }

    /// SIGTERM, then SIGKILL if it has not exited after `grace`: its exit code (-9 if it had to be
    /// killed; -1 if SIGTERM ended it without a handler).
    pub fn stop(&mut self, grace: Duration) -> i32 {
        if let Some(c) = self.exited() {
            return c;
        }
        self.terminate();
        match self.wait_until(Instant::now() + grace) {
            Some(c) => c,
            None => {
                let _ = self.0.kill();
                let _ = self.0.wait();
                -9
            }
        }
    }

    /// Sends SIGTERM and returns at once.
    pub fn terminate(&mut self) {
        self.signal(libc::SIGTERM);
    }

    /// Sends `signal` (SIGSTOP and SIGCONT to stall it, SIGKILL to crash it) and returns at once.
    pub fn signal(&mut self, signal: libc::c_int) {
        // SAFETY: kill(2) on our own child's pid; the child is not reaped yet (it is reaped only by
        // a wait, and a wait that saw its exit makes this a signal to a zombie at worst, a no-op).
        unsafe {
            libc::kill(self.0.id() as libc::pid_t, signal);
        }
    }
}

impl Drop for Reaped {
    fn drop(&mut self) {
        if let Ok(None) = self.0.try_wait() {
            let _ = self.0.kill();
        }
        let _ = self.0.wait();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::process::Command;

    #[test]
    fn a_child_is_stopped_politely_and_one_that_ignores_sigterm_is_killed() {
        let mut polite = Reaped(Command::new("sleep").arg("30").spawn().unwrap());
        assert_eq!(polite.exited(), None);
        // sleep has no SIGTERM handler: the signal ends it (-1: no exit code).
        assert_eq!(polite.stop(Duration::from_secs(5)), -1);
        // It says when SIGTERM is ignored (an ignored signal stays ignored across exec).
        let mut stubborn = Reaped(
            Command::new("sh")
                .args(["-c", "trap '' TERM; echo ready; exec sleep 30"])
                .stdout(std::process::Stdio::piped())
                .spawn()
                .unwrap(),
        );
        let mut line = String::new();
        std::io::BufRead::read_line(&mut std::io::BufReader::new(stubborn.0.stdout.take().unwrap()), &mut line).unwrap();
        assert_eq!(line, "ready\n");
        assert_eq!(stubborn.stop(Duration::from_millis(200)), -9);
    }

    #[test]
    fn a_dropped_child_is_killed_and_reaped() {
        let guard = Reaped(Command::new("sleep").arg("30").spawn().unwrap());
        let pid = guard.0.id() as libc::pid_t;
        drop(guard);
        // Reaped: the pid no longer names a process of ours.
        // SAFETY: signal 0 only checks that the pid exists.
        assert_eq!(unsafe { libc::kill(pid, 0) }, -1);
    }
}
