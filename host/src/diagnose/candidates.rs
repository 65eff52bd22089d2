//! Which auxiliary columns are candidate drivers of an unmodelled effect.
//!
//! A survey file carries ~100 channels besides the ones the model reads (SGL: BARO, UTM-X,
//! UNCOMPMAG1, LINE, YEAR, …). Testing each as `current:CH` / `periodic:CH` costs
//! Bonferroni power and time, and a "winner" like `current:UNCOMPMAG1` (another
//! magnetometer, which carries the same interference) or `periodic:LINE` is nonsense. By
//! default the columns that are position, navigation and air data, attitude, time and
//! date, identifiers, other magnetometers or base stations, fluxgate channels, or
//! constant are left out; `--aux 'CUR_*,V_*'` names the candidates explicitly instead.

use crate::io::trace::Trace;
use anyhow::{bail, Result};

/// Name patterns (case-insensitive globs) that are never candidates by default, by kind.
pub const EXCLUDED: &[(&str, &[&str])] = &[
    (
        "position and navigation",
        &[
            "lat",
            "lon",
            "long",
            "latitude",
            "longitude",
            "x",
            "y",
            "z",
            "utm*",
            "msl*",
            "alt",
            "altitude",
            "height",
            "hgt",
            "*_hgt",
            "baro*",
            "radar*",
            "topo*",
            "dem",
            "drape*",
            "ins_*",
            "gps_*",
            "gnss_*",
            "easting",
            "northing",
            "*vel*",
            "*_acc",
            "*_acc_*",
            "true_as",
            "tas",
            "ias",
            "pitot*",
            "static_p",
            "tot_p",
        ],
    ),
    (
        "attitude",
        &[
            "pitch*", "roll*", "yaw*", "azimuth", "heading", "hdg", "track",
        ],
    ),
    (
        "time, date and identifiers",
        &[
            "t", "tt", "time", "*_time", "utc*", "date", "year", "doy", "day", "hour", "sec",
            "fid", "line", "line_*", "flt", "flight", "tie", "segment",
        ],
    ),
    (
        "another magnetometer or a base station",
        &[
            "mag",
            "mag_*",
            "*compmag*",
            "lagmag*",
            "dcmag*",
            "igrfmag*",
            "ogs_mag",
            "diurnal",
            "base*",
            "igrf*",
        ],
    ),
    ("fluxgate", &["flux*"]),
];

/// `*` (any run) and `?` (one character) glob match, ASCII case-insensitive.
pub fn glob_match(pattern: &str, name: &str) -> bool {
    let p: Vec<char> = pattern.chars().map(|c| c.to_ascii_lowercase()).collect();
    let n: Vec<char> = name.chars().map(|c| c.to_ascii_lowercase()).collect();
    // Iterative matcher with one backtrack point (the last `*`).
    let (mut pi, mut ni) = (0, 0);
    let mut star: Option<(usize, usize)> = None;
    while ni < n.len() {
        if pi < p.len() && (p[pi] == '?' || p[pi] == n[ni]) {
            pi += 1;
            ni += 1;
        } else if pi < p.len() && p[pi] == '*' {
            star = Some((pi, ni));
            pi += 1;
        } else if let Some((sp, sn)) = star {
            pi = sp + 1;
            ni = sn + 1;
            star = Some((sp, sn + 1));
        } else {
            return false;
        }
    }
    p[pi..].iter().all(|&c| c == '*')
}

/// Why a column is not a default candidate (the kind from [`EXCLUDED`], or "constant").
pub fn excluded_reason(name: &str, values: &[f64]) -> Option<&'static str> {
    for (kind, pats) in EXCLUDED {
        if pats.iter().any(|p| glob_match(p, name)) {
            return Some(kind);
        }
    }
    constant(values).then_some("constant")
}

/// No two different finite values (a constant carries no signal to test).
fn constant(v: &[f64]) -> bool {
    let mut finite = v.iter().copied().filter(|x| x.is_finite());
    match finite.next() {
        None => true,
        Some(first) => finite.all(|x| x == first),
    }
}

/// `--aux` patterns.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct AuxSelection {
    patterns: Vec<String>,
}

impl AuxSelection {
    /// `CUR_*,V_*` (comma-separated globs).
    pub fn parse(text: &str) -> Result<Self> {
        let patterns: Vec<String> = text
            .split(',')
            .map(|s| s.trim().to_string())
            .filter(|s| !s.is_empty())
            .collect();
        if patterns.is_empty() {
            bail!("--aux '{text}': no pattern (e.g. --aux 'CUR_*,V_*')");
        }
        Ok(Self { patterns })
    }

    pub fn matches(&self, name: &str) -> bool {
        self.patterns.iter().any(|p| glob_match(p, name))
    }
}

/// The candidate channels of a trace, file order: the auxiliary (unmapped numeric)
/// columns that `sel` matches, or, without `sel`, all but the excluded kinds. Constant
/// columns are never candidates.
pub fn channels<'a>(trace: &'a Trace, sel: Option<&AuxSelection>) -> Vec<&'a str> {
    trace
        .aux_columns()
        .into_iter()
        .filter(|n| {
            let v = trace.col(n).unwrap_or(&[]);
            match sel {
                Some(s) => s.matches(n) && !constant(v),
                None => excluded_reason(n, v).is_none(),
            }
        })
        .collect()
}

/// Errors when `--aux` matches no auxiliary column, listing those there are.
pub fn check_selection(trace: &Trace, sel: &AuxSelection) -> Result<()> {
    if channels(trace, Some(sel)).is_empty() {
        bail!(
            "--aux {}: no non-constant auxiliary column matches; the trace has: {}",
            sel.patterns.join(","),
            trace.aux_columns().join(", ")
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn globs() {
        assert!(glob_match("CUR_*", "cur_pump"));
        assert!(glob_match("*compmag*", "UNCOMPMAG1"));
        assert!(glob_match("v_?at?", "V_BAT1"));
        assert!(!glob_match("v_*", "CUR_V"));
        assert!(glob_match("*", ""));
        assert!(!glob_match("mag_*", "temp_mag"));
    }
}
