//! Every command the docs show exists, and the command and profile references are complete.
//!
//! Reads `README.md`, every `docs/*.md` and `systemd/README.md`: the command lines of each fenced
//! `sh` block (`\` continuations joined, comments and a leading `$ ` stripped, `VAR=value`
//! assignments and the wrappers `sudo`, `nice -n N`, `taskset -c N`, `env`, `time`, `exec`,
//! `nohup` skipped; pipes, `&&`, `||`, `;` and `&` split a line into commands), and every inline
//! code span that starts with `op3dsg`, `op3dsgd` or `cargo` (a reference table's synopsis marks
//! `[`, `]`, `...`, `<placeholder>` taken out). Each command is checked:
//!
//! - `op3dsg` / `op3dsgd` / `op3dsg-detectd` (bare, `target/<profile>/op3dsg*`, `/usr/bin/op3dsg*`, or
//!   `cargo run ... --bin op3dsgd -- args`): the binary built from this checkout, given the same
//!   subcommand words and `--help`, exits 0, and every `--flag` / `-f` the line uses is an option
//!   in that help; every `--set KEY=VALUE` names a key the profile accepts;
//! - `./scripts/*.sh` and `systemd/*.sh`: the file exists and is executable;
//! - `cargo`: `-p X` names a workspace package, `--bin` / `--example` / `--test` / `--bench` a
//!   target of it, `--features` a feature of it;
//! - `python`: a `.py` file it names exists.
//!
//! Anything else (systemctl, pip, journalctl, ...) is not checked. Every failure names the doc
//! file and line. The reference page (`docs/robot.md`) must also have a table row for every
//! subcommand with every option its `--help` lists, and its profile-key table every key of
//! `op3dsgd --print-config` and no key the profile would refuse. Relative links must resolve,
//! anchors included.
//!
//! Needs `op3dsg` and `op3dsgd` built (`cargo build --bin op3dsg --bin op3dsgd`); no camera,
//! network or `../shared`.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::process::Command;

use op3dsg_tests::binary;

/// The repository root.
fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("tests/ has a parent").to_path_buf()
}

/// The pages whose `sh` blocks are checked, relative to the root.
fn doc_files() -> Vec<String> {
    let root = root();
    let mut files = vec!["README.md".to_owned()];
    let mut docs: Vec<String> = std::fs::read_dir(root.join("docs"))
        .expect("read docs/")
        .filter_map(|entry| entry.ok().map(|e| e.file_name().to_string_lossy().into_owned()))
        .filter(|name| name.ends_with(".md"))
        .map(|name| format!("docs/{name}"))
        .collect();
    docs.sort();
    files.extend(docs);
    if root.join("systemd/README.md").exists() {
        files.push("systemd/README.md".to_owned());
    }
    files
}

/// One command line of a doc: where it starts and its text, continuations joined.
#[derive(Debug)]
struct DocLine {
    file: String,
    line: usize,
    text: String,
    /// Whether it is an inline code span rather than a line of an `sh` block.
    inline: bool,
    /// Whether it is a cell of a Markdown table (a command reference row).
    table_row: bool,
}

impl DocLine {
    fn at(&self) -> String {
        format!("{}:{}", self.file, self.line)
    }
}

/// The command lines of every fenced `sh` block of `text`.
fn sh_lines(file: &str, text: &str) -> Vec<DocLine> {
    let mut lines = Vec::new();
    let mut in_sh = false;
    let mut in_other = false;
    let mut pending: Option<DocLine> = None;
    for (index, raw) in text.lines().enumerate() {
        let trimmed = raw.trim();
        if let Some(lang) = trimmed.strip_prefix("```") {
            if in_sh || in_other {
                in_sh = false;
                in_other = false;
                if let Some(open) = pending.take() {
                    lines.push(open);
                }
            } else if matches!(lang.trim(), "sh" | "bash" | "shell") {
                in_sh = true;
            } else {
                in_other = true;
            }
            continue;
        }
        if !in_sh {
            continue;
        }
        let (body, continues) = match trimmed.strip_suffix('\\') {
            Some(body) => (body, true),
            None => (trimmed, false),
        };
        let body = body.strip_prefix("$ ").unwrap_or(body);
        match pending.as_mut() {
            Some(open) => {
                open.text.push(' ');
                open.text.push_str(body);
            }
            None => {
                pending = Some(DocLine {
                    file: file.to_owned(),
                    line: index + 1,
                    text: body.to_owned(),
                    inline: false,
                    table_row: false,
                })
            }
        }
        if !continues && let Some(done) = pending.take() {
            lines.push(done);
        }
    }
    lines.retain(|l| !l.text.trim().is_empty());
    lines
}

