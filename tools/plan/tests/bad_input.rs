//! No tool panics on bad input. Every file-taking command is fed binary junk, a 50 MB line, NaN /
//! Inf / 1e308 numbers, inconsistent arcs, an empty file, a missing file, a folder, invalid UTF-8, a
//! truncated segment file, a bad TOML config and a truncated MCAP log, and must refuse each: a
//! non-zero exit, stderr naming the file (and the line, for line-oriented input), and no
//! `panicked`. The inputs are made at test time in a scratch folder (the 50 MB line too), and the
//! tools run there, outside the repository.

use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::OnceLock;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};
use strand_testkit::{bin, root, temp_dir};

/// One bad input: a label, the file, and the line an error must name (None: the file alone).
struct Bad {
    label: &'static str,
    path: PathBuf,
    line: Option<usize>,
}

/// The bad inputs, made once per test binary.
struct Inputs {
    dir: PathBuf,
    /// G-code programs (and what is given in their place).
    programs: Vec<Bad>,
    /// Config files (service, robot, plant).
    configs: Vec<Bad>,
    /// MCAP logs.
    logs: Vec<Bad>,
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

/// Deterministic junk (xorshift), starting with bytes that are neither G-code nor UTF-8.
fn junk(n: usize) -> Vec<u8> {
    let mut x = 0x9E37_79B9_7F4A_7C15u64;
    let mut v = vec![0xFF, 0xFE, 0x00, 0x89];
    while v.len() < n {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        v.push(x as u8);
    }
    v
}

fn inputs() -> &'static Inputs {
    static INPUTS: OnceLock<Inputs> = OnceLock::new();
    INPUTS.get_or_init(|| {
        remove_stale_inputs();
        let dir = temp_dir("bad-input", "inputs");
        let b = |label, path, line| Bad { label, path, line };
        // Each program's bad line comes after a good one, so the line number is checked.
        let g = |name: &str, bad: &str| write(&dir, name, format!("G21\nG1 X1 Y1 F1200\n{bad}\n").as_bytes());
        let mut long = b"G1 X1 ".to_vec();
        long.resize(50 * 1024 * 1024, b'1');
        long.push(b'\n');
        let missing = dir.join("missing.gcode");
        let folder = dir.join("folder.gcode");
        std::fs::create_dir_all(&folder).unwrap();
        let common_bad = |ext: &str| {
            let folder = dir.join(format!("folder.{ext}"));
            std::fs::create_dir_all(&folder).unwrap();
            vec![
                b("binary junk", write(&dir, &format!("junk.{ext}"), &junk(4096)), None),
                b("empty file", write(&dir, &format!("empty.{ext}"), b""), None),
                b("missing file", dir.join(format!("missing.{ext}")), None),
                b("a folder", folder, None),
                b("invalid UTF-8", write(&dir, &format!("utf8.{ext}"), b"# strand\nrobot = \"\xff\xfe\"\n"), Some(2)),
            ]
        };
        let programs = vec![
            b("binary junk", write(&dir, "junk.gcode", &junk(4096)), Some(1)),
            b("a 50 MB line", write(&dir, "long.gcode", &long), Some(1)),
            b("G1 X nan", g("nan.gcode", "G1 X nan"), Some(3)),
            b("G1 X1.2.3 F100", g("malformed.gcode", "G1 X1.2.3 F100"), Some(3)),
            b("G1 XInf", g("inf.gcode", "G1 XInf"), Some(3)),
            b("G1 X<400 digits>", g("digits.gcode", &format!("G1 X{} F100", "9".repeat(400))), Some(3)),
            b("G2 X10 Y0 I1 J1", g("arc.gcode", "G2 X10 Y0 I1 J1"), Some(3)),
            b("G2 X10 Y0 R1 (R too small)", g("arc_r.gcode", "G2 X10 Y0 R1"), Some(3)),
            b("empty file", write(&dir, "empty.gcode", b""), None),
            b("missing file", missing, None),
            b("a folder", folder, None),
            b("invalid UTF-8", write(&dir, "utf8.gcode", b"G21\nG1 X1 Y1 F1200\nG1 X\xff\xfe\n"), Some(3)),
            b(
                "a truncated segment file",
                write(
                    &dir,
                    "truncated.jsonl",
                    b"{\"format\": \"strand-segments\", \"version\": 1}\n{\"end\": [0.01, 0, 0.001], \"feed\": 0.01}\n{\"end\": [0.02, 0.0",
                ),
                Some(3),
            ),
        ];
        let mut configs = common_bad("toml");
        configs.push(b("bad TOML", write(&dir, "bad.toml", b"robot = \"robots/iiwa7.toml\"\n[path\nmax_speed = 1\n"), Some(2)));
        configs.push(b("a NaN in TOML", write(&dir, "nan.toml", b"robot = \"robots/iiwa7.toml\"\n[path]\nmax_speed = nan\n"), None));
        let mut logs = common_bad("mcap");
        logs.retain(|l| l.label != "invalid UTF-8");
        logs.push(b("a TOML file", dir.join("bad.toml"), None));
        let full = make_log(&dir);
        logs.push(b("an MCAP cut inside its first chunk", write(&dir, "cut.mcap", &full[..first_chunk_middle(&full)]), None));
        Inputs { dir, programs, configs, logs }
    })
}

