//! The sim's ground truth, one row a robot cycle: where the nozzle really was (the actual joints
//! through the actual base) and how much melt really left it, stamped with the sim's time. strand-sim
//! writes it (`--truth`, CSV); the bead analysis and the demo's summary read it back beside the log.
//! It lives here, with its readers, so that the sim depends on the replay tools and not the reverse.

use std::path::Path;

use strand_cli::error::{Result, ToolError};

/// What really happened in one cycle, at the sim's time.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Truth {
    /// Sim time (ns), the stamp of the JointState measured at the end of this cycle.
    pub time_ns: u64,
    /// The nozzle tip (m, W): actual joints through the actual base.
    pub tcp: [f64; 3],
    /// The robot base (m, W).
    pub base: [f64; 3],
    /// The base's heading (rad).
    pub base_theta: f64,
    /// Where the base should be (m, W; the flyer's plan, else the mount).
    pub base_planned: [f64; 3],
    /// Melt flow the controller asked for (m³/s).
    pub flow_commanded: f64,
    /// Melt flow leaving the nozzle (m³/s).
    pub flow_actual: f64,
    /// Largest thruster command over its limit (1 = at the limit; 0 without a flyer).
    pub thrust_saturation: f64,
    /// The nozzle tip on the part (m, W, in the work frame at home, where a job's points are):
    /// with a positioner, brought back from where its actual axes carry the part; else `tcp`.
    pub tcp_part: [f64; 3],
    /// The nozzle tip's height above the true bed (m, along the bed's normal): above the sim's
    /// `[bed]` surface if it has one, else above the service config's bed plane. NaN in a file
    /// from before the column.
    pub bed_gap: f64,
}

impl Truth {
    /// The CSV header of [`Truth::csv_row`].
    pub const CSV_HEADER: &'static str = "time_ns,tcp_x,tcp_y,tcp_z,base_x,base_y,base_z,base_theta,base_plan_x,base_plan_y,flow_cmd_m3s,flow_actual_m3s,thrust_saturation,tcp_part_x,tcp_part_y,tcp_part_z,bed_gap";

    /// One CSV row (SI units; f64 printed exactly so the reader gets the same bits).
    pub fn csv_row(&self) -> String {
        let t = self;
        format!(
            "{},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?}",
            t.time_ns,
            t.tcp[0],
            t.tcp[1],
            t.tcp[2],
            t.base[0],
            t.base[1],
            t.base[2],
            t.base_theta,
            t.base_planned[0],
            t.base_planned[1],
            t.flow_commanded,
            t.flow_actual,
            t.thrust_saturation,
            t.tcp_part[0],
            t.tcp_part[1],
            t.tcp_part[2],
            t.bed_gap
        )
    }
}

/// Reads the truth CSV written by `strand-sim --truth`.
pub fn read_truth(path: &Path) -> Result<Vec<Truth>> {
    let mut rd = csv::Reader::from_path(path).map_err(|e| ToolError::Content(format!("{}: {e}", path.display())))?;
    let mut rows = Vec::new();
    for (i, rec) in rd.records().enumerate() {
        let rec = rec.map_err(|e| ToolError::Content(format!("{}: line {}: {e}", path.display(), i + 2)))?;
        let f = |k: usize| -> Result<f64> {
            rec.get(k)
                .unwrap_or("")
                .parse::<f64>()
                .map_err(|_| ToolError::Content(format!("{}: line {}: column {} is not a number", path.display(), i + 2, k + 1)))
        };
        rows.push(Truth {
            time_ns: rec
                .get(0)
                .unwrap_or("")
                .parse()
                .map_err(|_| ToolError::Content(format!("{}: line {}: time_ns is not a whole number", path.display(), i + 2)))?,
            tcp: [f(1)?, f(2)?, f(3)?],
            base: [f(4)?, f(5)?, f(6)?],
            base_theta: f(7)?,
            base_planned: [f(8)?, f(9)?, f(6)?],
            flow_commanded: f(10)?,
            flow_actual: f(11)?,
            thrust_saturation: f(12)?,
            // A file from before the column: no positioner, the part is where W is.
            tcp_part: if rec.len() > 15 { [f(13)?, f(14)?, f(15)?] } else { [f(1)?, f(2)?, f(3)?] },
            bed_gap: if rec.len() > 16 { f(16)? } else { f64::NAN },
        });
    }
    Ok(rows)
}