/// Splits a shell line into commands (at `|`, `||`, `&&`, `;`, `&`), each a list of words with
/// quotes removed; a `#` at the start of a word ends the line; redirections and their targets
/// are left out.
fn split_commands(line: &str) -> Vec<Vec<String>> {
    let mut commands = Vec::new();
    let mut words: Vec<String> = Vec::new();
    let mut word = String::new();
    let mut in_word = false;
    let mut skip_next_word = false;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '\'' => {
                in_word = true;
                for q in chars.by_ref() {
                    if q == '\'' {
                        break;
                    }
                    word.push(q);
                }
            }
            '"' => {
                in_word = true;
                while let Some(q) = chars.next() {
                    match q {
                        '"' => break,
                        '\\' => {
                            if let Some(escaped) = chars.next() {
                                word.push(escaped);
                            }
                        }
                        _ => word.push(q),
                    }
                }
            }
            '\\' => {
                in_word = true;
                if let Some(escaped) = chars.next() {
                    word.push(escaped);
                }
            }
            ' ' | '\t' => end_word(&mut word, &mut in_word, &mut words, &mut skip_next_word),
            '#' if !in_word => break,
            '|' | '&' | ';' => {
                if c == '&' && chars.peek() == Some(&'>') {
                    // `&>file`: a redirection.
                    chars.next();
                    end_word(&mut word, &mut in_word, &mut words, &mut skip_next_word);
                    skip_next_word = true;
                    continue;
                }
                if (c == '|' || c == '&') && chars.peek() == Some(&c) {
                    chars.next();
                }
                end_word(&mut word, &mut in_word, &mut words, &mut skip_next_word);
                if !words.is_empty() {
                    commands.push(std::mem::take(&mut words));
                }
            }
            '>' | '<' => {
                // `2>` / `1>`: the digit belongs to the redirection.
                if in_word && (word == "1" || word == "2") {
                    word.clear();
                    in_word = false;
                }
                end_word(&mut word, &mut in_word, &mut words, &mut skip_next_word);
                while chars.peek().is_some_and(|n| *n == '>' || *n == '&') {
                    chars.next();
                }
                if chars.peek().is_some_and(char::is_ascii_digit) {
                    // `2>&1`: no target word follows.
                    chars.next();
                } else {
                    skip_next_word = true;
                }
            }
            _ => {
                in_word = true;
                word.push(c);
            }
        }
    }
    end_word(&mut word, &mut in_word, &mut words, &mut skip_next_word);
    if !words.is_empty() {
        commands.push(words);
    }
    commands
}

/// Ends the word being read: kept in `words`, or dropped when it is a redirection's target.
fn end_word(word: &mut String, in_word: &mut bool, words: &mut Vec<String>, skip: &mut bool) {
    if *in_word {
        if *skip {
            *skip = false;
        } else {
            words.push(std::mem::take(word));
        }
    }
    word.clear();
    *in_word = false;
}

/// The command without leading `VAR=value` assignments and wrappers (`sudo`, `nice -n N`,
/// `taskset -c N`, `env`, `time`, `exec`, `nohup`).
fn strip_wrappers(words: &[String]) -> &[String] {
    let mut rest = words;
    loop {
        let Some(first) = rest.first() else { return rest };
        let is_assignment = first.split_once('=').is_some_and(|(name, _)| {
            !name.is_empty() && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') && !first.starts_with('-')
        });
        if is_assignment {
            rest = &rest[1..];
            continue;
        }
        match first.as_str() {
            "sudo" | "env" | "time" | "exec" | "nohup" => {
                let takes_value = first == "sudo";
                rest = &rest[1..];
                while let Some(flag) = rest.first().filter(|w| w.starts_with('-')) {
                    // sudo's -u USER, -g GROUP: the next word is the option's.
                    let skip = if takes_value && (flag == "-u" || flag == "-g") { 2 } else { 1 };
                    rest = &rest[skip.min(rest.len())..];
                }
            }
            "nice" => {
                rest = &rest[1..];
                if rest.first().is_some_and(|w| w == "-n") {
                    rest = &rest[2.min(rest.len())..];
                } else if rest.first().is_some_and(|w| w.starts_with('-')) {
                    rest = &rest[1..];
                }
            }
            "taskset" => {
                rest = &rest[1..];
                if rest.first().is_some_and(|w| w == "-c") {
                    rest = &rest[2.min(rest.len())..];
                } else if !rest.is_empty() {
                    rest = &rest[1..];
                }
            }
            _ => return rest,
        }
    }
}

/// The workspace's packages: name → targets and features, read from the `Cargo.toml` files.
#[derive(Debug, Default)]
struct Package {
    bins: BTreeSet<String>,
    examples: BTreeSet<String>,
    tests: BTreeSet<String>,
    benches: BTreeSet<String>,
    features: BTreeSet<String>,
}

fn stems(dir: &Path) -> BTreeSet<String> {
    let Ok(entries) = std::fs::read_dir(dir) else { return BTreeSet::new() };
    entries
        .filter_map(Result::ok)
        .filter_map(|entry| {
            let path = entry.path();
            if path.extension().is_some_and(|e| e == "rs") {
                path.file_stem().map(|s| s.to_string_lossy().into_owned())
            } else if path.join("main.rs").exists() {
                path.file_name().map(|s| s.to_string_lossy().into_owned())
            } else {
                None
            }
        })
        .collect()
}

fn quoted(value: &str) -> Option<String> {
    let value = value.trim();
    let inner = value.strip_prefix('"')?;
    Some(inner[..inner.find('"')?].to_owned())
}

fn workspace_packages() -> BTreeMap<String, Package> {
    let root = root();
    let manifest = std::fs::read_to_string(root.join("Cargo.toml")).expect("read Cargo.toml");
    let members_start = manifest.find("members = [").expect("workspace members");
    let members_text = &manifest[members_start..];
    let members_text = &members_text[..members_text.find(']').expect("end of members")];
    let mut packages = BTreeMap::new();
    for member in members_text.split(',').filter_map(|m| quoted(m.trim_start_matches("members = ["))) {
        let dir = root.join(&member);
        let text = std::fs::read_to_string(dir.join("Cargo.toml")).expect("read a member's Cargo.toml");
        let mut package = Package {
            bins: stems(&dir.join("src/bin")),
            examples: stems(&dir.join("examples")),
            tests: stems(&dir.join("tests")),
            benches: stems(&dir.join("benches")),
            features: BTreeSet::new(),
        };
        let mut name = String::new();
        let mut section = String::new();
        for line in text.lines().map(str::trim) {
            if line.starts_with('[') {
                section = line.to_owned();
                continue;
            }
            let Some((key, value)) = line.split_once('=') else { continue };
            let key = key.trim();
            match (section.as_str(), key) {
                ("[package]", "name") => name = quoted(value).unwrap_or_default(),
                ("[[bin]]", "name") => package.bins.extend(quoted(value)),
                ("[[example]]", "name") => package.examples.extend(quoted(value)),
                ("[[test]]", "name") => package.tests.extend(quoted(value)),
                ("[[bench]]", "name") => package.benches.extend(quoted(value)),
                ("[features]", feature) if !feature.starts_with('#') => {
                    package.features.insert(feature.to_owned());
                }
                _ => {}
            }
        }
        if dir.join("src/main.rs").exists() {
            package.bins.insert(name.clone());
        }
        packages.insert(name, package);
    }
    packages
}

