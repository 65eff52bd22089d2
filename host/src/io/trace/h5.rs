//! HDF5 flight files in the layout MagNav.jl reads (`get_XYZ0/1/20/21`, written by its
//! `xyz2h5`/`write_field`): one dataset per channel at the root of the file, each a
//! vector of one value per sample (`tt`, `lat`, `mag_1_uc`, `flux_a_x`, …). Scalars
//! (`N`, `dt`) become metadata; matrices per sample (`Cnb` 3×3×N) have no place in a
//! trace and are listed in the `h5_skipped` metadata; a vector of another length is an
//! error, as MagNav's own `read_check` would misalign it.
use super::{ColumnMap, Trace, TraceError};
use std::path::Path;

#[cfg(feature = "hdf5")]
use hdf5_metno as h5;

/// The 8-byte signature at the start of an HDF5 file (or of its superblock after a user
/// block of 512, 1024, 2048, … bytes).
const SIGNATURE: &[u8; 8] = b"\x89HDF\r\n\x1a\n";

/// Whether the file starts like HDF5 (signature at offset 0 or a power-of-two user block
/// up to 64 KiB).
pub fn is_hdf5(path: &Path) -> bool {
    use std::io::{Read, Seek, SeekFrom};
    // Only a regular file is sniffed: a pipe or device must not lose its first bytes.
    if !std::fs::metadata(path).is_ok_and(|m| m.is_file()) {
        return false;
    }
    let Ok(mut f) = std::fs::File::open(path) else {
        return false;
    };
    let mut offset = 0u64;
    loop {
        let mut b = [0u8; 8];
        if f.seek(SeekFrom::Start(offset)).is_err() || f.read_exact(&mut b).is_err() {
            return false;
        }
        if &b == SIGNATURE {
            return true;
        }
        offset = if offset == 0 { 512 } else { offset * 2 };
        if offset > 65_536 {
            return false;
        }
    }
}

/// Whether the extension names an HDF5 file.
pub fn has_hdf5_extension(path: &Path) -> bool {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
    ["h5", "hdf5", "hdf", "he5"]
        .iter()
        .any(|e| ext.eq_ignore_ascii_case(e))
}

fn err(file: &str, msg: impl Into<String>) -> TraceError {
    TraceError::Hdf5 {
        file: file.to_string(),
        msg: msg.into(),
    }
}

/// One root dataset, read.
#[cfg(feature = "hdf5")]
enum Channel {
    Num(Vec<f64>),
    Text(Vec<String>),
}

/// Reads `path` into a trace: every 1-D root dataset of the common length is a column
/// (renamed by `map`), `t` (after the map) checked strictly increasing if `check_time`.
#[cfg(feature = "hdf5")]
pub fn read_hdf5(path: &Path, map: &ColumnMap, check_time: bool) -> Result<Trace, TraceError> {
    let name = path.display().to_string();
    if !path.exists() {
        return Err(TraceError::Io {
            file: name,
            source: std::io::Error::from(std::io::ErrorKind::NotFound),
        });
    }
    if !is_hdf5(path) {
        return Err(err(
            &name,
            "not an HDF5 file (no HDF5 signature); CSV and XYZ traces need another extension \
             (docs/trace-format.md)",
        ));
    }
    let file = open(path, &name)?;
    let RootDatasets { vectors, meta } = RootDatasets::read(&file, &name)?;
    let rows = sample_count(&vectors);
    check_lengths(&vectors, rows, &name)?;
    let header: Vec<String> = vectors.iter().map(|(n, _)| n.clone()).collect();
    let canon = map.apply(&header)?;
    let mut trace = Trace {
        meta,
        ..Trace::default()
    };
    for ((_, ch), cname) in vectors.into_iter().zip(canon) {
        add_column(&mut trace, ch, cname, &name)?;
    }
    if check_time {
        check_time_increases(&trace, &name)?;
    }
    // Messages about a row name its 1-based row of the datasets.
    let mut origin = super::RowOrigin::new(&name);
    for i in 0..rows {
        origin.push(i as u64 + 1);
    }
    trace.origin = Some(origin);
    Ok(trace)
}

