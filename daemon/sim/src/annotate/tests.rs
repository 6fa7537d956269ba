use super::*;

fn parse(text: &str) -> Result<Annotation, String> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("a.toml");
    std::fs::write(&path, text).unwrap();
    Annotation::read(&path)
}

const GOOD: &str = r#"
schema = "op3dsg.annotation/1"
annotator = "test"
[[node]]
id = 1
label = "cabinet"
kind = "object"
boxes = [{ frame = 0, box = [0, 0, 10, 10] }]
[[node]]
id = 2
label = "cabinet door"
kind = "part"
parent = 1
affordances = ["hook_pull"]
boxes = [{ frame = 0, box = [0, 0, 5, 5] }]
"#;

#[test]
fn a_good_file_parses() {
    let a = parse(GOOD).unwrap();
    assert_eq!(a.nodes.len(), 2);
    assert_eq!(a.lift, LiftParams::default());
}

#[test]
fn bad_files_name_the_field() {
    let cases = [
        (GOOD.replace("op3dsg.annotation/1", "x"), "schema: expected"),
        (GOOD.replace("parent = 1", "parent = 7"), "node[1] (id 2 \"cabinet door\").parent: no node with id 7"),
        (GOOD.replace("parent = 1\n", ""), "node[1] (id 2 \"cabinet door\").parent: a part must name"),
        (GOOD.replace("id = 2", "id = 1"), "node[1] (id 1 \"cabinet door\").id: duplicate id 1"),
        (GOOD.replace("hook_pull", "yank"), ".affordances[0]: unknown affordance \"yank\""),
        (
            GOOD.replace("[0, 0, 5, 5]", "[5, 0, 5, 5]"),
            "node[1] (id 2 \"cabinet door\").boxes[0].box: expected [x0, y0, x1, y1]",
        ),
        (GOOD.replace("kind = \"object\"", "kind = \"thing\""), "node[0] (id 1 \"cabinet\").kind: expected"),
        (GOOD.replace("frame = 0, box", "frame = -1, box"), "node[0].boxes[0].frame"),
        (
            GOOD.replace("annotator = \"test\"", "annotator = \"test\"\n[lift]\nband_m = 0"),
            "lift.band_m: must be within",
        ),
        (GOOD.replace("label = \"cabinet\"", "label = \"cabinet\"\ncolour = 1"), "unknown field `colour`"),
    ];
    for (text, expected) in cases {
        let e = parse(&text).unwrap_err();
        assert!(e.contains("a.toml") && e.contains(expected), "{e}\nexpected: {expected}");
    }
}

#[test]
fn percentile_is_nearest_rank() {
    let mut v: Vec<f64> = (0..=100).map(f64::from).rev().collect();
    assert_eq!(percentile(&mut v, 2.0), Some(2.0));
    assert_eq!(percentile(&mut v, 50.0), Some(50.0));
    assert_eq!(percentile(&mut v, 100.0), Some(100.0));
    assert_eq!(percentile(&mut [], 50.0), None);
}
