//! The real-frames ground truth: `daemon/sim/data/icl_livingroom1/annotation.toml` (2D boxes
//! drawn by hand on the ICL-NUIM living room) lifted with `op3dsg_sim::annotate` reproduces the
//! committed `gt.json` beside it, its boxes are where and as large as the room's furniture is,
//! and bad annotations fail with errors naming the file, the node, the box and the frame.
//!
//! Needs the shared development data (`../shared/data/rgbd/icl_livingroom1`): skipped with a
//! message when it is absent, a failure in CI (`CI=true`).

use std::path::{Path, PathBuf};

use op3dsg_drivers::graph_json::GraphJson;
use op3dsg_sim::annotate::{Annotation, lift};

fn data_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/icl_livingroom1")
}

fn sequence() -> Option<PathBuf> {
    op3dsg_shared_data::shared_data("rgbd/icl_livingroom1/rgb.txt")?;
    op3dsg_shared_data::shared_data("rgbd/icl_livingroom1")
}

#[test]
fn the_committed_annotation_lifts_to_the_committed_ground_truth() {
    let Some(sequence) = sequence() else { return };
    let path = data_dir().join("annotation.toml");
    let annotation = Annotation::read(&path).unwrap();
    // The file's own `sequence` (relative to it) is the shared recording.
    let own = annotation.sequence_dir(&path).unwrap();
    assert_eq!(own.canonicalize().unwrap(), sequence.canonicalize().unwrap());
    let lifted = lift(&annotation, &path, &sequence).unwrap();
    let committed = GraphJson::read(&data_dir().join("gt.json")).unwrap();
    assert_eq!(lifted.graph.schema, committed.schema);
    assert_eq!(lifted.graph.source, committed.source);
    assert_eq!(lifted.graph.edges, committed.edges);
    assert_eq!(lifted.graph.nodes.len(), committed.nodes.len());
    for (a, b) in lifted.graph.nodes.iter().zip(&committed.nodes) {
        assert_eq!(
            (a.id, &a.label, &a.kind, a.parent, &a.affordances),
            (b.id, &b.label, &b.kind, b.parent, &b.affordances)
        );
        for (x, y) in a
            .box_min_m
            .iter()
            .chain(&a.box_max_m)
            .chain(&a.centre_m)
            .zip(b.box_min_m.iter().chain(&b.box_max_m).chain(&b.centre_m))
        {
            assert!((x - y).abs() <= 1e-3, "node {} '{}': lifted {a:?}, committed {b:?}", a.id, a.label);
        }
    }
}

#[test]
fn the_lifted_boxes_are_the_rooms_furniture() {
    let Some(_) = sequence() else { return };
    let gt = GraphJson::read(&data_dir().join("gt.json")).unwrap();
    let node = |label: &str| {
        gt.nodes.iter().find(|n| n.label.split(" / ").any(|l| l == label)).unwrap_or_else(|| panic!("{label}"))
    };
    let size = |label: &str| {
        let n = node(label);
        [0, 1, 2].map(|a| n.box_max_m[a] - n.box_min_m[a])
    };
    // ICL-NUIM's world has +y up; the floor is at y = 0.13 m.
    let floor = node("chair").box_min_m[1];
    assert!((0.05..0.2).contains(&floor), "floor at {floor} m");
    let chair = size("chair");
    assert!(chair.iter().all(|s| (0.4..1.1).contains(s)), "chair {chair:?} m");
    let cabinet = node("cabinet");
    assert!((cabinet.box_max_m[1] - floor - 0.5).abs() < 0.1, "the sideboard is about 0.5 m tall: {cabinet:?}");
    assert!((cabinet.box_min_m[1] - floor).abs() < 0.05, "the sideboard stands on the floor");
    let tv = size("tv");
    assert!(tv[0].min(tv[2]) < 0.1 && tv[0].max(tv[2]) > 0.7, "the TV is a flat screen on the wall: {tv:?}");
    let vase = node("vase");
    assert!((vase.box_min_m[1] - cabinet.box_max_m[1]).abs() < 0.05, "the vase stands on the sideboard");
    assert!(node("tv").box_min_m[1] > vase.box_min_m[1] + 0.2, "the TV hangs above the vase");
    for door in gt.nodes.iter().filter(|n| n.kind == "part") {
        assert_eq!(door.parent, Some(cabinet.id));
        assert!(door.box_max_m[1] <= cabinet.box_max_m[1] + 0.02, "door {} below the sideboard's top", door.id);
    }
    let curtain = size("curtain");
    assert!(curtain[1] > 1.0, "the curtain hangs over a metre of the frames: {curtain:?}");
}

