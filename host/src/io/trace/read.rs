//! Streaming reader for the CSV trace layout and the whitespace-separated `.xyz` survey
//! layout. One pass, one reused line buffer, columns built directly (no row structs), so a
//! multi-million-row file costs about its own size in f64s.
use super::view::{column_kind, ColumnKind};
use super::{ColumnMap, RowOrigin, Trace, TraceError};
use std::fs::File;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;

/// File layout.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Layout {
    /// `.xyz`/`.XYZ` extension, or first non-blank character `/`, means [`Layout::Xyz`];
    /// anything else is [`Layout::Csv`].
    #[default]
    Auto,
    /// trace-format.md CSV.
    Csv,
    /// Public survey (Geosoft-style) XYZ: `/` comment lines, the last one before the data
    /// holding the column names; whitespace-separated fields; `*` = missing. Lines of the
    /// form `Line 1003.01` / `Tie 10` (line separators) are skipped.
    Xyz,
}

/// Options for [`read_trace_with`] / [`read_trace_from_with`].
pub struct ReadOptions<'a> {
    pub layout: Layout,
    /// Check while reading that `t` (after the map) is present and strictly increasing on
    /// every row, erroring with the file line. Default true. No effect without a `t` column.
    pub check_time: bool,
    /// Called as `(bytes_read, total_bytes)` every few MiB and once at the end;
    /// `total_bytes` is 0 when unknown (a reader that is not a file).
    pub progress: Option<&'a mut dyn FnMut(u64, u64)>,
}

impl Default for ReadOptions<'_> {
    fn default() -> Self {
        ReadOptions {
            layout: Layout::Auto,
            check_time: true,
            progress: None,
        }
    }
}

/// Reads a trace file (layout detected automatically; `t` checked).
pub fn read_trace(path: &Path, map: &ColumnMap) -> Result<Trace, TraceError> {
    read_trace_with(path, map, ReadOptions::default())
}

/// Reads a trace file with options (layout, time check, progress).
pub fn read_trace_with(
    path: &Path,
    map: &ColumnMap,
    mut opts: ReadOptions<'_>,
) -> Result<Trace, TraceError> {
    if is_hdf5_path(path) {
        return super::h5::read_hdf5(path, map, opts.check_time);
    }
    if super::board_log::is_board_log(path) {
        let trace = super::board_log::read_board_log(path)?;
        if opts.check_time {
            super::h5::check_time_increases(&trace, &path.display().to_string())?;
        }
        return Ok(trace);
    }
    let (file, name, total) = open(path, &mut opts)?;
    read_impl(file, &name, map, opts, total)
}

/// HDF5 by extension or by signature (a `.dat` from h5py is still HDF5).
pub fn is_hdf5_path(path: &Path) -> bool {
    super::h5::has_hdf5_extension(path) || super::h5::is_hdf5(path)
}

/// Opens a trace file: (file, its name for messages, its size); an `.xyz` extension
/// sets the layout when it is `Auto`.
pub(super) fn open(
    path: &Path,
    opts: &mut ReadOptions<'_>,
) -> Result<(File, String, u64), TraceError> {
    let name = path.display().to_string();
    let file = File::open(path).map_err(|source| TraceError::Io {
        file: name.clone(),
        source,
    })?;
    let total = file.metadata().map(|m| m.len()).unwrap_or(0);
    if opts.layout == Layout::Auto {
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
        if ext.eq_ignore_ascii_case("xyz") {
            opts.layout = Layout::Xyz;
        }
    }
    Ok((file, name, total))
}

/// Reads a trace from any reader (layout detected from the content); `name_for_errors`
/// is what error messages call the source.
pub fn read_trace_from<R: Read>(
    reader: R,
    name_for_errors: &str,
    map: &ColumnMap,
) -> Result<Trace, TraceError> {
    read_impl(reader, name_for_errors, map, ReadOptions::default(), 0)
}

/// [`read_trace_from`] with options; `total_bytes` (0 if unknown) is passed to the
/// progress callback.
pub fn read_trace_from_with<R: Read>(
    reader: R,
    name_for_errors: &str,
    map: &ColumnMap,
    opts: ReadOptions<'_>,
    total_bytes: u64,
) -> Result<Trace, TraceError> {
    read_impl(reader, name_for_errors, map, opts, total_bytes)
}

