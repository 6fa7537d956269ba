//! `op3dsg map info|save|reset`: the operator's view of the daemon's map snapshots
//! (`op3dsg_runtime::fusion::snapshot`). They work on the snapshot directory, so they need
//! read (info) or write (save, reset) access to it: on the robot, `sudo -u op3dsg` or root.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime};

use anyhow::{Context, Result, bail};
use op3dsg_runtime::fusion::snapshot::{self, SAVE_REQUEST, SNAPSHOT_FILE, SnapshotError};
use op3dsg_runtime::ipc::card::DaemonCard;
use op3dsg_runtime::persist::PersistError;

/// Where the packaged unit keeps snapshots (`StateDirectory=op3dsg` + `snapshots`).
pub(super) const DEFAULT_DIR: &str = "/var/lib/op3dsg/snapshots";

/// The snapshot folder to work on: `--dir` (or `$OP3DSG_SNAPSHOT_DIR`) when given; else the one
/// the daemon serving `prefix` names on its card (in this user's iceoryx2 root, then in the
/// installed service's); else [`DEFAULT_DIR`], saying on standard error why.
pub(super) fn dir_of(dir: Option<PathBuf>, prefix: &str) -> Result<PathBuf> {
    if let Some(dir) = dir {
        return Ok(dir);
    }
    let own = op3dsg_ipc_types::IpcRoot::resolve();
    let mut roots = vec![own.path().to_path_buf()];
    if own.path() != Path::new(op3dsg_ipc_types::access::SERVICE_ROOT) {
        roots.push(PathBuf::from(op3dsg_ipc_types::access::SERVICE_ROOT));
    }
    let mut why = Vec::new();
    for root in &roots {
        match DaemonCard::read(root, prefix) {
            Ok(Some(card)) => {
                return card.snapshot_dir.ok_or_else(|| {
                    anyhow::anyhow!(
                        "the op3dsgd serving prefix '{prefix}' (pid {}) keeps no snapshots: snapshot.enabled is \
                         false, or it runs outside systemd without a snapshot.dir (set one, or pass --dir)",
                        card.pid
                    )
                });
            }
            Ok(None) => why.push(format!("no op3dsgd serving prefix '{prefix}' left its card in {}", root.display())),
            Err(e) => why.push(e),
        }
    }
    eprintln!("op3dsg map: {}; using {DEFAULT_DIR} (pass --dir to choose)", why.join("; "));
    Ok(PathBuf::from(DEFAULT_DIR))
}

/// `op3dsg map info`: checks the snapshot (header, checksum, decoding) and prints what it holds.
pub(super) fn info(dir: &Path, json: bool) -> Result<()> {
    let path = dir.join(SNAPSHOT_FILE);
    if !path.exists() {
        // After `map reset` (or a damaged file moved aside at start) the earlier maps are still
        // here: name them, so nothing looks lost.
        let aside = moved_aside(dir);
        let listed: String = aside.iter().map(|p| format!("\nmoved aside    {}", p.display())).collect();
        bail!(
            "{}: no map snapshot (the daemon writes one every snapshot.period_s once it has mapped something){listed}",
            path.display()
        );
    }
    let bytes_on_disk = std::fs::metadata(&path).with_context(|| format!("reading {}", path.display()))?.len();
    let snap = snapshot::read(&path).map_err(|e| {
        anyhow::anyhow!("{e}\n(the daemon moves such a file aside at start and begins with an empty map)")
    })?;
    let (objects, parts) = snap.map.kind_counts();
    let now_ms = SystemTime::now().duration_since(SystemTime::UNIX_EPOCH).map_or(0, |d| d.as_millis() as u64);
    let age_s = now_ms.saturating_sub(snap.taken_unix_ms) as f64 / 1000.0;
    let aside = moved_aside(dir);
    let locked = matches!(snapshot::ensure_unlocked(dir), Err(SnapshotError::Persist(PersistError::Locked { .. })));
    if json {
        let value = serde_json::json!({
            "schema": "op3dsg.map_info/1",
            "file": path.display().to_string(),
            "format_version": snapshot::FORMAT_VERSION,
            "bytes": bytes_on_disk,
            "checksum_ok": true,
            "graph_version": snap.graph_version,
            "taken_unix_ms": snap.taken_unix_ms,
            "age_s": age_s,
            "nodes": snap.map.nodes.len(),
            "objects": objects,
            "parts": parts,
            "points": snap.map.point_count(),
            "labels": snap.map.labels.len(),
            "keyframes": snap.map.keyframes,
            "next_node_id": snap.map.next_id,
            "daemon_running": locked,
            "moved_aside": aside.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
        });
        println!("{}", serde_json::to_string_pretty(&value).context("serialising the map info")?);
        return Ok(());
    }
    println!(
        "file           {} ({} bytes, format {}, checksum ok)",
        path.display(),
        bytes_on_disk,
        snapshot::FORMAT_VERSION
    );
    println!("taken          {age_s:.0} s ago (unix ms {})", snap.taken_unix_ms);
    println!("graph version  {}", snap.graph_version);
    println!(
        "nodes          {} ({objects} objects, {parts} parts, {} points)",
        snap.map.nodes.len(),
        snap.map.point_count()
    );
    println!(
        "keyframes      {} fused; next node id {}; {} labels",
        snap.map.keyframes,
        snap.map.next_id,
        snap.map.labels.len()
    );
    println!(
        "daemon         {}",
        if locked { "running with this directory" } else { "not running with this directory" }
    );
    for p in aside {
        println!("moved aside    {}", p.display());
    }
    Ok(())
}