/// Runs the built binaries' `--help` once per subcommand path.
#[derive(Debug, Default)]
struct HelpCache {
    texts: HashMap<(String, Vec<String>), Result<String, String>>,
}

impl HelpCache {
    fn help(&mut self, bin: &str, words: &[String]) -> Result<String, String> {
        self.texts
            .entry((bin.to_owned(), words.to_vec()))
            .or_insert_with(|| {
                let out = Command::new(binary(bin))
                    .args(words)
                    .arg("--help")
                    .output()
                    .map_err(|e| format!("cannot run {bin}: {e}"))?;
                let text = String::from_utf8_lossy(&out.stdout).into_owned();
                if out.status.success() {
                    Ok(text)
                } else {
                    Err(format!(
                        "`{bin} {} --help` exited with {}: {}",
                        words.join(" "),
                        out.status,
                        String::from_utf8_lossy(&out.stderr).trim()
                    ))
                }
            })
            .clone()
    }
}

/// The subcommand names of a clap help text's "Commands:" list.
fn subcommands(help: &str) -> Vec<String> {
    help.lines()
        .skip_while(|l| l.trim() != "Commands:")
        .skip(1)
        .take_while(|l| !l.trim().is_empty())
        .filter(|l| l.starts_with("  ") && !l[2..].starts_with(' '))
        .filter_map(|l| l.split_whitespace().next().map(str::to_owned))
        .filter(|name| name != "help")
        .collect()
}

/// The options a clap help text lists (`-p`, `--profile`, ...), from its option lines only, not
/// from the descriptions.
fn options(help: &str) -> BTreeSet<String> {
    let mut found = BTreeSet::new();
    for line in help.lines() {
        let indent = line.len() - line.trim_start().len();
        if indent > 6 || !line.trim_start().starts_with('-') {
            continue;
        }
        for word in line.split([' ', ',', '=', '<', '[']) {
            let word = word.trim();
            let flag_chars = |w: &str| w.chars().all(|c| c.is_ascii_alphanumeric() || c == '-');
            if (word.starts_with("--") && word.len() > 2 || word.starts_with('-') && word.len() == 2)
                && flag_chars(word)
            {
                found.insert(word.to_owned());
            }
        }
    }
    found
}

/// Options every clap command has; a reference need not list them.
const ALWAYS: [&str; 4] = ["-h", "--help", "-V", "--version"];

/// A profile key as the docs write it in `--set KEY=VALUE` (lower case, dotted), not a
/// placeholder such as `KEY=VALUE` or `section.key=value`.
fn is_profile_key(key: &str) -> bool {
    key.contains('.')
        && key != "section.key"
        && key.split('.').all(|part| {
            !part.is_empty() && part.chars().all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
        })
}

/// A value in a synopsis that stands for something (`ARG`, `FILE`, `N`, `<crate>`).
fn is_placeholder(value: &str) -> bool {
    value == "ARG" || value.contains('<') || value.chars().all(|c| c.is_ascii_uppercase() || c == '_' || c == '.')
}

/// One use of a binary the docs make: where, which subcommand path, which options.
#[derive(Debug)]
struct BinaryUse {
    file: String,
    table_row: bool,
    bin: String,
    path: Vec<String>,
    flags: BTreeSet<String>,
}

/// The checks, with the failures they found.
#[derive(Debug, Default)]
struct Checker {
    helps: HelpCache,
    set_keys: HashMap<String, Option<String>>,
    packages: BTreeMap<String, Package>,
    failures: Vec<String>,
    uses: Vec<BinaryUse>,
}

impl Checker {
    fn new() -> Self {
        Self { packages: workspace_packages(), ..Self::default() }
    }

    fn fail(&mut self, line: &DocLine, message: String) {
        self.failures.push(format!("{}: {message}\n    {}", line.at(), line.text));
    }

    /// The help text of `bin` with `path`, recording a failure when it cannot be had.
    fn help(&mut self, line: &DocLine, bin: &str, path: &[String]) -> Option<String> {
        match self.helps.help(bin, path) {
            Ok(help) => Some(help),
            Err(e) => {
                self.fail(line, e);
                None
            }
        }
    }

    fn check(&mut self, line: &DocLine) {
        for words in split_commands(&line.text) {
            let command = strip_wrappers(&words);
            let Some(program) = command.first() else { continue };
            let args = &command[1..];
            let base = program.rsplit('/').next().unwrap_or(program);
            if matches!(base, "op3dsg" | "op3dsgd" | "op3dsg-detectd") {
                self.check_binary(line, base, args);
            } else if program.ends_with(".sh") && (program.contains("scripts/") || program.contains("systemd/")) {
                self.check_script(line, program);
            } else if base == "cargo" {
                self.check_cargo(line, args);
            } else if base.starts_with("python") {
                for script in args.iter().filter(|a| a.ends_with(".py") && !a.starts_with('-')) {
                    if !root().join(script).is_file() {
                        self.fail(line, format!("{script}: no such file"));
                    }
                }
            }
        }
    }

