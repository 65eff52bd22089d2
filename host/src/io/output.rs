//! Output files that are never left half-written, and outputs that never overwrite an
//! input.
//!
//! Every regular file a command writes goes to a temporary file in the same directory (so
//! the rename cannot cross a file system) and is renamed over the final name only after
//! the last byte is flushed and synced: a full disk, a write error or an interrupted run
//! leaves the previous file (or none) under the final name, never a truncated one. The
//! temporary file is deleted on any error (`tempfile` removes it on drop) and on SIGINT /
//! SIGTERM (the handler installed by the first [`AtomicFile`]).
//!
//! An output that is not a regular file is written through, never replaced: a symlink is
//! followed (its target is written atomically, the link stays), a device node or FIFO is
//! opened and written in place (a rename would put a regular file where `/dev/null` was).
//!
//! `monitor --save` is the exception: a live log must keep what it has when the link
//! drops or the operator presses Ctrl-C, so it appends in place.

use anyhow::{bail, Context, Result};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// The temporary files being written now: what the SIGINT/SIGTERM handler removes.
static LIVE_TEMPORARIES: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// Installs, once, the handler that removes the live temporaries and exits 130 (as a
/// shell reports an interrupted command). Without it an interrupted run left hidden
/// 60–120 MB `.NAME.*.tmp` files behind.
fn install_cleanup_handler() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // Another handler already installed (a library user's) is left in charge.
        let _ = ctrlc::set_handler(remove_live_temporaries_and_exit);
    });
}

/// Exits holding the temporaries' lock: a file the program starts to create meanwhile
/// waits for it and is never made.
fn remove_live_temporaries_and_exit() {
    let live = LIVE_TEMPORARIES.lock().unwrap_or_else(|p| p.into_inner());
    for p in live.iter() {
        let _ = std::fs::remove_file(p);
    }
    std::process::exit(130);
}

fn forget_temporary(p: &Path) {
    if let Ok(mut l) = LIVE_TEMPORARIES.lock() {
        l.retain(|q| q != p);
    }
}

enum Sink {
    /// A regular file: a temporary renamed on commit.
    Temporary(BufWriter<tempfile::NamedTempFile>, PathBuf),
    /// A device node or FIFO, written through.
    Through(BufWriter<std::fs::File>),
}

/// A file being written under a temporary name; [`commit`](Self::commit) renames it to
/// its final name. Dropped without a commit, it leaves nothing behind.
pub struct AtomicFile {
    w: Option<Sink>,
    path: PathBuf,
}

/// What `path` writes to: a symlink's target (followed, as `open` would follow it), else
/// `path` itself.
fn resolve_symlinks(path: &Path) -> PathBuf {
    let mut p = path.to_path_buf();
    // A loop of links ends here and fails at the open with the system's message.
    for _ in 0..40 {
        match std::fs::symlink_metadata(&p) {
            Ok(m) if m.file_type().is_symlink() => match std::fs::read_link(&p) {
                Ok(t) if t.is_absolute() => p = t,
                Ok(t) => p = p.parent().unwrap_or(Path::new(".")).join(t),
                Err(_) => break,
            },
            _ => break,
        }
    }
    p
}

/// Whether `path` (resolved) exists and is something other than a regular file or
/// directory: a device node, FIFO or socket, to be written through.
fn is_special(path: &Path) -> bool {
    std::fs::metadata(path).is_ok_and(|m| !m.is_file() && !m.is_dir())
}

impl AtomicFile {
    /// Starts writing `path` (its directory must exist).
    pub fn create(path: &Path) -> Result<Self> {
        let target = resolve_symlinks(path);
        if std::fs::metadata(&target).is_ok_and(|m| m.is_dir()) {
            bail!("{} is a directory, not a file name", path.display());
        }
        if is_special(&target) {
            let f = std::fs::OpenOptions::new()
                .write(true)
                .open(&target)
                .with_context(|| format!("opening {} for writing", path.display()))?;
            return Ok(Self {
                w: Some(Sink::Through(BufWriter::with_capacity(1 << 16, f))),
                path: path.to_path_buf(),
            });
        }
        let dir = match target.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        let name = target
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
        install_cleanup_handler();
        // Created and registered under the handler's lock: a signal between the two would
        // otherwise find the file unregistered and leave it (CI under load, `robust_io`).
        let tmp = {
            let mut live = LIVE_TEMPORARIES.lock().unwrap_or_else(|p| p.into_inner());
            let tmp = b
                .tempfile_in(dir)
                .with_context(|| format!("creating {} (in {})", path.display(), dir.display()))?;
            live.push(tmp.path().to_path_buf());
            tmp
        };
        Ok(Self {
            w: Some(Sink::Temporary(
                BufWriter::with_capacity(1 << 16, tmp),
                target,
            )),
            path: path.to_path_buf(),
        })
    }

