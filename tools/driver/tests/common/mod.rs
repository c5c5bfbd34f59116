//! What the driver tests share: the job every cell prints.

/// Two layers of three 10 mm squares at 30 mm/s in the middle of the bundled robots' beds (G-code).
pub fn squares_gcode() -> String {
    let mut g = String::from("G21\nG90\nM83\n");
    for l in 0..2 {
        let z = 0.2 * (l + 1) as f64;
        g += &format!(";LAYER_CHANGE\n;Z:{z:.1}\nG0 X120 Y120 Z{z:.1} F6000\nG1 F1800\n");
        for _ in 0..3 {
            g += "G1 X130 Y120 E0.4\nG1 X130 Y130 E0.4\nG1 X120 Y130 E0.4\nG1 X120 Y120 E0.4\n";
        }
    }
    g
}