/// Opens the file for reading. HDF5 locks the file (flock) while it is open; where the
/// file system cannot lock (NFS, Lustre) the lock is skipped instead of refusing the file.
#[cfg(feature = "hdf5")]
fn open(path: &Path, name: &str) -> Result<h5::File, TraceError> {
    h5::File::with_options()
        .with_fapl(|p| p.file_locking(true))
        .open(path)
        .map_err(|e| {
            let e = e.to_string();
            let why = if e.contains("lock") {
                " (another program has the file open for writing)"
            } else {
                ""
            };
            err(name, format!("cannot open: {e}{why}"))
        })
}

/// The root datasets, sorted by shape: vectors (the channels) and scalars (metadata, with
/// `h5_skipped` listing the matrices left out).
#[cfg(feature = "hdf5")]
struct RootDatasets {
    vectors: Vec<(String, Channel)>,
    meta: Vec<(String, String)>,
}

#[cfg(feature = "hdf5")]
impl RootDatasets {
    fn read(file: &h5::File, name: &str) -> Result<Self, TraceError> {
        let datasets = file
            .datasets()
            .map_err(|e| err(name, format!("cannot list the datasets: {e}")))?;
        if datasets.is_empty() {
            return Err(no_root_dataset(file, name));
        }
        let mut vectors: Vec<(String, Channel)> = Vec::new();
        let mut meta = Vec::new();
        let mut skipped = Vec::new();
        for ds in &datasets {
            let dname = ds.name().trim_start_matches('/').to_string();
            let shape = ds.shape();
            let read_err = |e: h5::Error| err(name, format!("dataset '{dname}': {e}"));
            let text = is_text(ds);
            let n: usize = shape.iter().product();
            // A scalar, or a 1-element vector beside longer ones, is a property of the file.
            if shape.is_empty() || (shape.len() == 1 && n == 1) {
                let v = if text {
                    ds.read_raw::<h5::types::VarLenUnicode>()
                        .map(|v| v.first().map(|s| s.to_string()).unwrap_or_default())
                } else {
                    ds.read_raw::<f64>()
                        .map(|v| v.first().map(|x| x.to_string()).unwrap_or_default())
                };
                meta.push((dname.clone(), v.map_err(read_err)?));
                continue;
            }
            if shape.len() != 1 {
                let dims: Vec<String> = shape.iter().map(usize::to_string).collect();
                skipped.push(format!("{dname} ({})", dims.join("×")));
                continue;
            }
            let ch = read_channel(ds, text, &dname, name)?;
            vectors.push((dname, ch));
        }
        if !skipped.is_empty() {
            meta.push(("h5_skipped".to_string(), skipped.join(", ")));
        }
        Ok(Self { vectors, meta })
    }
}

/// The error for a file with nothing at its root, naming the groups it has instead.
#[cfg(feature = "hdf5")]
fn no_root_dataset(file: &h5::File, name: &str) -> TraceError {
    let groups: Vec<String> = file
        .groups()
        .map(|g| g.iter().map(|g| g.name()).collect())
        .unwrap_or_default();
    err(
        name,
        format!(
            "no dataset at the root of the file (MagNav's layout: one dataset per \
             channel at the root){}",
            if groups.is_empty() {
                String::new()
            } else {
                format!("; it has groups {}", groups.join(", "))
            }
        ),
    )
}

/// Whether the dataset holds variable-length strings.
#[cfg(feature = "hdf5")]
fn is_text(ds: &h5::Dataset) -> bool {
    ds.dtype()
        .and_then(|t| t.to_descriptor())
        .map(|d| {
            matches!(
                d,
                h5::types::TypeDescriptor::VarLenUnicode | h5::types::TypeDescriptor::VarLenAscii
            )
        })
        .unwrap_or(false)
}

