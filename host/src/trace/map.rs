use super::TraceError;
use std::str::FromStr;

/// Renames file columns to canonical trace-format names, from the `--map` syntax
/// `canonical=file_name,...` (e.g. `mag=mag_4_uc,flux_x=flux_b_x,t=tt`).
/// Columns not named in the map keep their file names.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ColumnMap {
    /// (canonical, file name) pairs in the order given.
    pairs: Vec<(String, String)>,
}

impl ColumnMap {
    /// The identity map (file names are already canonical).
    pub fn new() -> Self {
        Self::default()
    }

    /// Parses `canonical=file,canonical=file,...`. Whitespace around names is ignored; an
    /// empty string gives the identity map. Errors name the offending entry.
    pub fn parse(spec: &str) -> Result<Self, TraceError> {
        let mut map = ColumnMap::new();
        if spec.trim().is_empty() {
            return Ok(map);
        }
        for (i, entry) in spec.split(',').enumerate() {
            let err = |msg: String| TraceError::Map {
                msg: format!(
                    "entry {} '{}': {msg} (expected canonical=file_column)",
                    i + 1,
                    entry.trim()
                ),
            };
            let Some((canon, file)) = entry.split_once('=') else {
                return Err(err("missing '='".into()));
            };
            let (canon, file) = (canon.trim(), file.trim());
            if canon.is_empty() {
                return Err(err("empty canonical name before '='".into()));
            }
            if file.is_empty() {
                return Err(err("empty file column name after '='".into()));
            }
            if file.contains('=') {
                return Err(err("more than one '='".into()));
            }
            map.insert(canon, file)?;
        }
        Ok(map)
    }

    /// Adds one mapping; errors if `canonical` or `file` is already mapped.
    pub fn insert(&mut self, canonical: &str, file: &str) -> Result<(), TraceError> {
        if let Some((_, f)) = self.pairs.iter().find(|(c, _)| c == canonical) {
            return Err(TraceError::Map {
                msg: format!("'{canonical}' is mapped twice (to '{f}' and '{file}')"),
            });
        }
        if let Some((c, _)) = self.pairs.iter().find(|(_, f)| f == file) {
            return Err(TraceError::Map {
                msg: format!("file column '{file}' is mapped twice (to '{c}' and '{canonical}')"),
            });
        }
        self.pairs.push((canonical.to_string(), file.to_string()));
        Ok(())
    }

    /// (canonical, file name) pairs in the order given.
    pub fn pairs(&self) -> &[(String, String)] {
        &self.pairs
    }

    pub fn is_empty(&self) -> bool {
        self.pairs.is_empty()
    }

    /// The canonical name a file column gets (its own name when unmapped).
    pub fn canonical_name<'a>(&'a self, file_name: &'a str) -> &'a str {
        self.pairs
            .iter()
            .find(|(_, f)| f == file_name)
            .map(|(c, _)| c.as_str())
            .unwrap_or(file_name)
    }

    /// Renames a header. Errors when a mapped file column is absent, or when a mapped
    /// canonical name collides with another, unmapped file column of that name (dropping
    /// either silently would lose data; map the other one elsewhere, e.g. `mag_orig=mag`).
    pub fn apply(&self, header: &[String]) -> Result<Vec<String>, TraceError> {
        for (canon, file) in &self.pairs {
            if !header.iter().any(|h| h == file) {
                return Err(TraceError::Map {
                    msg: format!(
                        "'{canon}={file}': the file has no column '{file}'; it has: {}",
                        header.join(", ")
                    ),
                });
            }
            let mapped_away = self.pairs.iter().any(|(_, f)| f == canon);
            if canon != file && !mapped_away && header.iter().any(|h| h == canon) {
                return Err(TraceError::Map {
                    msg: format!(
                        "'{canon}={file}': the file also has a column named '{canon}'; \
                         map that one to another name too (e.g. {canon}_orig={canon})"
                    ),
                });
            }
        }
        Ok(header
            .iter()
            .map(|h| self.canonical_name(h).to_string())
            .collect())
    }
}

impl FromStr for ColumnMap {
    type Err = TraceError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        ColumnMap::parse(s)
    }
}
