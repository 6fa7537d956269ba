use super::*;

fn small_profile(frames: u64) -> Profile {
    let mut profile = crate::load_profile(None, &[]).unwrap().profile;
    let mut synthetic = synthetic_config(&profile).unwrap();
    synthetic.frame_count = Some(frames);
    synthetic.intrinsics =
        op3dsg_drivers::frame::Intrinsics { width: 160, height: 120, fx: 153.75, fy: 153.75, cx: 80.0, cy: 60.0 };
    crate::backends::set_synthetic_config(&mut profile, &synthetic);
    profile
}

#[test]
fn an_unbounded_source_is_refused() {
    let profile = crate::load_profile(None, &[]).unwrap().profile;
    let error = run(&profile, &VisibilityThresholds::default()).unwrap_err();
    assert!(matches!(error, BatchError::Unbounded), "{error}");
    assert!(error.to_string().contains("set source.synthetic.frame_count"), "{error}");
}

#[test]
fn counts_are_consistent_and_runs_repeat_exactly() {
    let profile = small_profile(40);
    let a = run(&profile, &VisibilityThresholds::default()).unwrap();
    let b = run(&profile, &VisibilityThresholds::default()).unwrap();
    assert_eq!(a.graph, b.graph);
    assert_eq!((a.frames, a.keyframes, a.detections), (b.frames, b.keyframes, b.detections));
    assert_eq!(a.visible_keyframes, b.visible_keyframes);
    assert_eq!(a.detected_keyframes, b.detected_keyframes);
    assert_eq!(a.frames, 40);
    assert!(a.keyframes >= 2 && a.keyframes < 40, "{} keyframes", a.keyframes);
    let scene = a.scene.as_ref().unwrap();
    assert_eq!(a.visible_keyframes.len(), scene.instances().len() + 1);
    assert!(a.visible_keyframes.iter().all(|v| u64::from(*v) <= a.keyframes));
    assert!(a.detected_keyframes.iter().any(|d| *d > 0));
    // run.max_frames stops the source early, as in the pipeline.
    let mut limited = profile.clone();
    limited.run.max_frames = 10;
    assert_eq!(run(&limited, &VisibilityThresholds::default()).unwrap().frames, 10);
}

#[test]
fn several_fusions_see_the_same_keyframes() {
    let profile = small_profile(30);
    let single = run(&profile, &VisibilityThresholds::default()).unwrap();
    let both = run_with_fusions(
        &profile,
        &VisibilityThresholds::default(),
        [crate::backends().fusion(&profile).unwrap(), crate::backends().fusion(&profile).unwrap()],
    )
    .unwrap();
    for r in &both {
        assert_eq!(r.graph, single.graph);
        assert_eq!((r.keyframes, r.detections), (single.keyframes, single.detections));
    }
}

#[test]
fn lower_thresholds_see_more() {
    let profile = small_profile(20);
    let strict = run(&profile, &VisibilityThresholds { object_min_px: 2000, part_min_px: 2000 }).unwrap();
    let loose = run(&profile, &VisibilityThresholds { object_min_px: 1, part_min_px: 1 }).unwrap();
    let (s, l): (u32, u32) = (strict.visible_keyframes.iter().sum(), loose.visible_keyframes.iter().sum());
    assert!(s < l, "strict {s} loose {l}");
}
