//! Real-time set-up of the calling thread and process: SCHED_FIFO priority, CPU pinning, locked
//! memory, timer slack and a pre-faulted stack, each tried on its own and reported, never fatal.
//!
//! A cell that refuses a step (no `CAP_SYS_NICE`, a low `RLIMIT_MEMLOCK`, a container without the
//! CPU) still runs, with worse jitter; [`apply`] says which step the OS refused, what it said, and what
//! the process runs with instead. Call [`apply`] on the cycle thread itself, after the ports are open
//! and before the first tick: the scheduling policy, the affinity and the timer slack are
//! per-thread (threads spawned afterwards inherit them), the memory lock is process-wide.
//!
//! Nothing here is tick-path code: every function makes system calls and [`apply`] allocates its
//! report.

use std::fmt;

use serde::{Deserialize, Serialize};
use strand_core::InvalidSetting;

/// Largest stack pre-fault [`RealtimeConfig::validate`] accepts (bytes): 8 MiB, the usual main-thread
/// stack limit.
pub(crate) const MAX_PREFAULT_STACK_BYTES: usize = 8 * 1024 * 1024;

/// Stack left untouched below the pre-faulted region (bytes), for the frames of the pre-fault itself
/// and whatever runs after it.
const STACK_MARGIN_BYTES: usize = 256 * 1024;

/// The `[realtime]` config section. The default turns every step off: the process keeps
/// SCHED_OTHER, floats over all CPUs, pages normally and keeps the default 50 µs timer slack.
#[derive(Clone, Debug, Default, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct RealtimeConfig {
    /// SCHED_FIFO priority of the cycle thread, 1..=99; 0 leaves it on SCHED_OTHER. Keep it below
    /// the robot driver's if they share a CPU, and remember the kernel throttles real-time threads
    /// that never sleep (`/proc/sys/kernel/sched_rt_runtime_us`).
    pub fifo_priority: u32,
    /// Pin the cycle thread to this CPU (index as the kernel counts them, from 0); `None` leaves the
    /// affinity alone. Best combined with `isolcpus`/`nohz_full` on that CPU.
    pub cpu: Option<usize>,
    /// Lock all current and future pages of the process into RAM (`mlockall(MCL_CURRENT |
    /// MCL_FUTURE)`), so no tick waits for a page fault. Needs `CAP_IPC_LOCK` or a large enough
    /// `RLIMIT_MEMLOCK`.
    pub lock_memory: bool,
    /// Timer slack of the cycle thread (ns), `PR_SET_TIMERSLACK`; 0 leaves the default (50 000 ns).
    /// SCHED_FIFO threads get no slack anyway; this matters when priority is refused.
    pub timer_slack_ns: u64,
    /// Stack to touch once after locking memory (bytes), so the cycle thread's deepest call never
    /// faults a stack page in; 0 skips it. At most [`MAX_PREFAULT_STACK_BYTES`], and never more than
    /// the thread's stack holds (the rest is reported as refused).
    pub prefault_stack_bytes: usize,
    /// Hold the kernel's PM QoS CPU latency at this many µs for the life of the process (writes it to
    /// `/dev/cpu_dma_latency` and keeps the file open): CPUs then skip idle states slower to leave,
    /// which is most of an idle machine's wake-up latency (cyclictest does the same for itself).
    /// `None` leaves power management alone. Costs power: a real robot PC sets it, a laptop may not.
    pub cpu_dma_latency_us: Option<u32>,
}

impl RealtimeConfig {
    /// Checks the ranges: priority ≤ 99, CPU index below the number of online CPUs, pre-fault at most
    /// 8 MiB. The message names the key, as `[realtime] fifo_priority: ...`.
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        if self.fifo_priority > 99 {
            return Err(InvalidSetting::new(
                "realtime",
                format!("[realtime] fifo_priority: must be 0 (stay on SCHED_OTHER) or 1..=99 (SCHED_FIFO), got {}", self.fifo_priority),
            ));
        }
        if let Some(cpu) = self.cpu {
            let online = online_cpus();
            if cpu >= online {
                return Err(InvalidSetting::new(
                    "realtime",
                    format!("[realtime] cpu: CPU {cpu} does not exist: this machine has {online} online CPU(s), numbered from 0"),
                ));
            }
        }
        if self.prefault_stack_bytes > MAX_PREFAULT_STACK_BYTES {
            return Err(InvalidSetting::new(
                "realtime",
                format!("[realtime] prefault_stack_bytes: at most {MAX_PREFAULT_STACK_BYTES} (8 MiB), got {}", self.prefault_stack_bytes),
            ));
        }
        Ok(())
    }
}

