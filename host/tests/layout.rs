//! The source layout, checked by reading the sources. Issue 11 item 7: `src/cli/` (one file
//! per subcommand) is the only place with clap, nothing outside it imports it, and the two
//! former import cycles stay broken. Issue 18 items 1 and 2: the module import graph (built
//! from the `crate::`/`super::`/`self::` paths) has no cycle, and the folders keep their
//! layers ([`LAYERS`], [`NEVER`], [`ONLY`]).

use std::path::{Path, PathBuf};

/// Every `.rs` file under `dir`, recursively.
fn rust_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).expect("read_dir") {
        let p = e.expect("entry").path();
        if p.is_dir() {
            out.extend(rust_files(&p));
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
    out.sort();
    out
}

fn src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// The file's code without comment lines (a doc comment may name a module freely).
fn code(path: &Path) -> String {
    std::fs::read_to_string(path)
        .expect("read")
        .lines()
        .filter(|l| !l.trim_start().starts_with("//"))
        .collect::<Vec<_>>()
        .join("\n")
}

/// Processing files: everything but the command layer and the binary's entry point.
fn processing_files() -> Vec<PathBuf> {
    let cli = src().join("cli");
    rust_files(&src())
        .into_iter()
        .filter(|p| !p.starts_with(&cli) && !p.ends_with("main.rs") && !p.ends_with("lib.rs"))
        .collect()
}

/// Files under `src/<module>` (a directory) or `src/<module>.rs`.
fn module_files(module: &str) -> Vec<PathBuf> {
    let dir = src().join(module);
    if dir.is_dir() {
        rust_files(&dir)
    } else {
        vec![src().join(format!("{module}.rs"))]
    }
}

fn offenders(files: &[PathBuf], needles: &[&str]) -> Vec<String> {
    files
        .iter()
        .filter(|p| {
            let c = code(p);
            needles.iter().any(|n| c.contains(n))
        })
        .map(|p| p.strip_prefix(src()).unwrap_or(p).display().to_string())
        .collect()
}

#[test]
fn processing_neither_imports_the_command_layer_nor_uses_clap() {
    let files = processing_files();
    // The check must see the processing modules, or it passes on nothing.
    assert!(files.len() > 40, "{} processing files", files.len());
    for must in [
        "calibration/mod.rs",
        "calibration/coefficients.rs",
        "diagnose/mod.rs",
    ] {
        assert!(files.iter().any(|p| p.ends_with(must)), "{must} not seen");
    }
    let bad = offenders(&files, &["crate::cli", "magcomp::cli", "super::cli"]);
    assert!(
        bad.is_empty(),
        "processing imports the command layer: {bad:?}"
    );
    let bad = offenders(&files, &["clap::", "#[arg(", "#[command("]);
    assert!(bad.is_empty(), "clap outside src/cli: {bad:?}");
}

#[test]
fn every_subcommand_has_its_file_in_cli() {
    for sub in [
        "simulate",
        "calibrate",
        "compensate",
        "nmea",
        "diagnose",
        "report",
        "capture",
        "replay",
        "monitor",
        "upload",
        "demo",
        "args",
    ] {
        assert!(
            src().join("cli").join(format!("{sub}.rs")).is_file(),
            "{sub}"
        );
    }
    // main.rs parses and dispatches only: no processing module is called from it.
    let main = code(&src().join("main.rs"));
    assert!(main.contains("Cli::parse()"), "main.rs does not parse");
    let calls: Vec<&str> = main
        .lines()
        .filter(|l| l.contains("magcomp::") && !l.contains("magcomp::cli"))
        .collect();
    assert!(
        calls.is_empty(),
        "main.rs reaches past the command layer: {calls:?}"
    );
}

#[test]
fn diagnose_and_report_do_not_import_each_other_both_ways() {
    let report_uses_diagnose = !offenders(&module_files("report"), &["crate::diagnose"]).is_empty();
    let diagnose_uses_report = offenders(&module_files("diagnose"), &["crate::report"]);
    // The report is built from diagnoses: that direction is the one kept.
    assert!(
        report_uses_diagnose,
        "the check no longer sees report → diagnose"
    );
    assert!(
        diagnose_uses_report.is_empty(),
        "diagnose imports report: {diagnose_uses_report:?}"
    );
}

#[test]
fn flight_does_not_import_fluxgate() {
    assert!(!offenders(&module_files("estimate/fluxcal"), &["crate::flight"]).is_empty());
    let bad = offenders(
        &module_files("flight"),
        &["crate::estimate::fluxcal", "fluxcal::"],
    );
    assert!(bad.is_empty(), "flight imports fluxgate: {bad:?}");
}

#[test]
fn command_layer_and_the_split_modules_stay_under_1000_lines() {
    let mut files = rust_files(&src().join("cli"));
    files.extend(module_files("calibration"));
    files.extend(module_files("estimate/kf"));
    files.extend(["calibration/coefficients.rs", "main.rs"].map(|f| src().join(f)));
    for p in files {
        let n = std::fs::read_to_string(&p).expect("read").lines().count();
        assert!(n <= 1000, "{}: {n} lines", p.display());
    }
}

// ---------------------------------------------------------------------------------------
// The module import graph (issue 18 items 1 and 2).
//
// A node is a module: a file, or a folder (its `mod.rs` is the folder's own face). An edge
// is a `crate::…`, `super::…` or `self::…` path in a file's code (`use` trees expanded,
// comments and string literals left out), resolved to the deepest module it names. Cycles
// are looked for among the entries of every folder (files and sub-folders, the folder's
// `mod.rs` aside) and among the top-level folders, so a cycle anywhere shows at the level
// where it closes.

use std::collections::{BTreeMap, BTreeSet};

/// The top-level folders, bottom layer first: each imports only folders before it.
const LAYERS: [&str; 15] = [
    "io",
    "signal",
    "model",
    "flight",
    "sim",
    "qc",
    "estimate",
    "calibration",
    "multi",
    "board",
    "diagnose",
    "stream",
    "report",
    "live",
    "cli",
];

/// The layering as the issue states it: `from` never imports any of these.
const NEVER: &[(&str, &[&str])] = &[
    // The estimators know nothing of how their results are stored, shown or asked for.
    (
        "estimate",
        &[
            "calibration",
            "board",
            "report",
            "stream",
            "diagnose",
            "cli",
        ],
    ),
    // Calibration is the result and its file; rendering and discovery sit above it.
    (
        "calibration",
        &["board", "report", "stream", "diagnose", "cli"],
    ),
    // The simulator judges the compensator, so it must not share its estimators.
    ("sim", &["qc", "estimate", "calibration", "diagnose", "cli"]),
    // A flight is what the core consumes, before any check or estimate of it.
    ("flight", &["qc", "estimate", "calibration", "sim"]),
    (
        "qc",
        &["estimate", "calibration", "report", "stream", "cli"],
    ),
    // Several magnetometers build on one sensor's estimators and calibration.
    ("multi", &["board", "report", "stream", "diagnose", "cli"]),
    ("diagnose", &["report", "stream", "cli"]),
    ("board", &["report", "stream", "diagnose", "cli"]),
    ("stream", &["report", "diagnose", "cli"]),
    ("report", &["stream", "cli"]),
];

/// Modules that import nothing in the crate beyond these (module paths, `/`-joined): the
/// I/O and signal tools at the bottom, and the flight's own geometry (IGRF, positions).
const ONLY: &[(&str, &[&str])] = &[
    ("io", &["io"]),
    ("signal", &["signal"]),
    ("model", &["model"]),
    ("flight/igrf", &[]),
    ("flight/position", &["io"]),
];

type ModPath = Vec<String>;

/// The import graph: every module and the modules its code names.
struct Graph {
    edges: BTreeMap<ModPath, BTreeSet<ModPath>>,
}

/// The module a file under `src` is (`lib.rs` the crate root, `x/mod.rs` the folder `x`).
fn module_of(rel: &Path) -> ModPath {
    let mut parts: Vec<String> = rel
        .iter()
        .map(|c| c.to_string_lossy().into_owned())
        .collect();
    let last = parts.pop().unwrap_or_default();
    let stem = last.trim_end_matches(".rs");
    if stem != "mod" && !(parts.is_empty() && stem == "lib") {
        parts.push(stem.to_string());
    }
    parts
}

/// `text` with comments removed and string and char literals emptied, so neither a doc
/// comment nor a message naming a module counts as an import.
fn code_only(text: &str) -> String {
    let b = text.as_bytes();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    while i < b.len() {
        let rest = &text[i..];
        if rest.starts_with("//") {
            i += rest.find('\n').unwrap_or(rest.len());
        } else if rest.starts_with("/*") {
            let mut depth = 0;
            while i < b.len() {
                if text[i..].starts_with("/*") {
                    depth += 1;
                    i += 2;
                } else if text[i..].starts_with("*/") {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    i += 1;
                }
            }
            out.push(' ');
        } else if b[i] == b'r' && (rest.starts_with("r\"") || rest.starts_with("r#")) {
            let hashes = rest[1..].bytes().take_while(|&c| c == b'#').count();
            if rest.as_bytes().get(1 + hashes) != Some(&b'"') {
                out.push('r');
                i += 1;
                continue;
            }
            let close = format!("\"{}", "#".repeat(hashes));
            let body = 2 + hashes;
            i += body
                + rest[body..]
                    .find(&close)
                    .map_or(rest.len() - body, |k| k + close.len());
            out.push_str("\"\"");
        } else if b[i] == b'"' {
            i += 1;
            while i < b.len() && b[i] != b'"' {
                i += if b[i] == b'\\' { 2 } else { 1 };
            }
            i += 1;
            out.push_str("\"\"");
        } else if b[i] == b'\'' {
            // A char literal ('x', '\n', '\u{..}') or a lifetime ('a): only the first is
            // skipped whole.
            let lit = rest
                .char_indices()
                .skip(1)
                .take(12)
                .find(|&(k, c)| c == '\'' && k > 1)
                .filter(|&(k, _)| rest[1..k].starts_with('\\') || rest[1..k].chars().count() == 1);
            match lit {
                Some((k, _)) => {
                    i += k + 1;
                    out.push_str("' '");
                }
                None => {
                    out.push('\'');
                    i += 1;
                }
            }
        } else {
            let c = rest.chars().next().unwrap_or(' ');
            out.push(c);
            i += c.len_utf8();
        }
    }
    out
}

/// The inline modules of `code` (`mod name { … }`), outermost first, with their spans.
fn inline_modules(code: &str) -> Vec<(String, std::ops::Range<usize>)> {
    let s = code.as_bytes();
    let mut found = Vec::new();
    let mut from = 0;
    while let Some(k) = code[from..].find("mod ") {
        let at = from + k;
        from = at + 4;
        if at > 0 && is_ident(s[at - 1]) {
            continue;
        }
        let name_end = from + s[from..].iter().take_while(|&&c| is_ident(c)).count();
        let open = name_end
            + s[name_end..]
                .iter()
                .take_while(|c| c.is_ascii_whitespace())
                .count();
        if name_end == from || s.get(open) != Some(&b'{') {
            continue;
        }
        let mut depth = 0usize;
        let mut end = s.len();
        for (j, &c) in s.iter().enumerate().skip(open) {
            depth = match c {
                b'{' => depth + 1,
                b'}' => depth - 1,
                _ => depth,
            };
            if depth == 0 {
                end = j;
                break;
            }
        }
        found.push((code[from..name_end].to_string(), open..end));
    }
    found
}

fn is_ident(c: u8) -> bool {
    c.is_ascii_alphanumeric() || c == b'_'
}

/// The paths of a use tree starting at `i` (after a `::`): `a::b`, `a::{b, c::d}`, `*`.
fn use_tree(s: &[u8], mut i: usize) -> (Vec<Vec<String>>, usize) {
    while i < s.len() && s[i].is_ascii_whitespace() {
        i += 1;
    }
    if s.get(i) == Some(&b'{') {
        let mut paths = Vec::new();
        i += 1;
        loop {
            while i < s.len() && (s[i].is_ascii_whitespace() || s[i] == b',') {
                i += 1;
            }
            if i >= s.len() || s[i] == b'}' {
                return (paths, i + 1);
            }
            let (sub, j) = use_tree(s, i);
            paths.extend(sub);
            // `x as y`: the alias names nothing new.
            i = j;
            while i < s.len() && !matches!(s[i], b',' | b'}') {
                i += 1;
            }
        }
    }
    let start = i;
    while i < s.len() && (is_ident(s[i]) || s[i] == b'*') {
        i += 1;
    }
    let name = String::from_utf8_lossy(&s[start..i]).into_owned();
    if name.is_empty() {
        return (vec![vec![]], i);
    }
    let mut j = i;
    while j < s.len() && s[j].is_ascii_whitespace() {
        j += 1;
    }
    if s[j..].starts_with(b"::") {
        let (sub, k) = use_tree(s, j + 2);
        let paths = sub
            .into_iter()
            .map(|p| std::iter::once(name.clone()).chain(p).collect())
            .collect();
        return (paths, k);
    }
    (vec![vec![name]], i)
}

impl Graph {
    /// From `(path under src, text)` pairs.
    fn from_sources(files: &[(PathBuf, String)]) -> Graph {
        let modules: BTreeSet<ModPath> = files.iter().map(|(p, _)| module_of(p)).collect();
        let mut edges = BTreeMap::new();
        for (path, text) in files {
            let here = module_of(path);
            let code = code_only(text);
            let s = code.as_bytes();
            let inline = inline_modules(&code);
            let mut out = BTreeSet::new();
            for root in ["crate", "super", "self"] {
                let pat = format!("{root}::");
                let mut from = 0;
                while let Some(k) = code[from..].find(&pat) {
                    let at = from + k;
                    from = at + pat.len();
                    if at > 0 && (is_ident(s[at - 1]) || s[at - 1] == b':') {
                        continue;
                    }
                    let (paths, _) = use_tree(s, at + pat.len());
                    // `self`/`super` count from the inline module (`mod tests { … }`) the
                    // path is written in.
                    let mut inner = here.clone();
                    inner.extend(
                        inline
                            .iter()
                            .filter(|(_, span)| span.contains(&at))
                            .map(|(name, _)| name.clone()),
                    );
                    for p in paths {
                        let mut base = match root {
                            "crate" => vec![],
                            "super" => inner[..inner.len().saturating_sub(1)].to_vec(),
                            _ => inner.clone(),
                        };
                        let mut rest = p.as_slice();
                        while let Some(("super", tail)) =
                            rest.split_first().map(|(a, t)| (a.as_str(), t))
                        {
                            base.pop();
                            rest = tail;
                        }
                        base.extend(rest.iter().filter(|x| *x != "self").cloned());
                        // The deepest module the path names (the rest is an item in it).
                        let target = (0..=base.len())
                            .rev()
                            .map(|n| base[..n].to_vec())
                            .find(|m| modules.contains(m));
                        if let Some(t) = target.filter(|t| *t != here && !t.is_empty()) {
                            out.insert(t);
                        }
                    }
                }
            }
            edges.insert(here, out);
        }
        Graph { edges }
    }

    /// The crate under `src` (the binary's `main.rs` aside: it is its own crate).
    fn of_crate() -> Graph {
        let files: Vec<(PathBuf, String)> = rust_files(&src())
            .into_iter()
            .filter(|p| !p.ends_with("main.rs"))
            .map(|p| {
                let text = std::fs::read_to_string(&p).expect("read");
                (
                    p.strip_prefix(src()).expect("under src").to_path_buf(),
                    text,
                )
            })
            .collect();
        Graph::from_sources(&files)
    }

    /// Whether module `m` imports anything under `target`.
    fn imports(&self, m: &ModPath, target: &[&str]) -> bool {
        self.edges[m].iter().any(|t| t.starts_with(&own(target)))
    }

    /// Edges between the entries of `folder` (its `mod.rs` aside), every module under an
    /// entry counting as the entry.
    fn entries_of(&self, folder: &[String]) -> BTreeMap<String, BTreeSet<String>> {
        let n = folder.len();
        let entry = |m: &ModPath| (m.len() > n && m[..n] == *folder).then(|| m[n].clone());
        let mut g: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
        for (from, to) in &self.edges {
            let Some(a) = entry(from) else { continue };
            let set = g.entry(a.clone()).or_default();
            for b in to.iter().filter_map(&entry).filter(|b| *b != a) {
                set.insert(b);
            }
        }
        g
    }

    /// Every folder (module with sub-modules), the crate root first.
    fn folders(&self) -> BTreeSet<ModPath> {
        self.edges
            .keys()
            .filter(|m| !m.is_empty())
            .map(|m| m[..m.len() - 1].to_vec())
            .collect()
    }

    /// The cycles: for each folder, one cycle among its entries if there is one.
    fn cycles(&self) -> Vec<String> {
        let mut found = Vec::new();
        for folder in self.folders() {
            if let Some(c) = find_cycle(&self.entries_of(&folder)) {
                let at = if folder.is_empty() {
                    "src".to_string()
                } else {
                    format!("src/{}", folder.join("/"))
                };
                found.push(format!("{at}: {}", c.join(" → ")));
            }
        }
        found
    }
}

fn own(p: &[&str]) -> ModPath {
    p.iter().map(|s| s.to_string()).collect()
}

fn path_of(s: &str) -> ModPath {
    s.split('/').map(String::from).collect()
}

/// One cycle of `g` (first node repeated at the end), by depth-first search.
fn find_cycle(g: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(
        n: &str,
        g: &BTreeMap<String, BTreeSet<String>>,
        state: &mut BTreeMap<String, u8>,
        stack: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        state.insert(n.to_string(), 1);
        stack.push(n.to_string());
        for m in g.get(n).into_iter().flatten() {
            match state.get(m.as_str()) {
                Some(1) => {
                    let k = stack.iter().position(|x| x == m).expect("on the stack");
                    let mut c = stack[k..].to_vec();
                    c.push(m.clone());
                    return Some(c);
                }
                Some(_) => {}
                None => {
                    if let Some(c) = visit(m, g, state, stack) {
                        return Some(c);
                    }
                }
            }
        }
        stack.pop();
        state.insert(n.to_string(), 2);
        None
    }
    let mut state = BTreeMap::new();
    for n in g.keys() {
        if !state.contains_key(n.as_str()) {
            if let Some(c) = visit(n, g, &mut state, &mut Vec::new()) {
                return Some(c);
            }
        }
    }
    None
}

#[test]
fn the_import_graph_is_seen() {
    let g = Graph::of_crate();
    // The graph must hold the modules and the edges every layer has, or the checks below
    // pass on nothing.
    assert!(g.edges.len() > 100, "{} modules", g.edges.len());
    for (from, to) in [
        ("calibration/kf", "estimate/corrections"),
        ("estimate/corrections/lag", "estimate/kf"),
        ("estimate/kf", "estimate/fluxcal"),
        ("report/flight_report", "diagnose"),
        ("stream/apply", "io/csv"),
        ("io/trace/write", "io/output"),
        ("diagnose/regression", "signal/stats"),
    ] {
        assert!(
            g.imports(&path_of(from), &to.split('/').collect::<Vec<_>>()),
            "{from} → {to} not seen"
        );
    }
}

#[test]
fn no_import_cycle_anywhere() {
    let cycles = Graph::of_crate().cycles();
    assert!(cycles.is_empty(), "import cycles:\n{}", cycles.join("\n"));
}

#[test]
fn a_cycle_is_found_where_it_closes() {
    // The check itself, on made-up sources: a cycle through two folders and one inside a
    // folder are reported; a child naming its folder's `mod.rs` is the folder's own affair.
    let file = |p: &str, t: &str| (PathBuf::from(p), t.to_string());
    let g = Graph::from_sources(&[
        file("lib.rs", "pub mod a; pub mod b;"),
        file("a/mod.rs", "pub mod x; pub mod y; pub struct T;"),
        file(
            "a/x.rs",
            "use crate::b::{c::{self, D}, E as F};\n// crate::nothing",
        ),
        file(
            "a/y.rs",
            "use super::{x, T}; fn f() { let _ = \"super::z\"; }",
        ),
        file("b/mod.rs", "pub mod c; pub struct E;"),
        file(
            "b/c.rs",
            "pub struct D; fn g() -> crate::a::y::Z { todo!() }\n\
             mod tests { use super::*; use super::super::E; }",
        ),
    ]);
    assert_eq!(
        g.edges[&path_of("a/x")],
        [path_of("b"), path_of("b/c")].into_iter().collect()
    );
    assert_eq!(
        g.edges[&path_of("a/y")],
        [path_of("a"), path_of("a/x")].into_iter().collect()
    );
    // The test module's `super` is `b::c` itself, its `super::super` the folder `b`.
    assert_eq!(
        g.edges[&path_of("b/c")],
        [path_of("a/y"), path_of("b")].into_iter().collect()
    );
    assert_eq!(g.cycles(), vec!["src: a → b → a".to_string()]);
    let g = Graph::from_sources(&[
        file("a/mod.rs", "pub mod x; pub mod y;"),
        file("a/x.rs", "use super::y::Y;"),
        file("a/y.rs", "pub struct Y; fn f() { super::x::g(); }"),
    ]);
    assert_eq!(g.cycles(), vec!["src/a: x → y → x".to_string()]);
}

#[test]
fn only_lib_and_main_are_loose_and_every_folder_is_a_layer() {
    let mut loose = Vec::new();
    let mut folders = Vec::new();
    for e in std::fs::read_dir(src()).expect("read_dir") {
        let p = e.expect("entry").path();
        let name = p.file_name().expect("name").to_string_lossy().into_owned();
        if p.is_dir() {
            folders.push(name);
        } else {
            loose.push(name);
        }
    }
    loose.sort();
    folders.sort();
    assert_eq!(loose, ["lib.rs", "main.rs"], "loose files in src");
    let mut layers = LAYERS.map(String::from).to_vec();
    layers.sort();
    assert_eq!(folders, layers, "src's folders and LAYERS differ");
    // Each folder says its one concern at the top of its mod.rs.
    for f in &folders {
        let text = std::fs::read_to_string(src().join(f).join("mod.rs")).expect("mod.rs");
        assert!(text.starts_with("//!"), "src/{f}/mod.rs has no //! doc");
    }
}

#[test]
fn every_folder_imports_only_the_layers_below_it() {
    let g = Graph::of_crate();
    let layer = |m: &ModPath| {
        LAYERS
            .iter()
            .position(|l| m.first().is_some_and(|f| f == l))
    };
    let mut bad = Vec::new();
    for (from, to) in &g.edges {
        let Some(a) = layer(from) else { continue };
        for t in to {
            if layer(t).is_some_and(|b| b > a) {
                bad.push(format!("{} → {}", from.join("/"), t.join("/")));
            }
        }
    }
    assert!(bad.is_empty(), "imports running up the layers: {bad:#?}");
}

#[test]
fn the_never_rules_hold() {
    let g = Graph::of_crate();
    let mut bad = Vec::new();
    for (from, never) in NEVER {
        for (m, to) in g
            .edges
            .iter()
            .filter(|(m, _)| m.first().is_some_and(|f| f == from))
        {
            for t in to.iter().filter(|t| never.iter().any(|n| t[0] == *n)) {
                bad.push(format!("{} → {}", m.join("/"), t.join("/")));
            }
        }
    }
    // Nothing but the command layer imports it (main.rs is its own crate: checked above).
    for (m, to) in &g.edges {
        if m.first().is_none_or(|f| f != "cli") && to.iter().any(|t| t[0] == "cli") {
            bad.push(format!("{} → cli", m.join("/")));
        }
    }
    for (module, allowed) in ONLY {
        let prefix = path_of(module);
        for (m, to) in g.edges.iter().filter(|(m, _)| m.starts_with(&prefix)) {
            for t in to
                .iter()
                .filter(|t| !allowed.iter().any(|a| t.starts_with(&path_of(a))))
            {
                bad.push(format!(
                    "{} → {} (only {allowed:?})",
                    m.join("/"),
                    t.join("/")
                ));
            }
        }
    }
    assert!(bad.is_empty(), "layering broken: {bad:#?}");
}

#[test]
fn no_source_file_reaches_1000_lines() {
    for p in rust_files(&src()) {
        let n = std::fs::read_to_string(&p).expect("read").lines().count();
        assert!(n < 1000, "{}: {n} lines", p.display());
    }
}
