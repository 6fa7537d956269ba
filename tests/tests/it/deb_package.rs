//! The Debian package `op3dsg` as an operator gets it: built with cargo-deb from the debug build
//! next to this test (`--no-build --profile dev`: CI builds once), installed by dpkg into a
//! scratch root (`dpkg --root DIR --force-script-chrootless`: the maintainer scripts run with
//! `DPKG_ROOT=DIR` and work on DIR's files), and then:
//!
//! - every file lands where the unit and the binaries look (unit, robot profile as a conffile,
//!   profiles, ONNX Runtime, the text encoder, librealsense), and postinst made the user `op3dsg`
//!   (in `video` and `plugdev`; as root only, which `useradd --prefix` needs) and the LLM key file;
//! - `systemd-analyze verify` and `security --offline=true` (exposure at most 3.0) pass on the
//!   installed unit, also with the drop-in `op3dsg-service-user` writes for a login user;
//! - the installed `op3dsgd`, started with the installed `/etc/op3dsg/op3dsgd.toml` and a
//!   librealsense recording, loads librealsense and ONNX Runtime from the scratch root's
//!   `/usr/lib/op3dsg` (no `LD_LIBRARY_PATH`, working directory outside the checkout), stops with
//!   the placing command when the detector model is missing, and, once it is placed, publishes a
//!   graph of the recording that the installed `op3dsg dump` reads, recording into
//!   `$LOGS_DIRECTORY`;
//! - a reinstall keeps an edited conffile; a purge removes it;
//! - `systemd/install.sh --destdir` stages the same files as the package.
//!
//! Needs: cargo-deb (`$CARGO_DEB`, `.deps/cargo-deb/bin/cargo-deb` as `scripts/test.sh` installs
//! it, or on `PATH`), dpkg, systemd-analyze, the venv's pyrealsense2 (to record the `.bag`),
//! `.models/` and `.deps/realsense/` (the package's files), and the YOLOX-nano model from
//! `../shared/data/models/`. Missing cargo-deb or shared data fail the test when `CI=true`.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use op3dsg_tests::{binary, is_root, unique_prefix, wait_for};

/// The PATH dpkg and the maintainer scripts run with (useradd, ldconfig are in sbin).
const SYSTEM_PATH: &str = "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin";
const MAX_EXPOSURE: f64 = 3.0;
const RECORDED: usize = 12;
const FPS: u32 = 10;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").canonicalize().expect("repository root")
}

fn run(what: &str, cmd: &mut Command) -> Output {
    let out = cmd.stdin(Stdio::null()).output().unwrap_or_else(|e| panic!("{what}: cannot run: {e}"));
    assert!(
        out.status.success(),
        "{what} failed ({}):\nstdout:\n{}\nstderr:\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

fn text(out: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr))
}

/// cargo-deb, or `None` (skip, said on stderr) outside CI; a failure in CI.
fn cargo_deb() -> Option<PathBuf> {
    let candidates = [
        std::env::var_os("CARGO_DEB").map(PathBuf::from),
        Some(repo().join(".deps/cargo-deb/bin/cargo-deb")),
        std::env::var_os("PATH")
            .and_then(|paths| std::env::split_paths(&paths).map(|d| d.join("cargo-deb")).find(|p| p.is_file())),
    ];
    if let Some(found) = candidates.into_iter().flatten().find(|p| p.is_file()) {
        return Some(found);
    }
    assert!(
        !op3dsg_shared_data::in_ci(),
        "cargo-deb not found ($CARGO_DEB, .deps/cargo-deb/bin, PATH): scripts/test.sh installs it \
         (cargo install cargo-deb --locked --root .deps/cargo-deb)"
    );
    eprintln!("SKIP: cargo-deb not found (cargo install cargo-deb --locked --root .deps/cargo-deb)");
    None
}

