use std::path::{Path, PathBuf};

use op3dsg_drivers::replay::PlaybackMode;

use super::*;
use crate::perception::YOLOX_DETECTOR;

fn write(dir: &tempfile::TempDir, name: &str, text: &str) -> PathBuf {
    let path = dir.path().join(name);
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn built_in_base_loads_and_validates() {
    let loaded = load(None, &[]).unwrap();
    assert_eq!(loaded.profile.source.kind, "synthetic");
    assert_eq!(loaded.layers, [BASE_PROFILE_NAME]);
}

#[test]
fn yolox_detector_paths_resolve_and_ranges_name_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(
        &dir,
        "icl.toml",
        "[detector]\nkind = \"onnx\"\n[detector.yolox]\nmodel_path = \"m/yolox.onnx\"\n\
         [detector.yolox.class_map]\nchair = \"chair\"\n",
    );
    let profile = load(Some(&path), &[]).unwrap().profile;
    assert_eq!(profile.detector.kind, YOLOX_DETECTOR, "onnx is an alias of yolox");
    assert_eq!(profile.detector.yolox.model_path, dir.path().join("m/yolox.onnx"), "relative to the profile");
    let path = write(&dir, "bad.toml", "[detector]\nkind = \"yolox\"\n[detector.yolox]\nnms_iou_threshold = 0.0\n");
    let err = load(Some(&path), &[]).unwrap_err();
    assert!(err.to_string().contains("detector.yolox.nms_iou_threshold: must be within (0, 1]"), "{err}");
    let path = write(&dir, "empty.toml", "[detector]\nkind = \"yolox\"\n");
    let err = load(Some(&path), &[]).unwrap_err();
    assert!(err.to_string().contains("detector.yolox.class_map: must map at least one class"), "{err}");
}

#[test]
fn unknown_key_names_file_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(&dir, "robot.toml", "[fusion]\nvoxel_sise_m = 0.02\n");
    let err = load(Some(&path), &[]).unwrap_err();
    assert_eq!(err.file, path.display().to_string());
    assert!(err.message.starts_with("fusion"), "{err}");
    assert!(err.message.contains("voxel_sise_m"), "{err}");
}

#[test]
fn wrong_type_names_file_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(&dir, "robot.toml", "[detector]\nworkers = \"two\"\n");
    let err = load(Some(&path), &[]).unwrap_err();
    assert_eq!(err.file, path.display().to_string());
    assert!(err.message.starts_with("detector.workers: "), "{err}");
}

#[test]
fn out_of_range_names_file_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(&dir, "robot.toml", "[detector]\nworkers = 0\n");
    let err = load(Some(&path), &[]).unwrap_err();
    assert_eq!(err.to_string(), format!("{}: detector.workers: must be within [1, 64], got 0", path.display()));
}

#[test]
fn sections_of_backends_not_in_the_registry_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(
        &dir,
        "r.toml",
        "[source]\nkind = \"replay\"\nrate_hz = 0.0\n[source.replay]\npath = \"rec\"\n[detector.yolx]\nmodel_path = \"m.onnx\"\n",
    );
    let backends = crate::backend::Backends::runtime();
    let err = load_with(&backends, Some(&path), &[]).unwrap_err();
    // The base's [source.synthetic] comes first: no such backend in the runtime alone.
    assert_eq!(
        err.to_string(),
        format!(
            "{BASE_PROFILE_NAME}: source.synthetic: no source backend \"synthetic\" in this build (it has: mcap, replay)"
        )
    );
    // Without a registry the sections are kept as they are, for their backend to check.
    let loaded = load(Some(&path), &[]).unwrap();
    assert!(loaded.profile.section("detector.yolx").is_some());
    assert!(loaded.profile.section("source.synthetic").is_some());
    assert!(loaded.effective["detector"]["yolx"].is_table(), "--print-config shows them");
}

#[test]
fn extends_chain_and_set_overrides_layer_in_order() {
    let dir = tempfile::tempdir().unwrap();
    write(&dir, "common.toml", "[detector]\nworkers = 3\n[health]\nperiod_ms = 250\n");
    let path = write(&dir, "robot.toml", "extends = \"common.toml\"\n[detector]\nworkers = 4\n");
    let loaded = load(Some(&path), &["health.period_ms=500".to_owned()]).unwrap();
    assert_eq!(loaded.profile.detector.workers, 4);
    assert_eq!(loaded.profile.health.period_ms, 500);
    assert_eq!(loaded.layers.len(), 4);
    let err = load(Some(&path), &["detector.workers=99".to_owned()]).unwrap_err();
    assert_eq!(err.file, "--set");
}

