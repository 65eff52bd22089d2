//! Output cells of the CSV files the commands write. The in-memory and the streamed
//! `compensate` write their rows with the same cells, so the two files are identical.

/// An output cell of a computed value: `d` decimals, empty when missing.
pub fn fixed_cell(v: f64, d: usize) -> String {
    if v.is_finite() {
        format!("{v:.d$}")
    } else {
        String::new()
    }
}

/// `v` rounded to `d` decimals, still a number: for the tables written by the shortest
/// round-trip writer (`io::trace::write_number`), so an f32 filter's interference is
/// written `-574.6337` as [`fixed_cell`] writes it in the one-sensor table, not
/// `-574.6337280273438`. NaN stays NaN (an empty cell).
pub fn rounded(v: f64, d: i32) -> f64 {
    let scale = 10f64.powi(d);
    (v * scale).round() / scale
}

/// An output cell of a carried input number: as read, empty when missing.
pub fn number_cell(v: f64) -> String {
    if v.is_finite() {
        v.to_string()
    } else {
        String::new()
    }
}

/// An output cell of text, quoted when it holds a comma, a quote or a newline.
pub fn csv_text(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}
