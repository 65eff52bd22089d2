//! Reading, validating and writing traces (trace-format.md).
use magcomp::io::trace::*;
use std::path::{Path, PathBuf};

fn read_str(text: &str, map: &str) -> Result<Trace, TraceError> {
    read_trace_from(
        text.as_bytes(),
        "flight.csv",
        &ColumnMap::parse(map).unwrap(),
    )
}

fn err_str(text: &str) -> String {
    read_str(text, "").unwrap_err().to_string()
}

const BASIC: &str =
    "# sample_rate_hz: 10\r\n# aircraft: Cessna 208\r\n# free comment, not metadata\r\n\
t,mag,flux_x,flux_y,flux_z,segment,cur_strobe,note\r\n\
0.0,53620.44,-5460.864,46219.785,-21467.076,cal_h045,1.5,ok\r\n\
0.1,,nan,NaN,*,cal_h045,,x1\r\n\
# a comment between rows\r\n\
\r\n\
0.2,53619.9,1,2,3,line_1010,2.5,\r\n";

#[test]
fn reads_metadata_missing_values_and_text_columns() {
    let tr = read_str(BASIC, "").unwrap();
    assert_eq!(tr.len(), 3);
    assert_eq!(tr.meta("sample_rate_hz"), Some("10"));
    assert_eq!(tr.meta("aircraft"), Some("Cessna 208"));
    assert_eq!(
        tr.meta.len(),
        2,
        "a free comment is not metadata: {:?}",
        tr.meta
    );
    assert_eq!(tr.col("t").unwrap(), &[0.0, 0.1, 0.2]);
    let mag = tr.col("mag").unwrap();
    assert_eq!(mag[0], 53620.44);
    assert!(mag[1].is_nan(), "empty field is missing, never zero");
    for c in ["flux_x", "flux_y", "flux_z"] {
        assert!(tr.col(c).unwrap()[1].is_nan(), "{c}");
    }
    assert_eq!(
        tr.text_col("segment").unwrap(),
        &["cal_h045", "cal_h045", "line_1010"]
    );
    assert_eq!(tr.text_col("note").unwrap(), &["ok", "x1", ""]);
    assert!(tr.col("note").is_none());
    let cur = tr.col("cur_strobe").unwrap();
    assert_eq!((cur[0], cur[2]), (1.5, 2.5));
    assert!(cur[1].is_nan());
    assert_eq!(tr.aux_columns(), vec!["cur_strobe"]);
    let flux = tr.flux().unwrap();
    assert_eq!(flux[2], [1.0, 2.0, 3.0]);
    tr.require(required_columns()[..5].as_ref()).unwrap();
}

#[test]
fn auto_column_with_leading_missing_values_is_typed_by_first_value() {
    let tr = read_str("t,a,b,c\n1,,,\n2,,x,\n3,4,y,\n", "").unwrap();
    let a = tr.col("a").unwrap();
    assert!(a[0].is_nan() && a[1].is_nan() && a[2] == 4.0);
    assert_eq!(tr.text_col("b").unwrap(), &["", "x", "y"]);
    assert!(
        tr.col("c").unwrap().iter().all(|v| v.is_nan()),
        "all-missing column is numeric NaN"
    );
}

#[test]
fn quoted_fields_from_spreadsheets() {
    let tr = read_str(
        "\u{feff}t,segment,\"v\"\n1,\"turn, left\",\"2.5\"\n2, \"say \"\"hi\"\"\" ,3\n",
        "",
    )
    .unwrap();
    assert_eq!(
        tr.text_col("segment").unwrap(),
        &["turn, left", "say \"hi\""]
    );
    assert_eq!(tr.col("v").unwrap(), &[2.5, 3.0]);
}

#[test]
fn unparsable_number_names_file_line_column_and_text() {
    let text = "# m: 1\nt,mag\n0,1\n1,53x12.1\n";
    assert_eq!(
        err_str(text),
        "flight.csv:4: column 'mag': cannot parse \"53x12.1\" as a number"
    );
    // An auxiliary column that started numeric stays numeric: a later word is an error.
    let e = err_str("t,cur_a\n0,1\n1,2\n2,oops\n");
    assert_eq!(
        e,
        "flight.csv:4: column 'cur_a': cannot parse \"oops\" as a number"
    );
    // Defined numeric columns never become text, even when the first value is bad.
    let e = err_str("t,lat\n0,N45\n");
    assert!(e.contains("column 'lat'") && e.contains("\"N45\""), "{e}");
    // Infinity is not a reading.
    assert!(err_str("t,mag\n0,inf\n").contains("\"inf\""));
}