#[test]
fn extends_falls_back_to_the_installed_profiles() {
    let dir = tempfile::tempdir().unwrap();
    let etc = dir.path().join("etc");
    let installed = dir.path().join("usr/share/op3dsg/profiles");
    std::fs::create_dir_all(&etc).unwrap();
    std::fs::create_dir_all(&installed).unwrap();
    std::fs::write(installed.join("robot.toml"), "").unwrap();
    // Beside the naming profile first, then the installed profiles.
    let found = layers::find_extended(&etc, Path::new("robot.toml"), Some(installed.clone())).unwrap();
    assert_eq!(found, installed.join("robot.toml"));
    std::fs::write(etc.join("robot.toml"), "").unwrap();
    assert_eq!(
        layers::find_extended(&etc, Path::new("robot.toml"), Some(installed.clone())).unwrap(),
        etc.join("robot.toml")
    );
    // Absolute names are not looked for elsewhere; a missing one lists every place looked at.
    let missing = layers::find_extended(&etc, Path::new("other.toml"), Some(installed.clone())).unwrap_err();
    assert_eq!(missing, vec![etc.join("other.toml"), installed.join("other.toml")]);
    let missing = layers::find_extended(&etc, Path::new("/no/such.toml"), Some(installed)).unwrap_err();
    assert_eq!(missing, vec![PathBuf::from("/no/such.toml")]);
    // Through the loader: the error names the profile and every place.
    let path = write(&dir, "robot.toml", "extends = \"nowhere.toml\"\n");
    let err = load(Some(&path), &[]).unwrap_err().to_string();
    assert!(err.contains("robot.toml") && err.contains("extends: no profile \"nowhere.toml\": looked for "), "{err}");
}

#[test]
fn model_store_paths_are_not_relative_to_the_profile() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(
        &dir,
        "robot.toml",
        "[detector]\nkind = \"yolox\"\n[detector.yolox]\nmodel_path = \".models/yolox_nano/yolox_nano.onnx\"\n\
         [detector.yolox.class_map]\nchair = \"chair\"\n",
    );
    let profile = load(Some(&path), &[]).unwrap().profile;
    assert_eq!(profile.detector.yolox.model_path, PathBuf::from(".models/yolox_nano/yolox_nano.onnx"));
}

const REPLAY: &str = "[source]\nkind = \"replay\"\nrate_hz = 0.0\n[source.replay]\npath = \"rec/icl\"\n";

#[test]
fn replay_path_is_relative_to_the_profile_that_sets_it() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir(dir.path().join("robots")).unwrap();
    let path = write(&dir, "robots/replay.toml", REPLAY);
    let loaded = load(Some(&path), &[]).unwrap();
    let replay = loaded.profile.source.replay.unwrap();
    assert_eq!(replay.path, dir.path().join("robots").join("rec/icl"));
    assert_eq!(replay.mode, PlaybackMode::Recorded);
    assert_eq!(replay.on_bad_frame, op3dsg_drivers::replay::OnBadFrame::Stop);
    // An extending profile that does not set the path keeps the base file's folder.
    let child = write(&dir, "child.toml", "extends = \"robots/replay.toml\"\n[source.replay]\nloop = true\n");
    let replay = load(Some(&child), &[]).unwrap().profile.source.replay.unwrap();
    assert_eq!(replay.path, dir.path().join("robots").join("rec/icl"));
    assert!(replay.looping);
    // Absolute paths stay; --set paths are relative to the working directory.
    let replay = load(Some(&path), &["source.replay.path=\"/data/seq\"".to_owned()]).unwrap().profile.source.replay;
    assert_eq!(replay.unwrap().path, PathBuf::from("/data/seq"));
    let replay = load(Some(&path), &["source.replay.path=\"seq\"".to_owned()]).unwrap().profile.source.replay;
    assert_eq!(replay.unwrap().path, PathBuf::from("seq"));
}