/// `.deb` from the debug build this test belongs to.
fn build_deb(cargo_deb: &Path, out_dir: &Path) -> PathBuf {
    let op3dsgd = binary("op3dsgd");
    let target_dir = op3dsgd.parent().and_then(Path::parent).expect("target dir");
    let deb = out_dir.join("op3dsg.deb");
    let started = Instant::now();
    run(
        "cargo-deb",
        Command::new(cargo_deb)
            .current_dir(repo())
            .env("CARGO_TARGET_DIR", target_dir)
            .args(["-p", "op3dsgd", "--no-build", "--profile", "dev", "--no-dbgsym", "--fast", "--quiet", "--output"])
            .arg(&deb),
    );
    eprintln!("cargo-deb: {:.1} s", started.elapsed().as_secs_f64());
    deb
}

/// An empty system for dpkg: its database, the accounts of a base system and a login user
/// `robot` (uid 1000), and the host's systemd targets (for `systemd-analyze verify`).
fn scratch_root(root: &Path) {
    for dir in ["var/lib/dpkg/info", "var/lib/dpkg/updates", "etc", "usr/lib/systemd/system"] {
        std::fs::create_dir_all(root.join(dir)).expect("mkdir");
    }
    std::fs::write(root.join("var/lib/dpkg/status"), "").expect("status");
    std::fs::write(
        root.join("etc/passwd"),
        "root:x:0:0:root:/root:/bin/bash\nrobot:x:1000:1000:robot:/home/robot:/bin/bash\n",
    )
    .expect("passwd");
    std::fs::write(root.join("etc/group"), "root:x:0:\nvideo:x:44:\nplugdev:x:46:\nrobot:x:1000:\n").expect("group");
    std::fs::write(root.join("etc/shadow"), "").expect("shadow");
    std::fs::write(root.join("etc/gshadow"), "").expect("gshadow");
    // The unit's dependencies (sysinit.target, ...): the host's targets and slices, no more.
    let host = ["/usr/lib/systemd/system", "/lib/systemd/system"]
        .into_iter()
        .map(Path::new)
        .find(|d| d.join("sysinit.target").exists())
        .expect("the host's systemd units (/usr/lib/systemd/system/sysinit.target)");
    for entry in std::fs::read_dir(host).expect("read systemd units").flatten() {
        let path = entry.path();
        let unit = path.extension().is_some_and(|e| e == "target" || e == "slice");
        if unit && path.is_file() {
            std::fs::copy(&path, root.join("usr/lib/systemd/system").join(entry.file_name())).expect("copy unit");
        }
    }
}

fn dpkg(root: &Path, args: &[&str]) -> Output {
    run(
        &format!("dpkg {}", args.join(" ")),
        Command::new("dpkg")
            .env("PATH", SYSTEM_PATH)
            .arg(format!("--root={}", root.display()))
            .args(["--force-script-chrootless", "--force-not-root", "--force-depends", "--log=/dev/null"])
            .args(args),
    )
}

