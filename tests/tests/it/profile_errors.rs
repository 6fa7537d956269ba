//! A bad profile stops the real daemon binary with exit code 2 and a message that names the file
//! and the field.

use std::process::Command;

use op3dsg_tests::binary;

fn run_with_profile(text: &str) -> (Option<i32>, String, String) {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("robot.toml");
    std::fs::write(&path, text).expect("write profile");
    let out = Command::new(binary("op3dsgd")).arg("--profile").arg(&path).output().expect("run op3dsgd");
    (out.status.code(), String::from_utf8_lossy(&out.stderr).into_owned(), path.display().to_string())
}

#[test]
fn unknown_key_stops_the_daemon_naming_file_and_field() {
    let (code, stderr, path) = run_with_profile("[fusion]\nvoxel_sise_m = 0.02\n");
    assert_eq!(code, Some(2), "{stderr}");
    assert!(stderr.contains(&format!("{path}: fusion.voxel_sise_m: unknown field")), "{stderr}");
}

#[test]
fn wrong_type_stops_the_daemon_naming_file_and_field() {
    let (code, stderr, path) = run_with_profile("[detector]\nworkers = \"two\"\n");
    assert_eq!(code, Some(2), "{stderr}");
    assert!(stderr.contains(&format!("{path}: detector.workers: invalid type")), "{stderr}");
}

#[test]
fn out_of_range_value_stops_the_daemon_naming_file_and_field() {
    let (code, stderr, path) = run_with_profile("[source.synthetic.depth_noise]\nedge_hole_probability = 1.5\n");
    assert_eq!(code, Some(2), "{stderr}");
    assert!(
        stderr.contains(&format!("{path}: source.synthetic.depth_noise.edge_hole_probability: must be within [0, 1]")),
        "{stderr}"
    );
}

#[test]
fn print_config_shows_the_effective_profile() {
    let out = Command::new(binary("op3dsgd"))
        .args(["--set", "detector.workers=3", "--print-config"])
        .output()
        .expect("run op3dsgd");
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("workers = 3"), "{text}");
    // The oracle preset is expanded into its knobs.
    assert!(text.contains("part_miss_rate"), "{text}");
}
