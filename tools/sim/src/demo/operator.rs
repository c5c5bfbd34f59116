//! The operator's hand in a demo run (`strand-demo --operator T:ACTION`): pauses, resumes and
//! overrides sent at given robot times into the job, as `strand ctl` would send them from the
//! console. A print is judged on what it survives, and the actions a cell's operator takes are the
//! first thing it must survive (a moving-base print once died on one feed override).

use std::fmt;
use std::str::FromStr;

use strand_ipc::{Command, Control};

/// One action at one time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OperatorAction {
    /// Robot time since the job started (s): the service's clock, not the wall's (a lockstep demo
    /// runs many times faster than real time).
    pub at_s: f64,
    /// What is sent.
    pub command: Command,
    /// Its value (a fraction for the overrides; 0 otherwise).
    pub value: f64,
}

impl FromStr for OperatorAction {
    type Err = String;

    /// `T:pause`, `T:resume`, `T:stop`, `T:feed PERCENT`, `T:flow PERCENT` (T in s of robot time
    /// since the job started; PERCENT as `strand ctl feed` takes it).
    fn from_str(text: &str) -> Result<Self, String> {
        let (at, action) = text.split_once(':').ok_or_else(|| format!("{text:?}: expected T:ACTION, e.g. 250:feed 50 or 30:pause"))?;
        let at_s: f64 = at.trim().parse().map_err(|_| format!("{text:?}: the time {at:?} is not a number of seconds"))?;
        if !(at_s.is_finite() && at_s >= 0.0) {
            return Err(format!("{text:?}: the time must be ≥ 0 s"));
        }
        let mut words = action.split_whitespace();
        let verb = words.next().unwrap_or("");
        let percent = |words: &mut std::str::SplitWhitespace| -> Result<f64, String> {
            let p: f64 = words
                .next()
                .ok_or_else(|| format!("{text:?}: {verb} takes a percentage"))?
                .parse()
                .map_err(|_| format!("{text:?}: the percentage is not a number"))?;
            if p.is_finite() && p > 0.0 && p <= 200.0 {
                Ok(p / 100.0)
            } else {
                Err(format!("{text:?}: the percentage must lie in (0, 200]"))
            }
        };
        let (command, value) = match verb {
            "pause" => (Command::Pause, 0.0),
            "resume" => (Command::Resume, 0.0),
            "stop" => (Command::Stop, 0.0),
            "feed" => (Command::FeedOverride, percent(&mut words)?),
            "flow" => (Command::FlowOverride, percent(&mut words)?),
            other => return Err(format!("{text:?}: unknown action {other:?} (pause, resume, stop, feed PERCENT, flow PERCENT)")),
        };
        if let Some(extra) = words.next() {
            return Err(format!("{text:?}: unexpected {extra:?}"));
        }
        Ok(OperatorAction { at_s, command, value })
    }
}

impl fmt::Display for OperatorAction {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.command {
            Command::FeedOverride => write!(f, "{} s: feed {} %", self.at_s, self.value * 100.0),
            Command::FlowOverride => write!(f, "{} s: flow {} %", self.at_s, self.value * 100.0),
            c => write!(f, "{} s: {c:?}", self.at_s),
        }
    }
}

/// The actions still to send, in time order.
pub(crate) struct Operator {
    pending: Vec<OperatorAction>,
    /// The service's time when the job started (ns), once seen.
    job_start_ns: Option<u64>,
    seq: u64,
}

impl Operator {
    pub(crate) fn new(mut actions: Vec<OperatorAction>) -> Self {
        actions.sort_by(|a, b| a.at_s.total_cmp(&b.at_s));
        actions.reverse();
        Operator { pending: actions, job_start_ns: None, seq: 0 }
    }

    /// The controls due at the service's time `now_ns`, with `job_running` saying whether the job
    /// has started (its clock starts then).
    pub(crate) fn due(&mut self, now_ns: u64, job_running: bool) -> Vec<(OperatorAction, Control)> {
        if job_running && self.job_start_ns.is_none() {
            self.job_start_ns = Some(now_ns);
        }
        let Some(start) = self.job_start_ns else {
            return Vec::new();
        };
        let t = now_ns.saturating_sub(start) as f64 * 1e-9;
        let mut out = Vec::new();
        while self.pending.last().is_some_and(|a| a.at_s <= t) {
            let a = self.pending.pop().expect("checked");
            self.seq += 1;
            out.push((a, Control { seq: self.seq, stamp_ns: now_ns, command: a.command as u32, value: a.value, _reserved: 0 }));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn actions_parse_and_bad_ones_are_named() {
        let a: OperatorAction = "250:feed 50".parse().unwrap();
        assert_eq!((a.at_s, a.command, a.value), (250.0, Command::FeedOverride, 0.5));
        assert_eq!("30:pause".parse::<OperatorAction>().unwrap().command, Command::Pause);
        for bad in ["pause", "x:pause", "-1:pause", "3:feed", "3:feed 0", "3:feed 300", "3:jump", "3:pause now"] {
            assert!(bad.parse::<OperatorAction>().is_err(), "{bad}");
        }
    }

    #[test]
    fn actions_come_due_by_the_jobs_clock_in_order() {
        let mut op = Operator::new(vec!["2:resume".parse().unwrap(), "1:pause".parse().unwrap()]);
        assert!(op.due(5_000_000_000, false).is_empty());
        assert!(op.due(6_000_000_000, true).is_empty());
        let first = op.due(7_000_000_000, true);
        assert_eq!(first.len(), 1);
        assert_eq!(first[0].0.command, Command::Pause);
        let second = op.due(9_000_000_000, true);
        assert_eq!((second.len(), second[0].1.seq), (1, 2));
    }
}
