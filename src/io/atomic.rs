//! Atomic file writes: a crash or an error never leaves a half-written file.
//!
//! One file is atomic by itself (temporary name, then rename). A command
//! writes several, so an [`OutputBatch`] makes the set atomic too: while it
//! is open, files under its directory stay under their temporary names, and
//! are renamed together when it commits; dropped without a commit, they are
//! removed. A command that fails half-way leaves the directory as it was.

use std::collections::HashMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

use crate::error::{Error, Result};

/// Open batches: directory -> (temporary, final) paths written under it.
/// Keyed by directory (not global, not per thread): writes may come from
/// worker threads, and concurrent commands (tests) write to different
/// directories.
static BATCHES: Mutex<Option<Batches>> = Mutex::new(None);

type Batches = HashMap<PathBuf, Vec<(PathBuf, PathBuf)>>;

fn batches() -> std::sync::MutexGuard<'static, Option<Batches>> {
    // a panic while holding the lock leaves the map consistent (plain pushes)
    BATCHES.lock().unwrap_or_else(|e| e.into_inner())
}

/// Temporary files that exist now (created, not yet renamed or removed), so
/// that an interrupt can remove them ([`remove_temporaries`]).
static LIVE: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

fn live() -> std::sync::MutexGuard<'static, Vec<PathBuf>> {
    LIVE.lock().unwrap_or_else(|e| e.into_inner())
}

fn forget_live(done: &[&Path]) {
    live().retain(|p| !done.contains(&p.as_path()));
}

/// Set when a batch has made its files visible (see [`outputs_committed`]).
static COMMITTED: AtomicBool = AtomicBool::new(false);

/// Whether an [`OutputBatch`] of this process has committed its files: an
/// interrupt after that point leaves complete outputs, not none.
pub fn outputs_committed() -> bool {
    COMMITTED.load(Ordering::SeqCst)
}

/// Removes every temporary file of [`write_atomic`] and of the open
/// batches, for an interrupt handler (Ctrl-C): the process must exit right
/// after, since no temporary can be created from this call on (the
/// registry stays locked), so a worker thread still writing blocks instead
/// of leaving a new one behind. Returns how many files were removed.
pub fn remove_temporaries() -> usize {
    let mut g = live();
    let mut n = 0;
    for p in g.drain(..) {
        if std::fs::remove_file(&p).is_ok() {
            n += 1;
        }
    }
    std::mem::forget(g);
    n
}

/// What makes two paths the same file: device and inode on Unix (hard
/// links, symlinks and `..` alike), else the canonical path. `None` if the
/// file does not exist.
pub fn file_identity(p: &Path) -> Option<(u64, u64, PathBuf)> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        let m = std::fs::metadata(p).ok()?;
        Some((m.dev(), m.ino(), PathBuf::new()))
    }
    #[cfg(not(unix))]
    {
        std::fs::canonicalize(p).ok().map(|c| (0, 0, c))
    }
}

/// The files the running command reads ([`protect`]): no output may
/// replace one.
static PROTECTED: Mutex<Vec<(FileId, PathBuf)>> = Mutex::new(Vec::new());

/// [`file_identity`]: device, inode, canonical path.
type FileId = (u64, u64, PathBuf);

/// Marks `paths` as inputs of the running command until the guard drops:
/// meanwhile a [`write_atomic`] onto any of them (an output named like an
/// input in the same directory, e.g. `cwt` writing `modulus_00.npy` beside
/// an input of that name) is refused instead of destroying the input.
#[must_use = "the inputs are protected only while the guard lives"]
pub fn protect(paths: &[&Path]) -> Protected {
    let mut g = PROTECTED.lock().unwrap_or_else(|e| e.into_inner());
    let ids: Vec<_> = paths
        .iter()
        .filter_map(|&p| file_identity(p).map(|id| (id, p.to_path_buf())))
        .collect();
    g.extend(ids.iter().cloned());
    Protected(ids)
}

