//! Any bytes through the G-code parser and then the path engine: it finishes the program within a
//! bound and keeps every limit (see `strand_fuzz::checks::check_path`).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    strand_fuzz::checks::check_path(data);
});