fn check_installed_files(root: &Path, postinst: &str) {
    for file in [
        "usr/bin/op3dsgd",
        "usr/bin/op3dsg",
        "usr/bin/op3dsg-detectd",
        "usr/sbin/op3dsg-service-user",
        "lib/systemd/system/op3dsgd.service",
        "lib/systemd/system/op3dsg-detectd.service",
        "etc/op3dsg/op3dsgd.toml",
        "etc/op3dsg/op3dsg-detectd.toml",
        "usr/share/op3dsg/profiles/base.toml",
        "usr/share/op3dsg/profiles/stretch3-d435i.toml",
        "usr/share/op3dsg/profiles/knowledge/objects.toml",
        "usr/lib/op3dsg/onnxruntime/libonnxruntime.so.1.31.1",
        "usr/lib/op3dsg/minilm/model.onnx",
        "usr/lib/op3dsg/minilm/tokenizer.json",
        "usr/lib/op3dsg/librealsense2.so.2.56",
        "usr/lib/op3dsg/libpystub.so",
        "usr/share/doc/op3dsg/systemd.md",
    ] {
        assert!(root.join(file).is_file(), "/{file} not installed");
    }
    let unit = std::fs::read_to_string(root.join("lib/systemd/system/op3dsgd.service")).expect("unit");
    assert!(unit.contains("\nExecStart=/usr/bin/op3dsgd --profile /etc/op3dsg/op3dsgd.toml\n"), "unit's ExecStart");
    assert!(unit.contains("\nLogsDirectory=op3dsg\n") && unit.contains("\nRuntimeDirectory=op3dsg\n"));
    let profile = std::fs::read_to_string(root.join("etc/op3dsg/op3dsgd.toml")).expect("robot profile");
    assert!(profile.contains("\nextends = \"stretch3-d435i.toml\"\n"), "the robot profile extends the Stretch's");
    let conffiles = std::fs::read_to_string(root.join("var/lib/dpkg/info/op3dsg.conffiles")).expect("conffiles");
    assert_eq!(conffiles.trim(), "/etc/op3dsg/op3dsgd.toml\n/etc/op3dsg/op3dsg-detectd.toml");
    let worker_unit =
        std::fs::read_to_string(root.join("lib/systemd/system/op3dsg-detectd.service")).expect("the worker's unit");
    assert!(
        worker_unit.contains("\nExecStart=/usr/bin/op3dsg-detectd --profile /etc/op3dsg/op3dsg-detectd.toml\n"),
        "the worker unit's ExecStart"
    );
    let key = root.join("etc/op3dsg/credentials/llm-api-key");
    let mode = std::os::unix::fs::PermissionsExt::mode(&std::fs::metadata(&key).expect("LLM key file").permissions());
    assert_eq!(mode & 0o777, 0o600, "the LLM key file is root's only");
    assert!(
        postinst.contains("sudo install -D -m 0644 yolox_nano.onnx /etc/op3dsg/models/yolox_nano.onnx"),
        "{postinst}"
    );
    let passwd = std::fs::read_to_string(root.join("etc/passwd")).expect("passwd");
    let group = std::fs::read_to_string(root.join("etc/group")).expect("group");
    if is_root() {
        let user = passwd.lines().find(|l| l.starts_with("op3dsg:")).expect("postinst created the user op3dsg");
        assert!(user.ends_with(":/nonexistent:/usr/sbin/nologin"), "{user}");
        let uid: u32 = user.split(':').nth(2).and_then(|u| u.parse().ok()).expect("uid");
        assert!(uid < 1000, "a system user: {user}");
        for g in ["video", "plugdev"] {
            let line = group.lines().find(|l| l.starts_with(&format!("{g}:"))).expect("group");
            assert!(line.ends_with(":op3dsg"), "op3dsg in {g}: {line}");
        }
        assert!(group.lines().any(|l| l.starts_with("op3dsg:")), "its own group");
    } else {
        assert!(postinst.contains("no user op3dsg created"), "{postinst}");
        eprintln!("not root: the user op3dsg was not created in the scratch root (useradd --prefix needs root)");
    }
}

/// `systemd-analyze verify` clean, and the exposure score, of the daemon's unit.
fn analyze(root: &Path) -> f64 {
    analyze_unit(root, "op3dsgd.service")
}

/// `systemd-analyze verify` clean, and the exposure score, of `unit` as installed under `root`.
fn analyze_unit(root: &Path, unit: &str) -> f64 {
    let root_arg = format!("--root={}", root.display());
    let verify = run("systemd-analyze verify", Command::new("systemd-analyze").args(["verify", &root_arg, unit]));
    assert!(text(&verify).trim().is_empty(), "systemd-analyze verify {unit} printed:\n{}", text(&verify));
    let security = run(
        "systemd-analyze security",
        Command::new("systemd-analyze").args(["security", "--offline=true", &root_arg, unit]),
    );
    let report = text(&security);
    let line = report.lines().find(|l| l.contains("Overall exposure level")).expect("an exposure line");
    let score = line.split(':').nth(1).and_then(|s| s.split_whitespace().next()).and_then(|s| s.parse().ok());
    let score: f64 = score.unwrap_or_else(|| panic!("no score in {line:?}"));
    assert!(score <= MAX_EXPOSURE, "exposure {score} > {MAX_EXPOSURE}:\n{report}");
    score
}