    fn check_script(&mut self, line: &DocLine, program: &str) {
        let path = root().join(program.trim_start_matches("./"));
        match std::fs::metadata(&path) {
            Ok(meta) if meta.permissions().mode() & 0o111 != 0 => {}
            Ok(_) => self.fail(line, format!("{program} is not executable")),
            Err(e) => self.fail(line, format!("{program}: {e}")),
        }
    }

    fn check_binary(&mut self, line: &DocLine, bin: &str, args: &[String]) {
        let args: Vec<&String> = args.iter().take_while(|a| *a != "--").collect();
        // The subcommand path: the words that name a subcommand of the level reached so far.
        let mut path: Vec<String> = Vec::new();
        let Some(mut help) = self.help(line, bin, &path) else { return };
        for arg in &args {
            let names = subcommands(&help);
            if names.is_empty() {
                break;
            }
            if names.contains(arg) {
                path.push((*arg).clone());
                let Some(next) = self.help(line, bin, &path) else { return };
                help = next;
            }
        }
        let shown = std::iter::once(bin).chain(path.iter().map(String::as_str)).collect::<Vec<_>>().join(" ");
        let asks_help = args.iter().any(|a| *a == "--help" || *a == "-h");
        // Prose may name a group of commands (`op3dsg map`); a command line must be complete.
        if !line.inline && !subcommands(&help).is_empty() && !asks_help {
            self.fail(line, format!("`{shown}` needs a subcommand: one of {}", subcommands(&help).join(", ")));
        }
        let known = options(&help);
        let mut flags = BTreeSet::new();
        let mut words = args.iter().peekable();
        while let Some(arg) = words.next() {
            let is_flag = arg.starts_with('-') && arg.len() > 1 && !arg[1..].starts_with(|c: char| c.is_ascii_digit());
            if !is_flag {
                continue;
            }
            let flag = arg.split_once('=').map_or(arg.as_str(), |(name, _)| name);
            flags.insert(flag.to_owned());
            if !known.contains(flag) {
                self.fail(line, format!("`{shown}` has no option {flag} (not in `{shown} --help`)"));
            }
            if flag == "--set" {
                let value =
                    arg.split_once('=').map(|(_, v)| v.to_owned()).or_else(|| words.peek().map(|v| v.to_string()));
                if let Some(assignment) = value {
                    self.check_set(line, &assignment);
                }
            }
        }
        self.uses.push(BinaryUse {
            file: line.file.clone(),
            table_row: line.table_row,
            bin: bin.to_owned(),
            path,
            flags,
        });
    }

    /// `KEY=VALUE` of a `--set`: the key must be one the profile knows.
    fn check_set(&mut self, line: &DocLine, assignment: &str) {
        let Some((key, _)) = assignment.split_once('=') else { return };
        if !is_profile_key(key) {
            return;
        }
        if let Some(error) = self.set_error(assignment) {
            self.fail(line, format!("--set {assignment}: {error}"));
        }
    }

    /// What `op3dsgd --print-config --set ASSIGNMENT` says when it does not know the key (or
    /// the value's variant); `None` when it knows them (other complaints, such as a section
    /// missing a required key, are not the key's fault).
    fn set_error(&mut self, assignment: &str) -> Option<String> {
        self.set_keys
            .entry(assignment.to_owned())
            .or_insert_with(|| {
                let out = Command::new(binary("op3dsgd"))
                    .args(["--print-config", "--set", assignment])
                    .output()
                    .expect("run op3dsgd --print-config");
                let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
                (stderr.contains("unknown field") || stderr.contains("unknown variant"))
                    .then(|| stderr.trim().to_owned())
            })
            .clone()
    }

    fn check_cargo(&mut self, line: &DocLine, args: &[String]) {
        let (cargo_args, after) = match args.iter().position(|a| a == "--") {
            Some(at) => (&args[..at], &args[at + 1..]),
            None => (args, &args[args.len()..]),
        };
        let value_of = |flag: &str| -> Vec<String> {
            let mut values = Vec::new();
            for (i, arg) in cargo_args.iter().enumerate() {
                if arg == flag {
                    values.extend(cargo_args.get(i + 1).cloned());
                } else if let Some(value) = arg.strip_prefix(&format!("{flag}=")) {
                    values.push(value.to_owned());
                }
            }
            values.retain(|v| !is_placeholder(v));
            values
        };
        let mut named: Vec<String> = value_of("-p");
        named.extend(value_of("--package"));
        let mut problems = Vec::new();
        for package in named.iter().filter(|p| !self.packages.contains_key(*p)) {
            problems.push(format!("-p {package}: no such workspace package"));
        }
        let candidates: Vec<&Package> = if named.is_empty() {
            self.packages.values().collect()
        } else {
            named.iter().filter_map(|p| self.packages.get(p)).collect()
        };
        let where_ = if named.is_empty() { "the workspace".to_owned() } else { named.join(", ") };
        for (flag, kind) in [("--bin", "binary"), ("--example", "example"), ("--test", "test"), ("--bench", "bench")] {
            for target in value_of(flag) {
                let found = candidates.iter().any(|p| {
                    let set = match kind {
                        "binary" => &p.bins,
                        "example" => &p.examples,
                        "test" => &p.tests,
                        _ => &p.benches,
                    };
                    set.contains(&target)
                });
                if !found {
                    problems.push(format!("{flag} {target}: no such {kind} in {where_}"));
                }
            }
        }
        for features in value_of("--features").into_iter().chain(value_of("-F")) {
            for feature in features.split([',', ' ']).filter(|f| !f.is_empty()) {
                let found = match feature.split_once('/') {
                    Some((package, feature)) => {
                        self.packages.get(package).is_some_and(|p| p.features.contains(feature))
                    }
                    // Without -p, cargo applies it to the workspace's packages that have it.
                    None => candidates.iter().any(|p| p.features.contains(feature)),
                };
                if !found {
                    problems.push(format!("--features {feature}: no such feature of {where_}"));
                }
            }
        }
        for message in problems {
            self.fail(line, message);
        }
        if cargo_args.first().is_some_and(|c| c == "run")
            && let Some(bin) = value_of("--bin").into_iter().find(|b| b == "op3dsg" || b == "op3dsgd")
        {
            self.check_binary(line, &bin, after);
        }
    }
}

