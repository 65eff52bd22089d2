//! Issue 11's "done when": no `--help` text and no document refers to a documentation file
//! that is not in the repository. Every subcommand's `--help` is run; each `*.md` path it
//! mentions must exist under the repository root, and no help text may point outside it
//! (`../`, an absolute path, the shared reference data). Every `*.md` path in `README.md`
//! and `docs/*.md` must exist beside the document or under the root.

use std::path::{Path, PathBuf};
use std::process::Command;

fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("host/ has a parent")
        .to_path_buf()
}

fn help(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_magcomp"))
        .args(args)
        .output()
        .expect("run magcomp");
    assert!(out.status.success(), "magcomp {args:?} failed");
    String::from_utf8(out.stdout).expect("utf-8 help")
}

/// The subcommands `magcomp --help` lists (without `help`).
fn subcommands() -> Vec<String> {
    let top = help(&["--help"]);
    let list = top
        .split("Commands:")
        .nth(1)
        .expect("a Commands: section")
        .lines()
        .skip(1)
        .take_while(|l| !l.trim().is_empty());
    list.filter_map(|l| l.split_whitespace().next())
        .filter(|c| *c != "help")
        .map(String::from)
        .collect()
}

/// Path-like words of `text`: runs of `[A-Za-z0-9_./~-]`, trailing dots trimmed.
fn path_words(text: &str) -> Vec<String> {
    text.split(|c: char| !(c.is_ascii_alphanumeric() || "_./~-".contains(c)))
        .map(|w| w.trim_end_matches('.'))
        .filter(|w| !w.is_empty())
        .map(String::from)
        .collect()
}

fn md_paths(text: &str) -> Vec<String> {
    path_words(text)
        .into_iter()
        .filter(|w| w.ends_with(".md"))
        .collect()
}

#[test]
fn help_texts_cite_only_documents_in_the_repository() {
    let root = repo_root();
    let cmds = subcommands();
    // The command layer has one file per subcommand (`host/src/cli/`): all are listed.
    assert!(cmds.len() >= 10, "{cmds:?}");
    let mut cited = 0;
    let mut problems = Vec::new();
    for cmd in &cmds {
        let text = help(&[cmd.as_str(), "--help"]);
        for p in md_paths(&text) {
            cited += 1;
            if !root.join(&p).is_file() {
                problems.push(format!("{cmd} --help: {p} is not a file of the repository"));
            }
        }
        for w in path_words(&text) {
            // (a lone `/` or `~0.001` is prose, `/dir/file` and `~/file` are paths)
            let absolute = w.starts_with('/') && w[1..].contains('/');
            if w.contains("../") || absolute || w.starts_with("~/") || w.contains("shared/") {
                problems.push(format!("{cmd} --help: {w} is outside the repository"));
            }
        }
    }
    println!("{} subcommands, {cited} document citations", cmds.len());
    assert!(problems.is_empty(), "{problems:#?}");
    // The data contract is cited by the commands that read traces.
    assert!(
        cited >= 4,
        "only {cited} citations: the help texts lost docs/trace-format.md"
    );
}

#[test]
fn documents_cite_only_documents_in_the_repository() {
    let root = repo_root();
    let mut docs = vec![root.join("README.md")];
    for e in std::fs::read_dir(root.join("docs")).expect("docs/") {
        let p = e.expect("entry").path();
        if p.extension().is_some_and(|x| x == "md") {
            docs.push(p);
        }
    }
    let mut problems = Vec::new();
    let mut cited = 0;
    for doc in &docs {
        let text = std::fs::read_to_string(doc).expect("read doc");
        let dir = doc.parent().expect("dir");
        for p in md_paths(&text) {
            cited += 1;
            // A link is relative to the document; a path in prose to the repository root.
            if !dir.join(&p).is_file() && !root.join(&p).is_file() {
                problems.push(format!("{}: {p} does not exist", doc.display()));
            }
        }
    }
    println!("{} documents, {cited} document citations", docs.len());
    assert!(problems.is_empty(), "{problems:#?}");
    assert!(cited > 10, "{cited}");
}