/// A progress bar for reading `total_bytes`, drawn on stderr; hidden when stderr is not a
/// terminal (logs and CI stay clean). Feed it from [`ReadOptions::progress`]:
/// `|done, total| { bar.set_length(total); bar.set_position(done) }`.
pub fn progress_bar(total_bytes: u64) -> indicatif::ProgressBar {
    use std::io::IsTerminal;
    if !std::io::stderr().is_terminal() {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(total_bytes);
    if let Ok(style) = indicatif::ProgressStyle::with_template(
        "{msg} [{bar:40}] {bytes}/{total_bytes} {bytes_per_sec} eta {eta}",
    ) {
        bar.set_style(style.progress_chars("=> "));
    }
    bar
}

/// The data contract's time rule, for the column store and the row reader alike: `t`
/// present and strictly increasing. `previous` advances to `t` when it holds.
pub(super) fn check_time_order(
    file: &str,
    line: u64,
    t: f64,
    previous: &mut f64,
) -> Result<(), TraceError> {
    if t.is_nan() || t <= *previous {
        return Err(TraceError::Time {
            file: file.to_string(),
            line,
            value: t,
            previous: *previous,
        });
    }
    *previous = t;
    Ok(())
}

/// Values that mean "missing" in any layout.
pub(super) fn is_missing(text: &str) -> bool {
    text.is_empty() || text == "*" || text.eq_ignore_ascii_case("nan")
}

/// Some(value) for a number or a missing marker (NaN), None for anything else.
/// Infinite values are refused: no sensor reports them, so they are corruption.
pub(super) fn parse_num(text: &str) -> Option<f64> {
    match text.parse::<f64>() {
        Ok(v) if v.is_finite() => Some(v),
        Ok(v) if v.is_nan() => Some(f64::NAN),
        Ok(_) => None,
        Err(_) if text.is_empty() || text == "*" => Some(f64::NAN),
        Err(_) => None,
    }
}

enum ColData {
    /// Type not decided yet (only for `ColumnKind::Auto`): this many leading missing values.
    Pending(usize),
    Num(Vec<f64>),
    Text(Vec<String>),
}

struct Col {
    name: String,
    data: ColData,
}

impl Col {
    fn new(name: String) -> Self {
        let data = match column_kind(&name) {
            ColumnKind::Numeric => ColData::Num(Vec::new()),
            ColumnKind::Text => ColData::Text(Vec::new()),
            ColumnKind::Auto => ColData::Pending(0),
        };
        Col { name, data }
    }

    /// Appends one field; `Err(())` if it is not a number in a numeric column.
    fn push(&mut self, text: &str) -> Result<(), ()> {
        match &mut self.data {
            ColData::Num(v) => v.push(parse_num(text).ok_or(())?),
            ColData::Text(v) => v.push(if is_missing(text) {
                String::new()
            } else {
                text.to_string()
            }),
            ColData::Pending(n) => {
                if is_missing(text) {
                    *n += 1;
                } else if let Some(x) = parse_num(text) {
                    let mut v = vec![f64::NAN; *n];
                    v.push(x);
                    self.data = ColData::Num(v);
                } else {
                    let mut v = vec![String::new(); *n];
                    v.push(text.to_string());
                    self.data = ColData::Text(v);
                }
            }
        }
        Ok(())
    }
}

/// Splits a CSV line into trimmed fields, calling `f(index, field)`; returns the count.
/// Double-quoted fields (`"a,b"`, `""` for a quote) are accepted because spreadsheets
/// write them; the fast path is taken when the line has no quote at all.
pub(super) fn csv_fields(
    line: &str,
    scratch: &mut String,
    mut f: impl FnMut(usize, &str) -> Result<(), TraceError>,
) -> Result<usize, TraceError> {
    if !line.contains('"') {
        let mut n = 0;
        for field in line.split(',') {
            f(n, field.trim_ascii())?;
            n += 1;
        }
        return Ok(n);
    }
    let mut n = 0;
    let mut chars = line.chars().peekable();
    loop {
        scratch.clear();
        let mut quoted = false;
        // Skip leading blanks so ` "x"` is still a quoted field.
        while let Some(&c) = chars.peek() {
            if c == ' ' || c == '\t' {
                chars.next();
            } else {
                break;
            }
        }
        if chars.peek() == Some(&'"') {
            chars.next();
            quoted = true;
            while let Some(c) = chars.next() {
                if c == '"' {
                    if chars.peek() == Some(&'"') {
                        chars.next();
                        scratch.push('"');
                    } else {
                        break;
                    }
                } else {
                    scratch.push(c);
                }
            }
        }
        let mut end = false;
        loop {
            match chars.next() {
                None => {
                    end = true;
                    break;
                }
                Some(',') => break,
                // Blanks after a closing quote are padding, not content.
                Some(' ' | '\t') if quoted => {}
                Some(c) => scratch.push(c),
            }
        }
        let field = if quoted {
            scratch.as_str()
        } else {
            scratch.trim_ascii()
        };
        f(n, field)?;
        n += 1;
        if end {
            return Ok(n);
        }
    }
}

/// `# key: value` with a one-word key; other comments are not metadata.
fn parse_meta(comment: &str) -> Option<(String, String)> {
    let (key, value) = comment.split_once(':')?;
    let key = key.trim();
    let ok = !key.is_empty()
        && key
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-' || c == '.');
    ok.then(|| (key.to_string(), value.trim().to_string()))
}

/// What the line scanner ([`scan`]) hands its rows to: the column store of
/// [`read_trace_with`], or the row-at-a-time sink of [`super::rows`].
pub(super) trait Sink {
    fn header(&mut self, names: Vec<String>, line: u64) -> Result<(), TraceError>;
    fn field(&mut self, line: u64, i: usize, text: &str) -> Result<(), TraceError>;
    fn end_row(&mut self, line: u64, found: usize) -> Result<(), TraceError>;
    fn columns(&self) -> usize;
    /// Whether the sink has read all it wants (a header read stops at the first row).
    fn done(&self) -> bool {
        false
    }
}

impl Sink for Reader<'_> {
    fn header(&mut self, names: Vec<String>, line: u64) -> Result<(), TraceError> {
        self.set_header(names, line)
    }
    fn field(&mut self, line: u64, i: usize, text: &str) -> Result<(), TraceError> {
        Reader::field(self, line, i, text)
    }
    fn end_row(&mut self, line: u64, found: usize) -> Result<(), TraceError> {
        Reader::end_row(self, line, found)
    }
    fn columns(&self) -> usize {
        self.cols.len()
    }
}

