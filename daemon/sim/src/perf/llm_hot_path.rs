//! `op3dsg bench llm`: the hot path never waits for the LLM. The real pipeline on the synthetic
//! scene of the profile, as fast as possible ([`super::pipeline_run::Mode::AsFastAsPossible`]),
//! once with `reasoner.kind = "knowledge"` and once with `reasoner.kind = "llm"` against a slow
//! chat-completions server on 127.0.0.1 in this process ([`SlowChatServer`]: every answer after
//! a fixed delay, built from the prompt's ids and labels), one run after the other in one
//! process. Reported per stage of the fusion thread (`fusion`: integrating a keyframe; `prior`:
//! the prior graph, the reasoner and applying the LLM's latest result; `publish`) and for
//! capture → published graph: p50 and p99 of each run and the p99 ratio llm / knowledge.
//!
//! The server is a few lines of blocking HTTP/1.1 on `std::net` (one thread per connection,
//! `Connection: close`): the product has no HTTP server dependency, and this one only needs to
//! answer `POST /v1/chat/completions` late.

use std::io::{BufRead as _, BufReader, Read as _, Write as _};
use std::net::{TcpListener, TcpStream};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context as _, anyhow};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

use super::pipeline_run::{Mode, PipelineRun, pipeline_run};
use super::{Machine, PerfOptions};

/// A chat-completions server that answers every request after `delay`.
#[derive(Debug)]
pub struct SlowChatServer {
    base_url: String,
    requests: Arc<AtomicU64>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl SlowChatServer {
    /// Listens on `address` (`127.0.0.1:0`: any free port) on thread `op3dsg-bench-llm`.
    pub fn start(address: &str, delay: Duration) -> anyhow::Result<Self> {
        let listener = TcpListener::bind(address).with_context(|| format!("binding {address}"))?;
        listener.set_nonblocking(true).context("a non-blocking listener")?;
        let base_url = format!("http://{}/v1", listener.local_addr()?);
        let requests = Arc::new(AtomicU64::new(0));
        let stop = Arc::new(AtomicBool::new(false));
        let (count, flag) = (requests.clone(), stop.clone());
        let thread = std::thread::Builder::new()
            .name("op3dsg-bench-llm".to_owned())
            .spawn(move || {
                while !flag.load(Ordering::Relaxed) {
                    match listener.accept() {
                        Ok((stream, _)) => {
                            let (count, flag) = (count.clone(), flag.clone());
                            let _ = std::thread::Builder::new()
                                .name("op3dsg-bench-llm-conn".to_owned())
                                .spawn(move || serve(stream, delay, &count, &flag));
                        }
                        Err(_) => std::thread::sleep(Duration::from_millis(5)),
                    }
                }
            })
            .context("starting the server thread")?;
        Ok(Self { base_url, requests, stop, thread: Some(thread) })
    }

    /// `http://<address>/v1`.
    pub fn base_url(&self) -> &str {
        &self.base_url
    }

    /// Requests received so far.
    pub fn requests(&self) -> u64 {
        self.requests.load(Ordering::Relaxed)
    }
}

impl Drop for SlowChatServer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// One connection: one request, answered after `delay` (sooner when stopped), then closed.
fn serve(stream: TcpStream, delay: Duration, count: &AtomicU64, stop: &AtomicBool) {
    let _ = stream.set_nonblocking(false);
    let _ = stream.set_read_timeout(Some(Duration::from_secs(10)));
    let mut reader = BufReader::new(match stream.try_clone() {
        Ok(s) => s,
        Err(_) => return,
    });
    let mut length = 0usize;
    let mut line = String::new();
    loop {
        line.clear();
        match reader.read_line(&mut line) {
            Ok(0) | Err(_) => return,
            Ok(_) => {}
        }
        if line == "\r\n" || line == "\n" {
            break;
        }
        if let Some((name, value)) = line.split_once(':')
            && name.trim().eq_ignore_ascii_case("content-length")
        {
            length = value.trim().parse().unwrap_or(0);
        }
    }
    let mut body = vec![0u8; length.min(16 << 20)];
    if reader.read_exact(&mut body).is_err() {
        return;
    }
    count.fetch_add(1, Ordering::Relaxed);
    let until = Instant::now() + delay;
    while Instant::now() < until && !stop.load(Ordering::Relaxed) {
        std::thread::sleep(Duration::from_millis(20).min(until.saturating_duration_since(Instant::now())));
    }
    let request: Value = serde_json::from_slice(&body).unwrap_or(Value::Null);
    let completion = json!({
        "id": "chatcmpl-bench",
        "object": "chat.completion",
        "choices": [{"index": 0, "message": {"role": "assistant", "content": answer(&request).to_string()}, "finish_reason": "stop"}],
    })
    .to_string();
    let mut stream = stream;
    let _ = write!(
        stream,
        "HTTP/1.1 200 OK\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{completion}",
        completion.len()
    );
    let _ = stream.flush();
}

/// A plausible model's answer, from the prompt's ids and labels.
fn answer(request: &Value) -> Value {
    let user: Value =
        serde_json::from_str(request["messages"][1]["content"].as_str().unwrap_or("null")).unwrap_or(Value::Null);
    let label = |v: &Value| v["label"].as_str().unwrap_or("").to_owned();
    let mut items = Vec::new();
    if let Some(pairs) = user["part_of_pairs"].as_array() {
        for pair in pairs {
            let relation = match label(&pair["part"]) {
                l if l.ends_with("handle") => "pull to open or close",
                l if l.ends_with("knob") => "rotate to adjust the setting or temperature",
                _ => continue,
            };
            items.push(json!({"part_id": pair["part"]["id"], "object_id": pair["object"]["id"], "relation": relation, "confidence": 0.8}));
        }
        return json!({"relations": items});
    }
    if let Some(sources) = user["sources"].as_array() {
        for source in sources {
            let relation = match label(&source["source"]) {
                l if l.contains("outlet") => "provide power",
                l if l.contains("switch") => "turn on or turn off",
                l if l.contains("knob") => "rotate to adjust the setting or temperature",
                _ => "remote to control",
            };
            items.push(json!({"source_id": source["source"]["id"], "target_id": source["candidate_targets"][0]["id"], "relation": relation, "confidence": 0.8}));
        }
        return json!({"relations": items});
    }
    for node in user["nodes"].as_array().into_iter().flatten() {
        let names = match label(node) {
            l if l.ends_with("handle") => ["hook_pull"],
            l if l.ends_with("knob") => ["rotate"],
            _ => continue,
        };
        items.push(json!({"node_id": node["id"], "affordances": names, "confidence": 0.8}));
    }
    json!({"affordances": items})
}

/// One stage in both runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageComparison {
    /// `fusion`, `prior`, `publish`, `end_to_end`.
    pub name: String,
    /// p50 with `reasoner.kind = "knowledge"`, ms.
    pub knowledge_p50_ms: f64,
    /// p99 with `reasoner.kind = "knowledge"`, ms.
    pub knowledge_p99_ms: f64,
    /// p50 with the slow LLM, ms.
    pub llm_p50_ms: f64,
    /// p99 with the slow LLM, ms.
    pub llm_p99_ms: f64,
    /// `llm_p99_ms / knowledge_p99_ms`.
    pub p99_ratio: f64,
}

