//! Output files that are never left half-written, and outputs that never overwrite an
//! input.
//!
//! Every file a command writes goes to a temporary file in the same directory (so the
//! rename cannot cross a file system) and is renamed over the final name only after the
//! last byte is flushed and synced: a full disk, a write error or an interrupted run
//! leaves the previous file (or none) under the final name, never a truncated one. The
//! temporary file is deleted on any error (`tempfile` removes it on drop).
//!
//! `monitor --save` is the exception: a live log must keep what it has when the link
//! drops or the operator presses Ctrl-C, so it appends in place.

use anyhow::{bail, Context, Result};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// A file being written under a temporary name; [`commit`](Self::commit) renames it to
/// its final name. Dropped without a commit, it leaves nothing behind.
pub struct AtomicFile {
    w: BufWriter<tempfile::NamedTempFile>,
    path: PathBuf,
}

impl AtomicFile {
    /// Starts writing `path` (its directory must exist).
    pub fn create(path: &Path) -> Result<Self> {
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        let name = path
            .file_name()
            .with_context(|| format!("{} is not a file name", path.display()))?;
        let mut b = tempfile::Builder::new();
        let prefix = format!(".{}.", name.to_string_lossy());
        b.prefix(&prefix).suffix(".tmp");
        // tempfile's default 0600 would make every output private; ask for what a plain
        // create gives (0666 less the umask).
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            b.permissions(std::fs::Permissions::from_mode(0o666));
        }
        let tmp = b
            .tempfile_in(dir)
            .with_context(|| format!("creating {} (in {})", path.display(), dir.display()))?;
        Ok(Self {
            w: BufWriter::with_capacity(1 << 16, tmp),
            path: path.to_path_buf(),
        })
    }

    /// The final name.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Flushes, syncs and renames the file to its final name.
    pub fn commit(self) -> Result<()> {
        let path = self.path;
        let writing = || format!("writing {}", path.display());
        let tmp = self
            .w
            .into_inner()
            .map_err(|e| e.into_error())
            .with_context(writing)?;
        tmp.as_file().sync_all().with_context(writing)?;
        tmp.persist(&path)
            .map_err(|e| e.error)
            .with_context(|| format!("renaming the finished output to {}", path.display()))?;
        Ok(())
    }
}

impl Write for AtomicFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.w.write(buf)
    }
    fn write_all(&mut self, buf: &[u8]) -> std::io::Result<()> {
        self.w.write_all(buf)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.w.flush()
    }
}

/// Writes `path` through `f` atomically; on any error nothing appears under `path`
/// and the error names it.
pub fn write_with<T>(path: &Path, f: impl FnOnce(&mut AtomicFile) -> Result<T>) -> Result<T> {
    let mut out = AtomicFile::create(path)?;
    let v = f(&mut out).with_context(|| format!("writing {}", path.display()))?;
    out.commit()?;
    Ok(v)
}

/// Writes `bytes` to `path` atomically.
pub fn write_file(path: &Path, bytes: impl AsRef<[u8]>) -> Result<()> {
    write_with(path, |w| Ok(w.write_all(bytes.as_ref())?))
}

/// Refuses, before anything is read or written, an output that is one of the inputs
/// (the same file by identity, so another spelling or a symlink is caught too) or that
/// is named twice. Outputs that do not exist yet cannot be an existing input; they are
/// compared by their canonical directory and name.
pub fn refuse_overwriting(inputs: &[&Path], outputs: &[&Path]) -> Result<()> {
    for (k, out) in outputs.iter().enumerate() {
        for input in inputs {
            if same_file(input, out) {
                bail!(
                    "the output {} is the input {}: refusing to overwrite it (choose another output name)",
                    out.display(),
                    input.display()
                );
            }
        }
        for other in &outputs[..k] {
            if same_file(other, out) {
                bail!(
                    "{} and {} are the same file: give each output its own name",
                    other.display(),
                    out.display()
                );
            }
        }
    }
    Ok(())
}

/// Whether `a` and `b` name the same file: by identity (device and inode) when both
/// exist, else by canonical parent directory and file name.
fn same_file(a: &Path, b: &Path) -> bool {
    if let Ok(same) = same_file::is_same_file(a, b) {
        return same;
    }
    match (canonical_name(a), canonical_name(b)) {
        (Some(x), Some(y)) => x == y,
        _ => false,
    }
}

/// Canonical directory joined with the file name, for a path that may not exist yet.
fn canonical_name(p: &Path) -> Option<PathBuf> {
    if let Ok(c) = p.canonicalize() {
        return Some(c);
    }
    let dir = match p.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    Some(dir.canonicalize().ok()?.join(p.file_name()?))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("magcomp-output-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    fn leftovers(d: &Path) -> Vec<String> {
        std::fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".tmp"))
            .collect()
    }

    #[test]
    fn a_failed_write_keeps_the_previous_file_and_leaves_no_temporary() {
        let d = dir("fail");
        let p = d.join("out.csv");
        std::fs::write(&p, "previous\n").unwrap();
        let e = write_with::<()>(&p, |w| {
            w.write_all(b"half a file")?;
            bail!("disk full (simulated)")
        })
        .unwrap_err();
        assert!(format!("{e:#}").contains("out.csv"), "{e:#}");
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "previous\n");
        assert!(leftovers(&d).is_empty(), "{:?}", leftovers(&d));
        write_file(&p, "new\n").unwrap();
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "new\n");
        assert!(leftovers(&d).is_empty());
    }

    #[test]
    fn the_same_file_under_another_name_is_refused() {
        let d = dir("same");
        let input = d.join("in.csv");
        std::fs::write(&input, "x\n").unwrap();
        let spelled = d.join(".").join("in.csv");
        let link = d.join("link.csv");
        let _ = std::fs::remove_file(&link);
        #[cfg(unix)]
        std::os::unix::fs::symlink(&input, &link).unwrap();
        #[cfg(not(unix))]
        std::fs::hard_link(&input, &link).unwrap();
        for out in [&input, &spelled, &link] {
            let e = refuse_overwriting(&[&input], &[out]).unwrap_err();
            assert!(e.to_string().contains("refusing to overwrite"), "{e}");
        }
        let fresh = d.join("new.csv");
        refuse_overwriting(&[&input], &[&fresh]).unwrap();
        let e = refuse_overwriting(&[&input], &[&fresh, &d.join(".").join("new.csv")]);
        assert!(e.unwrap_err().to_string().contains("same file"));
    }
}