/// Removes the inputs (50 MB each) of earlier runs whose process has ended.
fn remove_stale_inputs() {
    let Ok(entries) = std::fs::read_dir(std::env::temp_dir()) else { return };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().to_string();
        if let Some(pid) = name.strip_prefix("strand-bad-input-test-").and_then(|r| r.strip_suffix("-inputs"))
            && !Path::new("/proc").join(pid).exists()
        {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
}

/// A real log (`strand_testkit::service_log`): 300 ticks of the service.
fn make_log(dir: &Path) -> Vec<u8> {
    std::fs::read(strand_testkit::service_log(dir, "badinput")).unwrap()
}

/// The middle of the log's first Chunk record (MCAP: magic, then records of opcode, u64 length, body).
fn first_chunk_middle(mcap: &[u8]) -> usize {
    let mut at = 8;
    while at + 9 <= mcap.len() {
        let len = u64::from_le_bytes(mcap[at + 1..at + 9].try_into().unwrap()) as usize;
        if mcap[at] == 0x06 {
            return at + 9 + len / 2;
        }
        at += 9 + len;
    }
    panic!("no chunk in the log");
}

/// Runs a tool in the inputs' folder (outside the repository), with the built-in config; a run
/// that outlasts a minute is killed (and then fails its check: killed, nothing named).
fn run(name: &str, args: &[&str], file: &Path) -> Output {
    static RUNS: AtomicUsize = AtomicUsize::new(0);
    let dir = &inputs().dir;
    let n = RUNS.fetch_add(1, Ordering::Relaxed);
    let (out_path, err_path) = (dir.join(format!("run-{n}.out")), dir.join(format!("run-{n}.err")));
    let mut child = Command::new(bin(name))
        .args(args)
        .arg(file)
        .current_dir(dir)
        .env_remove("STRAND_CONFIG_DIR")
        .env("XDG_CACHE_HOME", dir.join("cache"))
        .env("RUST_BACKTRACE", "0")
        .stdin(Stdio::null())
        .stdout(File::create(&out_path).unwrap())
        .stderr(File::create(&err_path).unwrap())
        .spawn()
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(60);
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            break child.wait().unwrap();
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    let output = Output { status, stdout: std::fs::read(&out_path).unwrap(), stderr: std::fs::read(&err_path).unwrap() };
    let _ = std::fs::remove_file(out_path);
    let _ = std::fs::remove_file(err_path);
    output
}

/// The tool refused `bad`: non-zero exit, the file (and line) named on stderr, no panic. Returns
/// the failures as text (so one test reports every one of them).
fn check(what: &str, bad: &Bad, out: &Output) -> Option<String> {
    let stderr = String::from_utf8_lossy(&out.stderr);
    let file = bad.path.display().to_string();
    let name = bad.path.file_name().unwrap().to_string_lossy().to_string();
    let mut wrong = Vec::new();
    if out.status.success() {
        wrong.push("exit 0".to_string());
    }
    if stderr.contains("panicked") {
        wrong.push("panicked".to_string());
    }
    if !stderr.contains(&name) {
        wrong.push(format!("{name} not named"));
    }
    if let Some(line) = bad.line
        && !stderr.contains(&format!("{file}:{line}"))
        && !stderr.contains(&format!("line {line}"))
    {
        wrong.push(format!("line {line} not named"));
    }
    (!wrong.is_empty()).then(|| format!("{what} on {} ({}): {}\n    stderr: {}", bad.label, name, wrong.join(", "), stderr.trim()))
}

fn is_segfile(bad: &Bad) -> bool {
    bad.path.extension().is_some_and(|e| e == "jsonl")
}

fn assert_all(failures: Vec<String>) {
    assert!(failures.is_empty(), "{} refusals wrong:\n  {}", failures.len(), failures.join("\n  "));
}

#[test]
fn strand_plan_refuses_bad_programs_naming_file_and_line() {
    let mut failures = Vec::new();
    let commands: [(&str, &[&str]); 4] = [
        ("strand-plan time", &["time"]),
        ("strand-plan base", &["base"]),
        ("strand-plan strips", &["strips", "--width", "0.02", "--overlap", "0.005", "--reach", "0.5", "-o", "strips.gcode"]),
        ("strand-plan tilt", &["tilt", "--angle", "10", "-o", "tilted.jsonl"]),
    ];
    for bad in &inputs().programs {
        // The planners read G-code only: a segment file fails on its first line.
        let as_gcode = Bad { label: bad.label, path: bad.path.clone(), line: if is_segfile(bad) { Some(1) } else { bad.line } };
        for (what, args) in commands {
            failures.extend(check(what, &as_gcode, &run("strand-plan", args, &bad.path)));
        }
    }
    assert_all(failures);
}

#[test]
fn strand_check_job_refuses_bad_programs_and_configs_with_exit_2() {
    let mut failures = Vec::new();
    for bad in &inputs().programs {
        let out = run("strand", &["check-job"], &bad.path);
        failures.extend(check("strand check-job", bad, &out));
        if out.status.code() != Some(2) {
            failures.push(format!("strand check-job on {}: exit {:?}, not 2", bad.label, out.status.code()));
        }
    }
    let job = root().join("tests/data/gcode/truss/truss_200mm.gcode").canonicalize().unwrap();
    for bad in &inputs().configs {
        let out = run("strand", &["check-job", job.to_str().unwrap(), "--config"], &bad.path);
        failures.extend(check("strand check-job --config", bad, &out));
    }
    // A base trajectory that is not one.
    let traj = Bad { label: "a trajectory without t", path: write(&inputs().dir, "plan.csv", b"x,y\n1,2\n"), line: Some(1) };
    let out = run("strand", &["check-job", job.to_str().unwrap(), "--base-trajectory"], &traj.path);
    failures.extend(check("strand check-job --base-trajectory", &traj, &out));
    assert_all(failures);
}

#[test]
fn strand_plan_refuses_bad_configs() {
    let mut failures = Vec::new();
    let job = root().join("tests/data/gcode/truss/truss_200mm.gcode").canonicalize().unwrap();
    for bad in &inputs().configs {
        for sub in ["time", "base"] {
            let out = run("strand-plan", &[sub, job.to_str().unwrap(), "--config"], &bad.path);
            failures.extend(check(&format!("strand-plan {sub} --config"), bad, &out));
        }
    }
    assert_all(failures);
}

#[test]
fn strand_feed_refuses_a_bad_file_before_it_looks_for_a_service() {
    // No service runs under this prefix: each refusal is exit 2 (a bad program or config), never
    // 1 (no service), and comes at once.
    let prefix = format!("strand/badinput-feed-{}", std::process::id());
    let mut failures = Vec::new();
    let started = std::time::Instant::now();
    for bad in &inputs().programs {
        let out = run("strand-feed", &["--prefix", &prefix, "--wait-service", "30", "--quiet"], &bad.path);
        failures.extend(check("strand-feed", bad, &out));
        if out.status.code() != Some(2) {
            failures.push(format!("strand-feed on {}: exit {:?}, not 2", bad.label, out.status.code()));
        }
    }
    let program = strand_testkit::square_program(&inputs().dir, 1, 1, 1200.0);
    for bad in &inputs().configs {
        let out = run("strand-feed", &[program.to_str().unwrap(), "--prefix", &prefix, "--wait-service", "30", "--config"], &bad.path);
        failures.extend(check("strand-feed --config", bad, &out));
        if out.status.code() != Some(2) {
            failures.push(format!("strand-feed --config {}: exit {:?}, not 2", bad.label, out.status.code()));
        }
    }
    assert_all(failures);
    assert!(started.elapsed().as_secs() < 30, "a refusal waited for the service");
}

#[test]
fn strand_replay_refuses_bad_logs() {
    let mut failures = Vec::new();
    for bad in &inputs().logs {
        for sub in ["info", "verify"] {
            failures.extend(check(&format!("strand-replay {sub}"), bad, &run("strand-replay", &[sub], &bad.path)));
        }
        let csv = inputs().dir.join("csv");
        failures.extend(check("strand-replay export", bad, &run("strand-replay", &["export", "--csv", csv.to_str().unwrap()], &bad.path)));
    }
    assert_all(failures);
}

#[test]
fn strand_replay_reads_a_log_cut_short_and_says_so() {
    // A crash leaves a log without its footer; what is in its closed chunks is still a record of
    // the run (strand-replay recover rewrites it). The tools read it and say it was cut short.
    // Long enough for a few blocks of the compact record (a free-run service closes one per 1,024
    // ticks), so that half the file holds some.
    let long = strand_testkit::service_log_of(&inputs().dir, "cut-short", 5000);
    let full = std::fs::read(long).unwrap();
    let cut = write(&inputs().dir, "half.mcap", &full[..full.len() / 2]);
    for sub in ["info", "verify"] {
        let out = run("strand-replay", &[sub], &cut);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!stderr.contains("panicked"), "{stderr}");
        assert!(out.status.success(), "{sub}: {stderr}");
        assert!(stderr.contains("half.mcap: cut short"), "{sub}: {stderr}");
    }
}

