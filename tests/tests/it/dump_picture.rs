//! `op3dsg dump --format dot` and `--format svg` against a real daemon (the built-in synthetic
//! profile, a short run so the graph stops changing): the DOT, read by a small DOT reader here
//! (not the code that writes it), has one node per node of `dump --json` of the same version
//! (objects as boxes, parts as ellipses, each labelled with its label and id) and one labelled
//! edge per edge (part-of dashed, spatial solid, functional bold); the SVG is well-formed XML
//! (Python's own XML parser) with one element per node.

use std::collections::BTreeMap;
use std::process::Command;
use std::time::Duration;

use op3dsg_tests::{Daemon, binary, health_where, unique_prefix};
use serde_json::Value;

fn dump(prefix: &str, args: &[&str]) -> String {
    let output = Command::new(binary("op3dsg"))
        .args(["--prefix", prefix, "dump", "--timeout-s", "30"])
        .args(args)
        .output()
        .expect("run op3dsg dump");
    assert!(output.status.success(), "op3dsg dump {args:?}: {}", String::from_utf8_lossy(&output.stderr));
    String::from_utf8(output.stdout).expect("UTF-8 output")
}

/// A DOT statement: a node (`id [attrs]`) or an edge (`a -> b [attrs]`).
#[derive(Debug)]
enum Statement {
    Node(String, BTreeMap<String, String>),
    Edge(String, String, BTreeMap<String, String>),
}

/// DOT tokens: identifiers, quoted strings (escapes undone) and punctuation.
fn tokens(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut chars = text.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            c if c.is_whitespace() => {}
            '/' if chars.peek() == Some(&'/') => {
                for c in chars.by_ref() {
                    if c == '\n' {
                        break;
                    }
                }
            }
            '"' => {
                let mut s = String::from("\"");
                loop {
                    match chars.next().expect("a quoted string ends") {
                        '"' => break,
                        '\\' => match chars.next().expect("an escape ends") {
                            'n' => s.push('\n'),
                            c => s.push(c),
                        },
                        c => s.push(c),
                    }
                }
                out.push(s);
            }
            '-' if chars.peek() == Some(&'>') => {
                chars.next();
                out.push("->".into());
            }
            '{' | '}' | '[' | ']' | '=' | ',' | ';' => out.push(c.to_string()),
            c if c.is_alphanumeric() || c == '_' || c == '.' || c == '#' => {
                let mut s = c.to_string();
                while let Some(&n) = chars.peek().filter(|n| n.is_alphanumeric() || **n == '_' || **n == '.') {
                    s.push(n);
                    chars.next();
                }
                out.push(s);
            }
            c => panic!("unexpected character {c:?} in the DOT"),
        }
    }
    out
}

/// Reads `digraph NAME { statements }`; `graph`, `node` and `edge` defaults are checked for form
/// and dropped.
fn read_dot(text: &str) -> Vec<Statement> {
    let t = tokens(text);
    assert_eq!(&t[..3], ["digraph", "op3dsg", "{"], "{text}");
    assert_eq!(t.last().map(String::as_str), Some("}"), "{text}");
    let body = &t[3..t.len() - 1];
    let mut statements = Vec::new();
    for statement in body.split(|t| t == ";") {
        if statement.is_empty() {
            continue;
        }
        let open = statement.iter().position(|t| t == "[").unwrap_or(statement.len());
        assert!(statement.len() == open || statement.last().map(String::as_str) == Some("]"), "{statement:?}");
        let mut attrs = BTreeMap::new();
        if open < statement.len() {
            for pair in statement[open + 1..statement.len() - 1].split(|t| t == ",") {
                let [key, eq, value] = pair else { panic!("attribute {pair:?} is not key=value") };
                assert_eq!(eq, "=", "{pair:?}");
                attrs.insert(key.clone(), value.strip_prefix('"').unwrap_or(value).to_owned());
            }
        }
        match &statement[..open] {
            [keyword] if ["graph", "node", "edge"].contains(&keyword.as_str()) => {}
            [id] => statements.push(Statement::Node(id.clone(), attrs)),
            [a, arrow, b] if arrow == "->" => statements.push(Statement::Edge(a.clone(), b.clone(), attrs)),
            other => panic!("not a DOT statement: {other:?}"),
        }
    }
    statements
}

/// The Python interpreter: the project's venv, else python3 on the PATH.
fn python() -> String {
    let venv = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../.venv/bin/python");
    if venv.exists() { venv.to_string_lossy().into_owned() } else { "python3".to_owned() }
}

