//! Reading/writing speed on a generated large trace. Ignored by default (it writes a few
//! hundred MB); run with
//! `cargo test --release -p magcomp --test trace_speed -- --ignored --nocapture`
//! (`MAGCOMP_SPEED_ROWS` sets the row count, default 1 000 000 × 20 columns).
use magcomp::io::trace::*;
use std::path::PathBuf;
use std::time::Instant;

#[test]
#[ignore]
fn read_speed_large_csv() {
    let rows: usize = std::env::var("MAGCOMP_SPEED_ROWS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1_000_000);
    let mut tr = Trace::default();
    tr.meta.push(("sample_rate_hz".into(), "1000".into()));
    tr.set_col("t", (0..rows).map(|i| 1000.0 + i as f64 * 1e-3).collect());
    let names = [
        "mag", "flux_x", "flux_y", "flux_z", "lat", "lon", "alt", "vn", "ve", "vd", "roll",
        "pitch", "yaw", "base", "igrf", "cur_a", "cur_b", "v_bus", "rpm",
    ];
    for (k, n) in names.iter().enumerate() {
        // Realistic magnitudes and 3-decimal survey precision.
        let scale = [52000.0, 40000.0, 30000.0, 11000.0, 45.3, -75.6, 223.5][k % 7];
        tr.set_col(
            n,
            (0..rows)
                .map(|i| {
                    ((scale + (i as f64 * 0.37 + k as f64).sin() * 10.0) * 1000.0).round() / 1000.0
                })
                .collect(),
        );
    }
    let path = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("trace_speed.csv");
    let t0 = Instant::now();
    write_trace(&path, &tr).unwrap();
    let write_s = t0.elapsed().as_secs_f64();
    let bytes = std::fs::metadata(&path).unwrap().len();
    let t0 = Instant::now();
    let back = read_trace(&path, &ColumnMap::new()).unwrap();
    let read_s = t0.elapsed().as_secs_f64();
    assert_eq!(back.len(), rows);
    assert_eq!(back.col("mag"), tr.col("mag"));
    println!(
        "{rows} rows x {} columns, {:.0} MB: write {:.2} s ({:.0} rows/s), read {:.2} s ({:.0} rows/s, {:.0} MB/s)",
        names.len() + 1,
        bytes as f64 / 1e6,
        write_s,
        rows as f64 / write_s,
        read_s,
        rows as f64 / read_s,
        bytes as f64 / 1e6 / read_s
    );
    std::fs::remove_file(&path).ok();
}
