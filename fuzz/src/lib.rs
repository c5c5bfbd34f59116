//! Support for the fuzz targets: the checks, shared with `tests/fuzz_regressions.rs`.

pub mod checks;
