//! An OpenAI-compatible chat-completions client over HTTP (reqwest on tokio).
//!
//! One [`ChatClient::complete`] is one HTTP request: `POST <base_url>/chat/completions` with the
//! model, a system and a user message, `temperature`, `max_tokens` and a `response_format`
//! (a strict JSON schema, or `json_object`). A server that answers 400 to a `json_schema`
//! request (no structured-output support) is sent `json_object` from then on: that call returns
//! [`CallError::SchemaRefused`] (the refiner repeats it at once, not as a failure) and every
//! later one asks for `json_object`. It returns the first choice's message content;
//! retries, backoff, the breaker and the budget are the refiner's. The API key travels only in
//! the `Authorization` header, marked sensitive; [`ApiKey`] never prints it.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use reqwest::header::{AUTHORIZATION, HeaderValue, RETRY_AFTER};
use serde::Deserialize;
use serde_json::{Value, json};

use super::config::{LlmConfig, ResponseFormat};
use super::prompt::Prompt;

/// An API key. `Debug` and `Display` print `<redacted>`.
#[derive(Clone)]
pub struct ApiKey(String);

impl ApiKey {
    /// Wraps a key (trimmed).
    pub fn new(key: &str) -> Option<Self> {
        let key = key.trim();
        (!key.is_empty()).then(|| Self(key.to_owned()))
    }
}

impl std::fmt::Debug for ApiKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("<redacted>")
    }
}

impl std::fmt::Display for ApiKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("<redacted>")
    }
}

/// Where the key comes from, first match wins: `api_key_file` (first line); the systemd
/// credential `api_key_credential` in `$CREDENTIALS_DIRECTORY` (first line; a missing or empty
/// file counts as none, so the unit's empty placeholder means "no key"); the variable
/// `api_key_env`. `Ok(None)` when none is set (a local server without authentication). Errors
/// name the field, never the key.
pub fn load_api_key(config: &LlmConfig) -> Result<Option<ApiKey>, (&'static str, String)> {
    let credentials = std::env::var_os("CREDENTIALS_DIRECTORY").map(std::path::PathBuf::from);
    load_api_key_from(config, credentials.as_deref(), |name| std::env::var(name).ok())
}

/// [`load_api_key`] with the credentials directory and the environment given.
pub fn load_api_key_from(
    config: &LlmConfig,
    credentials_dir: Option<&std::path::Path>,
    env: impl Fn(&str) -> Option<String>,
) -> Result<Option<ApiKey>, (&'static str, String)> {
    if let Some(path) = &config.api_key_file {
        let text = std::fs::read_to_string(path)
            .map_err(|e| ("reasoner.llm.api_key_file", format!("cannot read {}: {e}", path.display())))?;
        let key = ApiKey::new(text.lines().next().unwrap_or(""));
        if key.is_none() {
            return Err(("reasoner.llm.api_key_file", format!("{} holds no key on its first line", path.display())));
        }
        return Ok(key);
    }
    if let Some(dir) = credentials_dir
        && !config.api_key_credential.is_empty()
    {
        let path = dir.join(&config.api_key_credential);
        match std::fs::read_to_string(&path) {
            Ok(text) => {
                if let Some(key) = ApiKey::new(text.lines().next().unwrap_or("")) {
                    tracing::info!(credential = %path.display(), "LLM API key from the systemd credential");
                    return Ok(Some(key));
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => {
                return Err(("reasoner.llm.api_key_credential", format!("cannot read {}: {e}", path.display())));
            }
        }
    }
    if config.api_key_env.is_empty() {
        return Ok(None);
    }
    Ok(env(&config.api_key_env).as_deref().and_then(ApiKey::new))
}

/// What a transport error came from, found by walking the error's source chain.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TransportCause {
    /// Nothing listens at the address (`ECONNREFUSED`).
    Refused,
    /// The host name did not resolve.
    Dns,
    /// TLS handshake or certificate failure.
    Tls,
    /// Any other failure to connect (unreachable network, ...).
    Connect,
    /// The connection broke after it was made (reset, closed early, protocol error).
    Other,
}

impl TransportCause {
    /// Short name for logs and health (`op3dsg_ipc_types::REFINER_ERRORS`).
    pub fn name(self) -> &'static str {
        match self {
            TransportCause::Refused => "refused",
            TransportCause::Dns => "dns",
            TransportCause::Tls => "tls",
            TransportCause::Connect => "connect",
            TransportCause::Other => "transport",
        }
    }
}

