//! Shared pieces of the strand command-line tools.

pub mod bench;
pub mod demo;
pub mod feed;
pub mod jobs;
pub mod plan;
pub mod replay;
pub mod robot_arg;
pub mod sim;