/// Header checks shared by every sink: no empty or duplicate name; the map applied.
pub(super) fn check_header(
    file: &str,
    map: &ColumnMap,
    names: &[String],
    line: u64,
) -> Result<Vec<String>, TraceError> {
    for (i, n) in names.iter().enumerate() {
        if n.is_empty() {
            return Err(TraceError::Header {
                file: file.to_string(),
                line,
                msg: format!("column {} has an empty name", i + 1),
            });
        }
        if let Some(j) = names[..i].iter().position(|m| m == n) {
            return Err(TraceError::Header {
                file: file.to_string(),
                line,
                msg: format!(
                    "duplicate column name '{n}' (columns {} and {})",
                    j + 1,
                    i + 1
                ),
            });
        }
    }
    map.apply(names)
}

struct Reader<'m> {
    file: String,
    map: &'m ColumnMap,
    check_time: bool,
    cols: Vec<Col>,
    t_idx: Option<usize>,
    prev_t: f64,
    origin: RowOrigin,
}

impl Reader<'_> {
    fn set_header(&mut self, names: Vec<String>, line: u64) -> Result<(), TraceError> {
        let canon = check_header(&self.file, self.map, &names, line)?;
        self.t_idx = canon
            .iter()
            .position(|n| n == "t")
            .filter(|_| self.check_time);
        self.cols = canon.into_iter().map(Col::new).collect();
        Ok(())
    }

    fn parse_err(&self, line: u64, i: usize, text: &str) -> TraceError {
        TraceError::Parse {
            file: self.file.clone(),
            line,
            column: self.cols[i].name.clone(),
            text: text.to_string(),
        }
    }

    fn count_err(&self, line: u64, found: usize) -> TraceError {
        TraceError::FieldCount {
            file: self.file.clone(),
            line,
            expected: self.cols.len(),
            found,
        }
    }

    /// Pushes one field of a data row; fields beyond the header are only counted.
    fn field(&mut self, line: u64, i: usize, text: &str) -> Result<(), TraceError> {
        match self.cols.get_mut(i) {
            Some(col) => col.push(text).map_err(|()| self.parse_err(line, i, text)),
            None => Ok(()),
        }
    }

    fn end_row(&mut self, line: u64, found: usize) -> Result<(), TraceError> {
        if found != self.cols.len() {
            return Err(self.count_err(line, found));
        }
        if let Some(ti) = self.t_idx {
            if let ColData::Num(v) = &self.cols[ti].data {
                let t = v.last().copied().unwrap_or(f64::NAN);
                check_time_order(&self.file, line, t, &mut self.prev_t)?;
            }
        }
        self.origin.push(line);
        Ok(())
    }
}