#[test]
fn dump_dot_and_svg_draw_the_graph_of_the_json_dump() {
    let prefix = unique_prefix("dump-picture");
    let daemon =
        Daemon::start(&prefix, &["--set", "source.synthetic.frame_count=120", "--set", "health.period_ms=200"]);
    let mut health = daemon.health_subscriber("dump-picture-health");
    health_where(&mut health, "all 120 frames captured", Duration::from_secs(120), |h| h.frames_captured >= 120);
    // The last keyframes may still be fusing: the JSON before and after the pictures agree.
    let (json, dot, svg) = loop {
        let before: Value = serde_json::from_str(&dump(&prefix, &["--json"])).expect("dump JSON");
        let dot = dump(&prefix, &["--format", "dot"]);
        let svg = dump(&prefix, &["--format", "svg"]);
        let after: Value = serde_json::from_str(&dump(&prefix, &["--format", "json"])).expect("dump JSON");
        if before["graph_version"] == after["graph_version"] {
            break (after, dot, svg);
        }
        std::thread::sleep(Duration::from_millis(500));
    };
    let version = json["graph_version"].as_u64().expect("graph_version");
    assert!(dot.contains(&format!("op3dsg graph version {version} ")), "the DOT of version {version}:\n{dot}");

    let nodes = json["nodes"].as_array().expect("nodes");
    let edges = json["edges"].as_array().expect("edges");
    let statements = read_dot(&dot);
    let mut dot_nodes = BTreeMap::new();
    let mut dot_edges = Vec::new();
    for statement in &statements {
        match statement {
            Statement::Node(id, attrs) => {
                assert!(dot_nodes.insert(id.clone(), attrs.clone()).is_none(), "node {id} twice");
            }
            Statement::Edge(a, b, attrs) => dot_edges.push((a.clone(), b.clone(), attrs.clone())),
        }
    }
    let parts = nodes.iter().filter(|n| n["kind"] == "part").count();
    assert!(parts > 0 && nodes.len() > parts && !edges.is_empty(), "a graph with objects, parts and edges: {json}");
    assert_eq!(dot_nodes.len(), nodes.len(), "one DOT node per node");
    for node in nodes {
        let id = node["id"].as_u64().expect("id");
        let attrs = dot_nodes.get(&format!("n{id}")).unwrap_or_else(|| panic!("node {id} not in the DOT"));
        let label = node["label"].as_str().expect("label");
        assert_eq!(attrs["label"], format!("{label}\n#{id}"), "node {id}'s label");
        let shape = if node["kind"] == "part" { "ellipse" } else { "box" };
        assert_eq!(attrs["shape"], shape, "node {id} ({})", node["kind"]);
    }
    assert_eq!(dot_edges.len(), edges.len(), "one DOT edge per edge");
    let mut want: Vec<(String, String, String, &str)> = edges
        .iter()
        .map(|e| {
            let relation = e["relation"].as_str().expect("relation").to_owned();
            let style = match (e["kind"].as_str(), relation.as_str()) {
                (Some("functional"), _) => "bold",
                (_, "part of") => "dashed",
                _ => "solid",
            };
            (format!("n{}", e["source"]), format!("n{}", e["target"]), relation, style)
        })
        .collect();
    let mut got: Vec<(String, String, String, &str)> = dot_edges
        .iter()
        .map(|(a, b, attrs)| (a.clone(), b.clone(), attrs["label"].clone(), attrs["style"].as_str()))
        .collect();
    want.sort();
    got.sort();
    assert_eq!(got, want, "the DOT's edges: ends, label, style");

    // The SVG: well-formed XML, one <g> per node with its id and kind.
    let script = r#"
import sys, xml.etree.ElementTree as ET
root = ET.fromstring(sys.stdin.read())
assert root.tag == "{http://www.w3.org/2000/svg}svg", root.tag
for g in root.iter("{http://www.w3.org/2000/svg}g"):
    if g.get("class") in ("object", "part"):
        print(g.get("class"), g.get("id"))
"#;
    let mut child = Command::new(python())
        .args(["-c", script])
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("run python3 (the project's .venv, or python3 on the PATH)");
    std::io::Write::write_all(&mut child.stdin.take().expect("stdin"), svg.as_bytes()).expect("write the SVG");
    let output = child.wait_with_output().expect("python's XML check");
    assert!(output.status.success(), "the SVG is not well-formed XML: {}", String::from_utf8_lossy(&output.stderr));
    let mut drawn: Vec<String> = String::from_utf8_lossy(&output.stdout).lines().map(str::to_owned).collect();
    let mut expected: Vec<String> =
        nodes.iter().map(|n| format!("{} node-{}", n["kind"].as_str().unwrap_or("?"), n["id"])).collect();
    drawn.sort();
    expected.sort();
    assert_eq!(drawn, expected, "one SVG element per node");
}
