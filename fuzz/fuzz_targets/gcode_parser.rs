//! Any bytes through the G-code parser: no panic, errors name file, line and column, segments are
//! finite and pass `Segment::check` (see `strand_fuzz::checks::check_parser`). An input whose first
//! byte is 0x80 or above runs the rest with 5-axis options (rotary words A/B/C mapped onto external
//! axes, the tool-direction dialect: `strand_fuzz::checks::split_options`).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    strand_fuzz::checks::check_parser(data);
});