fn read_impl<R: Read>(
    reader: R,
    name: &str,
    map: &ColumnMap,
    opts: ReadOptions<'_>,
    total_bytes: u64,
) -> Result<Trace, TraceError> {
    let mut rd = Reader {
        file: name.to_string(),
        map,
        check_time: opts.check_time,
        cols: Vec::new(),
        t_idx: None,
        prev_t: f64::NEG_INFINITY,
        origin: RowOrigin::new(name),
    };
    let meta = scan(reader, name, opts, total_bytes, &mut rd)?;
    let mut trace = Trace {
        meta,
        origin: Some(rd.origin),
        ..Trace::default()
    };
    for col in rd.cols {
        match col.data {
            // Never had a value: numeric and all missing.
            ColData::Pending(n) => trace.numeric.push((col.name, vec![f64::NAN; n])),
            // Grown by doubling: up to half of each column would be spare capacity
            // for the whole run.
            ColData::Num(mut v) => {
                v.shrink_to_fit();
                trace.numeric.push((col.name, v))
            }
            ColData::Text(mut v) => {
                v.shrink_to_fit();
                trace.text.push((col.name, v))
            }
        }
    }
    Ok(trace)
}

/// The longest trace line read: a survey row of a few hundred columns is tens of KB.
pub const MAX_LINE_BYTES: usize = 1 << 20;

/// Reads every line of `reader` into `sink` (header, fields, row ends) and returns the
/// `# key: value` metadata. Layout detection, BOM, comments, quoting and the XYZ line
/// separators are handled here, once for every sink.
pub(super) fn scan<R: Read>(
    reader: R,
    name: &str,
    mut opts: ReadOptions<'_>,
    total_bytes: u64,
    rd: &mut impl Sink,
) -> Result<Vec<(String, String)>, TraceError> {
    let mut lines = Lines::new(reader, name);
    let layout = match opts.layout {
        Layout::Auto => lines.sniff_layout()?,
        given => given,
    };
    let mut scan = Scan {
        name,
        layout,
        meta: Vec::new(),
        have_header: false,
        xyz_names: None,
        scratch: String::new(),
    };
    while let Some((line_no, raw)) = lines.next_line(&mut opts.progress, total_bytes)? {
        scan.line(line_no, raw, rd)?;
        if rd.done() {
            break;
        }
    }
    if let Some(p) = opts.progress.as_mut() {
        p(lines.bytes, total_bytes);
    }
    if !scan.have_header {
        return Err(TraceError::NoHeader {
            file: name.to_string(),
        });
    }
    Ok(scan.meta)
}

/// Progress is reported every this many bytes read.
const PROGRESS_STEP: u64 = 4 << 20;

/// The file's lines through one reused buffer, counted and reported as progress.
struct Lines<'n, R> {
    r: BufReader<R>,
    name: &'n str,
    buf: Vec<u8>,
    line_no: u64,
    bytes: u64,
    next_progress: u64,
}

impl<'n, R: Read> Lines<'n, R> {
    fn new(reader: R, name: &'n str) -> Self {
        Self {
            r: BufReader::with_capacity(1 << 18, reader),
            name,
            buf: Vec::with_capacity(4096),
            line_no: 0,
            bytes: 0,
            next_progress: PROGRESS_STEP,
        }
    }

    fn io(&self, source: std::io::Error) -> TraceError {
        TraceError::Io {
            file: self.name.to_string(),
            source,
        }
    }

    /// The layout by the first non-blank character: `/` is XYZ, anything else CSV.
    fn sniff_layout(&mut self) -> Result<Layout, TraceError> {
        let head = match self.r.fill_buf() {
            Ok(head) => head,
            Err(e) => return Err(self.io(e)),
        };
        let head = head.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(head);
        let first = head.iter().find(|b| !b.is_ascii_whitespace());
        Ok(if first == Some(&b'/') {
            Layout::Xyz
        } else {
            Layout::Csv
        })
    }

    /// The next line's number and bytes without its line break (nor, on the first line, a
    /// UTF-8 byte-order mark); None at the end of the file.
    fn next_line(
        &mut self,
        progress: &mut Option<&mut dyn FnMut(u64, u64)>,
        total_bytes: u64,
    ) -> Result<Option<(u64, &[u8])>, TraceError> {
        self.buf.clear();
        // Bounded: a file without line breaks (`/dev/zero`) must end in an error, not in
        // one line growing until the allocation aborts.
        let n = match (&mut self.r)
            .take(MAX_LINE_BYTES as u64 + 1)
            .read_until(b'\n', &mut self.buf)
        {
            Ok(n) => n,
            Err(e) => return Err(self.io(e)),
        };
        if n == 0 {
            return Ok(None);
        }
        if n > MAX_LINE_BYTES && self.buf.last() != Some(&b'\n') {
            return Err(self.io(std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!(
                    "line {} is longer than {} MiB: not a trace (CSV or XYZ) file",
                    self.line_no + 1,
                    MAX_LINE_BYTES >> 20
                ),
            )));
        }
        self.bytes += n as u64;
        self.line_no += 1;
        if self.bytes >= self.next_progress {
            if let Some(p) = progress.as_mut() {
                p(self.bytes, total_bytes);
            }
            self.next_progress = self.bytes + PROGRESS_STEP;
        }
        let mut raw: &[u8] = &self.buf;
        if self.line_no == 1 {
            raw = raw.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(raw);
        }
        while let [rest @ .., b'\n' | b'\r'] = raw {
            raw = rest;
        }
        Ok(Some((self.line_no, raw)))
    }
}