/// Why a call failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CallError {
    /// No answer within `request_timeout_s` (or no connection within `connect_timeout_s`).
    #[error("timed out")]
    Timeout,
    /// Connection or protocol failure; `detail` is the whole source chain.
    #[error("transport error ({}): {detail}", cause.name())]
    Transport {
        /// What it came from.
        cause: TransportCause,
        /// The error and its sources, `: `-separated.
        detail: String,
    },
    /// An HTTP error status.
    #[error("HTTP status {status}")]
    Status {
        /// The status code.
        status: u16,
        /// `Retry-After` in seconds, when the server sent one.
        retry_after: Option<Duration>,
    },
    /// A 2xx answer that is not a chat completion with a text message (an HTML page, an empty
    /// `choices` list, null content): a failure like any other, it feeds the breaker.
    #[error("not a chat completion: {0}")]
    BadEnvelope(String),
    /// A 400 to a request with `response_format = json_schema`: the server has no structured
    /// output. The client asks for `json_object` from now on; not a failure of the endpoint.
    #[error("HTTP status 400 to response_format json_schema: {detail}")]
    SchemaRefused {
        /// `true` for the first such answer of this client (log it once).
        first: bool,
        /// The start of the server's error body.
        detail: String,
    },
}

impl CallError {
    /// Timeouts, transport errors, 429 and 5xx are worth another try.
    pub fn retryable(&self) -> bool {
        match self {
            CallError::Timeout | CallError::Transport { .. } => true,
            CallError::Status { status, .. } => *status == 429 || *status >= 500,
            CallError::BadEnvelope(_) => false,
            CallError::SchemaRefused { .. } => true,
        }
    }

    /// Short name of the kind of failure (`op3dsg_ipc_types::REFINER_ERRORS`).
    pub fn name(&self) -> &'static str {
        match self {
            CallError::Timeout => "timeout",
            CallError::Transport { cause, .. } => cause.name(),
            CallError::Status { status: 429, .. } => "rate_limited",
            CallError::Status { .. } | CallError::SchemaRefused { .. } => "http_status",
            CallError::BadEnvelope(_) => "not_chat",
        }
    }
}