#[test]
fn replay_errors_name_file_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        ("[source]\nkind = \"replay\"\nrate_hz = 0.0\n", "source.replay: required with source.kind = \"replay\""),
        (&format!("{REPLAY}on_bad_frame = \"ignore\"\n"), "source.replay.on_bad_frame: unknown variant `ignore`"),
        (&format!("{REPLAY}speed = 2.0\n"), "source.replay.speed: unknown field `speed`"),
        (
            &format!("{REPLAY}max_pose_gap_ms = -1.0\n"),
            "source.replay.max_pose_gap_ms: must be within (0, 10000], got -1",
        ),
        (
            &format!(
                "{REPLAY}intrinsics = {{ width = 640, height = 480, fx = 0.0, fy = 525.0, cx = 319.5, cy = 239.5 }}\n"
            ),
            "source.replay.intrinsics.fx: must be > 0, got 0",
        ),
        (
            &REPLAY.replace("rate_hz = 0.0\n", ""),
            "source.replay.mode: \"recorded\" paces frames itself; set source.rate_hz = 0 (it is 30)",
        ),
    ];
    for (i, (text, expected)) in cases.iter().enumerate() {
        let path = write(&dir, &format!("r{i}.toml"), text);
        let err = load(Some(&path), &[]).unwrap_err();
        assert_eq!(err.file, path.display().to_string(), "{err}");
        assert!(err.message.starts_with(expected), "case {i}: {err}");
    }
    // Fast mode is paced by source.rate_hz like the synthetic source.
    let path = write(&dir, "fast.toml", &format!("{REPLAY}mode = \"fast\"\n"));
    assert!(load(Some(&path), &["source.rate_hz=15".to_owned()]).is_ok());
}

#[test]
fn pose_keys_are_checked_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        (
            "[pose]\nmax_interpolation_gap_ms = 0.0\n",
            "pose.max_interpolation_gap_ms: must be within (0, 10000] milliseconds, got 0",
        ),
        (
            "[pose]\nmax_wait_ms = -5.0\n",
            "pose.max_wait_ms: must be within [0, 5000] milliseconds (0 = never wait), got -5",
        ),
        (
            "[pose]\nfuture_tolerance_ms = 0.0\n",
            "pose.future_tolerance_ms: must be within (0, 3600000] milliseconds, got 0",
        ),
        (
            "[pose]\nclock_warning_after_s = 0.0\n",
            "pose.clock_warning_after_s: must be within (0, 3600] seconds, got 0",
        ),
        ("[pose]\nmax_wait = 5.0\n", "pose.max_wait: unknown field `max_wait`"),
        (
            "[pose]\nbase_from_camera = { translation_m = [0.0, 0.0, nan], rotation_xyzw = [0.0, 0.0, 0.0, 1.0] }\n",
            "pose.base_from_camera.translation_m: must be finite metres, got [0.0, 0.0, NaN]",
        ),
        (
            "[pose]\nbase_from_camera = { translation_m = [0.0, 0.0, 1.3], rotation_xyzw = [0.0, 0.0, 0.0, 2.0] }\n",
            "pose.base_from_camera.rotation_xyzw: must be a unit quaternion, norm is 2",
        ),
    ];
    for (i, (text, expected)) in cases.iter().enumerate() {
        let path = write(&dir, &format!("p{i}.toml"), text);
        let err = load(Some(&path), &[]).unwrap_err();
        assert_eq!(err.file, path.display().to_string(), "{err}");
        assert!(err.message.starts_with(expected), "case {i}: {err}");
    }
    let pose = load(None, &[]).unwrap().profile.pose;
    assert_eq!((pose.max_interpolation_gap_ms, pose.max_wait_ms, pose.tolerance_ms), (250.0, 200.0, 50.0));
    assert_eq!(pose.future_tolerance_ms * 1e6, op3dsg_ipc_types::FUTURE_POSE_LIMIT_NS as f64);
}

#[test]
fn llm_section_is_checked_by_field_and_its_key_file_is_a_path() {
    let loaded = load(None, &[]).unwrap();
    assert_eq!(loaded.profile.reasoner.llm, crate::reasoner::llm::LlmConfig::default());
    let dir = tempfile::tempdir().unwrap();
    let path = write(&dir, "robot.toml", "[reasoner]\nkind = \"llm\"\n");
    let err = load(Some(&path), &[]).unwrap_err();
    // Named by the field (the empty base URL comes from the built-in base).
    assert!(err.to_string().ends_with(": reasoner.llm.base_url: required with reasoner.kind = \"llm\""), "{err}");
    let path = write(
        &dir,
        "robot.toml",
        "[reasoner]\nkind = \"llm\"\n[reasoner.llm]\nbase_url = \"http://127.0.0.1:8000/v1\"\nmodel = \"m\"\napi_key_file = \"llm.key\"\nmax_concurrent_calls = 0\n",
    );
    let err = load(Some(&path), &[]).unwrap_err();
    assert!(err.to_string().ends_with("reasoner.llm.max_concurrent_calls: must be within [1, 64], got 0"), "{err}");
    let ok = load(Some(&path), &["reasoner.llm.max_concurrent_calls=2".to_owned()]).unwrap();
    assert_eq!(ok.profile.reasoner.llm.api_key_file, Some(dir.path().join("llm.key")));
}

