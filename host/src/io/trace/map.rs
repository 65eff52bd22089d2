use super::TraceError;
use std::str::FromStr;

/// Renames file columns to canonical trace-format names, from the `--map` syntax
/// `canonical=file_name,...` (e.g. `mag=mag_4_uc,flux_x=flux_b_x,t=tt`).
/// Columns not named in the map keep their file names.
///
/// An entry may also be a preset name ([`PRESETS`]: `magnav`, `sgl`): its pairs apply
/// where the file has the preset's column and not already the canonical one, and
/// explicit entries override it (`magnav,mag=mag_4_uc`).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ColumnMap {
    /// (canonical, file name) pairs in the order given.
    pairs: Vec<(String, String)>,
    /// Pairs from presets: used only where they fit the file (see [`ColumnMap::apply`]).
    optional: Vec<(String, String)>,
}

/// Built-in maps: (name, what it is for, canonical=file pairs).
pub const PRESETS: &[(&str, &str, &str)] = &[
    (
        "magnav",
        "MagNav.jl HDF5 flight files (SGL 2020/2021 `Flt*.h5`, XYZ0/XYZ1 files): \
         tail-stinger scalar mag_1_uc, fluxgate A, INS attitude",
        "t=tt,mag=mag_1_uc,flux_x=flux_a_x,flux_y=flux_a_y,flux_z=flux_a_z,alt=utm_z,\
         roll=ins_roll,pitch=ins_pitch,yaw=ins_yaw",
    ),
    (
        "sgl",
        "SGL survey XYZ files (the MagNav challenge's `Flt*.xyz`): tail-stinger scalar \
         UNCOMPMAG1, fluxgate A, INS attitude",
        "t=TIME,mag=UNCOMPMAG1,flux_x=FLUXA_X,flux_y=FLUXA_Y,flux_z=FLUXA_Z,lat=LAT,\
         lon=LONG,alt=UTM-Z,roll=ROLL,pitch=PITCH,yaw=AZIMUTH",
    ),
];

/// For a message about a missing column: the built-in map whose names the file has
/// (MagNav's `tt`, SGL's `TIME`/`UNCOMPMAG1`), or nothing.
pub fn preset_hint(columns: &[&str]) -> &'static str {
    if columns.contains(&"tt") {
        " (MagNav names: try --map magnav, docs/trace-format.md)"
    } else if columns.contains(&"TIME") || columns.contains(&"UNCOMPMAG1") {
        " (SGL names: try --map sgl, docs/trace-format.md)"
    } else {
        ""
    }
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
            if let Some((_, _, pairs)) = PRESETS.iter().find(|p| p.0 == entry.trim()) {
                for pair in pairs.split(',') {
                    let (c, f) = pair.split_once('=').unwrap_or_default();
                    map.optional
                        .push((c.trim().to_string(), f.trim().to_string()));
                }
                continue;
            }
            let err = |msg: String| TraceError::Map {
                msg: format!(
                    "entry {} '{}': {msg} (expected canonical=file_column)",
                    i + 1,
                    entry.trim()
                ),
            };
            let Some((canon, file)) = entry.split_once('=') else {
                let names: Vec<&str> = PRESETS.iter().map(|p| p.0).collect();
                return Err(err(format!(
                    "missing '=' (and not a preset: {})",
                    names.join(", ")
                )));
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

    /// The file column named for `canonical`: an explicit entry, else a preset's (which
    /// applies where the file has it). None: the file's own `canonical` column.
    pub fn file_column(&self, canonical: &str) -> Option<&str> {
        self.pairs
            .iter()
            .chain(&self.optional)
            .find(|(c, _)| c == canonical)
            .map(|(_, f)| f.as_str())
    }

    pub fn is_empty(&self) -> bool {
        self.pairs.is_empty() && self.optional.is_empty()
    }

    /// The explicit pairs plus the preset pairs that fit `header`: the file has the
    /// preset's column, nothing explicit names the same canonical or file column, and
    /// the file has no column of the canonical name already (`alt` beside `utm_z`).
    fn resolve(&self, header: &[String]) -> ColumnMap {
        let mut out = ColumnMap {
            pairs: self.pairs.clone(),
            optional: Vec::new(),
        };
        for (c, f) in &self.optional {
            let taken = out.pairs.iter().any(|(c2, f2)| c2 == c || f2 == f);
            let has_file = header.iter().any(|h| h == f);
            let has_canon = header.iter().any(|h| h == c);
            if !taken && has_file && !has_canon {
                out.pairs.push((c.clone(), f.clone()));
            }
        }
        out
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
        if !self.optional.is_empty() {
            return self.resolve(header).apply(header);
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    fn names(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn a_preset_maps_only_what_the_file_has_and_explicit_entries_win() {
        let m = ColumnMap::parse("magnav,mag=mag_4_uc").unwrap();
        // SGL 2020 HDF5: utm_z is the height, mag_4_uc replaces the preset's mag_1_uc.
        let h = names(&[
            "tt", "lat", "lon", "utm_z", "mag_1_uc", "mag_4_uc", "flux_a_x",
        ]);
        assert_eq!(
            m.apply(&h).unwrap(),
            names(&["t", "lat", "lon", "alt", "mag_1_uc", "mag", "flux_x"])
        );
        // An XYZ0 file has `alt` itself: utm_z stays a column of its own.
        let h = names(&["tt", "alt", "utm_z", "mag_1_uc"]);
        assert_eq!(
            ColumnMap::parse("magnav").unwrap().apply(&h).unwrap(),
            names(&["t", "alt", "utm_z", "mag"])
        );
    }

    #[test]
    fn an_unknown_preset_is_an_error_naming_the_presets() {
        let e = ColumnMap::parse("magnv").unwrap_err().to_string();
        assert!(e.contains("magnav") && e.contains("sgl"), "{e}");
    }
}
