//! The daemon's card: a small JSON file in its iceoryx2 root, `op3dsgd-<prefix>.json`, saying
//! which process serves the prefix and where it keeps its files, so `op3dsg map` finds the
//! snapshot folder of the daemon it talks to without being told (`--dir`). The root belongs to
//! the daemon's user alone (mode 0700), as the services do; the daemon writes the card once its
//! services are up and removes it on an orderly exit. A card whose process is gone is stale:
//! readers say so instead of trusting it.

use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// What the card says.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct DaemonCard {
    /// The card's format, `op3dsg.daemon_card/1`.
    pub schema: String,
    /// The daemon's process id.
    pub pid: u32,
    /// The prefix it serves.
    pub prefix: String,
    /// Its snapshot folder (absolute), `None` with snapshots off.
    pub snapshot_dir: Option<PathBuf>,
}

/// The card's schema name.
pub const CARD_SCHEMA: &str = "op3dsg.daemon_card/1";

/// Where the card of the daemon serving `prefix` lies in `root` (a `/` of the prefix as `%`).
pub fn card_path(root: &Path, prefix: &str) -> PathBuf {
    root.join(format!("op3dsgd-{}.json", prefix.replace('/', "%")))
}

impl DaemonCard {
    /// The card of this process serving `prefix`.
    pub fn new(prefix: &str, snapshot_dir: Option<PathBuf>) -> Self {
        Self { schema: CARD_SCHEMA.to_owned(), pid: std::process::id(), prefix: prefix.to_owned(), snapshot_dir }
    }

    /// Writes the card into `root` (through a temporary file, so a reader never sees half).
    pub fn write(&self, root: &Path) -> std::io::Result<PathBuf> {
        let path = card_path(root, &self.prefix);
        let temp = path.with_extension("json.tmp");
        let text = serde_json::to_string_pretty(self).map_err(std::io::Error::other)?;
        // The daemon's user's alone, as everything in its root is.
        let mut file = std::fs::OpenOptions::new().write(true).create(true).truncate(true).mode(0o600).open(&temp)?;
        std::io::Write::write_all(&mut file, text.as_bytes())?;
        std::fs::rename(&temp, &path)?;
        Ok(path)
    }

    /// The card of the daemon serving `prefix` in `root`: `Ok(None)` when there is none, an error
    /// naming the file when it cannot be read or is not a card, or when its process is gone.
    pub fn read(root: &Path, prefix: &str) -> Result<Option<Self>, String> {
        let path = card_path(root, prefix);
        let text = match std::fs::read_to_string(&path) {
            Ok(text) => text,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(format!("{}: {e}", path.display())),
        };
        let card: Self = serde_json::from_str(&text).map_err(|e| {
            format!("{}: not a daemon card ({e}); remove it, the daemon writes it again", path.display())
        })?;
        if card.schema != CARD_SCHEMA {
            return Err(format!("{}: schema {:?}, this op3dsg reads {CARD_SCHEMA}", path.display(), card.schema));
        }
        if !Path::new(&format!("/proc/{}", card.pid)).exists() {
            return Err(format!(
                "{}: left by op3dsgd pid {}, which is no longer running (it did not exit in order)",
                path.display(),
                card.pid
            ));
        }
        Ok(Some(card))
    }

    /// Removes the card from `root` if it is this process's.
    pub fn remove(root: &Path, prefix: &str) {
        if let Ok(Some(card)) = Self::read(root, prefix)
            && card.pid == std::process::id()
        {
            let _ = std::fs::remove_file(card_path(root, prefix));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_card_round_trips_and_a_dead_one_is_named() {
        let dir = tempfile::tempdir().unwrap();
        assert_eq!(DaemonCard::read(dir.path(), "lab/a").unwrap(), None);
        let card = DaemonCard::new("lab/a", Some(PathBuf::from("/srv/snapshots")));
        let path = card.write(dir.path()).unwrap();
        assert_eq!(path.file_name().unwrap(), "op3dsgd-lab%a.json");
        let mode = std::os::unix::fs::PermissionsExt::mode(&std::fs::metadata(&path).unwrap().permissions());
        assert_eq!(mode & 0o777, 0o600, "the card is its user's alone");
        assert_eq!(DaemonCard::read(dir.path(), "lab/a").unwrap(), Some(card.clone()));
        // A process that is gone: pid far above any kernel's pid_max.
        let gone = DaemonCard { pid: u32::MAX - 1, ..card };
        std::fs::write(&path, serde_json::to_string(&gone).unwrap()).unwrap();
        let err = DaemonCard::read(dir.path(), "lab/a").unwrap_err();
        assert!(err.contains("no longer running") && err.contains("op3dsgd-lab%a.json"), "{err}");
        std::fs::write(&path, "{").unwrap();
        assert!(DaemonCard::read(dir.path(), "lab/a").unwrap_err().contains("not a daemon card"));
        DaemonCard::new("lab/a", None).write(dir.path()).unwrap();
        DaemonCard::remove(dir.path(), "lab/a");
        assert!(!path.exists());
    }
}
