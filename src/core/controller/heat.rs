//! Temperatures: the heater targets a job sets, its heat waits, and the guards that keep a cold
//! hot end from extruding.
//!
//! - **Targets travel with the motion.** A heat segment (`M104`, `M140`, `SET_HEATER_TEMPERATURE`)
//!   sets its target when the path reaches its place in the job — the executing segment's
//!   sequence number passes it — not when it arrives (the feeder streams far ahead, and the
//!   `M104 S0` at a job's end must not switch the heater off under the last layer). They are kept
//!   here in a fixed ring in arrival order; the path engine does not see the ones without a hold.
//! - **Waits are the path's.** A heat segment with a hold (`M109`, `M190`, `TEMPERATURE_WAIT`) is
//!   a hold piece in the path engine: the path stops there and nothing after it executes until
//!   [`Heat::step`] releases it — once the measured temperature has stayed inside the wait's band
//!   for `[extruder] temperature_settle_time` (Marlin's residency). A pause or a stop during the
//!   wait works as anywhere on the path; the settle clock keeps running meanwhile (the heater
//!   heats whatever the arm does).
//! - **Guards.** With `[extruder] heater = "wire"`: an extruding segment never starts with the hot
//!   end below `min_extrude_temp` (`ColdExtrusion`); a temperature older than
//!   `temperature_timeout` while a wait or an extruding move needs it is `TemperatureLost`.
//!   With `heater = "none"` nothing is measured: targets are passed on, every wait is skipped
//!   and reported ([`Event::HeatWaitSkipped`](super::Event::HeatWaitSkipped)), nothing is
//!   checked — never a silent pretence of having waited.
//! - **The owner's faults are the service's.** A `HeaterState` that says the owner switched a
//!   heater off ([`heater_flags::FAULT`]: Klipper's verify_heater, a thermistor out of range)
//!   faults `HeaterFault` (with `heater = "wire"`), whether a job runs or not.
//! - **Faults turn the heaters off**: every fault and emergency stop sets both targets to 0, as
//!   Marlin's kill and Klipper's shutdown do.
//!
//! Temperatures are in °C, the wire's one exception to SI.

use strand_wire as ipc;
use strand_wire::{FaultCode, HeatHold, heater_flags};

use crate::extrude::{ExtruderConfig, HeaterSource};
use crate::path::{HeatRequest, HeatWait, Heater, Motion, PathEngine, PathSample, SegmentFlags};

/// Temperatures a thermistor can report (°C): beyond them it is open or shorted, not measuring.
pub(super) const PLAUSIBLE: [f64; 2] = [-60.0, 1000.0];

/// Heat segments that may wait in the job ahead of the path (a job has a handful; a full ring
/// refuses the segment with `QueueFull` until the path has passed some).
pub(super) const MAX_PENDING_HEAT: usize = 64;

/// A wait the path holds at (or is about to hold at).
#[derive(Clone, Copy, Debug)]
struct ActiveWait {
    seq: u64,
    heater: Heater,
    /// The band (°C, low and high); None until the first measurement after the wait began
    /// decided it (a `Heating` wait above its band does not hold).
    band: Option<[f64; 2]>,
    request: HeatRequest,
    /// When the temperature entered the band and stayed (ns).
    in_band_since: Option<u64>,
}

/// What the heat stage decided this tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum HeatVerdict {
    /// Nothing to report.
    Fine,
    /// A wait was skipped (no temperature source): its segment.
    Skipped(u64),
    /// A fault to latch.
    Fault(FaultCode),
}

/// The heat stage. See the module documentation.
pub(super) struct Heat {
    source: HeaterSource,
    min_extrude_temp: f64,
    tolerance: [f64; 2],
    settle_ns: u64,
    timeout_ns: u64,
    /// The targets in force (°C): hot end, bed.
    targets: [f64; 2],
    /// The latest measurements (°C) and the tick time they arrived (ns).
    measured: [Option<(f64, u64)>; 2],
    pending: [(u64, HeatRequest); MAX_PENDING_HEAT],
    head: usize,
    len: usize,
    wait: Option<ActiveWait>,
    /// The extruding segment last checked for a cold hot end.
    checked_seq: Option<u64>,
    /// The heaters' owner reported a heater switched off for a fault ([`heater_flags::FAULT`]),
    /// not yet turned into the service's fault.
    owner_fault: bool,
}