/// The backtick spans of `text` outside fenced blocks that name a command (`op3dsg ...`,
/// `op3dsgd ...`, `cargo ...`, with at least one argument), as command lines: the synopsis
/// marks of a reference table (`[`, `]`, `...`, `<placeholder>`, `a\|b`) taken out. A span may
/// run on over a line break, as Markdown allows.
fn inline_commands(file: &str, text: &str) -> Vec<DocLine> {
    let mut lines = Vec::new();
    let mut fenced = false;
    // The span still open at the end of the previous line: where it started, its text so far.
    let mut open: Option<(usize, bool, String)> = None;
    for (index, raw) in text.lines().enumerate() {
        if raw.trim_start().starts_with("```") {
            fenced = !fenced;
            open = None;
            continue;
        }
        if fenced {
            continue;
        }
        let table_row = raw.trim_start().starts_with('|');
        let mut inside = open.is_some();
        for (i, piece) in raw.split('`').enumerate() {
            if i > 0 {
                inside = !inside;
                if !inside && let Some((line, row, span)) = open.take() {
                    lines.extend(command_of_span(file, line, row, &span));
                }
                if inside {
                    open = Some((index + 1, table_row, String::new()));
                }
            }
            if inside && let Some((_, _, span)) = open.as_mut() {
                if !span.is_empty() {
                    span.push(' ');
                }
                span.push_str(piece);
            }
        }
        if table_row || raw.trim().is_empty() {
            // A table cell or a paragraph ends here, and with it any span left open.
            open = None;
        }
    }
    lines
}

/// The command a code span names, if it names one.
fn command_of_span(file: &str, line: usize, table_row: bool, span: &str) -> Option<DocLine> {
    let mut plain = String::new();
    let mut in_placeholder = false;
    for c in span.replace("\\|", "/").replace("...", " ").replace('…', " ").chars() {
        match c {
            '<' => {
                in_placeholder = true;
                plain.push_str("ARG");
            }
            '>' => in_placeholder = false,
            '[' | ']' => plain.push(' '),
            '|' => plain.push('/'),
            _ if in_placeholder => {}
            _ => plain.push(c),
        }
    }
    let words: Vec<&str> = plain.split_whitespace().collect();
    let first = words.first().map(|w| w.rsplit('/').next().unwrap_or(w));
    (words.len() >= 2 && matches!(first, Some("op3dsg" | "op3dsgd" | "op3dsg-detectd" | "cargo"))).then(|| DocLine {
        file: file.to_owned(),
        line,
        text: words.join(" "),
        inline: true,
        table_row,
    })
}

/// Every command of every doc page, checked.
fn check_all_docs() -> Checker {
    let mut checker = Checker::new();
    for file in doc_files() {
        let text = std::fs::read_to_string(root().join(&file)).unwrap_or_else(|e| panic!("read {file}: {e}"));
        for line in sh_lines(&file, &text).iter().chain(&inline_commands(&file, &text)) {
            checker.check(line);
        }
    }
    checker
}

#[test]
fn every_documented_command_and_flag_exists() {
    let checker = check_all_docs();
    assert!(
        checker.failures.is_empty(),
        "{} documented commands name something that does not exist:\n{}",
        checker.failures.len(),
        checker.failures.join("\n")
    );
    for bin in ["op3dsg", "op3dsgd"] {
        let uses = checker.uses.iter().filter(|u| u.bin == bin).count();
        assert!(uses > 10, "only {uses} `{bin}` commands found in the docs: is the extraction broken?");
        println!("{uses} `{bin}` commands checked against `--help`");
    }
    println!("{} `--set` values checked against the profile", checker.set_keys.len());
}

/// The reference page of the two binaries.
const REFERENCE: &str = "docs/robot.md";

/// Every subcommand path of `bin` (the root included) with its own options: those its help lists
/// beyond its parent's (a global option is listed once, where it is defined) and beyond
/// `-h`, `--help`, `-V`, `--version`; and whether it is a leaf.
fn command_tree(helps: &mut HelpCache, bin: &str) -> Vec<(Vec<String>, BTreeSet<String>, bool)> {
    let mut tree = Vec::new();
    let mut pending = vec![(Vec::new(), BTreeSet::new())];
    while let Some((path, parent_options)) = pending.pop() {
        let help = helps.help(bin, &path).unwrap_or_else(|e| panic!("{e}"));
        let all = options(&help);
        let own: BTreeSet<String> =
            all.difference(&parent_options).filter(|o| !ALWAYS.contains(&o.as_str())).cloned().collect();
        let children = subcommands(&help);
        for child in &children {
            let mut next = path.clone();
            next.push(child.clone());
            pending.push((next, all.clone()));
        }
        tree.push((path, own, children.is_empty()));
    }
    tree.sort();
    tree
}

