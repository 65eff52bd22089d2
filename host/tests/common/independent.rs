//! The independent simulator's flights (`../shared/reference-data/independent-sim`, not
//! in the repository: its licence is not stated), with their truth columns appended.

use magcomp::io::trace::{read_trace, ColumnMap, Trace};
use std::path::PathBuf;

/// The flight `name` (`clean_s33`, `lag_s32`) with its truth columns; None where the
/// shared data are absent.
pub fn independent(name: &str) -> Option<Trace> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/reference-data/independent-sim");
    let lines = |f: &str| -> Option<Vec<String>> {
        let text = std::fs::read_to_string(dir.join(f)).ok()?;
        Some(
            text.lines()
                .filter(|l| !l.starts_with('#'))
                .map(str::to_owned)
                .collect(),
        )
    };
    let (data, truth) = (
        lines(&format!("{name}.csv"))?,
        lines(&format!("{name}.truth.csv"))?,
    );
    let merged: Vec<String> = data
        .iter()
        .zip(&truth)
        .map(|(d, t)| format!("{d},{}", t.split_once(',').map_or("", |x| x.1)))
        .collect();
    let path = std::env::temp_dir().join(format!(
        "magcomp-independent-{name}-{}.csv",
        std::process::id()
    ));
    std::fs::write(&path, merged.join("\n")).ok()?;
    let trace = read_trace(&path, &ColumnMap::new()).expect("read");
    let _ = std::fs::remove_file(&path);
    Some(trace)
}