/// See [`protect`].
pub struct Protected(Vec<(FileId, PathBuf)>);

impl Drop for Protected {
    fn drop(&mut self) {
        let mut g = PROTECTED.lock().unwrap_or_else(|e| e.into_inner());
        for e in &self.0 {
            if let Some(i) = g.iter().position(|x| x == e) {
                g.swap_remove(i);
            }
        }
    }
}

/// Whether `name` is the staged write of another process (`.NAME.tmpPID`,
/// as [`write_atomic`] names them, PID not this process's): left by a run
/// that was killed before it could remove it (SIGKILL, a power cut).
pub fn is_foreign_temp(name: &str) -> bool {
    let Some(rest) = name.strip_prefix('.') else {
        return false;
    };
    match rest.rsplit_once(".tmp") {
        Some((stem, pid)) => {
            !stem.is_empty()
                && !pid.is_empty()
                && pid.bytes().all(|b| b.is_ascii_digit())
                && pid != std::process::id().to_string()
        }
        None => false,
    }
}

fn check_not_input(path: &Path) -> Result<()> {
    let g = PROTECTED.lock().unwrap_or_else(|e| e.into_inner());
    if g.is_empty() {
        return Ok(());
    }
    if let Some(id) = file_identity(path)
        && let Some((_, input)) = g.iter().find(|(i, _)| *i == id)
    {
        return Err(Error::Input(format!(
            "{}: would overwrite the input {}; write the outputs to another directory (--out)",
            path.display(),
            input.display()
        )));
    }
    Ok(())
}

/// `value` as pretty JSON with a final newline, written with
/// [`write_atomic`] (every JSON output of the crate goes through here).
pub fn write_json<T: serde::Serialize>(path: &Path, value: &T) -> Result<()> {
    let s = serde_json::to_string_pretty(value)
        .map_err(|e| Error::format(path, format!("cannot encode JSON: {e}")))?;
    write_atomic(path, (s + "\n").as_bytes())
}

/// `value` as compact JSON (one line) with a final newline, atomically: for
/// the machine files whose pretty form would be several times larger
/// (`sums.json`: 14 MB pretty for 32 images, mostly indentation).
pub fn write_json_compact<T: serde::Serialize>(path: &Path, value: &T) -> Result<()> {
    let mut s = serde_json::to_string(value)
        .map_err(|e| Error::format(path, format!("cannot encode JSON: {e}")))?;
    s.push('\n');
    write_atomic(path, s.as_bytes())
}

/// Writes `bytes` to a temporary file beside `path`, then renames it over
/// `path` (or, under an open [`OutputBatch`], leaves the rename to its commit).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let err = |source| Error::Write {
        path: path.into(),
        source,
    };
    check_not_input(path)?;
    let name = path
        .file_name()
        .ok_or_else(|| err(std::io::Error::other("not a file path")))?;
    let tmp = path.with_file_name(format!(
        ".{}.tmp{}",
        name.to_string_lossy(),
        std::process::id()
    ));
    {
        // registered before it exists: an interrupt removes it either way
        let mut g = live();
        if !g.contains(&tmp) {
            g.push(tmp.clone());
        }
    }
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all().ok();
        if defer(&tmp, path) {
            return Ok(true);
        }
        std::fs::rename(&tmp, path).map(|()| false)
    })();
    match result {
        // the batch's commit or drop finishes it
        Ok(true) => Ok(()),
        Ok(false) => {
            forget_live(&[&tmp]);
            Ok(())
        }
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            forget_live(&[&tmp]);
            Err(err(e))
        }
    }
}