fn index(h: Heater) -> usize {
    match h {
        Heater::HotEnd => 0,
        Heater::Bed => 1,
    }
}

impl Heat {
    pub(super) fn new(cfg: &ExtruderConfig) -> Self {
        Heat {
            source: cfg.heater,
            min_extrude_temp: cfg.min_extrude_temp,
            tolerance: [cfg.temperature_tolerance, cfg.bed_temperature_tolerance],
            settle_ns: (cfg.temperature_settle_time * 1e9).round() as u64,
            timeout_ns: (cfg.temperature_timeout * 1e9).round() as u64,
            targets: [0.0; 2],
            measured: [None; 2],
            pending: [(0, HeatRequest::default()); MAX_PENDING_HEAT],
            head: 0,
            len: 0,
            wait: None,
            checked_seq: None,
            owner_fault: false,
        }
    }

    fn acting(&self) -> bool {
        self.source == HeaterSource::Wire
    }

    /// Takes a measurement (arrived this tick at `now_ns`: staleness is judged on the service's
    /// clock, not on the stamp of another process's); false if a temperature is not finite or
    /// outside [`PLAUSIBLE`] (a broken or shorted thermistor): ignored, so it goes stale.
    pub(super) fn measure(&mut self, h: &ipc::HeaterState, now_ns: u64) -> bool {
        self.owner_fault |= h.flags & heater_flags::FAULT != 0;
        let mut ok = true;
        for (i, bit, t) in [(0, heater_flags::HOT_END, h.hot_end), (1, heater_flags::BED, h.bed)] {
            if h.flags & bit != 0 {
                if t.is_finite() && (PLAUSIBLE[0]..=PLAUSIBLE[1]).contains(&t) {
                    self.measured[i] = Some((t, now_ns));
                } else {
                    ok = false;
                }
            }
        }
        ok
    }

    /// The measurement of `heater` if it is fresh at `now_ns`.
    fn fresh(&self, heater: Heater, now_ns: u64) -> Option<f64> {
        self.measured[index(heater)].filter(|(_, at)| now_ns.saturating_sub(*at) <= self.timeout_ns).map(|(t, _)| t)
    }

    /// Room for another heat segment.
    pub(super) fn has_room(&self) -> bool {
        self.len < MAX_PENDING_HEAT
    }

    /// Queues an accepted heat segment (call only with room).
    pub(super) fn push(&mut self, seq: u64, request: HeatRequest) {
        if self.len < MAX_PENDING_HEAT {
            self.pending[(self.head + self.len) % MAX_PENDING_HEAT] = (seq, request);
            self.len += 1;
        }
    }

    fn pop(&mut self) -> Option<(u64, HeatRequest)> {
        (self.len > 0).then(|| {
            let e = self.pending[self.head];
            self.head = (self.head + 1) % MAX_PENDING_HEAT;
            self.len -= 1;
            e
        })
    }

    fn apply(&mut self, seq: u64, r: HeatRequest) {
        if r.target >= 0.0 {
            self.targets[index(r.heater)] = r.target;
        }
        if r.wait != HeatWait::None {
            self.wait = Some(ActiveWait { seq, heater: r.heater, band: None, request: r, in_band_since: None });
        }
    }

    /// The job ended (finished: every target it set is now in force; stopped or faulted: the
    /// rest is discarded).
    pub(super) fn end_job(&mut self, finished: bool) {
        while let Some((seq, r)) = self.pop() {
            if finished {
                self.apply(seq, r);
            }
        }
        self.wait = None;
        self.checked_seq = None;
    }

    /// A fault or an emergency stop: heaters off, the job's heat forgotten.
    pub(super) fn fault(&mut self) {
        self.end_job(false);
        self.targets = [0.0; 2];
    }

