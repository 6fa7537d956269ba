//! `[text_encoder] enabled = true` makes the real daemon load ONNX Runtime and the model at
//! start-up: with the files (`./scripts/setup-models.sh`, run by `scripts/test.sh`) it starts and
//! runs; with a model path that does not exist it stops at once with exit code 1 and a message
//! naming the file and the script to run.

use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use op3dsg_tests::{binary, unique_prefix};

/// Runs `op3dsgd` to completion, killing it (and failing) after `limit`.
fn run_daemon(args: &[&str], limit: Duration) -> Output {
    let mut child = Command::new(binary("op3dsgd"))
        .args(args)
        .env("OP3DSG_LOG", "info")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn op3dsgd");
    let started = Instant::now();
    loop {
        if child.try_wait().expect("wait op3dsgd").is_some() {
            return child.wait_with_output().expect("collect op3dsgd output");
        }
        if started.elapsed() > limit {
            let _ = child.kill();
            let out = child.wait_with_output().expect("collect op3dsgd output");
            panic!("op3dsgd still running after {limit:?}:\n{}", String::from_utf8_lossy(&out.stderr));
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn missing_model_stops_the_daemon_naming_the_file_and_the_setup_script() {
    let prefix = unique_prefix("te-missing");
    let out = run_daemon(
        &[
            "--prefix",
            &prefix,
            "--max-frames",
            "3",
            "--set",
            "text_encoder.enabled=true",
            "--set",
            "text_encoder.model_path=\"/no/such/minilm.onnx\"",
        ],
        Duration::from_secs(60),
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("cannot start: text encoder: text encoder model"), "{stderr}");
    assert!(stderr.contains("looked for /no/such/minilm.onnx"), "{stderr}");
    assert!(stderr.contains("./scripts/setup-models.sh"), "{stderr}");
}

#[test]
fn enabled_text_encoder_loads_at_start_up_and_the_daemon_runs() {
    let prefix = unique_prefix("te-ok");
    let out = run_daemon(
        &["--prefix", &prefix, "--max-frames", "3", "--set", "text_encoder.enabled=true"],
        Duration::from_secs(120),
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    assert!(stderr.contains("ONNX Runtime loaded"), "{stderr}");
    assert!(stderr.contains("text encoder ready"), "{stderr}");
}