    /// The final name.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Flushes, syncs and renames the file to its final name (a device or FIFO: flushes).
    pub fn commit(mut self) -> Result<()> {
        let path = self.path.clone();
        let writing = || format!("writing {}", path.display());
        match self.w.take() {
            Some(Sink::Through(mut w)) => w.flush().with_context(writing)?,
            Some(Sink::Temporary(w, target)) => {
                let tmp = w.into_inner().map_err(|e| e.into_error());
                let tmp = match tmp {
                    Ok(t) => t,
                    Err(e) => {
                        return Err(e).with_context(writing);
                    }
                };
                let tmp_path = tmp.path().to_path_buf();
                let done = tmp
                    .as_file()
                    .sync_all()
                    .with_context(writing)
                    .and_then(|()| {
                        tmp.persist(&target).map_err(|e| e.error).with_context(|| {
                            format!("renaming the finished output to {}", path.display())
                        })
                    });
                forget_temporary(&tmp_path);
                done?;
            }
            None => {}
        }
        Ok(())
    }

    fn sink(&mut self) -> &mut dyn Write {
        match self.w.as_mut() {
            Some(Sink::Temporary(w, _)) => w,
            Some(Sink::Through(w)) => w,
            None => unreachable!("written after commit"),
        }
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if let Some(Sink::Temporary(w, _)) = &self.w {
            forget_temporary(w.get_ref().path());
        }
    }
}

impl Write for AtomicFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.sink().write(buf)
    }
    fn write_all(&mut self, buf: &[u8]) -> std::io::Result<()> {
        self.sink().write_all(buf)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.sink().flush()
    }
}

/// Checks, before the work starts, that `path` can be written: its directory exists and
/// takes a new file, or it is a device/FIFO (written through). Without this an unusable
/// `-o` was found only after the work (39 s on 4.9 M rows).
pub fn check_writable(path: &Path) -> Result<()> {
    let target = resolve_symlinks(path);
    match std::fs::metadata(&target) {
        Ok(m) if m.is_dir() => bail!("{} is a directory, not a file name", path.display()),
        // Opening a FIFO would wait for its reader: it is opened when written.
        Ok(m) if !m.is_file() => return Ok(()),
        _ => {}
    }
    let dir = match target.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    if !dir.is_dir() {
        bail!(
            "cannot write {}: the directory {} does not exist",
            path.display(),
            dir.display()
        );
    }
    // The same probe the write will make: a temporary in that directory.
    tempfile::Builder::new()
        .prefix(".magcomp-probe.")
        .tempfile_in(dir)
        .with_context(|| format!("cannot write {} (in {})", path.display(), dir.display()))?;
    Ok(())
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

/// [`refuse_overwriting`], then [`check_writable`] on each output: what a command checks
/// before its work (`report`/`diagnose --report` create their directory, and check only
/// the first).
pub fn check_outputs(inputs: &[&Path], outputs: &[&Path]) -> Result<()> {
    refuse_overwriting(inputs, outputs)?;
    outputs.iter().try_for_each(|o| check_writable(o))
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
    // By metadata, not by opening: opening a FIFO waits for its other end (`-o FIFO` and
    // `upload --to FIFO` hung here).
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        if let (Ok(x), Ok(y)) = (std::fs::metadata(a), std::fs::metadata(b)) {
            return (x.dev(), x.ino()) == (y.dev(), y.ino());
        }
    }
    #[cfg(not(unix))]
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

    /// Removed when the test ends.
    fn dir(name: &str) -> tempfile::TempDir {
        tempfile::Builder::new()
            .prefix(&format!("magcomp-output-{name}-"))
            .tempdir()
            .unwrap()
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
        let scratch = dir("fail");
        let d = scratch.path();
        let p = d.join("out.csv");
        std::fs::write(&p, "previous\n").unwrap();
        let e = write_with::<()>(&p, |w| {
            w.write_all(b"half a file")?;
            bail!("disk full (simulated)")
        })
        .unwrap_err();
        assert!(format!("{e:#}").contains("out.csv"), "{e:#}");
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "previous\n");
        assert!(leftovers(d).is_empty(), "{:?}", leftovers(d));
        write_file(&p, "new\n").unwrap();
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "new\n");
        assert!(leftovers(d).is_empty());
    }

    #[test]
    fn the_same_file_under_another_name_is_refused() {
        let scratch = dir("same");
        let d = scratch.path();
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