/// A reqwest error as a [`CallError`]: timeouts apart, the cause is read off the source chain
/// (an `io::Error` of kind `ConnectionRefused`, a resolver or TLS error), and the detail lists
/// every source (reqwest's own message alone is "error sending request").
fn classify(error: reqwest::Error) -> CallError {
    use std::error::Error as _;
    if error.is_timeout() {
        return CallError::Timeout;
    }
    let mut messages = Vec::new();
    let mut refused = false;
    let mut source: Option<&(dyn std::error::Error + 'static)> = error.source();
    while let Some(e) = source {
        if let Some(io) = e.downcast_ref::<std::io::Error>() {
            refused |= io.kind() == std::io::ErrorKind::ConnectionRefused;
            if io.kind() == std::io::ErrorKind::TimedOut {
                return CallError::Timeout;
            }
        }
        let text = e.to_string();
        if messages.last() != Some(&text) {
            messages.push(text);
        }
        source = e.source();
    }
    let chain = messages.join(": ").to_lowercase();
    let cause = if refused || chain.contains("connection refused") {
        TransportCause::Refused
    } else if chain.contains("dns error") || chain.contains("failed to lookup address") || chain.contains("resolve") {
        TransportCause::Dns
    } else if chain.contains("tls") || chain.contains("certificate") || chain.contains("handshake") {
        TransportCause::Tls
    } else if error.is_connect() {
        TransportCause::Connect
    } else {
        TransportCause::Other
    };
    // Without the URL: it is in the profile already, and keeps messages short.
    let mut detail = error.without_url().to_string();
    for m in messages {
        detail.push_str(": ");
        detail.push_str(&m);
    }
    CallError::Transport { cause, detail }
}

#[derive(Deserialize)]
struct Completion {
    choices: Vec<Choice>,
}

#[derive(Deserialize)]
struct Choice {
    message: Message,
}

#[derive(Deserialize)]
struct Message {
    content: Option<String>,
}

/// The HTTP client of one endpoint.
#[derive(Debug, Clone)]
pub struct ChatClient {
    http: reqwest::Client,
    url: String,
    model: String,
    temperature: f32,
    max_tokens: u32,
    format: ResponseFormat,
    /// The server answered 400 to `json_schema`: `json_object` is sent instead.
    schema_refused: Arc<AtomicBool>,
    authorization: Option<HeaderValue>,
}

impl ChatClient {
    /// A client for `config`'s endpoint with `key`.
    pub fn new(config: &LlmConfig, key: Option<&ApiKey>) -> Result<Self, String> {
        let http = reqwest::Client::builder()
            .timeout(config.request_timeout())
            .connect_timeout(config.connect_timeout())
            .build()
            .map_err(|e| format!("HTTP client: {e}"))?;
        let authorization = match key {
            Some(key) => {
                let mut value = HeaderValue::from_str(&format!("Bearer {}", key.0))
                    .map_err(|_| "the API key holds characters a header cannot carry".to_owned())?;
                value.set_sensitive(true);
                Some(value)
            }
            None => None,
        };
        Ok(Self {
            http,
            url: format!("{}/chat/completions", config.base_url.trim_end_matches('/')),
            model: config.model.clone(),
            temperature: config.temperature,
            max_tokens: config.max_tokens,
            format: config.response_format,
            schema_refused: Arc::new(AtomicBool::new(false)),
            authorization,
        })
    }

    /// The `response_format` sent now: the configured one, or `json_object` after the server
    /// refused `json_schema`.
    pub fn format_in_use(&self) -> ResponseFormat {
        if self.schema_refused.load(Ordering::Relaxed) { ResponseFormat::JsonObject } else { self.format }
    }

    /// Whether `json_object` is sent because the server refused `json_schema`.
    pub fn fell_back(&self) -> bool {
        self.schema_refused.load(Ordering::Relaxed)
    }

    /// The request body for `prompt`.
    pub fn body(&self, prompt: &Prompt) -> Value {
        self.body_as(prompt, self.format_in_use())
    }

    fn body_as(&self, prompt: &Prompt, format: ResponseFormat) -> Value {
        let response_format = match format {
            ResponseFormat::JsonSchema => json!({
                "type": "json_schema",
                "json_schema": {"name": prompt.agent.name(), "strict": true, "schema": prompt.schema},
            }),
            ResponseFormat::JsonObject => json!({"type": "json_object"}),
        };
        json!({
            "model": self.model,
            "messages": [
                {"role": "system", "content": prompt.system},
                {"role": "user", "content": prompt.user},
            ],
            "temperature": self.temperature,
            "max_tokens": self.max_tokens,
            "response_format": response_format,
        })
    }

    /// Sends `prompt`; the first choice's message content.
    pub async fn complete(&self, prompt: &Prompt) -> Result<String, CallError> {
        let format = self.format_in_use();
        let mut request = self.http.post(&self.url).json(&self.body_as(prompt, format));
        if let Some(value) = &self.authorization {
            request = request.header(AUTHORIZATION, value.clone());
        }
        let response = request.send().await.map_err(classify)?;
        let status = response.status();
        if status == reqwest::StatusCode::BAD_REQUEST && format == ResponseFormat::JsonSchema {
            let bytes = response.bytes().await.unwrap_or_default();
            let detail = String::from_utf8_lossy(&bytes[..bytes.len().min(200)]).replace(char::is_control, " ");
            let first = !self.schema_refused.swap(true, Ordering::Relaxed);
            return Err(CallError::SchemaRefused { first, detail });
        }
        if !status.is_success() {
            let retry_after = response
                .headers()
                .get(RETRY_AFTER)
                .and_then(|v| v.to_str().ok())
                .and_then(|v| v.trim().parse::<f64>().ok())
                .filter(|s| s.is_finite() && *s >= 0.0)
                .map(Duration::from_secs_f64);
            return Err(CallError::Status { status: status.as_u16(), retry_after });
        }
        let bytes = response.bytes().await.map_err(classify)?;
        let completion: Completion = serde_json::from_slice(&bytes).map_err(|e| {
            let body = String::from_utf8_lossy(&bytes[..bytes.len().min(60)]).replace(char::is_control, " ");
            CallError::BadEnvelope(format!("{e} (body starts {body:?})"))
        })?;
        let Some(choice) = completion.choices.into_iter().next() else {
            return Err(CallError::BadEnvelope("empty \"choices\" list".to_owned()));
        };
        choice.message.content.ok_or_else(|| CallError::BadEnvelope("the message's content is null".to_owned()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_key_never_prints() {
        let key = ApiKey::new(" sk-secret-123 \n").unwrap();
        assert_eq!(format!("{key} {key:?}"), "<redacted> <redacted>");
        let client = ChatClient::new(&LlmConfig::default(), Some(&key)).unwrap();
        assert!(!format!("{client:?}").contains("sk-secret-123"), "{client:?}");
    }

    fn call(base_url: String) -> Result<String, CallError> {
        let config = LlmConfig { base_url, model: "m".to_owned(), connect_timeout_s: 5.0, ..LlmConfig::default() };
        let client = ChatClient::new(&config, None).unwrap();
        let prompt = Prompt {
            agent: super::super::prompt::Agent::Local,
            system: "s".to_owned(),
            user: "{}".to_owned(),
            schema: json!({}),
        };
        let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
        runtime.block_on(client.complete(&prompt))
    }

    #[test]
    fn a_refused_connection_names_its_cause() {
        let port = {
            let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
            listener.local_addr().unwrap().port()
        };
        let error = call(format!("http://127.0.0.1:{port}/v1")).unwrap_err();
        let CallError::Transport { cause, detail } = &error else { panic!("{error:?}") };
        assert_eq!(*cause, TransportCause::Refused, "{detail}");
        assert_eq!(error.name(), "refused");
        let text = error.to_string();
        assert!(text.starts_with("transport error (refused): error sending request"), "{text}");
        assert!(text.to_lowercase().contains("refused"), "the source chain is in the message: {text}");
        assert!(!text.contains(&port.to_string()), "no URL: {text}");
    }

    #[test]
    fn every_failure_kind_has_a_health_name() {
        let errors = [
            CallError::Timeout,
            CallError::Transport { cause: TransportCause::Dns, detail: String::new() },
            CallError::Transport { cause: TransportCause::Tls, detail: String::new() },
            CallError::Transport { cause: TransportCause::Connect, detail: String::new() },
            CallError::Transport { cause: TransportCause::Other, detail: String::new() },
            CallError::Transport { cause: TransportCause::Refused, detail: String::new() },
            CallError::Status { status: 500, retry_after: None },
            CallError::Status { status: 429, retry_after: None },
            CallError::BadEnvelope(String::new()),
        ];
        for e in &errors {
            assert!(op3dsg_ipc_types::REFINER_ERRORS[1..].contains(&e.name()), "{e:?}");
        }
        assert_eq!(errors.len(), op3dsg_ipc_types::REFINER_ERRORS.len() - 1);
    }

    #[test]
    fn the_key_file_wins_and_errors_name_the_field() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("llm.key");
        std::fs::write(&path, "sk-from-file\n").unwrap();
        let config = LlmConfig { api_key_file: Some(path.clone()), ..LlmConfig::default() };
        assert!(load_api_key(&config).unwrap().is_some_and(|k| k.0 == "sk-from-file"));
        let missing = LlmConfig { api_key_file: Some(dir.path().join("none")), ..LlmConfig::default() };
        assert_eq!(load_api_key(&missing).unwrap_err().0, "reasoner.llm.api_key_file");
        let none = LlmConfig { api_key_env: String::new(), ..LlmConfig::default() };
        assert!(load_api_key(&none).unwrap().is_none());
    }

    #[test]
    fn the_systemd_credential_comes_between_the_file_and_the_variable() {
        let dir = tempfile::tempdir().unwrap();
        let env = |name: &str| (name == "OP3DSG_LLM_API_KEY").then(|| "sk-from-env".to_owned());
        let config = LlmConfig::default();
        let key = |dir: Option<&std::path::Path>, config: &LlmConfig| {
            load_api_key_from(config, dir, env).unwrap().map(|k| k.0)
        };
        // No credential file yet: the variable.
        assert_eq!(key(Some(dir.path()), &config).as_deref(), Some("sk-from-env"));
        // The unit's empty placeholder counts as none.
        std::fs::write(dir.path().join("llm-api-key"), "").unwrap();
        assert_eq!(key(Some(dir.path()), &config).as_deref(), Some("sk-from-env"));
        std::fs::write(dir.path().join("llm-api-key"), "sk-from-credential\n").unwrap();
        assert_eq!(key(Some(dir.path()), &config).as_deref(), Some("sk-from-credential"));
        // Not under systemd: no credentials directory, the variable.
        assert_eq!(key(None, &config).as_deref(), Some("sk-from-env"));
        // api_key_file wins over the credential.
        let file = dir.path().join("llm.key");
        std::fs::write(&file, "sk-from-file\n").unwrap();
        let with_file = LlmConfig { api_key_file: Some(file), ..LlmConfig::default() };
        assert_eq!(key(Some(dir.path()), &with_file).as_deref(), Some("sk-from-file"));
        // An empty name never looks.
        let off = LlmConfig { api_key_credential: String::new(), ..LlmConfig::default() };
        assert_eq!(key(Some(dir.path()), &off).as_deref(), Some("sk-from-env"));
        // A credential that cannot be read names the field.
        std::fs::remove_file(dir.path().join("llm-api-key")).unwrap();
        std::fs::create_dir(dir.path().join("llm-api-key")).unwrap();
        assert_eq!(load_api_key_from(&config, Some(dir.path()), env).unwrap_err().0, "reasoner.llm.api_key_credential");
        assert!(
            LlmConfig { api_key_credential: "sk abc/def".to_owned(), ..LlmConfig::default() }
                .validate("reasoner.llm", false)
                .is_err()
        );
    }
}