#[test]
fn wrong_field_count_names_line() {
    assert_eq!(
        err_str("t,mag,flux_x\n0,1,2\n1,2\n"),
        "flight.csv:3: expected 3 fields (as in the header), found 2"
    );
    assert_eq!(
        err_str("t,mag\n0,1,2,3\n"),
        "flight.csv:2: expected 2 fields (as in the header), found 4"
    );
}

#[test]
fn time_must_be_present_and_strictly_increasing() {
    assert_eq!(
        err_str("t,mag\n0,1\n0.1,1\n0.1,1\n"),
        "flight.csv:4: column 't' must be strictly increasing: 0.1 follows 0.1"
    );
    assert!(err_str("t,mag\n0,1\n,1\n").starts_with("flight.csv:3: column 't' is missing"));
    // Can be switched off, and then checked in memory by row.
    let opts = ReadOptions {
        check_time: false,
        ..Default::default()
    };
    let tr = read_trace_from_with("t\n2\n1\n".as_bytes(), "x", &ColumnMap::new(), opts, 0).unwrap();
    assert_eq!(
        tr.check_time().unwrap_err().to_string(),
        "row 2: column 't' must be strictly increasing: 1 follows 2"
    );
}

#[test]
fn header_errors() {
    assert_eq!(
        err_str(""),
        "flight.csv: no header line (the file is empty or only comments)"
    );
    assert_eq!(err_str("# a: b\n# only comments\n\n"), err_str(""));
    assert_eq!(
        err_str("t,mag,t\n"),
        "flight.csv:1: header: duplicate column name 't' (columns 1 and 3)"
    );
    assert_eq!(
        err_str("t,,mag\n"),
        "flight.csv:1: header: column 2 has an empty name"
    );
    assert!(matches!(
        read_trace_from(&b"t,mag\n\x00\xff\n"[..], "f", &ColumnMap::new()),
        Err(TraceError::Utf8 { line: 2, .. })
    ));
}

#[test]
fn column_map_renames_and_reports_its_errors() {
    let tr = read_str(
        "tt,mag_4_uc,flux_b_x\n0,1,2\n",
        "mag=mag_4_uc, t=tt,flux_x=flux_b_x",
    )
    .unwrap();
    assert_eq!(tr.column_names(), vec!["t", "mag", "flux_x"]);
    assert_eq!(tr.col("mag").unwrap(), &[1.0]);
    // Swapping two names is allowed.
    let tr = read_str("mag,mag_4_uc\n1,2\n", "mag=mag_4_uc,mag_orig=mag").unwrap();
    assert_eq!(
        (tr.col("mag").unwrap()[0], tr.col("mag_orig").unwrap()[0]),
        (2.0, 1.0)
    );

    let perr = |s: &str| ColumnMap::parse(s).unwrap_err().to_string();
    assert_eq!(
        perr("mag"),
        "column map: entry 1 'mag': missing '=' (and not a preset: magnav, sgl) (expected canonical=file_column)"
    );
    assert_eq!(perr("t=tt,=x"), "column map: entry 2 '=x': empty canonical name before '=' (expected canonical=file_column)");
    assert!(perr("t=").contains("empty file column name"));
    assert!(perr("a=b=c").contains("more than one '='"));
    assert_eq!(
        perr("t=a,t=b"),
        "column map: 't' is mapped twice (to 'a' and 'b')"
    );
    assert!(perr("t=a,u=a").contains("file column 'a' is mapped twice"));
    assert_eq!(ColumnMap::parse("  ").unwrap(), ColumnMap::new());
    assert!("t=tt".parse::<ColumnMap>().is_ok());

    let e = read_str("t,mag\n0,1\n", "mag=mag_4_uc")
        .unwrap_err()
        .to_string();
    assert_eq!(
        e,
        "column map: 'mag=mag_4_uc': the file has no column 'mag_4_uc'; it has: t, mag"
    );
    let e = read_str("t,mag,m4\n0,1,2\n", "mag=m4")
        .unwrap_err()
        .to_string();
    assert!(e.contains("also has a column named 'mag'"), "{e}");
}

