//! What every strand command-line tool shares, and nothing else: the typed error their library code
//! returns ([`error::ToolError`]; text is made only in the mains), the jobs built into the binaries
//! ([`jobs`]), and the guard a tool holds its child processes in ([`child`]).
//!
//! Each tool is its own crate under `tools/` (strand-feed, strand-replay, strand-kin, strand-plan,
//! strand-sim, strand-bench) and depends on this one; this one depends on no tool, so no tool links
//! another's dependencies through it.

pub mod child;
pub mod error;
pub mod jobs;
