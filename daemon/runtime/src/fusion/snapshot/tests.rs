use std::path::PathBuf;

use super::*;
use crate::fusion::multiview::MapState;
use crate::fusion::multiview::{MapGeometry, MapLife, NodeState};

fn snapshot(nodes: u32) -> Snapshot {
    let node = |id: u32| NodeState {
        id,
        kind: 0,
        points: vec![[id as f32, 0.0, 1.0]; 1],
        voxel_scale: 1,
        checked_points: 0,
        semantic: Vec::new(),
        colour: (vec![0.0; 11], vec![0.0; 64], vec![0.0; 64], 0),
        votes: vec![(0, 1)],
        score_sum: 0.9,
        observation_count: 1,
        last_keyframe: 1,
        last_seen_stamp_ns: 5,
    };
    Snapshot {
        graph_version: 7,
        stamp_ns: 5,
        taken_unix_ms: 1,
        map: MapState {
            geometry: MapGeometry {
                object_voxel_m: 0.02,
                part_voxel_m: 0.005,
                object_nnr_radius_m: 0.03,
                part_nnr_radius_m: 0.01,
            },
            labels: vec!["cabinet".to_owned()],
            next_id: nodes + 1,
            keyframes: 3,
            nodes: (1..=nodes).map(node).collect(),
            life: Some(MapLife { first_seen: (1..=nodes).map(|id| (id, 2, 1)).collect(), removed: Vec::new() }),
        },
    }
}

#[test]
fn round_trip_and_every_kind_of_damage_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = encode(&snapshot(3)).unwrap();
    crate::persist::write_atomic(dir.path(), SNAPSHOT_FILE, &bytes, None).unwrap();
    let path = dir.path().join(SNAPSHOT_FILE);
    assert_eq!(read(&path).unwrap(), snapshot(3));
    assert!(!dir.path().join(TEMP_FILE).exists());

    let check = |bytes: &[u8]| decode(bytes, &path).unwrap_err();
    assert!(matches!(check(&b"hello world, not a snapshot"[..]), SnapshotError::NotASnapshot { .. }));
    assert!(matches!(check(&bytes[..bytes.len() - 3]), SnapshotError::Truncated { .. }));
    let mut flipped = bytes.clone();
    let last = flipped.len() - 1;
    flipped[last] ^= 0x40;
    let err = check(&flipped);
    assert!(matches!(err, SnapshotError::BadChecksum { .. }), "{err}");
    assert!(err.to_string().starts_with(&format!("{}: checksum mismatch", path.display())), "{err}");
    let mut other_format = bytes.clone();
    other_format[8] = 9;
    assert!(matches!(check(&other_format), SnapshotError::UnsupportedFormat { found: 9, .. }));
    assert_eq!(check(&other_format).aside_reason(), "incompatible");
}

#[test]
fn one_daemon_per_directory_and_a_leftover_temp_file_goes() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join(TEMP_FILE), b"half a write").unwrap();
    let store = SnapshotStore::open(dir.path()).unwrap();
    assert!(!dir.path().join(TEMP_FILE).exists());
    let err = SnapshotStore::open(dir.path()).unwrap_err();
    assert!(matches!(err, SnapshotError::Persist(crate::persist::PersistError::Locked { .. })), "{err}");
    assert!(err.to_string().contains(&format!("(pid {})", std::process::id())), "{err}");
    assert!(ensure_unlocked(dir.path()).is_err());
    drop(store);
    ensure_unlocked(dir.path()).unwrap();
}

#[test]
fn the_directory_defaults_to_the_systemd_state_directory() {
    let config = SnapshotConfig::default();
    assert_eq!(config.resolve_dir_with(None), None);
    assert_eq!(
        config.resolve_dir_with(Some("/var/lib/op3dsg:/var/lib/other".into())),
        Some(PathBuf::from("/var/lib/op3dsg/snapshots"))
    );
    let set = SnapshotConfig { dir: "/data/maps".to_owned(), ..SnapshotConfig::default() };
    assert_eq!(set.resolve_dir_with(Some("/var/lib/op3dsg".into())), Some(PathBuf::from("/data/maps")));
    let off = SnapshotConfig { enabled: false, ..set };
    assert_eq!(off.resolve_dir_with(Some("/var/lib/op3dsg".into())), None);
    assert!(SnapshotConfig { period_s: -1.0, ..SnapshotConfig::default() }.validate("snapshot").is_err());
}

#[test]
fn a_format_1_file_reads_with_no_life_and_format_2_keeps_it() {
    let path = PathBuf::from("map.op3dsgmap");
    // Format 1: the same payload without `MapState::life` (its trailing `None` byte).
    let mut old = snapshot(2);
    old.map.life = None;
    let mut payload = postcard::to_stdvec(&old).unwrap();
    assert_eq!(payload.pop(), Some(0));
    let mut bytes = Vec::new();
    bytes.extend_from_slice(b"OP3DSGMP");
    bytes.extend_from_slice(&1u32.to_le_bytes());
    bytes.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    bytes.extend_from_slice(&crc32fast::hash(&payload).to_le_bytes());
    bytes.extend_from_slice(&payload);
    let read = decode(&bytes, &path).unwrap();
    assert_eq!(read, old);
    let current = snapshot(2);
    let read = decode(&encode(&current).unwrap(), &path).unwrap();
    assert_eq!(read.map.life, current.map.life);
    assert!(read.map.life.is_some());
}
