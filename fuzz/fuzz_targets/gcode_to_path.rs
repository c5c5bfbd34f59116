//! Any bytes through the G-code parser and then the path engine: it finishes the program within a
//! bound and keeps every limit (see `strand_fuzz::checks::check_path`). An input whose first byte is
//! 0x80 or above runs the rest with 5-axis options, and the engine then has external axes
//! (`strand_fuzz::checks::split_options`).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    strand_fuzz::checks::check_path(data);
});
