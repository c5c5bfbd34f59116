//! The counting global allocator (`strand::io::alloc_count`), for the tests that prove a path does
//! not touch the heap. A test binary installs it with
//! `#[global_allocator] static GLOBAL: counting::Counting = counting::Counting;`.
#![allow(unused_imports)]

pub(crate) use strand::io::alloc_count::{Counting, allocations};