#[test]
fn the_command_reference_lists_every_subcommand_and_option() {
    let mut checker = check_all_docs();
    let mut missing = Vec::new();
    for bin in ["op3dsgd", "op3dsg"] {
        let rows: Vec<&BinaryUse> =
            checker.uses.iter().filter(|u| u.file == REFERENCE && u.table_row && u.bin == bin).collect();
        for (path, own, leaf) in command_tree(&mut checker.helps, bin) {
            let shown = std::iter::once(bin).chain(path.iter().map(String::as_str)).collect::<Vec<_>>().join(" ");
            let below: Vec<&&BinaryUse> = rows.iter().filter(|u| u.path.starts_with(&path)).collect();
            if leaf && !below.iter().any(|u| u.path == path) {
                missing.push(format!("`{shown}`: no row"));
            }
            for option in own.iter().filter(|o| !below.iter().any(|u| u.flags.contains(*o))) {
                missing.push(format!("`{shown}`: option {option}"));
            }
        }
    }
    assert!(
        missing.is_empty(),
        "the command tables of {REFERENCE} miss what `--help` lists (one row per command, every option in a row):\n{}",
        missing.join("\n")
    );
}

/// The dotted keys of a TOML text as `op3dsgd --print-config` writes it (tables as `[a.b]`
/// headers, one `key = value` per line): every leaf key, an inline table or array being a leaf.
fn toml_keys(text: &str) -> BTreeSet<String> {
    let mut keys = BTreeSet::new();
    let mut table = String::new();
    for line in text.lines() {
        if let Some(header) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            table = header.trim_matches(['[', ']']).replace('"', "");
            continue;
        }
        let Some((key, _)) = line.split_once(" = ") else { continue };
        if key.starts_with([' ', '#']) || key.is_empty() {
            continue;
        }
        let key = key.replace('"', "");
        keys.insert(if table.is_empty() { key } else { format!("{table}.{key}") });
    }
    keys
}

/// The keys of the profile-key table of the reference page: each row a section in its first
/// cell (`` `[fusion.colour]` ``, or `(top level)`) and its keys in the second
/// (`` `tau_s`, `tau_v` ``).
fn documented_keys() -> BTreeMap<String, usize> {
    let text = std::fs::read_to_string(root().join(REFERENCE)).expect("read the reference page");
    let mut keys = BTreeMap::new();
    let mut in_table = false;
    for (index, line) in text.lines().enumerate() {
        if line.starts_with("| section | keys |") {
            in_table = true;
            continue;
        }
        if !in_table || line.starts_with("|---") {
            continue;
        }
        if !line.starts_with('|') {
            if !keys.is_empty() {
                break;
            }
            continue;
        }
        let cells: Vec<&str> = line.split(" | ").collect();
        let (Some(section), Some(names)) = (cells.first(), cells.get(1)) else { continue };
        // `(top level)`: keys outside any section.
        let section = section.trim_start_matches('|').trim().trim_matches('`').trim_matches(['[', ']']);
        let section = if section.starts_with('(') { "" } else { section };
        for (i, name) in names.split('`').enumerate() {
            if i % 2 == 1 {
                let key = if section.is_empty() { name.to_owned() } else { format!("{section}.{name}") };
                keys.insert(key, index + 1);
            }
        }
    }
    keys
}

#[test]
fn the_profile_key_table_lists_every_key_and_only_keys() {
    let documented = documented_keys();
    assert!(documented.len() > 100, "only {} keys read from {REFERENCE}'s profile-key table", documented.len());
    let mut problems = Vec::new();
    // Every key the effective profile of each shipped profile has (a profile this build cannot
    // load, such as the camera's without the feature `realsense`, is skipped).
    let mut profiles: Vec<Option<PathBuf>> = vec![None];
    let mut files: Vec<PathBuf> = std::fs::read_dir(root().join("profiles"))
        .expect("read profiles/")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    files.sort();
    profiles.extend(files.into_iter().map(Some));
    let mut seen = BTreeSet::new();
    for profile in &profiles {
        let mut command = Command::new(binary("op3dsgd"));
        command.arg("--print-config");
        if let Some(path) = profile {
            command.arg("--profile").arg(path);
        }
        let out = command.output().expect("run op3dsgd --print-config");
        if out.status.success() {
            seen.extend(toml_keys(&String::from_utf8_lossy(&out.stdout)));
        }
    }
    for key in &seen {
        let covered = documented.keys().any(|d| key == d || key.starts_with(&format!("{d}.")));
        if !covered {
            problems.push(format!("{key}: in `op3dsgd --print-config`, not in the table"));
        }
    }
    // Every documented key is one the profile accepts. A build without the camera backend does
    // not know `[source.realsense]`: its keys are then looked up in the section's struct.
    let realsense_fields = std::fs::read_to_string(root().join("drivers/realsense/src/config.rs")).expect("read");
    let mut checker = Checker::new();
    for (key, line) in &documented {
        let shown_by_print_config = seen.iter().any(|k| k == key || k.starts_with(&format!("{key}.")));
        if shown_by_print_config {
            continue;
        }
        let camera_key = key.strip_prefix("source.realsense.");
        let camera_built = seen.iter().any(|k| k.starts_with("source.realsense."));
        match camera_key {
            Some(field) if !camera_built => {
                if !realsense_fields.contains(&format!("    pub {field}:")) {
                    problems
                        .push(format!("{REFERENCE}:{line}: {key}: no such field in drivers/realsense/src/config.rs"));
                }
            }
            _ => {
                if let Some(error) = checker.set_error(&format!("{key}=0")) {
                    problems.push(format!("{REFERENCE}:{line}: {key}: {error}"));
                }
            }
        }
    }
    assert!(problems.is_empty(), "the profile-key table of {REFERENCE} is wrong:\n{}", problems.join("\n"));
    println!("{} documented keys; {} keys of `op3dsgd --print-config` covered", documented.len(), seen.len());
}

