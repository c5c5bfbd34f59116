//! Any bytes through the G-code parser: no panic, errors name file, line and column, segments are
//! finite (see `strand_fuzz::checks::check_parser`).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    strand_fuzz::checks::check_parser(data);
});