/// `op3dsg-service-user` in the scratch root: a login user gets the drop-in and logind's
/// RemoveIPC=no, the unit still verifies with it, `--reset` removes both; bad input is refused.
fn check_service_user(root: &Path) {
    let script = root.join("usr/sbin/op3dsg-service-user");
    let root_arg = root.display().to_string();
    let out = run("op3dsg-service-user robot", Command::new(&script).args(["--root", &root_arg, "robot"]));
    let said = text(&out);
    assert!(said.contains("sudo systemctl daemon-reload && sudo systemctl restart op3dsgd"), "{said}");
    let dropin = root.join("etc/systemd/system/op3dsgd.service.d/user.conf");
    let conf = std::fs::read_to_string(&dropin).expect("drop-in written");
    assert!(
        conf.contains("\nUser=robot\nGroup=robot\n") && conf.contains("\nSupplementaryGroups=video plugdev\n"),
        "{conf}"
    );
    let logind = std::fs::read_to_string(root.join("etc/systemd/logind.conf.d/op3dsg.conf")).expect("logind drop-in");
    assert!(logind.contains("[Login]\nRemoveIPC=no\n"), "{logind}");
    let score = analyze(root);
    let root_flag = format!("--root={root_arg}");
    let shown = run(
        "systemd-analyze cat-config",
        Command::new("systemd-analyze").args([
            root_flag.as_str(),
            "cat-config",
            "systemd/system/op3dsgd.service.d/user.conf",
        ]),
    );
    assert!(text(&shown).contains("User=robot"), "{}", text(&shown));
    eprintln!("exposure with the login user's drop-in: {score}");

    let unknown = Command::new(&script).args(["--root", &root_arg, "nosuchuser"]).output().expect("run");
    assert_eq!(unknown.status.code(), Some(1));
    assert!(text(&unknown).contains("no user 'nosuchuser'"), "{}", text(&unknown));
    let no_args = Command::new(&script).args(["--root", &root_arg]).output().expect("run");
    assert_eq!(no_args.status.code(), Some(2), "{}", text(&no_args));

    run("op3dsg-service-user --reset", Command::new(&script).args(["--root", &root_arg, "--reset"]));
    assert!(!dropin.exists() && !root.join("etc/systemd/logind.conf.d/op3dsg.conf").exists());
}

/// The installed daemon, killed on drop.
struct Installed(Child);

impl Drop for Installed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// The installed binary as the unit runs it: no `LD_LIBRARY_PATH` (cargo's test environment and
/// scripts/test.sh set one), the working directory outside the checkout.
fn installed(root: &Path, name: &str, cwd: &Path) -> Command {
    let mut cmd = Command::new(root.join("usr/bin").join(name));
    cmd.current_dir(cwd).env_remove("LD_LIBRARY_PATH").env_remove("OP3DSG_ORT_LIB").env_remove("OP3DSG_PROFILE");
    cmd
}

fn record_bag(dir: &Path) -> PathBuf {
    let python = repo().join(".venv/bin/python");
    assert!(python.exists(), "{} missing: run ./scripts/setup-python.sh (it installs pyrealsense2)", python.display());
    let bag = dir.join("playback.bag");
    run(
        "record a .bag",
        Command::new(python).arg(repo().join("drivers/realsense/tests/record_software_device.py")).arg(&bag).args([
            "--frames",
            &RECORDED.to_string(),
            "--width",
            "96",
            "--height",
            "72",
            "--fps",
            &FPS.to_string(),
            // As the head camera records it: the Stretch profile plays only a D435I's recording.
            "--name",
            "Intel RealSense D435I",
            "--serial",
            "135322062222",
        ]),
    );
    bag
}