#[test]
fn require_names_missing_and_available_columns() {
    let tr = read_str("t,mag,segment\n0,1,a\n", "").unwrap();
    tr.require(&["t", "segment"]).unwrap();
    assert_eq!(
        tr.require(&["t", "mag", "flux_x", "lat"])
            .unwrap_err()
            .to_string(),
        "missing required columns 'flux_x', 'lat'; the trace has: t, mag, segment"
    );
    assert_eq!(
        tr.require_contract().unwrap_err().to_string(),
        "missing required columns 'flux_x', 'flux_y', 'flux_z', 'lat', 'lon', 'alt'; the trace has: t, mag, segment"
    );
    assert!(tr.flux().is_none());
    assert_eq!(
        required_columns(),
        &["t", "mag", "flux_x", "flux_y", "flux_z", "lat", "lon", "alt"]
    );
}

#[test]
fn aux_columns_exclude_contract_truth_and_text() {
    let tr = read_str(
        "t,mag,base,igrf,vn,roll,truth_interference,cur_flap,v_bat1,segment,rpm\n0,1,2,3,4,5,6,7,8,a,9\n",
        "",
    )
    .unwrap();
    assert_eq!(tr.aux_columns(), vec!["cur_flap", "v_bat1", "rpm"]);
    assert_eq!(tr.truth_columns(), vec!["truth_interference"]);
}

#[test]
fn write_then_read_round_trips_exactly() {
    let mut tr = Trace::default();
    tr.meta.push(("sample_rate_hz".into(), "10".into()));
    tr.meta
        .push(("aircraft".into(), "Cessna 208: C-GNRC".into()));
    let n = 500;
    let t: Vec<f64> = (0..n).map(|i| 49820.0 + i as f64 * 0.1).collect();
    let mut rng = 0x2545F4914F6CDD1Du64;
    let mut next = || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng >> 11) as f64 / (1u64 << 53) as f64
    };
    let mag: Vec<f64> = (0..n)
        .map(|i| {
            if i % 37 == 5 {
                f64::NAN
            } else {
                50000.0 + 8000.0 * next()
            }
        })
        .collect();
    let tiny: Vec<f64> = (0..n).map(|_| (next() - 0.5) * 1e-9).collect();
    let huge: Vec<f64> = (0..n).map(|_| (next() - 0.5) * 1e22).collect();
    tr.set_col("t", t);
    tr.set_col("mag", mag);
    tr.set_col("cur_tiny", tiny);
    tr.set_col("cur_huge", huge);
    tr.set_text_col(
        "segment",
        (0..n)
            .map(|i| ["turn, left", "line_1010", "", "say \"x\""][i % 4].to_string())
            .collect(),
    );

    let mut out = Vec::new();
    write_trace_to(&mut out, &tr).unwrap();
    let text = String::from_utf8(out.clone()).unwrap();
    // Numeric fields (the first 4 columns) are plain decimals, even for 1e22 and 1e-10.
    for line in text.lines().skip(3) {
        for f in line.split(',').take(4) {
            assert!(
                f.chars()
                    .all(|c| c.is_ascii_digit() || c == '.' || c == '-'),
                "{f:?} in {line}"
            );
        }
    }
    assert!(text.starts_with(
        "# sample_rate_hz: 10\n# aircraft: Cessna 208: C-GNRC\nt,mag,cur_tiny,cur_huge,segment\n"
    ));
    let back = read_trace_from(out.as_slice(), "rt.csv", &ColumnMap::new()).unwrap();
    assert_eq!(back.meta, tr.meta);
    assert_eq!(back.text, tr.text);
    for (name, v) in &tr.numeric {
        let w = back.col(name).unwrap();
        assert_eq!(w.len(), v.len());
        for (a, b) in v.iter().zip(w) {
            assert!(
                a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()),
                "{name}: {a} vs {b}"
            );
        }
    }

    // Through a file too.
    let path = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("trace_roundtrip.csv");
    write_trace(&path, &tr).unwrap();
    assert_eq!(
        read_trace(&path, &ColumnMap::new())
            .unwrap()
            .col("mag")
            .unwrap()
            .len(),
        n
    );
}

#[test]
fn writer_refuses_what_the_reader_could_not_read_back() {
    let mut tr = Trace::default();
    tr.set_col("t", vec![1.0, 2.0]);
    tr.set_col("mag", vec![1.0]);
    assert!(write_trace_to(Vec::new(), &tr)
        .unwrap_err()
        .to_string()
        .contains("different lengths"));
    let mut tr = Trace::default();
    tr.set_col("a,b", vec![1.0]);
    assert!(write_trace_to(Vec::new(), &tr).is_err());
    // A lone all-missing column must not turn into blank (skipped) lines.
    let mut tr = Trace::default();
    tr.set_col("x", vec![f64::NAN, 1.0]);
    let mut out = Vec::new();
    write_trace_to(&mut out, &tr).unwrap();
    let back = read_trace_from(out.as_slice(), "x", &ColumnMap::new()).unwrap();
    assert_eq!(back.len(), 2);
}