/// Snapshots moved aside earlier (corrupt, incompatible, reset), oldest first.
fn moved_aside(dir: &Path) -> Vec<PathBuf> {
    let prefix = format!("{SNAPSHOT_FILE}.");
    let mut found: Vec<PathBuf> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.starts_with(&prefix) && n != snapshot::TEMP_FILE)
        })
        .collect();
    found.sort();
    found
}

/// `op3dsg map save`: asks the running daemon for a snapshot now and waits until it is written.
pub(super) fn save(dir: &Path, timeout: Duration) -> Result<()> {
    if snapshot::ensure_unlocked(dir).is_ok() {
        bail!(
            "{}: no op3dsgd runs with this snapshot directory (nothing to save; start it, or pass --dir)",
            dir.display()
        );
    }
    let path = dir.join(SNAPSHOT_FILE);
    let before = std::fs::metadata(&path).and_then(|m| m.modified()).ok();
    let request = dir.join(SAVE_REQUEST);
    std::fs::write(&request, b"")
        .with_context(|| format!("writing {} (run as the service user or root)", request.display()))?;
    let deadline = Instant::now() + timeout;
    while request.exists() {
        if Instant::now() >= deadline {
            let _ = std::fs::remove_file(&request);
            bail!(
                "the daemon did not write a snapshot within {timeout:?} (is its fusion thread alive? see `op3dsg health`)"
            );
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let after = std::fs::metadata(&path).and_then(|m| m.modified()).ok();
    if after.is_none() || after == before {
        bail!("{}: the request was taken but no new snapshot appeared; the daemon's log says why", path.display());
    }
    info(dir, false)
}

/// `op3dsg map reset`: moves the snapshot aside (never deletes it) so the next start begins
/// with an empty map. Refused while a daemon runs with the directory.
pub(super) fn reset(dir: &Path) -> Result<()> {
    snapshot::ensure_unlocked(dir).map_err(|e| anyhow::anyhow!("{e}"))?;
    // The occupancy map saved beside it goes too (op3dsg_runtime::occupancy::persist).
    let occupancy = dir.join(op3dsg_runtime::occupancy::persist::OCCUPANCY_FILE);
    if occupancy.exists() {
        let aside = op3dsg_runtime::persist::move_aside(&occupancy, "reset")
            .with_context(|| format!("moving {} aside", occupancy.display()))?;
        println!(
            "moved {} to {}; the next start begins with an empty occupancy map",
            occupancy.display(),
            aside.display()
        );
    }
    let path = dir.join(SNAPSHOT_FILE);
    if !path.exists() {
        println!("{}: no map snapshot; the next start begins with an empty map", path.display());
        return Ok(());
    }
    let aside = op3dsg_runtime::persist::move_aside(&path, "reset")
        .with_context(|| format!("moving {} aside", path.display()))?;
    println!("moved {} to {}; the next start begins with an empty map", path.display(), aside.display());
    Ok(())
}
