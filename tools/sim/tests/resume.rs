//! A print resumed from its own log after a crash (`strand-feed --resume-from-log`), under the sim:
//! the service and the feeder are killed with SIGKILL in the middle of a layer (the log cut short,
//! as a power cut leaves it) — the robot holding where it stopped, or the whole cell gone with them
//! (a new sim: the robot starts again at home) — started again, and the job resumed from the cut
//! log. Judged on the sim's truth (the melt that really left the nozzle, where the nozzle really
//! was, over both runs), as the bead metric counts it: along the layer around the seam, no stretch
//! longer than 1 mm without a bead, no overlap thicker than half a layer (1.5× the program's melt in
//! any 1 mm), and nothing laid standing by the resume (what the crash itself left standing, the
//! extruder's last push and the melt's lag, is reported).

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use nalgebra::Vector3;
use strand_ipc::ports::{ClientPorts, ClientRoles};
use strand_ipc::{JobOutcome, RunState, ServiceNames, Status};
use strand_replay::truth::read_truth;
use strand_testkit::{Reaped, bin, root, temp_dir};

/// Two layers of a serpentine (0.2 mm layers): lines 30 mm long, 1 mm apart, 0.03 mm of filament a
/// mm (a 0.45 mm wide bead), at 20 mm/s; bed coordinates (mm) near the iiwa7's start.
const LINES: usize = 8;
const LENGTH_MM: f64 = 30.0;
const E_PER_MM: f64 = 0.03;
const FEED_MM_MIN: f64 = 1200.0;

fn serpentine(dir: &Path) -> PathBuf {
    let mut g = String::from("G21\nG90\nM83\n");
    for layer in 0..2 {
        let z = 0.2 * (layer + 1) as f64;
        g += &format!(";LAYER_CHANGE\n;Z:{z:.1}\nG0 X-15 Y-26 Z{z:.1} F6000\nG1 F{FEED_MM_MIN}\n");
        for k in 0..LINES {
            let (x, y) = line_end(k);
            g += &format!("G1 X{x:.1} Y{y:.1} E{:.4}\n", LENGTH_MM * E_PER_MM);
            if k + 1 < LINES {
                g += &format!("G1 X{x:.1} Y{:.1} E{:.4}\n", y + 1.0, E_PER_MM);
            }
        }
    }
    let p = dir.join("serpentine.gcode");
    std::fs::write(&p, g).unwrap();
    p
}

/// Where the serpentine's line `k` ends (bed mm).
fn line_end(k: usize) -> (f64, f64) {
    (if k.is_multiple_of(2) { LENGTH_MM / 2.0 } else { -LENGTH_MM / 2.0 }, -26.0 + k as f64)
}

fn spawn(c: &mut Command) -> Reaped {
    Reaped(c.current_dir(root()).env("RUST_LOG", "warn").stdout(Stdio::null()).stderr(Stdio::inherit()).spawn().unwrap())
}

fn service(prefix: &str, dir: &Path, log: &str, chunk_interval: f64) -> Reaped {
    let set = |kv: String| ["--set".to_string(), kv];
    let mut c = Command::new(bin("strand"));
    c.args(["run", "--config", "config/default.toml", "--clock", "robot", "--prefix", prefix]);
    c.args(set(format!("log.dir={:?}", dir.display().to_string())))
        .args(set(format!("log.name={log:?}")))
        .args(set("log.wait_when_full=true".into()))
        .args(set(format!("log.chunk_interval={chunk_interval}")))
        .args(set("controller.approach_speed_fraction=1.0".into()))
        // Lockstep with the sim on a loaded machine: wait for its late state (up to 0.5 s, as the
        // sim waits for a late answer) rather than tick without it; a tick the sim never sees is a
        // lost extruder command, which the bead would show as a gap that is not the resume's.
        .args(set("controller.joint_state_timeout=0.5".into()));
    spawn(&mut c)
}

fn wait_for(m: &ClientPorts, seconds: u64, what: &str, until: impl Fn(&Status) -> bool) -> Status {
    strand_testkit::wait_for_status(m, seconds, what, until)
}