#[test]
fn strand_kin_check_config_and_sim_refuse_bad_files() {
    let mut failures = Vec::new();
    let dir = &inputs().dir;
    for bad in &inputs().configs {
        failures.extend(check("strand check-config", bad, &run("strand", &["check-config"], &bad.path)));
        failures.extend(check("strand run --config", bad, &run("strand", &["run", "--no-log", "--ticks", "1", "--config"], &bad.path)));
        failures.extend(check("strand-kin check", bad, &run("strand-kin", &["check"], &bad.path)));
        failures.extend(check("strand-sim --config", bad, &run("strand-sim", &["--config"], &bad.path)));
        // An empty plant config is a valid one (every section has defaults).
        if bad.label != "empty file" {
            failures.extend(check("strand-sim --sim", bad, &run("strand-sim", &["--sim"], &bad.path)));
        }
    }
    // A plant config out of range, and a robot file whose URDF is junk.
    let plant = Bad { label: "a NaN lag", path: write(dir, "plant.toml", b"[joints]\nlag = nan\n"), line: None };
    failures.extend(check("strand-sim --sim", &plant, &run("strand-sim", &["--sim"], &plant.path)));
    write(dir, "junk.urdf", &junk(2048));
    let robot = Bad {
        label: "a robot file with a junk URDF",
        path: write(
            dir,
            "robot.toml",
            b"urdf = \"junk.urdf\"\nroot_link = \"a\"\ntip_link = \"b\"\n[limits]\nacceleration = [1]\njerk = [1]\n",
        ),
        line: None,
    };
    failures.extend(check("strand-kin check", &robot, &run("strand-kin", &["check"], &robot.path)));
    let urdf = Bad { label: "a junk URDF", path: dir.join("junk.urdf"), line: None };
    failures.extend(check("strand-kin check --root --tip", &urdf, &run("strand-kin", &["check", "--root", "a", "--tip", "b"], &urdf.path)));
    assert_all(failures);
}

