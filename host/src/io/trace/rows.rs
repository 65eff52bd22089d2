//! Row-at-a-time reading: the same parser, typing rule and checks as [`super::read_trace`]
//! (one shared line scanner), but each row is handed to a callback and forgotten, so a
//! file of any length is read in constant memory (the streaming `compensate`).
use super::read::{check_header, is_missing, open, parse_num, scan, Sink};
use super::view::{column_kind, ColumnKind};
use super::{ColumnMap, ReadOptions, TraceError};
use std::path::Path;

/// How a column is typed so far (the module rule of [`super`]): `Pending` until an
/// `Auto` column's first non-missing value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    Pending,
    Num,
    Text,
}

/// One data row. A column's value is in `num` (NaN when missing or text) and in `text`
/// (empty when missing or numeric); which one counts is the column's final [`Kind`]
/// (known after a first pass, [`RowsHeader::kinds`]).
pub struct Row<'a> {
    /// File line of the row.
    pub line: u64,
    /// 0-based data row.
    pub index: usize,
    /// Canonical column names (the header after the map).
    pub names: &'a [String],
    nums: &'a [f64],
    texts: &'a [String],
}

impl Row<'_> {
    pub fn num(&self, col: usize) -> f64 {
        self.nums[col]
    }
    pub fn text(&self, col: usize) -> &str {
        &self.texts[col]
    }
}

/// What a complete pass learnt about the file's columns.
#[derive(Clone, Debug, Default)]
pub struct RowsHeader {
    /// Canonical (mapped) names in file order.
    pub names: Vec<String>,
    pub kinds: Vec<Kind>,
    pub meta: Vec<(String, String)>,
    pub rows: usize,
}

impl RowsHeader {
    pub fn index(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }
    /// The index of a column that is numeric (or never had a value: all missing).
    pub fn num_index(&self, name: &str) -> Option<usize> {
        self.index(name).filter(|&i| self.kinds[i] != Kind::Text)
    }
    pub fn text_index(&self, name: &str) -> Option<usize> {
        self.index(name).filter(|&i| self.kinds[i] == Kind::Text)
    }
}

struct RowSink<'m, F> {
    file: String,
    map: &'m ColumnMap,
    check_time: bool,
    head: RowsHeader,
    nums: Vec<f64>,
    texts: Vec<String>,
    t_idx: Option<usize>,
    prev_t: f64,
    on_row: F,
    /// The callback's own error (the scanner only carries `TraceError`s).
    failure: Option<anyhow::Error>,
    /// Stop after the first data row ([`read_head`]).
    head_only: bool,
}