#[test]
fn text_encoder_is_off_in_the_base_and_checked_by_field() {
    let loaded = load(None, &[]).unwrap();
    assert!(!loaded.profile.text_encoder.enabled);
    assert_eq!(loaded.profile.text_encoder, TextEncoderConfig::default());
    assert_eq!(loaded.profile.onnx, OnnxConfig::default());
    let dir = tempfile::tempdir().unwrap();
    let path = write(&dir, "robot.toml", "[text_encoder]\nenabled = true\nmax_sequence_length = 2\n");
    let err = load(Some(&path), &[]).unwrap_err();
    assert_eq!(
        err.to_string(),
        format!("{}: text_encoder.max_sequence_length: must be within [4, 512], got 2", path.display())
    );
    load(None, &["onnx.execution_provider=cuda".to_owned()]).expect("cuda is a provider (CPU fallback at run time)");
    let err = load(None, &["onnx.execution_provider=tpu".to_owned()]).unwrap_err();
    assert_eq!(err.file, "--set");
    assert!(err.message.starts_with("onnx.execution_provider: unknown variant `tpu`"), "{err}");
}

#[test]
fn toml_syntax_error_names_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(&dir, "bad.toml", "[fusion\n");
    let err = load(Some(&path), &[]).unwrap_err();
    assert_eq!(err.file, path.display().to_string());
}

#[test]
fn the_world_frame_defaults_to_world_and_a_bad_one_names_the_file_and_key() {
    assert_eq!(load(None, &[]).unwrap().profile.world.frame_id, "world");
    let dir = tempfile::tempdir().unwrap();
    let path = write(&dir, "robot.toml", "[world]\nframe_id = \"map\"\n");
    let profile = load(Some(&path), &[]).unwrap().profile;
    assert_eq!((profile.world.frame_id.as_str(), profile.world.up_axis), ("map", crate::world::UpAxis::Z));
    let path = write(&dir, "bad.toml", "[world]\nframe_id = \"base map\"\n");
    let err = load(Some(&path), &[]).unwrap_err();
    assert_eq!(
        err.to_string(),
        format!(
            "{}: world.frame_id: \"base map\" contains ' '; a ROS frame id is a letter, then letters, digits, '_' and '/'",
            path.display()
        )
    );
    let err = load(None, &["world.frame_id=\"\"".to_owned()]).unwrap_err();
    assert!(err.to_string().contains("world.frame_id: must not be empty"), "{err}");
}

// With the feature: without it, a profile that needs Zenoh is refused for that first.
#[cfg(feature = "zenoh")]
#[test]
fn a_zenoh_session_that_can_reach_nothing_is_refused_naming_the_keys() {
    for turn_on in ["zenoh.enabled=true", "detector.kind=\"remote\""] {
        let err = load(None, &[turn_on.to_owned()]).unwrap_err().to_string();
        assert!(err.contains("zenoh.listen: "), "{turn_on}: {err}");
        assert!(err.contains("neither listens (zenoh.listen) nor connects (zenoh.connect)"), "{turn_on}: {err}");
        // Either direction, or scouting, makes it reachable.
        for reach in [
            "zenoh.listen=[\"tcp/127.0.0.1:7447\"]",
            "zenoh.connect=[\"tcp/127.0.0.1:7447\"]",
            "zenoh.multicast_scouting=true",
        ] {
            let loaded = load(None, &[turn_on.to_owned(), reach.to_owned()]);
            assert!(loaded.is_ok(), "{turn_on} with {reach}: {:?}", loaded.err().map(|e| e.to_string()));
        }
    }
    assert!(load(None, &[]).is_ok(), "nothing speaks Zenoh by default");
}

#[test]
fn what_needs_zenoh_is_named_by_its_key() {
    // A build without the feature `zenoh` refuses exactly these, naming the key (Profile::validate).
    let base = load(None, &[]).unwrap().profile;
    assert_eq!(base.needs_zenoh(), None, "the built-in default runs without Zenoh");
    type TurnOn = fn(&mut Profile);
    let cases: [(&str, TurnOn); 5] = [
        ("zenoh.enabled", |p| p.zenoh.enabled = true),
        ("ros2.out", |p| p.ros2.out.markers = true),
        ("ros2.out", |p| p.ros2.out.graph_json = true),
        ("pose.source", |p| p.pose.source = crate::keyframe::PoseSourceKind::Ros2),
        ("detector.kind", |p| p.detector.kind = crate::perception::remote::REMOTE_DETECTOR.to_owned()),
    ];
    for (key, turn_on) in cases {
        let mut profile = base.clone();
        turn_on(&mut profile);
        assert_eq!(profile.needs_zenoh().map(|(k, _)| k), Some(key));
    }
}