fn check_daemon(root: &Path, work: &Path) {
    let profile = root.join("etc/op3dsg/op3dsgd.toml");
    let profile_arg = profile.display().to_string();
    // --print-config: the extends found among the installed profiles, the files in /usr/lib/op3dsg.
    let printed = text(&run(
        "op3dsgd --print-config",
        installed(root, "op3dsgd", work).args(["--profile", &profile_arg, "--print-config"]),
    ));
    let stretch = root.join("usr/share/op3dsg/profiles/stretch3-d435i.toml");
    assert!(printed.contains(&format!("<- {} <- {profile_arg}", stretch.display())), "{printed}");
    let lib = root.join("usr/lib/op3dsg");
    for file in ["onnxruntime/libonnxruntime.so.1.31.1", "minilm/model.onnx", "minilm/tokenizer.json"] {
        assert!(printed.contains(&format!("\"{}\"", lib.join(file).display())), "{file} from the package:\n{printed}");
    }
    let version = text(&run("op3dsgd --version", installed(root, "op3dsgd", work).arg("--version")));
    assert!(version.contains("realsense"), "{version}");

    let bag = record_bag(work);
    let bag_set = format!("source.realsense.bag={:?}", bag.display().to_string());
    let model = root.join("etc/op3dsg/models/yolox_nano.onnx");
    // No model placed: a start error naming the path and the command that places it.
    let missing = installed(root, "op3dsgd", work)
        .args(["--prefix", &unique_prefix("deb-nomodel"), "--profile", &profile_arg, "--set", &bag_set])
        .stdin(Stdio::null())
        .output()
        .expect("run op3dsgd");
    let said = text(&missing);
    assert_eq!(missing.status.code(), Some(1), "{said}");
    assert!(said.contains(&format!("looked for {}", model.display())), "{said}");
    assert!(said.contains("sudo install -D -m 0644 yolox_nano.onnx /etc/op3dsg/models/yolox_nano.onnx"), "{said}");

    let Some(shared_model) = op3dsg_shared_data::shared_data("models/yolox_nano/yolox_nano.onnx") else { return };
    std::fs::create_dir_all(model.parent().expect("models dir")).expect("mkdir");
    std::fs::copy(shared_model, &model).expect("place the model");
    check_worker(root, work);
    let prefix = unique_prefix("deb");
    let logs = work.join("var/log/op3dsg");
    std::fs::create_dir_all(&logs).expect("logs dir");
    // The recording has no poses: a fixed camera (pose.source = "frame") instead of the nav stack.
    let child = installed(root, "op3dsgd", work)
        .args(["--prefix", &prefix, "--profile", &profile_arg, "--set", &bag_set])
        .args(["--set", "pose.source=\"frame\"", "--set", "record.enabled=true", "--set", "run.exit_at_end=false"])
        .args(["--set", "source.realsense.world_from_camera={ translation_m = [0.0, 0.0, 1.0], rotation_xyzw = [0.0, 0.0, 0.0, 1.0] }"])
        .env("LOGS_DIRECTORY", &logs)
        .env("OP3DSG_LOG", "warn")
        .stdin(Stdio::null())
        .spawn()
        .expect("spawn the installed op3dsgd");
    let mut daemon = Installed(child);
    // The installed `op3dsg dump` reads a graph stamped with a frame of the recording.
    // (Real-time playback on a loaded machine may drop frame sets: any frame of the file counts.)
    let frame_ms: Vec<f64> = (0..RECORDED).map(|i| 1000.0 + i as f64 * 1000.0 / f64::from(FPS)).collect();
    let dumped =
        wait_for("the installed op3dsg dump to show a graph of the recording", Duration::from_secs(60), || {
            if let Ok(Some(status)) = daemon.0.try_wait() {
                panic!("the installed op3dsgd exited with {status}");
            }
            let out = installed(root, "op3dsg", work).args(["dump", "--prefix", &prefix]).output().ok()?;
            let shown = String::from_utf8_lossy(&out.stdout).into_owned();
            let stamp_ns: f64 = shown.split("stamp ").nth(1)?.split(' ').next()?.parse().ok()?;
            let of_the_recording = frame_ms.iter().any(|ms| (stamp_ns / 1e6 - ms).abs() < 1e-3);
            (out.status.success() && of_the_recording).then_some(shown)
        });
    assert!(dumped.starts_with("graph version "), "{dumped}");
    let maps = std::fs::read_to_string(format!("/proc/{}/maps", daemon.0.id())).expect("maps");
    for lib_file in ["librealsense2.so.2.56", "onnxruntime/libonnxruntime.so.1.31.1"] {
        let expected = lib.join(lib_file).display().to_string();
        assert!(maps.contains(&expected), "{expected} not loaded; the daemon's libraries:\n{}", libraries(&maps));
    }
    run("kill -TERM", Command::new("kill").args(["-TERM", &daemon.0.id().to_string()]));
    let status = wait_for("the daemon to stop", Duration::from_secs(30), || daemon.0.try_wait().ok().flatten());
    assert!(status.success(), "{status}");
    let recordings: Vec<_> = std::fs::read_dir(&logs).expect("logs").flatten().map(|e| e.path()).collect();
    assert!(
        recordings.iter().any(|p| p.extension().is_some_and(|e| e == "mcap")),
        "no recording in $LOGS_DIRECTORY: {recordings:?}"
    );
}

