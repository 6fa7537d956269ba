//! The change benchmark's chain on two rooms (`op3dsg bench change --scenes 2 --presets
//! realistic`): the script drawn from the room, two laps through the batch runner with change
//! handling on and off on the same keyframes, scored against the renderer's ground truth. The
//! map without change handling keeps every removed thing; with it, the scored removals and
//! moves are reflected, moved objects keep their ids, and nothing unchanged or behind a control
//! is removed. The figures over 24 rooms per preset are the benchmark's (docs/benchmarks.md).

use op3dsg_sim::eval::change_bench::{self, PresetReport};

#[test]
fn removed_and_moved_things_leave_the_map_and_unchanged_ones_stay() {
    let sets = ["detector.oracle.preset=realistic".to_owned()];
    let profile = op3dsg_sim::load_profile(None, &sets).expect("built-in profile").profile;
    let runs = change_bench::run_scenes(&profile, 2, 2, &|_| {}).expect("the scenes run");
    let scenes: Vec<_> = runs.iter().map(change_bench::score_scene).collect();
    let report = PresetReport { preset: "realistic".to_owned(), scenes };
    let text = change_bench::text(std::slice::from_ref(&report));
    let (reflected_on, scored) = report.reflected(None, 0);
    let (reflected_off, _) = report.reflected(None, 1);
    assert!(scored >= 3, "too few changes scored:\n{text}");
    // The map that only grows keeps a ghost of every removal and move; this one reflects them.
    assert_eq!(reflected_off, 0, "{text}");
    assert!(reflected_on * 10 >= scored * 8, "{reflected_on} of {scored} reflected:\n{text}");
    let (linked, moves) = report.linked(0);
    assert_eq!(linked, moves, "moved objects keep their ids:\n{text}");
    let ghosts = report.ghosts();
    assert!(ghosts[0] < ghosts[1], "{text}");
    assert_eq!(report.unchanged_removed().0, 0, "{text}");
    for kind in ["occluder", "depth hole"] {
        assert_eq!(report.controls(kind).0, 0, "{kind} control hit:\n{text}");
    }
}