    /// One tick, after the path's: targets the path has reached, the wait (released when
    /// settled), and the guards. `sample` is this tick's path sample while the path runs.
    pub(super) fn step(&mut self, engine: &mut PathEngine, sample: Option<&PathSample>, now_ns: u64) -> HeatVerdict {
        if std::mem::take(&mut self.owner_fault) && self.acting() {
            // Whatever the job does: the heater is off and will not come back by itself.
            return HeatVerdict::Fault(FaultCode::HeaterFault);
        }
        let mut verdict = HeatVerdict::Fine;
        if let Some(s) = sample {
            while self.len > 0 && self.pending[self.head].0 <= s.seq {
                let (seq, r) = self.pending[self.head];
                self.head = (self.head + 1) % MAX_PENDING_HEAT;
                self.len -= 1;
                self.apply(seq, r);
            }
        }
        if let Some(mut w) = self.wait {
            let at_wait = engine.waiting_at() == Some(w.seq);
            if !self.acting() {
                if at_wait {
                    engine.release_wait();
                    self.wait = None;
                    verdict = HeatVerdict::Skipped(w.seq);
                }
            } else {
                let Some(t) = self.fresh(w.heater, now_ns) else {
                    return HeatVerdict::Fault(FaultCode::TemperatureLost);
                };
                let band = *w.band.get_or_insert_with(|| {
                    let tol = self.tolerance[index(w.heater)];
                    let target = self.targets[index(w.heater)];
                    match w.request.wait {
                        // Marlin's M109 S: no wait for cooling.
                        HeatWait::Heating if t > target + tol => [f64::NEG_INFINITY, f64::INFINITY],
                        HeatWait::Range => w.request.band,
                        _ => [target - tol, target + tol],
                    }
                });
                let done = if band[0] == f64::NEG_INFINITY {
                    true
                } else if (band[0]..=band[1]).contains(&t) {
                    let since = *w.in_band_since.get_or_insert(now_ns);
                    now_ns.saturating_sub(since) >= self.settle_ns
                } else {
                    w.in_band_since = None;
                    false
                };
                self.wait = Some(w);
                if done && at_wait {
                    engine.release_wait();
                    self.wait = None;
                }
            }
        }
        if let (true, Some(s)) = (self.acting(), sample) {
            let extruding = s.flags.contains(SegmentFlags::EXTRUDE) || s.dwell_filament_rate > 0.0;
            if extruding && matches!(s.motion, Motion::Moving | Motion::Dwelling) {
                let Some(t) = self.fresh(Heater::HotEnd, now_ns) else {
                    return HeatVerdict::Fault(FaultCode::TemperatureLost);
                };
                if self.checked_seq != Some(s.seq) {
                    self.checked_seq = Some(s.seq);
                    if t < self.min_extrude_temp {
                        return HeatVerdict::Fault(FaultCode::ColdExtrusion);
                    }
                }
            }
        }
        verdict
    }

    /// Why the extruder may not push filament now, if it may not (the last guard, on the command
    /// itself): a hot end that is silent (`TemperatureLost`) or cold (`ColdExtrusion`).
    pub(super) fn push_fault(&self, now_ns: u64) -> Option<FaultCode> {
        if !self.acting() {
            return None;
        }
        match self.fresh(Heater::HotEnd, now_ns) {
            None => Some(FaultCode::TemperatureLost),
            Some(t) if t < self.min_extrude_temp => Some(FaultCode::ColdExtrusion),
            Some(_) => None,
        }
    }

    /// The command for the heaters' owner.
    pub(super) fn command(&self, seq: u64, stamp_ns: u64, tick: u64) -> ipc::HeaterCommand {
        ipc::HeaterCommand { seq, stamp_ns, tick, hot_end_target: self.targets[0], bed_target: self.targets[1], _reserved: 0 }
    }

    /// Fills the temperature fields of `status`.
    pub(super) fn fill_status(&self, status: &mut ipc::Status, now_ns: u64) {
        let mut flags = if self.acting() { heater_flags::ACTING } else { 0 };
        if let Some(t) = self.fresh(Heater::HotEnd, now_ns) {
            status.hot_end_temperature = t;
            flags |= heater_flags::HOT_END;
        }
        if let Some(t) = self.fresh(Heater::Bed, now_ns) {
            status.bed_temperature = t;
            flags |= heater_flags::BED;
        }
        status.heater_flags = flags;
        status.hot_end_target = self.targets[0];
        status.bed_target = self.targets[1];
        if let Some(w) = self.wait
            && let Some(band) = w.band
            && band[0].is_finite()
        {
            status.heat_hold = match w.heater {
                Heater::HotEnd => HeatHold::HotEnd,
                Heater::Bed => HeatHold::Bed,
            } as u32;
            let settle = self.settle_ns as f64 * 1e-9;
            status.heat_hold_left = w.in_band_since.map_or(settle, |since| (settle - now_ns.saturating_sub(since) as f64 * 1e-9).max(0.0));
            status.heat_hold_band = band;
        }
    }
}