/// One 1-D dataset's values.
#[cfg(feature = "hdf5")]
fn read_channel(
    ds: &h5::Dataset,
    text: bool,
    dname: &str,
    name: &str,
) -> Result<Channel, TraceError> {
    Ok(if text {
        Channel::Text(
            ds.read_raw::<h5::types::VarLenUnicode>()
                .map_err(|e| err(name, format!("dataset '{dname}': {e}")))?
                .into_iter()
                .map(|s| s.to_string())
                .collect(),
        )
    } else {
        // Any integer or float type converts to f64 (HDF5's own conversion).
        Channel::Num(ds.read_raw::<f64>().map_err(|e| {
            err(
                name,
                format!("dataset '{dname}' is not numbers or text: {e}"),
            )
        })?)
    })
}

#[cfg(feature = "hdf5")]
impl Channel {
    fn len(&self) -> usize {
        match self {
            Channel::Num(v) => v.len(),
            Channel::Text(v) => v.len(),
        }
    }
}

/// The sample count: the time vector's, else the most common length.
#[cfg(feature = "hdf5")]
fn sample_count(vectors: &[(String, Channel)]) -> usize {
    match vectors.iter().find(|(n, _)| n == "tt" || n == "t") {
        Some((_, c)) => c.len(),
        None => {
            let mut lens: Vec<usize> = vectors.iter().map(|(_, c)| c.len()).collect();
            lens.sort_unstable();
            let mut best = (0, 0);
            for w in lens.chunk_by(|a, b| a == b) {
                if w.len() > best.1 {
                    best = (w[0], w.len());
                }
            }
            best.0
        }
    }
}

/// Refuses vectors of another length than the samples' (MagNav's own `read_check` would
/// misalign them).
#[cfg(feature = "hdf5")]
fn check_lengths(vectors: &[(String, Channel)], rows: usize, name: &str) -> Result<(), TraceError> {
    let wrong: Vec<String> = vectors
        .iter()
        .filter(|(_, c)| c.len() != rows)
        .map(|(n, c)| format!("'{n}' has {}", c.len()))
        .collect();
    if wrong.is_empty() {
        return Ok(());
    }
    Err(err(
        name,
        format!(
            "datasets of different lengths: the file's samples are {rows} rows, but {}",
            wrong.join(", ")
        ),
    ))
}

/// One channel into the trace under its canonical name `cname`.
#[cfg(feature = "hdf5")]
fn add_column(trace: &mut Trace, ch: Channel, cname: String, name: &str) -> Result<(), TraceError> {
    match ch {
        Channel::Num(mut v) => {
            // Corruption, not a reading: the text reader refuses these too.
            if let Some(i) = v.iter().position(|x| x.is_infinite()) {
                return Err(err(
                    name,
                    format!("dataset for '{cname}', row {}: infinite value", i + 1),
                ));
            }
            v.shrink_to_fit();
            trace.numeric.push((cname, v));
        }
        Channel::Text(v) if super::view::column_kind(&cname) == super::ColumnKind::Numeric => {
            return Err(err(
                name,
                format!(
                    "dataset for '{cname}' holds text ('{}'), the column must be numbers",
                    v.first().map(String::as_str).unwrap_or("")
                ),
            ));
        }
        Channel::Text(v) => trace.text.push((cname, v)),
    }
    Ok(())
}

/// Refuses a `t` column that is not strictly increasing.
#[cfg(feature = "hdf5")]
pub(super) fn check_time_increases(trace: &Trace, name: &str) -> Result<(), TraceError> {
    let Some(t) = trace.col("t") else {
        return Ok(());
    };
    for i in 0..t.len() {
        let prev = if i == 0 { f64::NEG_INFINITY } else { t[i - 1] };
        if t[i].is_nan() || t[i] <= prev {
            return Err(err(
                name,
                format!(
                    "row {}: column 't' must be present and strictly increasing: {} follows {prev}",
                    i + 1,
                    t[i]
                ),
            ));
        }
    }
    Ok(())
}

/// Without the `hdf5` feature the format is recognised and refused clearly.
#[cfg(not(feature = "hdf5"))]
pub fn read_hdf5(path: &Path, _map: &ColumnMap, _check_time: bool) -> Result<Trace, TraceError> {
    Err(err(
        &path.display().to_string(),
        "this magcomp was built without HDF5 support (cargo feature `hdf5`, needs libhdf5)",
    ))
}
