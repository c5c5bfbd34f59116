//! The demo's summary as a table on stdout: one row per measurement, the units in the text.

use std::path::Path;

use super::summary::{Report, Spread};

fn mm(s: &Spread) -> String {
    format!("mean {:.3} mm, p99 {:.3} mm, max {:.3} mm", s.mean * 1e3, s.p99 * 1e3, s.max * 1e3)
}

fn us(s: &Spread) -> String {
    format!("p50 {:.1} µs, p99 {:.1} µs, max {:.1} µs", s.p50 * 1e6, s.p99 * 1e6, s.max * 1e6)
}

/// Prints the summary of a run `r` that took `wall` seconds, its log and the sim's round trip.
pub(crate) fn print_table(r: &Report, wall: f64, log: &Path, log_bytes: u64, sim: Option<&serde_json::Value>) {
    let mut rows: Vec<(String, String)> = vec![
        ("robot".into(), format!("{} at {} Hz", r.robot, r.rate_hz)),
        (
            "job".into(),
            match r.job_outcome.as_str() {
                "Faulted" => format!(
                    "FAULTED: {} after {:.1} s of robot time",
                    r.faults.first().map_or("fault not in the log".to_string(), |(t, c)| format!("{c} at tick {t}")),
                    r.job_time_s
                ),
                outcome => format!(
                    "{}{}, {:.1} s of robot time in {wall:.1} s wall ({:.1}× real time)",
                    if outcome == "Finished" { "" } else { "NOT FINISHED: " },
                    outcome,
                    r.job_time_s,
                    r.job_time_s / wall.max(1e-9)
                ),
            },
        ),
        ("segments".into(), format!("{} accepted, {} rejected, {} underruns", r.segments_accepted, r.segments_rejected, r.underruns)),
        (
            "heaters".into(),
            match &r.heat {
                Some(h) if h.extruding_c[0].is_finite() => format!(
                    "held {:.1} s for the bed, {:.1} s for the hot end (heat-up and settle); extruded at {:.1}-{:.1} °C",
                    h.bed_wait_s, h.hot_end_wait_s, h.extruding_c[0], h.extruding_c[1]
                ),
                Some(h) => format!("held {:.1} s for the bed, {:.1} s for the hot end; nothing extruded", h.bed_wait_s, h.hot_end_wait_s),
                None => "not acted on ([extruder] heater = \"none\")".into(),
            },
        ),
        ("TCP error (sim truth)".into(), format!("{} over {} ticks", mm(&r.tcp_error_m), r.tcp_error_m.samples)),
        ("TCP error (controller's view)".into(), mm(&r.tcp_error_estimated_m)),
        (
            "TCP error watchdog".into(),
            format!(
                "max {:.3} mm = {:.0} % of tcp_error_limit {:.1} mm",
                r.tcp_error_fault_m * 1e3,
                100.0 * r.tcp_error_fault_m / r.tcp_error_limit_m.max(1e-12),
                r.tcp_error_limit_m * 1e3
            ),
        ),
    ];
    if let Some(b) = &r.base_error_m {
        rows.push(("base vs its plan".into(), mm(b)));
    }
    if let Some(b) = &r.base_lag_m {
        rows.push(("base setpoint lag".into(), mm(b)));
    }
    if let Some(b) = &r.reach_m {
        rows.push(("arm's reach (base → nozzle)".into(), mm(b)));
    }
    // Not a bead error: the hot end's melt lags the extruder's command at every start and stop
    // (the bead row below is what a print is judged by), so say what it measures.
    rows.push((
        "hot-end lag (melt vs command)".into(),
        format!(
            "|melt − commanded melt| while extruding, the hot end's lag at starts and stops (the bead below judges the print): mean {:.1} %, p99 {:.1} % of the mean flow {:.2} mm³/s; deposited {:.1} % of commanded",
            100.0 * r.flow_error_m3s.mean / r.flow_mean_m3s.max(1e-30),
            100.0 * r.flow_error_m3s.p99 / r.flow_mean_m3s.max(1e-30),
            r.flow_mean_m3s * 1e9,
            100.0 * r.volume_ratio
        ),
    ));
    let b = &r.bead;
    rows.push((
        "bead (sim truth, 1 mm bins)".into(),
        format!(
            "{} bins: error p50 {:.1} %, p95 {:.1} %, p99 {:.1} %; {:.2} % beyond ±10 %; mean {:+.1} % (nozzle {:.0} ms behind its target)",
            b.all.bins,
            100.0 * b.all.p50,
            100.0 * b.all.p95,
            100.0 * b.all.p99,
            100.0 * b.all.beyond_10pct,
            100.0 * b.all.mean_signed,
            b.path_delay_s * 1e3
        ),
    ));
    for (name, e) in &b.by_feature {
        rows.push((
            format!("  {name}"),
            format!(
                "{} bins: p50 {:.1} %, p95 {:.1} %, {:.2} % beyond ±10 %",
                e.bins,
                100.0 * e.p50,
                100.0 * e.p95,
                100.0 * e.beyond_10pct
            ),
        ));
    }
    rows.push((
        "blobs / strings".into(),
        format!(
            "{:.3} % / {:.3} % of the melt ({:.1} mm of travel with melt flowing)",
            100.0 * b.blob_share(),
            100.0 * b.string_share(),
            b.string_length_m * 1e3
        ),
    ));
    rows.push(("controller step".into(), us(&r.step_s)));
    rows.push(("tick (wake → publish)".into(), us(&r.tick_s)));
    if let Some(rt) = sim.and_then(|s| s.get("round_trip")) {
        let f = |k: &str| rt.get(k).and_then(|v| v.as_f64()).unwrap_or(0.0) * 1e-3;
        rows.push((
            "state → command (sim)".into(),
            format!("p50 {:.1} µs, p99 {:.1} µs, max {:.1} µs", f("p50_ns"), f("p99_ns"), f("max_ns")),
        ));
    }
    rows.push(("lateness".into(), format!("{} (robot clock: the tick waits for the robot)", us(&r.lateness_s))));
    rows.push(("overruns / late / clamps".into(), format!("{} / {} / {}", r.overruns, r.late_wakeups, r.clamps)));
    rows.push((
        "faults".into(),
        if r.faults.is_empty() {
            "none".into()
        } else {
            r.faults.iter().map(|(t, c)| format!("{c} at tick {t}")).collect::<Vec<_>>().join(", ")
        },
    ));
    rows.push(("log".into(), format!("{} ({} ticks, {:.1} MB, {} dropped)", log.display(), r.ticks, log_bytes as f64 / 1e6, r.log_drops)));
    rows.push(("strand-replay verify".into(), r.verify.clone()));
    let w = rows.iter().map(|(k, _)| k.chars().count()).max().unwrap_or(0);
    println!();
    for (k, v) in rows {
        println!("  {k:<w$}  {v}");
    }
}