/// What the scan has seen so far: the layout, the metadata comments, whether the header
/// was read, and (XYZ) the last comment, which names the columns.
struct Scan<'n> {
    name: &'n str,
    layout: Layout,
    meta: Vec<(String, String)>,
    have_header: bool,
    xyz_names: Option<(u64, String)>,
    scratch: String,
}

impl Scan<'_> {
    fn line(&mut self, line_no: u64, raw: &[u8], rd: &mut impl Sink) -> Result<(), TraceError> {
        let first = raw.iter().find(|b| !b.is_ascii_whitespace()).copied();
        let Some(first) = first else {
            return Ok(()); // blank line
        };
        let comment_char = if self.layout == Layout::Xyz {
            b'/'
        } else {
            b'#'
        };
        if first == comment_char {
            self.comment(line_no, raw);
            return Ok(());
        }
        let line = std::str::from_utf8(raw).map_err(|_| TraceError::Utf8 {
            file: self.name.to_string(),
            line: line_no,
        })?;
        if self.layout == Layout::Csv {
            self.csv_line(line_no, line, rd)
        } else {
            self.xyz_line(line_no, line, rd)
        }
    }

    /// A comment before the header: metadata (`key: value`), and in XYZ the column names
    /// when it is the last one.
    fn comment(&mut self, line_no: u64, raw: &[u8]) {
        if self.have_header {
            return;
        }
        // Comments may carry any encoding (degree signs...): decode leniently.
        let text = String::from_utf8_lossy(raw);
        let body = text.trim_start().get(1..).unwrap_or("");
        if self.layout == Layout::Xyz {
            // `/ key: value` (as our XYZ writer puts them) is metadata as well; the
            // last comment is the header either way.
            if let Some(kv) = parse_meta(body) {
                self.meta.push(kv);
            }
            self.xyz_names = Some((line_no, body.to_string()));
        } else if let Some(kv) = parse_meta(body) {
            self.meta.push(kv);
        }
    }

    /// A CSV line: the header, then a row per line.
    fn csv_line(&mut self, line_no: u64, line: &str, rd: &mut impl Sink) -> Result<(), TraceError> {
        if !self.have_header {
            let mut names = Vec::new();
            csv_fields(line, &mut self.scratch, |_, f| {
                names.push(f.to_string());
                Ok(())
            })?;
            rd.header(names, line_no)?;
            self.have_header = true;
            return Ok(());
        }
        let found = csv_fields(line, &mut self.scratch, |i, f| rd.field(line_no, i, f))?;
        rd.end_row(line_no, found)
    }

    /// An XYZ data line (the header taken from the last comment before the first one);
    /// Geosoft line separators are skipped.
    fn xyz_line(&mut self, line_no: u64, line: &str, rd: &mut impl Sink) -> Result<(), TraceError> {
        if !self.have_header {
            let no_header = || TraceError::NoHeader {
                file: self.name.to_string(),
            };
            let Some((hl, names)) = self.xyz_names.take() else {
                return Err(no_header());
            };
            let names: Vec<String> = names.split_ascii_whitespace().map(str::to_string).collect();
            if names.is_empty() {
                return Err(no_header());
            }
            rd.header(names, hl)?;
            self.have_header = true;
        }
        let mut toks = line.split_ascii_whitespace();
        let first_tok = toks.next().unwrap_or("");
        if (first_tok.eq_ignore_ascii_case("line") || first_tok.eq_ignore_ascii_case("tie"))
            && toks.clone().count() <= 1
            && rd.columns() > 2
        {
            return Ok(()); // Geosoft line separator, not a data row
        }
        let mut found = 0;
        for (i, f) in line.split_ascii_whitespace().enumerate() {
            rd.field(line_no, i, f)?;
            found = i + 1;
        }
        rd.end_row(line_no, found)
    }
}
