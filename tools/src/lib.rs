//! Shared pieces of the strand command-line tools.

pub mod robot_arg;