#[test]
fn xyz_layout_detected_by_content() {
    let text = "/ survey\n/\n/  TIME  MAG  NAME\nLine 1001\n  1.0  5.5 a\n 2.0 * b\n/ trailing comment\n3.0 7 c\n";
    let tr = read_trace_from(
        text.as_bytes(),
        "s.xyz",
        &ColumnMap::parse("t=TIME").unwrap(),
    )
    .unwrap();
    assert_eq!(tr.col("t").unwrap(), &[1.0, 2.0, 3.0]);
    let m = tr.col("MAG").unwrap();
    assert!(m[0] == 5.5 && m[1].is_nan() && m[2] == 7.0);
    assert_eq!(tr.text_col("NAME").unwrap(), &["a", "b", "c"]);
    let e = read_trace_from("/ A B\n1 2 3\n".as_bytes(), "s.xyz", &ColumnMap::new()).unwrap_err();
    assert_eq!(
        e.to_string(),
        "s.xyz:2: expected 2 fields (as in the header), found 3"
    );
    // Forcing CSV on XYZ content reads the / lines as a header, not as comments.
    let opts = ReadOptions {
        layout: Layout::Csv,
        ..Default::default()
    };
    let tr = read_trace_from_with("/ A B\n".as_bytes(), "s", &ColumnMap::new(), opts, 0).unwrap();
    assert_eq!(tr.column_names(), vec!["/ A B"]);
}

fn reference_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/reference-data")
}

#[test]
fn reads_magnav_flt1003_sample() {
    let path = reference_dir().join("Flt1003_sample.xyz");
    if !path.exists() {
        println!(
            "SKIP reads_magnav_flt1003_sample: {} not found",
            path.display()
        );
        return;
    }
    let map = ColumnMap::parse(
        "mag=UNCOMPMAG4,flux_x=FLUXB_X,flux_y=FLUXB_Y,flux_z=FLUXB_Z,t=TIME,lat=LAT,lon=LONG,alt=MSL-Z",
    )
    .unwrap();
    let mut calls = Vec::new();
    let mut progress = |done: u64, total: u64| calls.push((done, total));
    let opts = ReadOptions {
        progress: Some(&mut progress),
        ..Default::default()
    };
    let tr = read_trace_with(&path, &map, opts).unwrap();
    let size = std::fs::metadata(&path).unwrap().len();
    assert_eq!(
        calls.last(),
        Some(&(size, size)),
        "progress ends at the file size"
    );
    tr.require_contract().unwrap();
    assert_eq!(tr.len(), 9);
    assert_eq!(tr.numeric.len(), 98);
    // TIME, UNCOMPMAG4, FLUXB_X, FLUXB_Y, FLUXB_Z, LAT, LONG, MSL-Z of the 9 rows, as in the file.
    let expected: [[f64; 8]; 9] = [
        [
            49820.00,
            52022.969,
            40991.107,
            31304.540,
            11463.397,
            45.3147665,
            -75.6633086,
            223.54,
        ],
        [
            49820.10,
            52021.758,
            40995.387,
            31300.636,
            11449.886,
            45.3147401,
            -75.6632662,
            223.84,
        ],
        [
            49820.20,
            52020.863,
            41000.448,
            31296.251,
            11437.925,
            45.3147135,
            -75.6632239,
            224.13,
        ],
        [
            50713.00,
            51477.832,
            45836.527,
            24991.904,
            7956.798,
            44.8750983,
            -76.0921488,
            418.36,
        ],
        [
            50713.10,
            51480.308,
            45820.851,
            25006.872,
            8008.160,
            44.8750590,
            -76.0920775,
            418.58,
        ],
        [
            50713.20,
            51482.489,
            45813.903,
            25010.751,
            8046.276,
            44.8750197,
            -76.0920061,
            418.79,
        ],
        [
            54497.00,
            51261.606,
            27755.498,
            35978.501,
            -23713.136,
            44.7990004,
            -76.1189638,
            425.66,
        ],
        [
            54497.10,
            51261.804,
            27694.667,
            36050.468,
            -23666.542,
            44.7990469,
            -76.1190241,
            425.71,
        ],
        [
            54497.20,
            51262.125,
            27653.441,
            36104.370,
            -23627.686,
            44.7990933,
            -76.1190844,
            425.76,
        ],
    ];
    let flux = tr.flux().unwrap();
    for (i, row) in expected.iter().enumerate() {
        for (j, name) in required_columns().iter().enumerate() {
            assert_eq!(tr.col(name).unwrap()[i], row[j], "row {i} column {name}");
        }
        assert_eq!(flux[i], [row[2], row[3], row[4]]);
    }
    assert_eq!(tr.col("LINE").unwrap()[0], 1003.01);
    let drape = tr.col("DRAPE").unwrap();
    assert!(drape[..3].iter().all(|v| v.is_nan()), "'*' is missing");
    assert_eq!(drape[3], 299.60);
    let ogs = tr.col("OGS_MAG").unwrap();
    assert!(ogs[0].is_nan() && ogs[3] == 54199.645);
    assert_eq!(tr.col("V_FAN").unwrap()[0], 48.284);
    let aux = tr.aux_columns();
    assert!(aux.contains(&"CUR_STRB") && aux.contains(&"UNCOMPMAG1") && !aux.contains(&"mag"));
}

