//! Files that survive a crash: atomic writes, a directory lock, and moving a bad file aside
//! instead of deleting it. Map snapshots (fusion) and the occupancy map's file use them. A leaf:
//! it imports nothing of the stages.
//!
//! An atomic write puts the bytes into `<name>.tmp`, fsyncs it, renames it over `<name>` and
//! fsyncs the directory, so `<name>` is always either the previous complete file or the new
//! complete one, whatever moment the process or the machine dies.

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::world::clock::unix_ms;

/// A file operation that failed, or a directory another process holds.
#[derive(Debug, thiserror::Error)]
pub enum PersistError {
    /// A file operation failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// Another process holds the directory's lock.
    #[error("{}: locked by a running op3dsgd{pid}; stop it first (systemctl stop op3dsgd)", path.display())]
    Locked {
        /// The lock file.
        path: PathBuf,
        /// " (pid N)" when the lock file names it.
        pid: String,
    },
}

/// The error of an I/O operation on `path`.
pub fn io(path: &Path) -> impl FnOnce(std::io::Error) -> PersistError + '_ {
    move |source| PersistError::Io { path: path.to_owned(), source }
}

/// The temporary file an atomic write of `file_name` goes through.
pub fn temp_name(file_name: &str) -> String {
    format!("{file_name}.tmp")
}

/// Writes `bytes` as `dir/file_name` atomically (module docs). `pause_midway` sleeps between the
/// two halves of the temporary file, for a test that kills the process during a write.
pub fn write_atomic(
    dir: &Path,
    file_name: &str,
    bytes: &[u8],
    pause_midway: Option<Duration>,
) -> Result<(), PersistError> {
    let temp = dir.join(temp_name(file_name));
    let target = dir.join(file_name);
    {
        let mut file = OpenOptions::new().write(true).create(true).truncate(true).open(&temp).map_err(io(&temp))?;
        match pause_midway {
            Some(pause) => {
                let (first, rest) = bytes.split_at(bytes.len() / 2);
                file.write_all(first).map_err(io(&temp))?;
                file.sync_data().map_err(io(&temp))?;
                std::thread::sleep(pause);
                file.write_all(rest).map_err(io(&temp))?;
            }
            None => file.write_all(bytes).map_err(io(&temp))?,
        }
        file.sync_all().map_err(io(&temp))?;
    }
    std::fs::rename(&temp, &target).map_err(io(&target))?;
    File::open(dir).and_then(|d| d.sync_all()).map_err(io(dir))?;
    Ok(())
}

/// Moves `path` aside to `path.<reason>-<unix ms>` (never deletes it); the new path.
pub fn move_aside(path: &Path, reason: &str) -> std::io::Result<PathBuf> {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(format!(".{reason}-{}", unix_ms()));
    let aside = path.with_file_name(name);
    std::fs::rename(path, &aside)?;
    if let Some(dir) = path.parent() {
        File::open(dir).and_then(|d| d.sync_all())?;
    }
    Ok(aside)
}

/// An exclusive lock on a directory (the lock file `lock_name` in it, holding this process's
/// id), held while the value lives.
#[derive(Debug)]
pub struct DirLock {
    _file: File,
}

impl DirLock {
    /// Takes the lock of `dir` (which must exist); [`PersistError::Locked`] while another process
    /// holds it.
    pub fn acquire(dir: &Path, lock_name: &str) -> Result<Self, PersistError> {
        let path = dir.join(lock_name);
        let mut file =
            OpenOptions::new().read(true).write(true).create(true).truncate(false).open(&path).map_err(io(&path))?;
        match file.try_lock() {
            Ok(()) => {
                file.set_len(0).map_err(io(&path))?;
                writeln!(file, "{}", std::process::id()).map_err(io(&path))?;
                Ok(Self { _file: file })
            }
            Err(std::fs::TryLockError::WouldBlock) => {
                let pid = std::fs::read_to_string(&path).ok().map(|t| t.trim().to_owned()).filter(|t| !t.is_empty());
                Err(PersistError::Locked { path, pid: pid.map(|p| format!(" (pid {p})")).unwrap_or_default() })
            }
            Err(std::fs::TryLockError::Error(source)) => Err(PersistError::Io { path, source }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_atomic_write_leaves_no_temporary_file_and_replaces_the_old_one() {
        let dir = tempfile::tempdir().unwrap();
        write_atomic(dir.path(), "f", b"one", None).unwrap();
        write_atomic(dir.path(), "f", b"two", Some(Duration::from_millis(1))).unwrap();
        assert_eq!(std::fs::read(dir.path().join("f")).unwrap(), b"two");
        assert!(!dir.path().join(temp_name("f")).exists());
    }

    #[test]
    fn moved_aside_never_deleted() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("map.snapshot");
        std::fs::write(&path, b"garbage").unwrap();
        let aside = move_aside(&path, "corrupt").unwrap();
        assert!(!path.exists());
        assert_eq!(std::fs::read(&aside).unwrap(), b"garbage");
        assert!(aside.file_name().unwrap().to_string_lossy().starts_with("map.snapshot.corrupt-"));
    }

    #[test]
    fn a_second_lock_on_one_directory_is_refused_naming_the_holder() {
        let dir = tempfile::tempdir().unwrap();
        let _held = DirLock::acquire(dir.path(), "x.lock").unwrap();
        let err = DirLock::acquire(dir.path(), "x.lock").unwrap_err();
        assert!(matches!(err, PersistError::Locked { .. }), "{err}");
        assert!(err.to_string().contains(&format!("(pid {})", std::process::id())), "{err}");
    }
}