/// Records `tmp -> path` in the batch whose directory holds `path`, if any.
fn defer(tmp: &Path, path: &Path) -> bool {
    let mut g = batches();
    let Some(map) = g.as_mut() else {
        return false;
    };
    let Some(list) = map
        .iter_mut()
        .filter(|(dir, _)| path.starts_with(dir))
        .max_by_key(|(dir, _)| dir.components().count())
        .map(|(_, l)| l)
    else {
        return false;
    };
    // a file written twice: its temporary name is reused, one rename
    if !list.iter().any(|(_, p)| p == path) {
        list.push((tmp.to_path_buf(), path.to_path_buf()));
    }
    true
}

/// The files a command writes into one directory, made visible together.
///
/// ```
/// use wtmm::io::{OutputBatch, write_atomic};
/// let dir = std::env::temp_dir().join(format!("wtmm-batch-doc-{}", std::process::id()));
/// std::fs::create_dir_all(&dir).unwrap();
/// let batch = OutputBatch::begin(&dir).unwrap();
/// write_atomic(&dir.join("a.txt"), b"a").unwrap();
/// assert!(!dir.join("a.txt").exists()); // not yet
/// batch.commit().unwrap();
/// assert!(dir.join("a.txt").exists());
/// # std::fs::remove_dir_all(&dir).unwrap();
/// ```
#[derive(Debug)]
pub struct OutputBatch {
    dir: PathBuf,
}

impl OutputBatch {
    /// Opens a batch for the files written under `dir`.
    ///
    /// **Errors** if a batch is already open for `dir`.
    pub fn begin(dir: &Path) -> Result<OutputBatch> {
        let mut g = batches();
        let map = g.get_or_insert_with(HashMap::new);
        if map.contains_key(dir) {
            return Err(Error::Input(format!(
                "{}: another command is writing to this directory",
                dir.display()
            )));
        }
        map.insert(dir.to_path_buf(), Vec::new());
        Ok(OutputBatch {
            dir: dir.to_path_buf(),
        })
    }

    fn take(&self) -> Vec<(PathBuf, PathBuf)> {
        let mut g = batches();
        g.as_mut()
            .and_then(|m| m.remove(&self.dir))
            .unwrap_or_default()
    }

    /// Renames or removes `files` (per `commit`), then unregisters them.
    ///
    /// The registry of temporaries stays locked throughout, so an interrupt
    /// ([`remove_temporaries`]) waits for the renames (milliseconds) and
    /// finds either the whole set still temporary or the whole set renamed,
    /// never a mix.
    fn finish(files: &[(PathBuf, PathBuf)], commit: bool) -> Result<()> {
        let mut g = live();
        let r = if commit {
            Self::rename_all(files)
        } else {
            for (t, _) in files {
                let _ = std::fs::remove_file(t);
            }
            Ok(())
        };
        g.retain(|p| !files.iter().any(|(t, _)| t == p));
        if commit && r.is_ok() && !files.is_empty() {
            COMMITTED.store(true, Ordering::SeqCst);
        }
        r
    }

    /// Renames every file written under the directory to its final name.
    ///
    /// **Errors** when a final name is taken by a directory (then nothing is
    /// renamed), or on the first rename that fails (the files not yet
    /// renamed are removed).
    pub fn commit(self) -> Result<()> {
        self.commit_files().map(|_| ())
    }

    /// [`commit`](Self::commit), returning the final names of the files
    /// written (so that a caller can tell them from older files in the
    /// directory).
    pub fn commit_files(self) -> Result<Vec<PathBuf>> {
        let files = self.take();
        Self::finish(&files, true)?;
        Ok(files.into_iter().map(|(_, p)| p).collect())
    }

    fn rename_all(files: &[(PathBuf, PathBuf)]) -> Result<()> {
        // what would make a rename fail, before any is done
        if let Some((_, path)) = files.iter().find(|(_, p)| p.is_dir()) {
            for (t, _) in files {
                let _ = std::fs::remove_file(t);
            }
            return Err(Error::Write {
                path: path.clone(),
                source: std::io::Error::other("a directory of that name is in the way"),
            });
        }
        let mut it = files.iter();
        for (tmp, path) in it.by_ref() {
            if let Err(source) = std::fs::rename(tmp, path) {
                let _ = std::fs::remove_file(tmp);
                for (t, _) in it {
                    let _ = std::fs::remove_file(t);
                }
                return Err(Error::Write {
                    path: path.clone(),
                    source,
                });
            }
        }
        Ok(())
    }
}