/// What `op3dsg bench llm` measured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LlmHotPath {
    /// Where it was measured.
    pub machine: Machine,
    /// Seconds each LLM answer took.
    pub delay_s: f64,
    /// Requests the server received during the LLM run.
    pub requests: u64,
    /// The run without the LLM.
    pub knowledge: PipelineRun,
    /// The run with the slow LLM.
    pub llm: PipelineRun,
    /// Per stage, both runs.
    pub stages: Vec<StageComparison>,
}

impl LlmHotPath {
    /// The table as text.
    pub fn to_text(&self) -> String {
        use std::fmt::Write as _;
        let mut s = String::new();
        let m = &self.machine;
        let _ = writeln!(s, "machine: {} cores, {} build, {}", m.cores, m.build, m.platform);
        let _ = writeln!(
            s,
            "runs: {} frames each as fast as possible; knowledge {} keyframes in {:.1} s; llm {} keyframes in {:.1} s, {} requests answered after {} s each",
            self.knowledge.frames,
            self.knowledge.keyframes,
            self.knowledge.elapsed_s,
            self.llm.keyframes,
            self.llm.elapsed_s,
            self.requests,
            self.delay_s
        );
        let _ = writeln!(
            s,
            "{:<12} {:>14} {:>14} {:>14} {:>14} {:>10}",
            "stage", "knowledge p50", "knowledge p99", "llm p50", "llm p99", "p99 ratio"
        );
        for st in &self.stages {
            let _ = writeln!(
                s,
                "{:<12} {:>11.3} ms {:>11.3} ms {:>11.3} ms {:>11.3} ms {:>10.2}",
                st.name, st.knowledge_p50_ms, st.knowledge_p99_ms, st.llm_p50_ms, st.llm_p99_ms, st.p99_ratio
            );
        }
        s
    }
}