/// The melt along the second layer's path around `seam`, as the bead metric counts it: what the
/// truth laid while the nozzle moved, in bins of `BIN` m of path over what the program asked for
/// there; and what it laid standing at the seam (the bead metric's "blobs", m³), before the resume
/// (the crash's own: the extruder's queued push and the melt's lag after the service died) and after.
const BIN: f64 = 0.25e-3;

struct Seam {
    bins: Vec<f64>,
    blob_crash_m3: f64,
    blob_resume_m3: f64,
}

fn seam_melt(program: &[(Vector3<f64>, Vector3<f64>)], truths: &[PathBuf], seam: Vector3<f64>, filament_area: f64) -> Seam {
    // The polyline's arc length at each vertex.
    let mut at = vec![0.0];
    for (a, b) in program {
        at.push(at.last().unwrap() + (b - a).norm());
    }
    // The nearest point of the path: (distance across, height above it, arc length there).
    let project = |p: &Vector3<f64>| -> (f64, f64, f64) {
        program
            .iter()
            .enumerate()
            .map(|(i, (a, b))| {
                let d = b - a;
                let f = ((p - a).dot(&d) / d.norm_squared()).clamp(0.0, 1.0);
                let v = p - (a + d * f);
                (v.xy().norm(), v.z, at[i] + f * d.norm())
            })
            .fold((f64::INFINITY, 0.0, 0.0), |best, x| if x.0 < best.0 { x } else { best })
    };
    let (_, _, s_seam) = project(&seam);
    let seam_at = seam;
    let half = 6e-3;
    let n = (2.0 * half / BIN) as usize;
    let mut seam = Seam { bins: vec![0.0; n], blob_crash_m3: 0.0, blob_resume_m3: 0.0 };
    // The resume begins where the tool comes down over the seam from above (the first run passes
    // it at the layer's height), or with the second sim's run (the whole cell restarted).
    for (run, truth) in truths.iter().enumerate() {
        let rows = read_truth(truth).unwrap();
        let mut resumed = run > 0;
        for w in rows.windows(2) {
            let (r, dt) = (&w[1], (w[1].time_ns - w[0].time_ns) as f64 * 1e-9);
            let p = Vector3::from(r.tcp);
            resumed |= (p - seam_at).xy().norm() < 1e-3 && p.z > seam_at.z + 1e-3;
            let speed = (p - Vector3::from(w[0].tcp)).norm() / dt.max(1e-9);
            let (across, above, s) = project(&p);
            // The second layer's melt only (the first lies 0.2 mm below), within a bead's width.
            if across >= 0.3e-3 || above.abs() >= 0.1e-3 || r.flow_actual <= 0.0 {
                continue;
            }
            let melt = r.flow_actual * dt;
            if speed < 1e-3 {
                if (s - s_seam).abs() < 1e-3 {
                    *(if resumed { &mut seam.blob_resume_m3 } else { &mut seam.blob_crash_m3 }) += melt;
                }
                continue;
            }
            let k = ((s - (s_seam - half)) / BIN).floor();
            if k >= 0.0 && (k as usize) < n {
                seam.bins[k as usize] += melt;
            }
        }
    }
    let asked = E_PER_MM * filament_area * BIN; // filament per path length (mm/mm) × m² × m: m³
    seam.bins.iter_mut().for_each(|v| *v /= asked);
    seam
}

#[test]
fn a_print_whose_service_was_killed_mid_layer_resumes_from_its_log_with_a_seam_the_bead_cannot_tell() {
    kill_and_resume("service", false);
}

#[test]
fn a_print_whose_whole_cell_was_killed_mid_layer_resumes_from_its_log_with_a_seam_the_bead_cannot_tell() {
    kill_and_resume("cell", true);
}