/// What became of one set-up step.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum RtOutcome {
    /// The step took effect; the text says what is in force now, e.g. `"SCHED_FIFO 80"`.
    Applied(String),
    /// The OS refused the step (or did only part of it). One line: the call, what the OS said
    /// (strerror) and what the process runs with instead, e.g. `"pthread_setschedparam(SCHED_FIFO,
    /// 80): Operation not permitted; staying on SCHED_OTHER"`.
    Refused(String),
    /// The step is not configured.
    Skipped,
}

/// One set-up step and its outcome.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RtStep {
    /// The step, named by its config key (`"fifo_priority"`, `"cpu"`, `"lock_memory"`,
    /// `"timer_slack_ns"`, `"prefault_stack_bytes"`).
    pub name: &'static str,
    /// What happened.
    pub outcome: RtOutcome,
}

/// The outcome of [`apply`]: every step, in the order tried, configured or not.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RealtimeReport {
    /// The steps: cpu, lock_memory, prefault_stack_bytes, timer_slack_ns, fifo_priority, cpu_dma_latency_us.
    pub steps: Vec<RtStep>,
}

impl RealtimeReport {
    /// The refusals, one line each, for the start-up log.
    pub fn warnings(&self) -> impl Iterator<Item = &str> + '_ {
        self.steps.iter().filter_map(|s| match &s.outcome {
            RtOutcome::Refused(line) => Some(line.as_str()),
            _ => None,
        })
    }

    /// The outcome of the step named `name` (a config key), if there is such a step.
    pub fn step(&self, name: &str) -> Option<&RtOutcome> {
        self.steps.iter().find(|s| s.name == name).map(|s| &s.outcome)
    }
}

impl fmt::Display for RealtimeReport {
    /// One line: `realtime: cpu CPU 1; lock_memory refused; ...` (skipped steps as `off`).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "realtime:")?;
        for (i, s) in self.steps.iter().enumerate() {
            let sep = if i == 0 { " " } else { "; " };
            match &s.outcome {
                RtOutcome::Applied(what) => write!(f, "{sep}{} {what}", s.name)?,
                RtOutcome::Refused(_) => write!(f, "{sep}{} REFUSED", s.name)?,
                RtOutcome::Skipped => write!(f, "{sep}{} off", s.name)?,
            }
        }
        Ok(())
    }
}

/// Applies `cfg` to the calling thread (and, for the memory lock, the process), step by step:
/// CPU affinity, memory lock, stack pre-fault, timer slack, SCHED_FIFO priority. Never fails and
/// never panics: a refused step is reported and the next one is still tried. Does not validate
/// `cfg` (call [`RealtimeConfig::validate`] first); impossible values come back as refusals.
pub fn apply(cfg: &RealtimeConfig) -> RealtimeReport {
    let steps = vec![
        RtStep { name: "cpu", outcome: cfg.cpu.map_or(RtOutcome::Skipped, pin_to_cpu) },
        RtStep { name: "lock_memory", outcome: if cfg.lock_memory { lock_memory() } else { RtOutcome::Skipped } },
        RtStep {
            name: "prefault_stack_bytes",
            outcome: if cfg.prefault_stack_bytes > 0 { prefault_stack(cfg.prefault_stack_bytes) } else { RtOutcome::Skipped },
        },
        RtStep {
            name: "timer_slack_ns",
            outcome: if cfg.timer_slack_ns > 0 { set_timer_slack(cfg.timer_slack_ns) } else { RtOutcome::Skipped },
        },
        RtStep { name: "fifo_priority", outcome: if cfg.fifo_priority > 0 { set_fifo(cfg.fifo_priority) } else { RtOutcome::Skipped } },
        RtStep { name: "cpu_dma_latency_us", outcome: cfg.cpu_dma_latency_us.map_or(RtOutcome::Skipped, hold_cpu_latency) },
    ];
    RealtimeReport { steps }
}

/// The PM QoS request stays in force while this file is open: for the life of the process.
static CPU_LATENCY_REQUEST: std::sync::Mutex<Option<std::fs::File>> = std::sync::Mutex::new(None);