/// The committed annotation with `edit` applied, written as `bad.toml` into a temporary folder
/// (the recording is passed to [`lift`] explicitly).
fn edited(edit: impl FnOnce(String) -> String) -> (tempfile::TempDir, PathBuf) {
    let text = std::fs::read_to_string(data_dir().join("annotation.toml")).expect("the committed annotation");
    let dir = tempfile::tempdir().expect("a temporary folder");
    let path = dir.path().join("bad.toml");
    std::fs::write(&path, edit(text)).expect("writing the edited annotation");
    (dir, path)
}

/// The error lifting the (well-formed) annotation at `path` on `sequence` gives.
fn lift_error(path: &Path, sequence: &Path) -> String {
    let annotation = Annotation::read(path).expect("the edit keeps the file well-formed");
    lift(&annotation, path, sequence).expect_err("the edit makes the lift fail")
}

#[test]
fn bad_annotations_name_the_file_node_box_and_frame() {
    let Some(sequence) = sequence() else { return };
    // A frame past the recording's last.
    let (_d, path) = edited(|t| {
        t.replacen("{ frame = 60, box = [570, 122, 630, 208] }", "{ frame = 300, box = [570, 122, 630, 208] }", 1)
    });
    let e = lift_error(&path, &sequence);
    assert!(
        e.contains("bad.toml: node[3] (id 4 \"vase\").boxes[0].frame: frame 300") && e.contains("211 frames"),
        "{e}"
    );
    // A box past the image.
    let (_d, path) = edited(|t| t.replacen("[570, 122, 630, 208]", "[570, 122, 700, 208]", 1));
    let e = lift_error(&path, &sequence);
    assert!(e.contains("bad.toml: node[3] (id 4 \"vase\").boxes[0] (frame 60).box") && e.contains("640x480"), "{e}");
    // A band so narrow that a box keeps too few pixels.
    let (_d, path) = edited(|t| {
        t.replacen(
            "{ frame = 60, box = [570, 122, 630, 208] }",
            "{ frame = 60, box = [570, 122, 630, 208], band_m = 0.0005 }",
            1,
        )
    });
    let e = lift_error(&path, &sequence);
    assert!(e.contains("node[3] (id 4 \"vase\").boxes[0] (frame 60): only") && e.contains("min_points"), "{e}");
    // A recording that is not there.
    let (_d, path) = edited(|t| t);
    let e = lift_error(&path, &sequence.join("missing"));
    assert!(e.contains("bad.toml") && e.contains("missing"), "{e}");
    // A part whose parent is not an object, and a field the format does not have.
    let (_d, path) = edited(|t| {
        t.replace("parent = 2", "parent = 3").replacen(
            "kind = \"object\"\nnote = \"the wall TV",
            "kind = \"part\"\nparent = 1\nnote = \"the wall TV",
            1,
        )
    });
    let e = Annotation::read(&path).unwrap_err();
    assert!(
        e.contains("bad.toml: node[6] (id 7 \"cabinet door / door\").parent: node 3 is a part, not an object"),
        "{e}"
    );
    let (_d, path) = edited(|t| t.replacen("band_m = 0.18", "band = 0.18", 1));
    let e = Annotation::read(&path).unwrap_err();
    assert!(e.contains("bad.toml") && e.contains("node[0]") && e.contains("unknown field `band`"), "{e}");
}
