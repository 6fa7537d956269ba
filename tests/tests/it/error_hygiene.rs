//! What a user reads when an input is wrong: a table of bad inputs to the real binaries, each
//! message naming the input and the fix, with no source path, no `Debug` dump and no escape code
//! (standard error is a pipe here, not a terminal). And the precedence of settings: the command
//! line over the environment over the profile, shown by `--print-config`.

use std::net::TcpListener;
use std::process::Command;

use op3dsg_tests::binary;

struct Case {
    what: &'static str,
    program: &'static str,
    args: Vec<String>,
    /// Each must appear in standard error: the input, and the fix.
    says: Vec<String>,
}

fn case(what: &'static str, program: &'static str, args: &[&str], says: &[&str]) -> Case {
    Case {
        what,
        program,
        args: args.iter().map(|a| (*a).to_owned()).collect(),
        says: says.iter().map(|s| (*s).to_owned()).collect(),
    }
}

/// Why `text` is not fit for a user, if it is not.
fn unfit(text: &str) -> Option<String> {
    if text.contains('\u{1b}') {
        return Some("an escape code".into());
    }
    // A source location: `/path/file.rs:123`.
    if let Some(at) = text.find(".rs:")
        && text[at + 4..].starts_with(|c: char| c.is_ascii_digit())
    {
        return Some(format!("a source location near {:?}", &text[at.saturating_sub(40)..(at + 8).min(text.len())]));
    }
    // A Debug dump: `Name { field: ...` or `Variant(Message ...`.
    for word in text.split(|c: char| !c.is_alphanumeric() && c != '_').filter(|w| w.len() > 2) {
        let camel = word.starts_with(|c: char| c.is_ascii_uppercase()) && word.chars().any(|c| c.is_ascii_lowercase());
        if camel && (text.contains(&format!("{word} {{ ")) || text.contains(&format!("{word}(Message"))) {
            return Some(format!("a Debug dump of {word}"));
        }
    }
    for dump in ["Some(", "Err(", "Ok(\""] {
        if text.contains(dump) {
            return Some(format!("a Debug dump ({dump})"));
        }
    }
    None
}

#[test]
fn every_bad_input_is_named_with_its_fix_in_plain_text() {
    let dir = tempfile::tempdir().expect("temporary folder");
    let missing = dir.path().join("missing.toml").display().to_string();
    let record = dir.path().join("nothing.mcap").display().to_string();
    let busy = TcpListener::bind("127.0.0.1:0").expect("bind a port");
    let busy_listen = format!("zenoh.listen=[\"tcp/127.0.0.1:{}\"]", busy.local_addr().expect("port").port());
    let cases = [
        case(
            "a list given without brackets and quotes",
            "op3dsgd",
            &["--set", "zenoh.listen=tcp/127.0.0.1:7447", "--print-config"],
            &["zenoh.listen", "'tcp/127.0.0.1:7447' is not a TOML value", "write a list in brackets"],
        ),
        case("a profile that is not there", "op3dsgd", &["--profile", &missing], &[&missing]),
        case(
            "a number that is not one",
            "op3dsgd",
            &["--set", "detector.workers=\"two\"", "--print-config"],
            &["detector.workers", "invalid type"],
        ),
        case(
            "a Zenoh endpoint without its protocol",
            "op3dsg",
            &["dump", "--zenoh", "127.0.0.1:7447", "--key-prefix", "op3dsg/x", "--timeout-s", "1"],
            &["127.0.0.1:7447", "<protocol>/<address>", "tcp/127.0.0.1:7447"],
        ),
        case(
            "a Zenoh port another process holds",
            "op3dsgd",
            &["--set", "zenoh.enabled=true", "--set", &busy_listen, "--max-frames", "1"],
            &["zenoh.listen"],
        ),
        case("a recording that is not there", "op3dsg", &["record", "info", &record], &[&record]),
        case(
            "a prefix no daemon serves",
            "op3dsg",
            &["--prefix", "op3dsg-x-nobody", "dump", "--timeout-s", "1"],
            &["op3dsg-x-nobody", "no op3dsgd is serving"],
        ),
        case("a snapshot folder that is not there", "op3dsg", &["map", "info", "--dir", &missing], &[&missing]),
    ];
    let mut failures = Vec::new();
    for case in &cases {
        let out = Command::new(binary(case.program))
            .args(&case.args)
            .env("OP3DSG_LOG", "warn")
            .env_remove("OP3DSG_PREFIX")
            .output()
            .expect("run the binary");
        let stderr = String::from_utf8_lossy(&out.stderr);
        if out.status.success() {
            failures.push(format!("{}: {} {:?} succeeded", case.what, case.program, case.args));
            continue;
        }
        for says in &case.says {
            if !stderr.contains(says.as_str()) {
                failures.push(format!("{}: no {says:?} in:\n{stderr}", case.what));
            }
        }
        if let Some(why) = unfit(&stderr) {
            failures.push(format!("{}: {why} in:\n{stderr}", case.what));
        }
    }
    drop(busy);
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
}

#[test]
fn the_command_line_wins_over_the_environment_which_wins_over_the_profile() {
    let dir = tempfile::tempdir().expect("temporary folder");
    let profile = dir.path().join("robot.toml");
    std::fs::write(&profile, "[ipc]\nprefix = \"from-file\"\n").expect("write the profile");
    let print = |env: Option<&str>, args: &[&str]| -> String {
        let mut command = Command::new(binary("op3dsgd"));
        command.arg("--profile").arg(&profile).args(args).arg("--print-config").env_remove("OP3DSG_PREFIX");
        if let Some(prefix) = env {
            command.env("OP3DSG_PREFIX", prefix);
        }
        let out = command.output().expect("run op3dsgd --print-config");
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let origin = |text: &str| -> String {
        let line = text.lines().find(|l| l.trim_start_matches('#').trim_start().starts_with("ipc.prefix "));
        line.unwrap_or_else(|| panic!("no origin line for ipc.prefix:\n{text}"))
            .rsplit("<- ")
            .next()
            .unwrap()
            .to_owned()
    };
    let value = |text: &str| -> String {
        let line = text.lines().find(|l| l.starts_with("prefix = ")).expect("prefix in the effective profile");
        line.trim_start_matches("prefix = ").trim_matches('"').to_owned()
    };
    let file = print(None, &[]);
    assert_eq!((value(&file), origin(&file)), ("from-file".to_owned(), profile.display().to_string()));
    let env = print(Some("from-env"), &[]);
    assert_eq!((value(&env), origin(&env)), ("from-env".to_owned(), "OP3DSG_PREFIX".to_owned()));
    assert!(env.contains(&format!("{} <- OP3DSG_PREFIX", profile.display())), "{env}");
    let set = print(Some("from-env"), &["--set", "ipc.prefix=\"from-set\""]);
    assert_eq!((value(&set), origin(&set)), ("from-set".to_owned(), "--set".to_owned()));
    let flag = print(Some("from-env"), &["--prefix", "from-flag"]);
    assert_eq!((value(&flag), origin(&flag)), ("from-flag".to_owned(), "--set".to_owned()));
}