/// Never panic: random bytes, truncations and mutations of valid files must give Ok or a
/// TraceError, never a panic.
#[test]
fn never_panics_on_garbage_or_truncated_input() {
    let mut seeds: Vec<Vec<u8>> = vec![BASIC.as_bytes().to_vec()];
    let path = reference_dir().join("Flt1003_sample.xyz");
    if let Ok(b) = std::fs::read(&path) {
        seeds.push(b);
    }
    seeds.push(b"t,segment,x\n1,\"unterminated,2\n2,\"a\"\"\n".to_vec());
    let mut state = 0x9E3779B97F4A7C15u64;
    let mut rnd = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let alphabet = b"0123456789.,-+eE\n\r#/*\" \tnaNINFtxyz:\xff\xc3";
    let mut cases = 0;
    for seed in &seeds {
        for cut in 0..=seed.len().min(400) {
            cases += 1;
            let _ = read_trace_from(&seed[..cut], "cut", &ColumnMap::new());
        }
        for _ in 0..300 {
            let mut b = seed.clone();
            for _ in 0..1 + rnd() % 8 {
                if b.is_empty() {
                    break;
                }
                let i = (rnd() as usize) % b.len();
                b[i] = alphabet[(rnd() as usize) % alphabet.len()];
            }
            cases += 1;
            let _ = read_trace_from(
                b.as_slice(),
                "mut",
                &ColumnMap::parse("t=TIME").unwrap_or_default(),
            );
            let _ = read_trace_from(b.as_slice(), "mut", &ColumnMap::new());
        }
    }
    for len in [0usize, 1, 2, 7, 100, 5000] {
        for _ in 0..50 {
            let b: Vec<u8> = (0..len).map(|_| rnd() as u8).collect();
            cases += 1;
            for layout in [Layout::Auto, Layout::Csv, Layout::Xyz] {
                let opts = ReadOptions {
                    layout,
                    ..Default::default()
                };
                let _ = read_trace_from_with(b.as_slice(), "rand", &ColumnMap::new(), opts, 0);
            }
        }
    }
    assert!(cases > 1000);
}

#[test]
fn progress_bar_is_hidden_without_a_terminal() {
    use std::io::IsTerminal;
    let bar = progress_bar(1000);
    if !std::io::stderr().is_terminal() {
        assert!(bar.is_hidden(), "no bar drawn into logs or CI output");
    }
    bar.set_position(10);
    bar.finish_and_clear();
}

#[test]
fn layout_is_detected_from_xyz_extension_even_without_slash_comments() {
    // A .xyz file whose first line is data cannot be read (no column names), and the error
    // says so instead of misreading it as CSV.
    let path = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("no_header.XYZ");
    std::fs::write(&path, "1 2 3\n").unwrap();
    let e = read_trace(&path, &ColumnMap::new()).unwrap_err();
    assert!(matches!(e, TraceError::NoHeader { .. }), "{e}");
    // The same bytes as .csv are one header line with one column named "1 2 3".
    let path = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("no_header.csv");
    std::fs::write(&path, "1 2 3\n").unwrap();
    assert_eq!(
        read_trace(&path, &ColumnMap::new()).unwrap().column_names(),
        vec!["1 2 3"]
    );
}