/// Both runs of `options` (its `frames`, `profile`, `overrides`), the LLM answering after
/// `delay`.
pub fn llm_hot_path(options: &PerfOptions, delay: Duration) -> anyhow::Result<LlmHotPath> {
    let with = |extra: Vec<String>| {
        let mut o = options.clone();
        o.overrides.extend(extra);
        o
    };
    eprintln!("bench llm: {} frames as fast as possible, reasoner.kind = knowledge ...", options.frames);
    let knowledge = pipeline_run(&with(vec!["reasoner.kind=\"knowledge\"".to_owned()]), Mode::AsFastAsPossible)
        .context("the run without the LLM")?;
    let server = SlowChatServer::start("127.0.0.1:0", delay)?;
    eprintln!("bench llm: the same with reasoner.kind = llm at {}, answers after {:?} ...", server.base_url(), delay);
    let llm_overrides = vec![
        "reasoner.kind=\"llm\"".to_owned(),
        format!("reasoner.llm.base_url={:?}", server.base_url()),
        "reasoner.llm.model=\"slow-bench-model\"".to_owned(),
        "reasoner.llm.api_key_env=\"\"".to_owned(),
        format!("reasoner.llm.request_timeout_s={}", (delay.as_secs_f64() + 5.0).min(600.0)),
        "reasoner.llm.refresh_min_changed_nodes=1".to_owned(),
        "reasoner.llm.refresh_period_s=1.0".to_owned(),
    ];
    let llm = pipeline_run(&with(llm_overrides), Mode::AsFastAsPossible).context("the run with the slow LLM")?;
    let requests = server.requests();
    if requests == 0 {
        return Err(anyhow!("the refiner sent no request during the LLM run: the comparison measured nothing"));
    }
    let latency = |run: &PipelineRun, name: &str| {
        run.stages
            .iter()
            .find(|s| s.name == name)
            .map_or((f64::NAN, f64::NAN), |s| (s.latency.p50_ms, s.latency.p99_ms))
    };
    let stages = ["fusion", "prior", "publish", "end_to_end"]
        .iter()
        .map(|&name| {
            let (k50, k99) = latency(&knowledge, name);
            let (l50, l99) = latency(&llm, name);
            StageComparison {
                name: name.to_owned(),
                knowledge_p50_ms: k50,
                knowledge_p99_ms: k99,
                llm_p50_ms: l50,
                llm_p99_ms: l99,
                p99_ratio: l99 / k99,
            }
        })
        .collect();
    Ok(LlmHotPath { machine: Machine::current(), delay_s: delay.as_secs_f64(), requests, knowledge, llm, stages })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_server_answers_a_chat_completion_after_its_delay() {
        let server = SlowChatServer::start("127.0.0.1:0", Duration::from_millis(200)).unwrap();
        let address = server.base_url().trim_start_matches("http://").trim_end_matches("/v1").to_owned();
        let user = json!({"part_of_pairs": [{"part": {"id": 5, "label": "cabinet handle"}, "object": {"id": 1, "label": "cabinet"}}]});
        let body =
            json!({"messages": [{"role": "system", "content": ""}, {"role": "user", "content": user.to_string()}]})
                .to_string();
        let started = Instant::now();
        let mut stream = TcpStream::connect(&address).unwrap();
        write!(stream, "POST /v1/chat/completions HTTP/1.1\r\nHost: x\r\nContent-Length: {}\r\n\r\n{body}", body.len())
            .unwrap();
        let mut response = String::new();
        stream.read_to_string(&mut response).unwrap();
        assert!(started.elapsed() >= Duration::from_millis(200));
        let (head, json_body) = response.split_once("\r\n\r\n").unwrap();
        assert!(head.starts_with("HTTP/1.1 200 OK"), "{head}");
        let completion: Value = serde_json::from_str(json_body).unwrap();
        let content: Value =
            serde_json::from_str(completion["choices"][0]["message"]["content"].as_str().unwrap()).unwrap();
        assert_eq!(content["relations"][0]["relation"], "pull to open or close");
        assert_eq!(server.requests(), 1);
    }
}
