//! Output safety: who owns an output directory, where a recording is written while it is
//! unfinished, and which paths may be read or written at all.
//!
//! * [`OutputLock`]: an exclusive advisory lock (`flock`/`LockFileEx` through
//!   [`std::fs::File::try_lock`]) on `DIR/.gpm.lock`, holding the owner's process id. A second
//!   run into the same directory fails at once (after 0.1 s of retries) with [`RecordError::Locked`] naming the holder.
//!   The lock ends with the process (also when it is killed), so a stale lock file is harmless;
//!   the file itself is left in place (removing it would let a third run lock a new file while a
//!   second still holds the old one).
//! * [`partial_path`] / [`failed_path`]: a [`Recorder`](super::Recorder) writes `run.mcap` as
//!   `run.mcap.partial` and renames it when finished, so an earlier recording is replaced only by
//!   a finished one; a run that fails keeps its steps as `run.failed.mcap`.
//! * [`check_input_file`]: an input (configuration, recording) must be a regular file: opening a
//!   FIFO would block until a writer appears, a device may never end.
//! * [`same_file`]: an output that is the input (`gpm replay f --csv f`) is refused.

use super::RecordError;
use std::fs::{File, OpenOptions, TryLockError};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

/// Name of the lock file in an output directory.
pub const LOCK_FILE: &str = ".gpm.lock";

/// An exclusive lock on an output directory, held until dropped (or the process ends).
#[derive(Debug)]
pub struct OutputLock {
    path: PathBuf,
    // the lock lives as long as this open file
    _file: File,
}

impl OutputLock {
    /// Locks `dir` (which must exist) for this process: creates or opens `dir/.gpm.lock`, takes
    /// an exclusive lock (tried for up to 0.1 s) and writes this process's id into it. Another
    /// holder is a [`RecordError::Locked`] naming its process id.
    pub fn acquire(dir: &Path) -> Result<OutputLock, RecordError> {
        let path = dir.join(LOCK_FILE);
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(|e| RecordError::io(&path, e))?;
        // A child process another thread is starting holds a copy of every open file, this
        // lock's included, from its fork until its exec closes it: a lock this process has
        // just released can look held for that moment (seen in the tests, which start `gpm`
        // processes beside recordings). So a held lock is tried again for up to 0.1 s
        // before its holder is reported.
        let mut attempts = 0;
        loop {
            match file.try_lock() {
                Ok(()) => break,
                Err(TryLockError::WouldBlock) if attempts < 20 => {
                    attempts += 1;
                    std::thread::sleep(std::time::Duration::from_millis(5));
                }
                Err(TryLockError::WouldBlock) => {
                    let mut text = String::new();
                    let _ = file.read_to_string(&mut text);
                    return Err(RecordError::Locked {
                        holder: text.trim().parse().ok(),
                        path,
                    });
                }
                Err(TryLockError::Error(e)) => return Err(RecordError::io(&path, e)),
            }
        }
        let pid = std::process::id();
        file.set_len(0)
            .and_then(|_| file.seek(SeekFrom::Start(0)))
            .and_then(|_| writeln!(file, "{pid}"))
            .and_then(|_| file.flush())
            .map_err(|e| RecordError::io(&path, e))?;
        Ok(OutputLock { path, _file: file })
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// Where a recording meant for `path` is written until it is finished: `path` with `.partial`
/// appended (`run.mcap.partial`).
pub fn partial_path(path: &Path) -> PathBuf {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    path.with_file_name(name)
}

/// Where the recording of a failed run meant for `path` is kept: `run.mcap` → `run.failed.mcap`
/// (`.failed` before the extension, or appended without one).
pub fn failed_path(path: &Path) -> PathBuf {
    let stem = path.file_stem().unwrap_or_default().to_os_string();
    let mut name = stem;
    name.push(".failed");
    if let Some(ext) = path.extension() {
        name.push(".");
        name.push(ext);
    }
    path.with_file_name(name)
}

/// What kind of file system object `m` is, for messages.
fn kind(m: &std::fs::Metadata) -> &'static str {
    let t = m.file_type();
    if t.is_dir() {
        return "a directory";
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return "a FIFO (named pipe)";
        }
        if t.is_socket() {
            return "a socket";
        }
        if t.is_char_device() || t.is_block_device() {
            return "a device";
        }
    }
    "not a regular file"
}

/// Checks that `path` is a regular file (symbolic links followed) before it is opened for
/// reading: a FIFO would block until a writer appears, a device may never end. Errors:
/// [`RecordError::Io`] (missing, unreadable), [`RecordError::NotAFile`].
pub fn check_input_file(path: &Path) -> Result<std::fs::Metadata, RecordError> {
    let m = std::fs::metadata(path).map_err(|e| RecordError::io(path, e))?;
    if !m.is_file() {
        return Err(RecordError::NotAFile {
            path: path.to_path_buf(),
            reason: format!("{}, not a regular file: refused as input", kind(&m)),
        });
    }
    Ok(m)
}

/// True when `a` and `b` name the same existing file (same device and inode on Unix; same
/// canonical path elsewhere). False when either does not exist.
pub fn same_file(a: &Path, b: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        match (std::fs::metadata(a), std::fs::metadata(b)) {
            (Ok(x), Ok(y)) => x.dev() == y.dev() && x.ino() == y.ino(),
            _ => false,
        }
    }
    #[cfg(not(unix))]
    {
        match (a.canonicalize(), b.canonicalize()) {
            (Ok(x), Ok(y)) => x == y,
            _ => false,
        }
    }
}

/// Refuses an output path that is the input file `input` ([`RecordError::NotAFile`] naming
/// both), or that exists and is not a regular file (writing into a FIFO would block).
pub fn check_output_file(output: &Path, input: &Path) -> Result<(), RecordError> {
    if same_file(output, input) {
        return Err(RecordError::NotAFile {
            path: output.to_path_buf(),
            reason: format!(
                "is the input file {}: refusing to overwrite it",
                input.display()
            ),
        });
    }
    if let Ok(m) = std::fs::metadata(output) {
        if !m.is_file() {
            return Err(RecordError::NotAFile {
                path: output.to_path_buf(),
                reason: format!("{}, not a regular file: refused as output", kind(&m)),
            });
        }
    }
    Ok(())
}

/// Writes `bytes` to `path` through a temporary sibling (`path.partial`) renamed over `path`
/// once complete and synced, so that a failed write never leaves a half-written `path` (nor
/// replaces a good one).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let tmp = partial_path(path);
    let result = (|| {
        let mut f = File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}