/// Once panics (an overflowing tick cap in the path timing, now tools/job/src/timing.rs) and hangs: a far move is refused by the
/// parser (coordinates beyond 1e6 m), a move of 1e20 s by strand-plan time, naming the line.
#[test]
fn absurd_moves_are_refused_not_timed() {
    let dir = &inputs().dir;
    // `tick_cap = tick + 1000 + (20.0 * lower_bound_s / dt) as u64 + …`: the cast saturates at
    // u64::MAX and the additions overflow. A far move or a tiny feed reaches it.
    let far = write(dir, "far.gcode", format!("G1 X{} F100\n", "9".repeat(20)).as_bytes());
    let slow = write(dir, "slow.gcode", b"G1 X1 F0.0000000000000000001\n");
    let mut failures = Vec::new();
    for (label, path) in [("a move of 1e17 m", far), ("F1e-19", slow)] {
        let bad = Bad { label, path, line: None };
        // check-job runs what the controller would: a lone travel is the approach's target (a
        // joint-space move, whatever its feed), so only the far move is absurd there.
        let tools: &[(&str, &[&str])] =
            if label == "F1e-19" { &[("strand-plan", &["time"])] } else { &[("strand-plan", &["time"]), ("strand", &["check-job"])] };
        for &(tool, args) in tools {
            let out = run(tool, args, &bad.path);
            let stderr = String::from_utf8_lossy(&out.stderr);
            if stderr.contains("panicked") || out.status.success() || !stderr.contains(":1") {
                failures.push(format!("{tool} {} on {label}: {stderr}", args[0]));
            }
        }
    }
    assert_all(failures);
}