impl Drop for OutputBatch {
    /// Without a commit: the temporary files are removed.
    fn drop(&mut self) {
        let _ = Self::finish(&self.take(), false);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("wtmm-batch-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn dropped_batch_leaves_the_directory_as_it_was() {
        let d = dir("drop");
        std::fs::write(d.join("old.json"), b"old").unwrap();
        {
            let _b = OutputBatch::begin(&d).unwrap();
            write_atomic(&d.join("old.json"), b"new").unwrap();
            write_atomic(&d.join("new.png"), b"png").unwrap();
        }
        let names: Vec<_> = std::fs::read_dir(&d)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        assert_eq!(names, vec!["old.json".to_string()]);
        assert_eq!(std::fs::read(d.join("old.json")).unwrap(), b"old");
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn commit_names_the_files_written_once_each() {
        let d = dir("names");
        std::fs::create_dir_all(d.join("sub")).unwrap();
        std::fs::write(d.join("older.csv"), b"old").unwrap();
        let b = OutputBatch::begin(&d).unwrap();
        write_atomic(&d.join("a.json"), b"1").unwrap();
        write_atomic(&d.join("a.json"), b"2").unwrap();
        write_atomic(&d.join("sub").join("b.png"), b"3").unwrap();
        let mut w = b.commit_files().unwrap();
        w.sort();
        assert_eq!(w, vec![d.join("a.json"), d.join("sub").join("b.png")]);
        assert_eq!(std::fs::read(d.join("a.json")).unwrap(), b"2");
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn commit_waits_for_the_registry_an_interrupt_holds() {
        // remove_temporaries (the Ctrl-C handler) runs under the registry
        // lock; a commit must not rename anything while it is held, so the
        // handler sees all the files temporary or all renamed
        let d = dir("lock");
        let b = OutputBatch::begin(&d).unwrap();
        write_atomic(&d.join("a.json"), b"1").unwrap();
        write_atomic(&d.join("b.json"), b"2").unwrap();
        let g = live();
        assert_eq!(g.iter().filter(|p| p.starts_with(&d)).count(), 2);
        let t = std::thread::spawn(move || b.commit());
        std::thread::sleep(std::time::Duration::from_millis(100));
        // still waiting (a commit that ignored the lock would be done by now)
        assert!(!t.is_finished());
        assert!(!d.join("a.json").exists() && !d.join("b.json").exists());
        drop(g);
        t.join().unwrap().unwrap();
        assert!(d.join("a.json").exists() && d.join("b.json").exists());
        assert!(!live().iter().any(|p| p.starts_with(&d)));
        assert!(outputs_committed());
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn committed_batch_shows_every_file_once_and_other_dirs_are_untouched() {
        let d = dir("commit");
        let other = dir("other");
        let b = OutputBatch::begin(&d).unwrap();
        assert!(OutputBatch::begin(&d).is_err());
        write_atomic(&d.join("a.json"), b"1").unwrap();
        write_atomic(&d.join("a.json"), b"2").unwrap();
        write_atomic(&other.join("x"), b"x").unwrap();
        assert!(other.join("x").exists(), "a write outside the batch waited");
        assert!(!d.join("a.json").exists());
        b.commit().unwrap();
        assert_eq!(std::fs::read(d.join("a.json")).unwrap(), b"2");
        assert_eq!(std::fs::read_dir(&d).unwrap().count(), 1);
        std::fs::remove_dir_all(&d).unwrap();
        std::fs::remove_dir_all(&other).unwrap();
    }
}
