//! One way to score a run: a live `op3dsgd` run of a synthetic room, scored the documented way
//! (`op3dsg gt --frames N` for the ground truth as that run saw it, `op3dsg dump --json`,
//! `op3dsg eval`), gives what `op3dsg bench quality` gives for the same scene and frames: the
//! same coverage (nodes seen in at least 3 keyframes) and, per column, R@3 within noise (the
//! live pipeline detects on a worker pool, so fusion's input order can differ from the batch
//! runner's). Needs the MiniLM model (`./scripts/setup-models.sh`, run by `scripts/test.sh`).

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use op3dsg_tests::{Daemon, binary, health_where, unique_prefix};
use serde_json::Value;

const FRAMES: &str = "300";
/// `op3dsg bench quality`'s scene 0.
const ROOM: &str = "kitchen";
const SEED: &str = "1";
/// What the benchmark sets for every scene.
const PART_PROMPTS: &str = "detector.oracle.part_prompts=knowledge";

fn op3dsg(args: &[&str]) -> String {
    let out = Command::new(binary("op3dsg")).args(args).output().expect("run op3dsg");
    assert!(
        out.status.success(),
        "op3dsg {args:?} failed: {}\n{}",
        String::from_utf8_lossy(&out.stderr),
        String::from_utf8_lossy(&out.stdout)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn read_json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).expect("read JSON")).expect("parse JSON")
}

/// (items, retrieved at R@3) of `column` in a recall figures object.
fn at3(figures: &Value, column: &str) -> (u64, u64) {
    let c = &figures[column];
    (c["total"].as_u64().expect("total"), c["retrieved"][0].as_u64().expect("retrieved at 3"))
}

#[test]
fn a_live_run_scored_the_documented_way_matches_bench_quality() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = |name: &str| dir.path().join(name);
    let (bench, live, gt, eval) = (path("bench.json"), path("live.json"), path("gt.json"), path("eval.json"));

    op3dsg(&[
        "bench",
        "quality",
        "--scenes",
        "1",
        "--frames",
        FRAMES,
        "--threads",
        "1",
        "--json",
        &bench.to_string_lossy(),
    ]);
    let bench = read_json(&bench);
    let report = &bench["report"];
    assert_eq!(report["scenes"][0].as_str(), Some(format!("{ROOM} seed {SEED}").as_str()), "{}", report["scenes"]);
    let full = report["rows"].as_array().and_then(|rows| rows.first()).expect("full row");
    assert_eq!(full[0].as_str(), Some("full"));
    let bench_figures = &full[1];

    let prefix = unique_prefix("score-live");
    let daemon = Daemon::start(
        &prefix,
        &[
            "--set",
            &format!("source.synthetic.room={ROOM}"),
            "--set",
            &format!("source.synthetic.seed={SEED}"),
            "--set",
            &format!("source.synthetic.frame_count={FRAMES}"),
            "--set",
            PART_PROMPTS,
            "--set",
            "health.period_ms=100",
        ],
    );
    let mut health = daemon.health_subscriber("score-live-health");
    // The source has ended and the graph of its last keyframe is out.
    let frames: u64 = FRAMES.parse().expect("frames");
    let ended = health_where(&mut health, "the run's end", Duration::from_secs(240), |h| {
        h.frames_captured >= frames && h.source_connected == 0
    });
    std::thread::sleep(Duration::from_millis(500));
    op3dsg(&["--prefix", &prefix, "dump", "--json", "--out", &live.to_string_lossy()]);
    drop(daemon);

    op3dsg(&[
        "gt",
        "--room",
        ROOM,
        "--seed",
        SEED,
        "--frames",
        FRAMES,
        "--set",
        PART_PROMPTS,
        "--out",
        &gt.to_string_lossy(),
    ]);
    let text = op3dsg(&[
        "eval",
        "--pred",
        &live.to_string_lossy(),
        "--gt",
        &gt.to_string_lossy(),
        "--json",
        &eval.to_string_lossy(),
    ]);
    println!("{text}");
    let coverage = &report["coverage"];
    assert!(
        text.contains(&format!(
            "coverage: {} of {} ground-truth nodes seen in at least 3 keyframes",
            coverage["scored"], coverage["total"]
        )),
        "the same coverage as the benchmark ({coverage}):\n{text}"
    );
    let eval = read_json(&eval);
    let live_figures = &eval["figures"];
    println!("live run: {} keyframes", ended.keyframes);
    for column in ["object", "part", "affordance", "functional", "spatial"] {
        let (bench_items, bench_hits) = at3(bench_figures, column);
        let (live_items, live_hits) = at3(live_figures, column);
        println!("{column}: bench {bench_hits}/{bench_items}, live {live_hits}/{live_items}");
        if matches!(column, "object" | "part") {
            assert_eq!(live_items, bench_items, "{column}: the same ground-truth nodes scored");
        }
        let rate = |hits: u64, items: u64| hits as f64 / items.max(1) as f64;
        let tolerance = (1.0 / bench_items.max(1) as f64).max(0.10);
        assert!(
            (rate(live_hits, live_items) - rate(bench_hits, bench_items)).abs() <= tolerance + 1e-9,
            "{column} R@3: live {live_hits}/{live_items} vs bench {bench_hits}/{bench_items}"
        );
    }
}