fn hold_cpu_latency(us: u32) -> RtOutcome {
    use std::io::Write;
    let path = "/dev/cpu_dma_latency";
    let opened = std::fs::OpenOptions::new().write(true).open(path).and_then(|mut f| f.write_all(&(us as i32).to_ne_bytes()).map(|_| f));
    match opened {
        Ok(f) => {
            if let Ok(mut held) = CPU_LATENCY_REQUEST.lock() {
                *held = Some(f);
            }
            RtOutcome::Applied(format!("{us} µs held"))
        }
        Err(e) => RtOutcome::Refused(format!("{path}: {e}; CPUs may enter deep idle states (slower wake-ups)")),
    }
}

/// The scheduling policy and priority of the calling thread, e.g. `"SCHED_FIFO 80"` or
/// `"SCHED_OTHER"`, for reports.
pub(crate) fn current_policy() -> String {
    let mut policy: libc::c_int = 0;
    let mut param = libc::sched_param { sched_priority: 0 };
    // SAFETY: pthread_self() is the calling thread; both out-pointers are valid locals.
    let rc = unsafe { libc::pthread_getschedparam(libc::pthread_self(), &mut policy, &mut param) };
    if rc != 0 {
        return format!("unknown ({})", os_error_text(rc));
    }
    // SCHED_RESET_ON_FORK may be or-ed into the policy.
    match policy & !0x4000_0000 {
        libc::SCHED_OTHER => "SCHED_OTHER".to_string(),
        libc::SCHED_FIFO => format!("SCHED_FIFO {}", param.sched_priority),
        libc::SCHED_RR => format!("SCHED_RR {}", param.sched_priority),
        libc::SCHED_BATCH => "SCHED_BATCH".to_string(),
        libc::SCHED_IDLE => "SCHED_IDLE".to_string(),
        other => format!("policy {other} priority {}", param.sched_priority),
    }
}

/// Number of online CPUs (`sysconf(_SC_NPROCESSORS_ONLN)`, at least 1).
pub(crate) fn online_cpus() -> usize {
    // SAFETY: sysconf has no preconditions.
    let n = unsafe { libc::sysconf(libc::_SC_NPROCESSORS_ONLN) };
    if n < 1 { 1 } else { n as usize }
}

/// strerror text of an error number, without Rust's " (os error N)" suffix.
fn os_error_text(code: i32) -> String {
    let text = std::io::Error::from_raw_os_error(code).to_string();
    match text.find(" (os error") {
        Some(i) => text[..i].to_string(),
        None => text,
    }
}

/// errno of the last failed libc call.
fn errno() -> i32 {
    std::io::Error::last_os_error().raw_os_error().unwrap_or(0)
}

fn pin_to_cpu(cpu: usize) -> RtOutcome {
    let set_size = libc::CPU_SETSIZE as usize;
    if cpu >= set_size {
        return RtOutcome::Refused(format!(
            "sched_setaffinity(CPU {cpu}): CPU index beyond the {set_size}-CPU set; thread keeps its affinity"
        ));
    }
    // SAFETY: cpu_set_t is plain data; CPU_ZERO/CPU_SET write within it (index checked above);
    // sched_setaffinity(0, ..) applies to the calling thread and reads `size` bytes of `set`.
    let rc = unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        libc::CPU_ZERO(&mut set);
        libc::CPU_SET(cpu, &mut set);
        libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set)
    };
    if rc == 0 {
        RtOutcome::Applied(format!("CPU {cpu}"))
    } else {
        RtOutcome::Refused(format!("sched_setaffinity(CPU {cpu}): {}; thread keeps its affinity", os_error_text(errno())))
    }
}

fn lock_memory() -> RtOutcome {
    // SAFETY: mlockall has no memory-safety preconditions.
    let rc = unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) };
    if rc == 0 {
        RtOutcome::Applied("mlockall(MCL_CURRENT|MCL_FUTURE)".to_string())
    } else {
        RtOutcome::Refused(format!(
            "mlockall(MCL_CURRENT|MCL_FUTURE): {}; memory stays pageable (raise RLIMIT_MEMLOCK or grant CAP_IPC_LOCK)",
            os_error_text(errno())
        ))
    }
}

fn set_timer_slack(ns: u64) -> RtOutcome {
    // SAFETY: PR_SET_TIMERSLACK takes one unsigned long argument and touches no memory.
    let rc =
        unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, ns as libc::c_ulong, 0 as libc::c_ulong, 0 as libc::c_ulong, 0 as libc::c_ulong) };
    if rc == 0 {
        RtOutcome::Applied(format!("{ns} ns"))
    } else {
        RtOutcome::Refused(format!("prctl(PR_SET_TIMERSLACK, {ns}): {}; keeping the default slack", os_error_text(errno())))
    }
}