impl<F: FnMut(&Row) -> anyhow::Result<()>> Sink for RowSink<'_, F> {
    fn header(&mut self, names: Vec<String>, line: u64) -> Result<(), TraceError> {
        let canon = check_header(&self.file, self.map, &names, line)?;
        self.t_idx = canon
            .iter()
            .position(|n| n == "t")
            .filter(|_| self.check_time);
        self.head.kinds = canon
            .iter()
            .map(|n| match column_kind(n) {
                ColumnKind::Numeric => Kind::Num,
                ColumnKind::Text => Kind::Text,
                ColumnKind::Auto => Kind::Pending,
            })
            .collect();
        self.nums = vec![f64::NAN; canon.len()];
        self.texts = vec![String::new(); canon.len()];
        self.head.names = canon;
        Ok(())
    }

    fn field(&mut self, line: u64, i: usize, text: &str) -> Result<(), TraceError> {
        let Some(kind) = self.head.kinds.get_mut(i) else {
            return Ok(()); // beyond the header: only counted
        };
        let parse_err = || TraceError::Parse {
            file: self.file.clone(),
            line,
            column: self.head.names[i].clone(),
            text: text.to_string(),
        };
        self.texts[i].clear();
        self.nums[i] = f64::NAN;
        match kind {
            Kind::Num => self.nums[i] = parse_num(text).ok_or_else(parse_err)?,
            Kind::Text => {
                if !is_missing(text) {
                    self.texts[i].push_str(text);
                }
            }
            Kind::Pending => {
                if is_missing(text) {
                } else if let Some(x) = parse_num(text) {
                    *kind = Kind::Num;
                    self.nums[i] = x;
                } else {
                    *kind = Kind::Text;
                    self.texts[i].push_str(text);
                }
            }
        }
        Ok(())
    }

    fn end_row(&mut self, line: u64, found: usize) -> Result<(), TraceError> {
        if found != self.head.names.len() {
            return Err(TraceError::FieldCount {
                file: self.file.clone(),
                line,
                expected: self.head.names.len(),
                found,
            });
        }
        if let Some(ti) = self.t_idx {
            super::read::check_time_order(&self.file, line, self.nums[ti], &mut self.prev_t)?;
        }
        let row = Row {
            line,
            index: self.head.rows,
            names: &self.head.names,
            nums: &self.nums,
            texts: &self.texts,
        };
        self.head.rows += 1;
        (self.on_row)(&row).map_err(|e| {
            self.failure = Some(e);
            TraceError::Write {
                msg: "stopped".into(),
            }
        })
    }

    fn columns(&self) -> usize {
        self.head.names.len()
    }

    fn done(&self) -> bool {
        self.head_only && self.head.rows > 0
    }
}

/// Reads `path` row by row (layout, time check and progress as `opts` say), calling
/// `on_row` for each data row; returns the header, the final column kinds, the metadata
/// and the row count. Memory: one row.
pub fn for_each_row(
    path: &Path,
    map: &ColumnMap,
    mut opts: ReadOptions<'_>,
    on_row: impl FnMut(&Row) -> anyhow::Result<()>,
) -> anyhow::Result<RowsHeader> {
    let (file, name, total) = open(path, &mut opts)?;
    let mut sink = RowSink {
        file: name.clone(),
        map,
        check_time: opts.check_time,
        head: RowsHeader::default(),
        nums: Vec::new(),
        texts: Vec::new(),
        t_idx: None,
        prev_t: f64::NEG_INFINITY,
        on_row,
        failure: None,
        head_only: false,
    };
    match scan(file, &name, opts, total, &mut sink) {
        Ok(meta) => {
            sink.head.meta = meta;
            Ok(sink.head)
        }
        Err(e) => Err(sink.failure.take().unwrap_or_else(|| e.into())),
    }
}

/// The file's header as far as its first data row: the column names, their kinds so far
/// (a column still missing on that row is `Pending`) and the metadata above it. What a
/// streamed run needs to resolve its sensors before the first pass.
pub fn read_head(path: &Path, map: &ColumnMap) -> anyhow::Result<RowsHeader> {
    let mut opts = ReadOptions::default();
    let (file, name, total) = open(path, &mut opts)?;
    let mut sink = RowSink {
        file: name.clone(),
        map,
        check_time: false,
        head: RowsHeader::default(),
        nums: Vec::new(),
        texts: Vec::new(),
        t_idx: None,
        prev_t: f64::NEG_INFINITY,
        on_row: |_: &Row| Ok(()),
        failure: None,
        head_only: true,
    };
    let meta = scan(file, &name, opts, total, &mut sink)?;
    sink.head.meta = meta;
    Ok(sink.head)
}

impl RowsHeader {
    /// A trace of no rows with these columns (text ones as text) and metadata: enough to
    /// resolve names and positions against (`multi::sensors`).
    pub fn empty_trace(&self) -> super::Trace {
        let mut t = super::Trace {
            meta: self.meta.clone(),
            ..Default::default()
        };
        for (n, k) in self.names.iter().zip(&self.kinds) {
            if *k == Kind::Text {
                t.text.push((n.clone(), Vec::new()));
            } else {
                t.numeric.push((n.clone(), Vec::new()));
            }
        }
        t
    }
}
