//! An OpenAI-compatible chat-completions client over HTTP (reqwest on tokio).
//!
//! One [`ChatClient::complete`] is one HTTP request: `POST <base_url>/chat/completions` with the
//! model, a system and a user message, `temperature`, `max_tokens` and a `response_format`
//! (a strict JSON schema, or `json_object`). It returns the first choice's message content;
//! retries, backoff, the breaker and the budget are the refiner's. The API key travels only in
//! the `Authorization` header, marked sensitive; [`ApiKey`] never prints it.

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

/// Where the key comes from: `api_key_file` (first line), else the variable `api_key_env`;
/// `Ok(None)` when neither is set (a local server without authentication). Errors name the
/// field, never the key.
pub fn load_api_key(config: &LlmConfig) -> Result<Option<ApiKey>, (&'static str, String)> {
    if let Some(path) = &config.api_key_file {
        let text = std::fs::read_to_string(path)
            .map_err(|e| ("reasoner.llm.api_key_file", format!("cannot read {}: {e}", path.display())))?;
        let key = ApiKey::new(text.lines().next().unwrap_or(""));
        if key.is_none() {
            return Err(("reasoner.llm.api_key_file", format!("{} holds no key on its first line", path.display())));
        }
        return Ok(key);
    }
    if config.api_key_env.is_empty() {
        return Ok(None);
    }
    Ok(std::env::var(&config.api_key_env).ok().as_deref().and_then(ApiKey::new))
}

/// Why a call failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CallError {
    /// No answer within `request_timeout_s` (or no connection within `connect_timeout_s`).
    #[error("timed out")]
    Timeout,
    /// Connection or protocol failure.
    #[error("transport error: {0}")]
    Transport(String),
    /// An HTTP error status.
    #[error("HTTP status {status}")]
    Status {
        /// The status code.
        status: u16,
        /// `Retry-After` in seconds, when the server sent one.
        retry_after: Option<Duration>,
    },
    /// A 2xx answer that is not a chat completion with a text message.
    #[error("not a chat completion: {0}")]
    BadEnvelope(String),
}

impl CallError {
    /// Timeouts, transport errors, 429 and 5xx are worth another try.
    pub fn retryable(&self) -> bool {
        match self {
            CallError::Timeout | CallError::Transport(_) => true,
            CallError::Status { status, .. } => *status == 429 || *status >= 500,
            CallError::BadEnvelope(_) => false,
        }
    }
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
            authorization,
        })
    }

    /// The request body for `prompt`.
    pub fn body(&self, prompt: &Prompt) -> Value {
        let response_format = match self.format {
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
        let mut request = self.http.post(&self.url).json(&self.body(prompt));
        if let Some(value) = &self.authorization {
            request = request.header(AUTHORIZATION, value.clone());
        }
        let classify = |e: reqwest::Error| {
            if e.is_timeout() {
                CallError::Timeout
            } else {
                // Without the URL: it is in the profile already, and keeps messages short.
                CallError::Transport(e.without_url().to_string())
            }
        };
        let response = request.send().await.map_err(classify)?;
        let status = response.status();
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
        let completion: Completion =
            serde_json::from_slice(&bytes).map_err(|e| CallError::BadEnvelope(e.to_string()))?;
        completion
            .choices
            .into_iter()
            .next()
            .and_then(|c| c.message.content)
            .ok_or_else(|| CallError::BadEnvelope("no choice with a text message".to_owned()))
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
}