fn set_fifo(priority: u32) -> RtOutcome {
    let Ok(prio) = libc::c_int::try_from(priority) else {
        return RtOutcome::Refused(format!("pthread_setschedparam(SCHED_FIFO, {priority}): priority out of range; staying on SCHED_OTHER"));
    };
    let param = libc::sched_param { sched_priority: prio };
    // SAFETY: pthread_self() is the calling thread; `param` is a valid local.
    let rc = unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param) };
    if rc == 0 {
        RtOutcome::Applied(format!("SCHED_FIFO {priority}"))
    } else {
        RtOutcome::Refused(format!("pthread_setschedparam(SCHED_FIFO, {priority}): {}; staying on {}", os_error_text(rc), current_policy()))
    }
}

/// Bytes of the calling thread's stack below the current frame, if the OS says.
fn stack_remaining() -> Option<usize> {
    // SAFETY: pthread_getattr_np fills `attr` for the calling thread, which is then read and
    // destroyed; all pointers are valid locals.
    unsafe {
        let mut attr: libc::pthread_attr_t = std::mem::zeroed();
        if libc::pthread_getattr_np(libc::pthread_self(), &mut attr) != 0 {
            return None;
        }
        let mut addr: *mut libc::c_void = std::ptr::null_mut();
        let mut size: libc::size_t = 0;
        let mut guard: libc::size_t = 0;
        let ok = libc::pthread_attr_getstack(&attr, &mut addr, &mut size) == 0;
        libc::pthread_attr_getguardsize(&attr, &mut guard);
        libc::pthread_attr_destroy(&mut attr);
        if !ok {
            return None;
        }
        let here = 0u8;
        let sp = std::hint::black_box(&here) as *const u8 as usize;
        let low = addr as usize + guard;
        Some(sp.saturating_sub(low))
    }
}

fn prefault_stack(bytes: usize) -> RtOutcome {
    let Some(remaining) = stack_remaining() else {
        return RtOutcome::Refused(format!("pthread_getattr_np: {}; stack not pre-faulted (size unknown)", os_error_text(errno())));
    };
    let room = remaining.saturating_sub(STACK_MARGIN_BYTES);
    let done = bytes.min(room);
    if done > 0 {
        touch_stack(done);
    }
    if done == bytes {
        RtOutcome::Applied(format!("{} KiB", bytes / 1024))
    } else {
        RtOutcome::Refused(format!(
            "prefault {} KiB: only {} KiB of this thread's stack remain; pre-faulted {} KiB",
            bytes / 1024,
            remaining / 1024,
            done / 1024
        ))
    }
}

const PREFAULT_CHUNK: usize = 16 * 1024;