/// The installed detection worker with its installed profile: refused (exit 2, naming the file)
/// until `[zenoh]` says how a robot reaches it; then it loads the Stretch profile's YOLOX with
/// ONNX Runtime from the scratch root's `/usr/lib/op3dsg` and serves until SIGTERM (exit 0).
fn check_worker(root: &Path, work: &Path) {
    let profile = root.join("etc/op3dsg/op3dsg-detectd.toml");
    let profile_arg = profile.display().to_string();
    let refused = installed(root, "op3dsg-detectd", work).args(["--profile", &profile_arg]).output().expect("run");
    let said = text(&refused);
    assert_eq!(refused.status.code(), Some(2), "{said}");
    assert!(said.contains(&profile_arg) && said.contains("zenoh.connect"), "{said}");
    let port = std::net::TcpListener::bind("127.0.0.1:0").expect("a free port").local_addr().expect("port").port();
    let child = installed(root, "op3dsg-detectd", work)
        .args(["--profile", &profile_arg, "--id", "deb-test"])
        .args(["--set", &format!("zenoh.connect=[\"tcp/127.0.0.1:{port}\"]")])
        .args(["--set", &format!("zenoh.key_prefix=\"{}\"", unique_prefix("deb-worker"))])
        .env("OP3DSG_LOG", "info")
        .stdin(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn the installed op3dsg-detectd");
    let mut worker = Installed(child);
    let ort = root.join("usr/lib/op3dsg/onnxruntime/libonnxruntime.so.1.31.1").display().to_string();
    wait_for("the installed worker to load ONNX Runtime from the package", Duration::from_secs(60), || {
        if let Ok(Some(status)) = worker.0.try_wait() {
            panic!("the installed op3dsg-detectd exited with {status}");
        }
        let maps = std::fs::read_to_string(format!("/proc/{}/maps", worker.0.id())).ok()?;
        maps.contains(&ort).then_some(())
    });
    // Serving: still running a moment after the model is loaded.
    std::thread::sleep(Duration::from_secs(1));
    assert!(worker.0.try_wait().expect("wait").is_none(), "the worker serves");
    run("kill -TERM", Command::new("kill").args(["-TERM", &worker.0.id().to_string()]));
    let status = wait_for("the worker to stop", Duration::from_secs(30), || worker.0.try_wait().ok().flatten());
    let mut log = String::new();
    if let Some(mut stderr) = worker.0.stderr.take() {
        let _ = std::io::Read::read_to_string(&mut stderr, &mut log);
    }
    assert!(status.success(), "{status}: {log}");
    assert!(log.contains("serving detection"), "{log}");
}

/// Every file under `root`, as an absolute path of the installed system, without dpkg's own
/// database and the host's units copied in for `systemd-analyze`.
fn files_under(root: &Path) -> Vec<String> {
    fn walk(dir: &Path, root: &Path, out: &mut Vec<String>) {
        for entry in std::fs::read_dir(dir).expect("read dir").flatten() {
            let path = entry.path();
            if path.is_dir() {
                walk(&path, root, out);
            } else {
                out.push(format!("/{}", path.strip_prefix(root).expect("below root").display()));
            }
        }
    }
    let mut files = Vec::new();
    walk(root, root, &mut files);
    files.retain(|f| {
        !f.starts_with("/var/lib/dpkg/") && !f.starts_with("/usr/lib/systemd/") && !f.starts_with("/etc/passwd")
    });
    files.retain(|f| !["/etc/group", "/etc/shadow", "/etc/gshadow"].iter().any(|db| f.starts_with(db)));
    files.sort();
    files
}

/// `systemd/install.sh --destdir` (for distributions without dpkg) stages the package's files,
/// less only the Debian copyright file.
fn check_install_sh_matches(packaged: &[String], work: &Path) {
    let staged = work.join("install-sh");
    let op3dsgd = binary("op3dsgd");
    let bin_dir = op3dsgd.parent().expect("bin dir").display().to_string();
    let staged_arg = staged.display().to_string();
    run(
        "systemd/install.sh --destdir",
        Command::new(repo().join("systemd/install.sh")).args([
            "--no-build",
            "--bin-dir",
            &bin_dir,
            "--destdir",
            &staged_arg,
        ]),
    );
    let expected: Vec<&String> = packaged.iter().filter(|f| *f != "/usr/share/doc/op3dsg/copyright").collect();
    let got = files_under(&staged);
    assert_eq!(got.iter().collect::<Vec<_>>(), expected, "install.sh and the package install the same files");
}

fn libraries(maps: &str) -> String {
    let mut libs: Vec<&str> =
        maps.lines().filter_map(|l| l.split_whitespace().nth(5)).filter(|p| p.contains(".so")).collect();
    libs.sort_unstable();
    libs.dedup();
    libs.join("\n")
}

#[test]
fn the_package_installs_a_service_that_publishes_graphs() {
    let Some(cargo_deb) = cargo_deb() else { return };
    let started = Instant::now();
    let dir = tempfile::tempdir().expect("tempdir");
    let deb = build_deb(&cargo_deb, dir.path());
    let root = dir.path().join("root");
    scratch_root(&root);
    let postinst = text(&dpkg(&root, &["-i", &deb.display().to_string()]));
    check_installed_files(&root, &postinst);
    let work = dir.path().join("work");
    std::fs::create_dir_all(&work).expect("work dir");
    check_install_sh_matches(&files_under(&root), &work);
    let score = analyze(&root);
    eprintln!("installed unit: systemd-analyze verify clean, exposure {score}");
    let worker_score = analyze_unit(&root, "op3dsg-detectd.service");
    eprintln!("installed detection worker unit: systemd-analyze verify clean, exposure {worker_score}");
    check_service_user(&root);
    check_daemon(&root, &work);

    // Upgrade (a reinstall): the edited conffile stays; purge removes it and the key, not the map.
    let profile = root.join("etc/op3dsg/op3dsgd.toml");
    let edited = format!("{}\n# edited on the robot\n", std::fs::read_to_string(&profile).expect("profile"));
    std::fs::write(&profile, &edited).expect("edit");
    dpkg(&root, &["-i", &deb.display().to_string()]);
    assert_eq!(std::fs::read_to_string(&profile).expect("profile"), edited, "the robot's profile is kept on upgrade");
    // What the robot built and recorded survives a purge.
    let snapshot = root.join("var/lib/op3dsg/snapshots/map.snapshot");
    let recording = root.join("var/log/op3dsg/field.mcap");
    for kept in [&snapshot, &recording] {
        std::fs::create_dir_all(kept.parent().expect("a folder")).expect("state folders");
        std::fs::write(kept, b"kept").expect("a file of the robot's");
    }
    let purged = text(&dpkg(&root, &["--purge", "op3dsg"]));
    assert!(snapshot.exists() && recording.exists(), "purge keeps the map and the recordings");
    assert!(purged.contains("kept") && purged.contains("/var/lib/op3dsg"), "purge says what it kept: {purged}");
    assert!(
        !profile.exists() && !root.join("etc/op3dsg/credentials/llm-api-key").exists(),
        "purge removes /etc/op3dsg"
    );
    assert!(!root.join("usr/bin/op3dsgd").exists() && !root.join("usr/lib/op3dsg/librealsense2.so.2.56").exists());
    eprintln!("package test: {:.1} s", started.elapsed().as_secs_f64());
}
