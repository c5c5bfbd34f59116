//! The strand command-line tools' code, one module per tool (the ripgrep way: the `bin/` mains
//! only turn the command line into an options struct, call the tool and turn its result into
//! output and an exit code). Every function here returns a typed [`error::ToolError`]; text is
//! made only at the edge.
//!
//! - [`bead`] — the deposited bead against the program (1 mm bins, blobs, strings), and the
//!   calibration of the hot end's lag and the arm's delay.
//! - [`demo`] — strand-demo: the service, the sim and the feeder on a bundled job, then a summary.
//! - [`feed`] — strand-feed: a job loaded, checked and streamed within the controller's credit.
//! - [`sim`] — strand-sim: the plant (robot, free flyer, tracker, extruder) and its process loop.
//! - [`kin`] — strand-kin: a robot chain checked and evaluated.
//! - [`plan`] — strand-plan: timing a job, and the papers' offline planners.
//! - [`replay`] — strand-replay: what a log says (summary, CSV, plots).
//! - [`bench`] — strand-bench: jitter, latency, tick cost and logger throughput as distributions.
//! - [`jobs`] — the bundled jobs the demo and the benches run when given none.

pub mod bead;
pub mod bench;
pub mod demo;
pub mod error;
pub mod feed;
pub mod jobs;
pub mod kin;
pub mod plan;
pub mod replay;
pub mod sim;