/// GitHub's anchor of a heading: lower case, punctuation but `-` and `_` dropped, spaces to `-`.
fn anchor(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter(|c| c.is_alphanumeric() || matches!(c, ' ' | '-' | '_'))
        .map(|c| if c == ' ' { '-' } else { c })
        .collect()
}

/// The anchors of a Markdown page's headings (a repeated one gets `-1`, `-2`, ... as on GitHub).
fn anchors(text: &str) -> BTreeSet<String> {
    let mut seen: BTreeMap<String, usize> = BTreeMap::new();
    let mut fenced = false;
    let mut found = BTreeSet::new();
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
        }
        let Some(heading) = line.strip_prefix('#').filter(|_| !fenced) else { continue };
        let base = anchor(heading.trim_start_matches('#'));
        let count = seen.entry(base.clone()).or_default();
        found.insert(if *count == 0 { base.clone() } else { format!("{base}-{count}") });
        *count += 1;
    }
    found
}

#[test]
fn every_relative_link_resolves() {
    let mut broken = Vec::new();
    for file in doc_files() {
        let path = root().join(&file);
        let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("read {file}: {e}"));
        let dir = path.parent().expect("a doc has a folder");
        for (index, line) in text.lines().enumerate() {
            for target in line.split("](").skip(1).filter_map(|rest| rest.split(')').next()) {
                if target.contains("://") || target.starts_with("mailto:") || target.contains(' ') {
                    continue;
                }
                let (file_part, fragment) = target.split_once('#').unwrap_or((target, ""));
                let linked = if file_part.is_empty() { path.clone() } else { dir.join(file_part) };
                if !linked.exists() {
                    broken.push(format!("{file}:{}: {target}: no such file", index + 1));
                    continue;
                }
                if !fragment.is_empty() {
                    let linked_text = std::fs::read_to_string(&linked).unwrap_or_default();
                    if !anchors(&linked_text).contains(fragment) {
                        broken.push(format!("{file}:{}: {target}: no heading with that anchor", index + 1));
                    }
                }
            }
        }
    }
    assert!(broken.is_empty(), "broken links in the docs:\n{}", broken.join("\n"));
}

#[test]
fn commands_are_split_as_a_shell_would() {
    let line =
        r#"FOO=1 sudo nice -n -10 op3dsg --prefix x dump --json | jq . && op3dsgd --set 'a.b="c d"' 2>&1 >log # why"#;
    let commands: Vec<Vec<String>> = split_commands(line);
    assert_eq!(commands.len(), 3, "{commands:?}");
    assert_eq!(strip_wrappers(&commands[0]), ["op3dsg", "--prefix", "x", "dump", "--json"]);
    assert_eq!(commands[2], ["op3dsgd", "--set", "a.b=\"c d\""]);
    let as_user = split_commands("sudo -u hello-robot op3dsg health");
    assert_eq!(strip_wrappers(&as_user[0]), ["op3dsg", "health"]);
    let text = "```sh\n$ op3dsgd --profile p.toml \\\n  --max-frames 5   # note\n```\n```text\nop3dsg nope\n```\n";
    let lines = sh_lines("x.md", text);
    assert_eq!(lines.len(), 1);
    assert_eq!((lines[0].line, split_commands(&lines[0].text)[0].len()), (2, 5));
}

#[test]
fn a_synopsis_in_a_table_becomes_a_command() {
    let text = "| `op3dsg goal <node-id\\|\"TEXT\"> [--json] [--timeout-s S]` | where `x` |\n";
    let lines = inline_commands("x.md", text);
    assert_eq!(lines.len(), 1);
    assert!(lines[0].table_row);
    assert_eq!(split_commands(&lines[0].text), [["op3dsg", "goal", "ARG", "--json", "--timeout-s", "S"]]);
}

#[test]
fn options_come_from_option_lines_only() {
    let help = "Options:\n  -p, --profile <PROFILE>\n          Profile; see --max-frames\n      --max-frames <N>\n";
    assert_eq!(options(help), ["--max-frames", "--profile", "-p"].map(str::to_owned).into());
}

/// The page a robot engineer follows from a fresh robot to a planner reading the graph: every
/// command of its `sh` blocks must be one the checks above cover, or one of [`SYSTEM_TOOLS`],
/// or one checked here against the files it names.
const ROBOT_PAGE: &str = "docs/robot.md";

/// Commands of the operating system the robot page uses as documented by their own manuals;
/// nothing of ours to check in them beyond their names. A command of the robot page that is
/// neither ours nor here fails the test, so a new one gets a check or a place on this list.
const SYSTEM_TOOLS: &[&str] = &[
    "cp",
    "getent",
    "grep",
    "head",
    "id",
    "install",
    "ls",
    "mkdir",
    "printf",
    "rs-enumerate-devices",
    "sudoedit",
    "tee",
    "udevadm",
    "usermod",
];

/// The verbs of `systemctl` the robot page may use.
const SYSTEMCTL_VERBS: &[&str] =
    &["daemon-reload", "edit", "enable", "is-active", "reset-failed", "restart", "show", "start", "status", "stop"];