/// Prints the serpentine, kills the service and the feeder (and with `whole_cell` the sim: the
/// robot starts again at home) mid-way through the second layer, resumes from the log, and judges
/// the seam. The whole cell's run logs with 10 ms chunks (`[log] chunk_interval`, the setting for a
/// cell that wants its crashes resumed to the millimetre: what the open chunk held is lost, and no
/// robot standing where it stopped says more); the service's with the default 100 ms, the robot's
/// standing nozzle telling the rest.
fn kill_and_resume(name: &str, whole_cell: bool) {
    let dir = temp_dir("resume", name);
    let program = serpentine(&dir);
    let prefix = format!("strand/simtest-resume-{name}-{}", std::process::id());
    let truths = [dir.join("truth-1.csv"), dir.join("truth-2.csv")];
    let chunk_interval = if whole_cell { 0.01 } else { 0.1 };
    let first = service(&prefix, &dir, "first", chunk_interval);
    let monitor =
        ClientPorts::open(&ServiceNames::new(&prefix), "test-monitor", ClientRoles { monitor: true, ..Default::default() }).unwrap();
    wait_for(&monitor, 30, "the service ticking without a robot", |s| s.tick > 3);
    let sim = |truth: &Path| {
        spawn(Command::new(bin("strand-sim")).args(["--config", "config/default.toml", "--prefix", &prefix]).args([
            "--truth".as_ref(),
            truth.as_os_str(),
            "--exit-after-silence".as_ref(),
            "10".as_ref(),
            // Lockstep, on a loaded machine: a late answer waits (a cycle run without it would
            // drop that tick's extruder command, which a real board, given positions, never does).
            "--answer-timeout".as_ref(),
            "0.5".as_ref(),
        ]))
    };
    let mut plant = sim(&truths[0]);
    wait_for(&monitor, 30, "the sim clocking the service", |s| s.tick > 100);
    let feed = |extra: &[&str]| {
        let mut c = Command::new(bin("strand-feed"));
        c.arg(&program).args(["--config", "config/default.toml", "--prefix", &prefix, "--quiet", "--no-check"]).args(extra);
        c.current_dir(root());
        c
    };
    let feeder = spawn(&mut feed(&[]));
    // Mid-way through the second layer's fourth line: SIGKILL, no goodbye.
    let lines_per_layer = 2 * LINES - 1;
    wait_for(&monitor, 120, "the second layer half done", |s| s.executing_seq as usize >= 2 + lines_per_layer + 1 + 6);
    std::thread::sleep(Duration::from_millis(600));
    drop(first);
    drop(feeder);
    if whole_cell {
        // The plant's physics outlive the crash (its truth is flushed), not its robot's pose.
        stop_sim(&mut plant);
        plant = sim(&truths[1]);
    }
    let log = dir.join("first.mcap");
    assert!(log.is_file(), "the killed service's log");
    // A dry run says where it would resume and sends nothing.
    let dry = feed(&["--resume-from-log", log.to_str().unwrap(), "--dry-run"]).output().unwrap();
    let said = String::from_utf8_lossy(&dry.stderr).to_string();
    assert!(dry.status.success(), "{said}");
    assert!(
        said.contains("resuming") && said.contains("layer 1,") && said.contains("cut short") && said.contains("nothing sent"),
        "{said}"
    );
    // The service again (a new log), and the job resumed from the cut one.
    let second = service(&prefix, &dir, "second", chunk_interval);
    let monitor =
        ClientPorts::open(&ServiceNames::new(&prefix), "test-monitor-2", ClientRoles { monitor: true, ..Default::default() }).unwrap();
    wait_for(&monitor, 30, "the second service clocked by the sim", |s| s.tick > 100);
    let out = feed(&["--resume-from-log", log.to_str().unwrap()]).output().unwrap();
    let said = String::from_utf8_lossy(&out.stderr).to_string();
    eprintln!("{}", said.lines().filter(|l| !l.contains(" % (segment")).collect::<Vec<_>>().join("\n"));
    assert!(out.status.success(), "{said}");
    let s = wait_for(&monitor, 30, "the resumed job's end", |s| s.run_state == RunState::Idle as u32);
    assert_eq!((s.job_outcome, s.clamps), (JobOutcome::Finished as u32, 0), "{s:?}");
    // A robot that held where it stopped says where the nozzle is; one that starts at home does not.
    assert_eq!(said.contains("the nozzle stands"), !whole_cell, "{said}");
    // The seam, as the feeder said it (W, mm).
    let xyz = said.split("resume point at [").nth(1).and_then(|r| r.split("] mm").next()).expect("the resume point").to_string();
    let seam: Vec<f64> = xyz.split(", ").map(|v| v.parse::<f64>().unwrap() * 1e-3).collect();
    let seam = Vector3::new(seam[0], seam[1], seam[2]);
    drop(second);
    stop_sim(&mut plant);
    // The second layer's path in W: the program's lines put on the bed as the feeder does.
    let cfg = strand::config::Config::load(&root().join("config/default.toml")).unwrap();
    let bed = cfg.bed_transform().unwrap();
    let mm = |x: f64, y: f64| bed.point(&Vector3::new(x * 1e-3, y * 1e-3, 0.4e-3));
    let mut path = Vec::new();
    let mut from = mm(-LENGTH_MM / 2.0, -26.0);
    for k in 0..LINES {
        let (x, y) = line_end(k);
        path.push((from, mm(x, y)));
        from = mm(x, y);
        if k + 1 < LINES {
            path.push((from, mm(x, y + 1.0)));
            from = mm(x, y + 1.0);
        }
    }
    assert!((seam.z - path[0].0.z).abs() < 1e-6, "the seam {seam:?} lies on the second layer");
    let area = std::f64::consts::PI * 0.25 * cfg.extruder.filament_diameter.powi(2);
    let truths = if whole_cell { &truths[..] } else { &truths[..1] };
    let melt = seam_melt(&path, truths, seam, area);
    let bins = &melt.bins;
    // Gaps: the longest run of bins with under a quarter of the asked melt.
    let (mut run, mut gap) = (0usize, 0usize);
    for b in bins {
        run = if *b < 0.25 { run + 1 } else { 0 };
        gap = gap.max(run);
    }
    let overlap = bins.windows((1e-3 / BIN) as usize).map(|w| w.iter().sum::<f64>() / w.len() as f64).fold(0.0, f64::max);
    let bead_mm3_per_mm = E_PER_MM * area * 1e6;
    eprintln!(
        "seam at {:?} mm: longest gap {:.2} mm, thickest 1 mm {:.2}× the program's melt; standing at the seam: {:.3} mm³ \
         from the crash ({:.1} mm of bead), {:.4} mm³ from the resume; bins {:?}",
        seam * 1e3,
        gap as f64 * BIN * 1e3,
        overlap,
        melt.blob_crash_m3 * 1e9,
        melt.blob_crash_m3 * 1e9 / bead_mm3_per_mm,
        melt.blob_resume_m3 * 1e9,
        bins.iter().map(|b| (b * 100.0).round() / 100.0).collect::<Vec<_>>()
    );
    assert!(gap as f64 * BIN <= 1e-3, "a gap of {} mm at the seam", gap as f64 * BIN * 1e3);
    assert!(overlap <= 1.5, "an overlap {overlap:.2}× the layer's melt at the seam");
    // The resume lays nothing standing (no prime after a crash; the first move starts the flow).
    assert!(melt.blob_resume_m3 < 0.01 * bead_mm3_per_mm * 1e-9, "{} mm³ laid standing by the resume", melt.blob_resume_m3 * 1e9);
}

/// Ends the sim with SIGTERM (it flushes its truth) and waits for it.
fn stop_sim(sim: &mut Reaped) {
    // SAFETY: a signal to our own child's pid.
    unsafe { libc::kill(sim.0.id() as i32, libc::SIGTERM) };
    let deadline = Instant::now() + Duration::from_secs(30);
    while sim.0.try_wait().unwrap().is_none() {
        assert!(Instant::now() < deadline, "the sim did not exit on SIGTERM");
        std::thread::sleep(Duration::from_millis(50));
    }
}
