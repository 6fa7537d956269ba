//! Fusion quality per benchmark room: one seeded scene per room, the base profile's fusion and
//! the `realistic` oracle, through the deterministic batch runner, scored against ground truth
//! (`op3dsg_sim::eval::fusion_match`, whose docs define every figure).
//!
//! Targets (never to be lowered): at least 90 % of eligible objects and 80 % of eligible parts
//! matched; fragmentation at most 1.15 for objects and 1.25 for parts.
//!
//! Each room runs one whole loop of its camera path with the synthetic camera at 10 Hz instead of
//! 30: the path is the same in metres and seconds and the keyframe gate (10 cm, 8°, 1 s) picks
//! about as many keyframes, but a third of the frames are rendered, so the debug build covers
//! every wall of all four rooms in well under a minute on two cores. Reproduce one room with
//! `op3dsg fusion-eval --room kitchen --seed 1 --frames 311 --set source.synthetic.frame_rate_hz=10 --details`.

use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use op3dsg_runtime::config::Profile;
use op3dsg_sim::batch::{self, BatchRun};
use op3dsg_sim::eval::fusion_match::{
    FusionMatchReport, MatchCriteria, QualityTargets, TABLE_LEGEND, details, match_run, table_header, table_row,
};
use op3dsg_synthetic::{CameraPath, RoomKind, Scene};

const SEED: u64 = 1;
const FRAME_RATE_HZ: f64 = 10.0;
/// Rooms run on this many threads at once (the development machine has two cores).
const THREADS: usize = 2;

/// The base profile on `room`, realistic oracle, camera at [`FRAME_RATE_HZ`], one path loop.
fn room_profile(room: RoomKind) -> Profile {
    let sets = [
        format!("source.synthetic.room={}", room.as_str()),
        format!("source.synthetic.seed={SEED}"),
        format!("source.synthetic.frame_rate_hz={FRAME_RATE_HZ}"),
        "detector.oracle.preset=realistic".to_owned(),
    ];
    let mut profile = op3dsg_sim::load_profile(None, &sets).expect("profile").profile;
    let path = CameraPath::new(&Scene::generate(room, SEED), SEED, FRAME_RATE_HZ);
    op3dsg_sim::backends::edit_synthetic(&mut profile, |s| s.frame_count = Some(path.period_frames()))
        .expect("[source.synthetic] of the profile");
    profile
}

struct RoomResult {
    room: RoomKind,
    run: BatchRun,
    report: FusionMatchReport,
}

fn evaluate(room: RoomKind) -> RoomResult {
    let profile = room_profile(room);
    let run = batch::run(&profile, &batch::VisibilityThresholds::default()).expect("batch run");
    let criteria = MatchCriteria { min_observations: profile.fusion.min_observations, ..MatchCriteria::default() };
    let report = match_run(&run, &criteria);
    RoomResult { room, run, report }
}

#[test]
fn fusion_meets_the_quality_targets_in_every_room() {
    let started = Instant::now();
    let next = AtomicUsize::new(0);
    let results = Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for t in 0..THREADS {
            let (next, results) = (&next, &results);
            std::thread::Builder::new()
                .name(format!("fusion-quality-{t}"))
                .spawn_scoped(scope, move || {
                    while let Some(&room) = RoomKind::ALL.get(next.fetch_add(1, Ordering::SeqCst)) {
                        let result = evaluate(room);
                        results.lock().expect("no room panicked").push(result);
                    }
                })
                .expect("start a room thread");
        }
    });
    let mut results = results.into_inner().expect("no room panicked");
    results.sort_by_key(|r| RoomKind::ALL.iter().position(|k| *k == r.room));
    assert_eq!(results.len(), RoomKind::ALL.len());

    let targets = QualityTargets::default();
    let mut table = table_header();
    let mut failures = Vec::new();
    let mut misses = String::new();
    for r in &results {
        let name = format!("{} seed {SEED}", r.room.as_str());
        table.push_str(&table_row(&name, r.run.keyframes, &r.report));
        for failure in targets.failures(&r.report) {
            failures.push(format!("{name}: {failure}"));
        }
        misses.push_str(&format!(
            "{name}: {} frames in {:.1} s\n{}",
            r.run.frames,
            r.run.timing.total.as_secs_f64(),
            details(&r.report)
        ));
    }
    println!("{table}{TABLE_LEGEND}\n\n{misses}all rooms in {:.1} s", started.elapsed().as_secs_f64());
    for r in &results {
        // Guard against a vacuous pass: every room has objects and parts to score.
        assert!(
            r.report.objects.eligible >= 5 && r.report.parts.eligible >= 5,
            "{}: too few eligible",
            r.room.as_str()
        );
    }
    assert!(failures.is_empty(), "quality targets missed:\n{}", failures.join("\n"));
}