/// The units of this repository (`systemd/*.service`), and the system's units the page names.
fn known_units() -> BTreeSet<String> {
    let mut units: BTreeSet<String> = std::fs::read_dir(root().join("systemd"))
        .expect("read systemd/")
        .filter_map(Result::ok)
        .filter_map(|e| e.file_name().to_string_lossy().strip_suffix(".service").map(str::to_owned))
        .collect();
    units.insert("systemd-logind".to_owned());
    units
}

/// The `.deb` cargo-deb writes for the daemon's package: `target/debian/<name>_<version>-1_<arch>.deb`.
fn deb_file_name(arch: &str) -> String {
    let manifest =
        std::fs::read_to_string(root().join("daemon/op3dsgd/Cargo.toml")).expect("read daemon/op3dsgd/Cargo.toml");
    let deb =
        &manifest[manifest.find("[package.metadata.deb]").expect("the daemon's package has [package.metadata.deb]")..];
    let name = deb
        .lines()
        .find_map(|l| l.trim().strip_prefix("name = ").and_then(quoted))
        .expect("[package.metadata.deb] names the package");
    let workspace = std::fs::read_to_string(root().join("Cargo.toml")).expect("read Cargo.toml");
    let version = workspace
        .lines()
        .skip_while(|l| l.trim() != "[workspace.package]")
        .find_map(|l| l.trim().strip_prefix("version = ").and_then(quoted))
        .expect("[workspace.package] version");
    format!("{name}_{version}-1_{arch}.deb")
}

/// What is wrong with one command of the robot page, `None` when it is covered.
fn robot_command_problem(program: &str, args: &[String]) -> Option<String> {
    let base = program.rsplit('/').next().unwrap_or(program);
    let operands: Vec<&String> = args.iter().filter(|a| !a.starts_with('-')).collect();
    match base {
        "op3dsg" | "op3dsgd" | "op3dsg-detectd" | "cargo" => None,
        _ if program.ends_with(".sh") || base.starts_with("python") => None,
        "systemctl" => {
            let verb = operands.first()?;
            if !SYSTEMCTL_VERBS.contains(&verb.as_str()) {
                return Some(format!("systemctl {verb}: not a verb the page may use ({SYSTEMCTL_VERBS:?})"));
            }
            let units = known_units();
            operands[1..]
                .iter()
                .find(|u| !units.contains(u.trim_end_matches(".service")))
                .map(|u| format!("systemctl {verb} {u}: no such unit in systemd/ ({units:?})"))
        }
        "journalctl" => {
            let unit = args.iter().position(|a| a == "-u").and_then(|i| args.get(i + 1));
            match unit {
                Some(u) if known_units().contains(u.trim_end_matches(".service")) => None,
                Some(u) => Some(format!("journalctl -u {u}: no such unit in systemd/")),
                None => Some("journalctl without -u <unit>".to_owned()),
            }
        }
        "apt" | "apt-get" => {
            let deb = operands.iter().find(|a| a.ends_with(".deb"))?;
            let expected = format!("./target/debian/{}", deb_file_name("amd64"));
            (deb.as_str() != expected).then(|| format!("{deb}: cargo-deb writes {expected}"))
        }
        "op3dsg-service-user" => {
            let script = root().join("systemd/op3dsg-service-user");
            let help = Command::new("sh").arg(&script).arg("--help").output().expect("run op3dsg-service-user --help");
            let help = String::from_utf8_lossy(&help.stdout).into_owned();
            args.iter()
                .filter(|a| a.starts_with('-'))
                .find(|flag| !help.contains(flag.split('=').next().unwrap_or(flag)))
                .map(|flag| format!("op3dsg-service-user {flag}: not an option of systemd/op3dsg-service-user"))
        }
        _ if SYSTEM_TOOLS.contains(&base) => None,
        _ => Some(format!("{base}: not checked; give it a check in docs_commands.rs or a place in SYSTEM_TOOLS")),
    }
}

#[test]
fn every_command_of_the_robot_page_is_checked() {
    let text = std::fs::read_to_string(root().join(ROBOT_PAGE)).expect("read the robot page");
    let lines = sh_lines(ROBOT_PAGE, &text);
    assert!(lines.len() > 30, "only {} command lines in {ROBOT_PAGE}: is the extraction broken?", lines.len());
    let mut failures = Vec::new();
    for line in &lines {
        for words in split_commands(&line.text) {
            let command = strip_wrappers(&words);
            let Some(program) = command.first() else { continue };
            if let Some(problem) = robot_command_problem(program, &command[1..]) {
                failures.push(format!("{}: {problem}\n    {}", line.at(), line.text));
            }
        }
    }
    assert!(failures.is_empty(), "{} commands of {ROBOT_PAGE}:\n{}", failures.len(), failures.join("\n"));
}

#[test]
fn the_robot_page_check_refuses_what_it_does_not_know() {
    let words = |s: &str| s.split(' ').map(str::to_owned).collect::<Vec<_>>();
    assert!(robot_command_problem("curl", &words("-fsSL https://example.org")).is_some());
    assert!(robot_command_problem("systemctl", &words("restart op3dsg")).is_some(), "a unit of another name");
    assert!(robot_command_problem("systemctl", &words("restart op3dsgd")).is_none());
    assert!(robot_command_problem("journalctl", &words("-u nothing -f")).is_some());
    assert!(robot_command_problem("apt", &words("install ./target/debian/op3dsg_0.0.1-1_amd64.deb")).is_some());
    assert!(
        robot_command_problem("apt", &words(&format!("install ./target/debian/{}", deb_file_name("amd64")))).is_none()
    );
    assert!(robot_command_problem("op3dsg-service-user", &words("--no-such-flag hello-robot")).is_some());
    assert!(robot_command_problem("op3dsg-service-user", &words("--reset")).is_none());
}
