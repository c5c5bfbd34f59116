//! Writes strand-cad's test models (`strand_cad::models`) into `tests/data/step/` of the workspace, or
//! into the folder given: `cargo run -p strand-cad --example make_step_models [DIR]`.

fn main() {
    let dir = std::env::args_os()
        .nth(1)
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/step"));
    strand_cad::models::write_all(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    println!("wrote the test models into {}", dir.display());
}