/// Writes one byte per 4 KiB into `bytes` of fresh stack, a 16 KiB frame at a time, so the pages
/// are faulted in (and, after `mlockall(MCL_FUTURE)`, locked).
#[inline(never)]
fn touch_stack(bytes: usize) {
    let mut chunk = [0u8; PREFAULT_CHUNK];
    let mut i = 0;
    while i < PREFAULT_CHUNK {
        // SAFETY: i < PREFAULT_CHUNK, inside `chunk`.
        unsafe { std::ptr::write_volatile(chunk.as_mut_ptr().add(i), 1) };
        i += 4096;
    }
    std::hint::black_box(&mut chunk);
    if bytes > PREFAULT_CHUNK {
        touch_stack(bytes - PREFAULT_CHUNK);
    }
    // Keeps the frame alive across the recursive call (no tail call reusing it).
    std::hint::black_box(&chunk);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_applies_nothing() {
        let cfg = RealtimeConfig::default();
        assert_eq!(cfg.validate(), Ok(()));
        let report = apply(&cfg);
        assert_eq!(report.steps.len(), 6);
        assert!(report.steps.iter().all(|s| s.outcome == RtOutcome::Skipped), "{report:?}");
        assert_eq!(report.warnings().count(), 0);
        assert!(report.to_string().starts_with("realtime: cpu off;"), "{report}");
    }

    #[test]
    fn timer_slack_is_applied_and_read_back() {
        // Its own thread: the slack is per-thread and other tests must keep the default.
        std::thread::spawn(|| {
            let report = apply(&RealtimeConfig { timer_slack_ns: 1, ..Default::default() });
            assert_eq!(report.step("timer_slack_ns"), Some(&RtOutcome::Applied("1 ns".to_string())));
            // SAFETY: PR_GET_TIMERSLACK takes no pointer arguments.
            let slack = unsafe {
                libc::prctl(libc::PR_GET_TIMERSLACK, 0 as libc::c_ulong, 0 as libc::c_ulong, 0 as libc::c_ulong, 0 as libc::c_ulong)
            };
            assert_eq!(slack, 1);
            assert!(report.to_string().contains("timer_slack_ns 1 ns"), "{report}");
        })
        .join()
        .unwrap();
    }

    #[test]
    fn validate_names_the_key() {
        let e = RealtimeConfig { fifo_priority: 100, ..Default::default() }.validate().unwrap_err().to_string();
        assert!(e.starts_with("[realtime] fifo_priority:"), "{e}");
        assert!(e.contains("100"), "{e}");
        let e = RealtimeConfig { cpu: Some(4096), ..Default::default() }.validate().unwrap_err().to_string();
        assert!(e.starts_with("[realtime] cpu:"), "{e}");
        let e =
            RealtimeConfig { prefault_stack_bytes: MAX_PREFAULT_STACK_BYTES + 1, ..Default::default() }.validate().unwrap_err().to_string();
        assert!(e.starts_with("[realtime] prefault_stack_bytes:"), "{e}");
        let ok = RealtimeConfig { fifo_priority: 99, cpu: Some(0), prefault_stack_bytes: MAX_PREFAULT_STACK_BYTES, ..Default::default() };
        assert_eq!(ok.validate(), Ok(()));
    }

    #[test]
    fn impossible_cpu_is_refused_not_a_panic() {
        std::thread::spawn(|| {
            let before = unsafe {
                let mut set: libc::cpu_set_t = std::mem::zeroed();
                libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set);
                libc::CPU_COUNT(&set)
            };
            // Beyond the kernel's CPU set, and inside it but not present.
            for cpu in [4096, 1000] {
                let report = apply(&RealtimeConfig { cpu: Some(cpu), ..Default::default() });
                match report.step("cpu") {
                    Some(RtOutcome::Refused(line)) => {
                        assert!(line.starts_with(&format!("sched_setaffinity(CPU {cpu})")), "{line}");
                        assert!(line.ends_with("thread keeps its affinity"), "{line}");
                        assert!(!line.contains('\n'));
                    }
                    other => panic!("cpu {cpu}: {other:?}"),
                }
                assert_eq!(report.warnings().count(), 1);
                assert!(report.to_string().contains("cpu REFUSED"), "{report}");
            }
            let after = unsafe {
                let mut set: libc::cpu_set_t = std::mem::zeroed();
                libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set);
                libc::CPU_COUNT(&set)
            };
            assert_eq!(before, after);
        })
        .join()
        .unwrap();
    }

    #[test]
    fn stack_prefault_fits_the_thread() {
        std::thread::Builder::new()
            .stack_size(1024 * 1024)
            .spawn(|| {
                let report = apply(&RealtimeConfig { prefault_stack_bytes: 256 * 1024, ..Default::default() });
                assert_eq!(report.step("prefault_stack_bytes"), Some(&RtOutcome::Applied("256 KiB".to_string())));
                // More than the thread has: capped and reported, not a stack overflow.
                let report = apply(&RealtimeConfig { prefault_stack_bytes: MAX_PREFAULT_STACK_BYTES, ..Default::default() });
                match report.step("prefault_stack_bytes") {
                    Some(RtOutcome::Refused(line)) => assert!(line.contains("pre-faulted"), "{line}"),
                    other => panic!("{other:?}"),
                }
            })
            .unwrap()
            .join()
            .unwrap();
    }

    #[test]
    fn current_policy_names_the_default() {
        let p = std::thread::spawn(current_policy).join().unwrap();
        assert_eq!(p, "SCHED_OTHER");
    }

    #[test]
    fn deserializes_with_defaults_and_rejects_unknown_keys() {
        let cfg: RealtimeConfig = toml::from_str("fifo_priority = 80\ncpu = 1").unwrap();
        assert_eq!(cfg, RealtimeConfig { fifo_priority: 80, cpu: Some(1), ..Default::default() });
        assert!(toml::from_str::<RealtimeConfig>("priority = 80").is_err());
    }
}
