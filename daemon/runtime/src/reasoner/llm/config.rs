//! `[reasoner.llm]`: the chat-completions endpoint and the refiner's policies (see the keys in
//! `profiles/base.toml`). The API key is never part of a profile: only the name of the
//! environment variable or the path of the file that holds it.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Duration;

use serde::{Deserialize, Serialize};

/// How the answer is constrained to JSON (`response_format` of the request).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ResponseFormat {
    /// `{"type": "json_schema", ...}` with a strict schema per agent (OpenAI, vLLM, llama.cpp).
    JsonSchema,
    /// `{"type": "json_object"}` (servers without schema support); the gate parses as strictly.
    JsonObject,
}

/// `[reasoner.llm]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LlmConfig {
    /// Base URL of an OpenAI-compatible API, e.g. `https://api.openai.com/v1`; requests go to
    /// `<base_url>/chat/completions`. Required with `reasoner.kind = "llm"`.
    pub base_url: String,
    /// Model name sent with each request.
    pub model: String,
    /// Environment variable holding the API key (read once at start-up). Empty: none.
    pub api_key_env: String,
    /// File holding the API key (first line, trimmed); wins over `api_key_env`. Relative to the
    /// profile file that sets it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub api_key_file: Option<PathBuf>,
    /// Name of a systemd credential holding the API key (`LoadCredential=` in
    /// `systemd/op3dsgd.service`): read from `$CREDENTIALS_DIRECTORY/<name>` (first line) when
    /// that variable is set and the file holds a key; between `api_key_file` and `api_key_env`.
    /// Empty: never look.
    #[serde(default = "default_api_key_credential")]
    pub api_key_credential: String,
    /// `json_schema` or `json_object`.
    pub response_format: ResponseFormat,
    /// Fields an answer or one of its items carries beyond the schema's are ignored (`true`);
    /// `false`: such an item (or answer) is rejected as `malformed`.
    #[serde(default = "default_true")]
    pub ignore_unknown_fields: bool,
    /// Sampling temperature.
    pub temperature: f32,
    /// Upper bound of answer tokens per call.
    pub max_tokens: u32,
    /// Whole-request timeout (connect, send, wait, read), seconds.
    pub request_timeout_s: f64,
    /// Connect timeout, seconds.
    pub connect_timeout_s: f64,
    /// Retries of a failed call (timeouts, transport errors, 429 and 5xx; other statuses are
    /// not retried).
    pub max_retries: u32,
    /// First backoff, seconds; doubled per retry up to `backoff_max_s`. A `Retry-After` header
    /// (seconds) is honoured when longer, up to `backoff_max_s`.
    pub backoff_initial_s: f64,
    /// Longest wait before a retry, seconds.
    pub backoff_max_s: f64,
    /// Consecutive failed calls (after their retries) that open the circuit breaker.
    pub breaker_failures: u32,
    /// How long an open breaker refuses calls, seconds; then one refresh tries again.
    pub breaker_cooldown_s: f64,
    /// Requests in flight at most (the three agents share this limit).
    pub max_concurrent_calls: u32,
    /// Requests per rolling hour at most, retries included; beyond, refreshes wait.
    pub hourly_call_budget: u32,
    /// Refresh once this many nodes were added, removed or relabelled since the last refresh.
    pub refresh_min_changed_nodes: u32,
    /// Refresh after this long when the graph changed at all since the last refresh, seconds.
    pub refresh_period_s: f64,
    /// Nearest canonical phrase by text-embedding cosine similarity: accepted at or above this
    /// (used only with `[text_encoder] enabled = true`).
    pub embedding_min_similarity: f32,
    /// Nodes (or pairs) listed in one prompt at most; beyond, the most confident are kept.
    pub max_prompt_items: u32,
    /// The plausibility rules of the verification gate (`[reasoner.llm.plausibility]`).
    #[serde(default)]
    pub plausibility: PlausibilityConfig,
}

/// `[reasoner.llm.plausibility]`: the gate's geometry and knowledge rules for canonical but
/// implausible items (see `crate::reasoner::llm::plausibility`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PlausibilityConfig {
    /// `false`: only ids, kinds and canonical labels are checked.
    pub enabled: bool,
    /// A local relation's part and its object: their boxes at most this far apart, metres.
    pub part_max_gap_m: f32,
    /// Per functional relation (phrase, `_` for spaces): a remote relation's source and target
    /// centres at most this far apart, metres; tightens the knowledge base's `max_distance_m` of
    /// the template the relation comes from (relations not listed: the template's alone).
    pub remote_max_distance_m: BTreeMap<String, f32>,
    /// Per affordance: a part node whose box's longest side exceeds this, metres, cannot afford
    /// it (affordances not listed: no limit). Objects are not limited: they afford through
    /// their parts.
    pub part_max_extent_m: BTreeMap<String, f32>,
}

impl Default for PlausibilityConfig {
    fn default() -> Self {
        let extent = [
            ("rotate", 0.5),
            ("key_press", 0.6),
            ("tip_push", 0.5),
            ("hook_pull", 1.5),
            ("pinch_pull", 0.3),
            ("hook_turn", 0.6),
            ("foot_push", 0.6),
            ("plug_in", 0.5),
            ("unplug", 0.5),
        ];
        Self {
            enabled: true,
            part_max_gap_m: 0.15,
            remote_max_distance_m: BTreeMap::new(),
            part_max_extent_m: extent.iter().map(|&(k, v)| (k.to_owned(), v)).collect(),
        }
    }
}

impl PlausibilityConfig {
    /// Range checks and canonical keys; errors are `path.field: message`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        let canonical = |key: &str, table: &[&str]| {
            let key = super::gate::normalise(key);
            table.iter().position(|p| super::gate::normalise(p) == key)
        };
        if !(self.part_max_gap_m.is_finite() && self.part_max_gap_m >= 0.0 && self.part_max_gap_m <= 10.0) {
            return Err(format!("{path}.part_max_gap_m: must be within [0, 10] metres, got {}", self.part_max_gap_m));
        }
        for (field, map, table, what) in [
            (
                "remote_max_distance_m",
                &self.remote_max_distance_m,
                &op3dsg_ipc_types::FUNCTIONAL_RELATIONS[..],
                "functional relation",
            ),
            ("part_max_extent_m", &self.part_max_extent_m, &op3dsg_ipc_types::AFFORDANCES[..], "affordance"),
        ] {
            for (key, value) in map {
                if canonical(key, table).is_none() {
                    return Err(format!("{path}.{field}.{key}: not a canonical {what} (one of {table:?})"));
                }
                if !(value.is_finite() && *value > 0.0 && *value <= 100.0) {
                    return Err(format!("{path}.{field}.{key}: must be within (0, 100] metres, got {value}"));
                }
            }
        }
        Ok(())
    }
}

/// The credential name `systemd/op3dsgd.service` loads the key under.
pub const DEFAULT_API_KEY_CREDENTIAL: &str = "llm-api-key";

fn default_api_key_credential() -> String {
    DEFAULT_API_KEY_CREDENTIAL.to_owned()
}

impl Default for LlmConfig {
    fn default() -> Self {
        Self {
            base_url: String::new(),
            model: String::new(),
            api_key_env: "OP3DSG_LLM_API_KEY".to_owned(),
            api_key_file: None,
            api_key_credential: default_api_key_credential(),
            response_format: ResponseFormat::JsonSchema,
            ignore_unknown_fields: true,
            temperature: 0.0,
            max_tokens: 4096,
            request_timeout_s: 60.0,
            connect_timeout_s: 5.0,
            max_retries: 2,
            backoff_initial_s: 1.0,
            backoff_max_s: 30.0,
            breaker_failures: 3,
            breaker_cooldown_s: 120.0,
            max_concurrent_calls: 3,
            hourly_call_budget: 360,
            refresh_min_changed_nodes: 5,
            refresh_period_s: 30.0,
            embedding_min_similarity: 0.8,
            max_prompt_items: 400,
            plausibility: PlausibilityConfig::default(),
        }
    }
}

fn default_true() -> bool {
    true
}

fn seconds(s: f64) -> Duration {
    Duration::from_secs_f64(s.clamp(0.0, 1e9))
}

impl LlmConfig {
    /// Range checks; errors are `path.field: message`. `required`: the LLM is in use (base URL
    /// and model must be set).
    pub fn validate(&self, path: &str, required: bool) -> Result<(), String> {
        if required {
            if self.base_url.trim().is_empty() {
                return Err(format!("{path}.base_url: required with reasoner.kind = \"llm\""));
            }
            if self.model.trim().is_empty() {
                return Err(format!("{path}.model: required with reasoner.kind = \"llm\""));
            }
        }
        let scheme_ok = self.base_url.starts_with("http://") || self.base_url.starts_with("https://");
        if !(self.base_url.is_empty() || scheme_ok) {
            return Err(format!("{path}.base_url: must start with http:// or https://, got {:?}", self.base_url));
        }
        if !self.api_key_env.is_empty() && !self.api_key_env.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
            return Err(format!(
                "{path}.api_key_env: must be an environment variable name (letters, digits, _), not the key itself"
            ));
        }
        if !self.api_key_credential.chars().all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c)) {
            return Err(format!(
                "{path}.api_key_credential: must be a credential name (letters, digits, '-', '_', '.'), not the key itself"
            ));
        }
        if self.api_key_file.as_ref().is_some_and(|p| p.as_os_str().is_empty()) {
            return Err(format!("{path}.api_key_file: must not be empty"));
        }
        if !(0.0..=2.0).contains(&self.temperature) {
            return Err(format!("{path}.temperature: must be within [0, 2], got {}", self.temperature));
        }
        if !(64..=65_536).contains(&self.max_tokens) {
            return Err(format!("{path}.max_tokens: must be within [64, 65536], got {}", self.max_tokens));
        }
        for (field, value, max) in [
            ("request_timeout_s", self.request_timeout_s, 600.0),
            ("connect_timeout_s", self.connect_timeout_s, 600.0),
            ("backoff_max_s", self.backoff_max_s, 3600.0),
            ("breaker_cooldown_s", self.breaker_cooldown_s, 86_400.0),
            ("refresh_period_s", self.refresh_period_s, 86_400.0),
        ] {
            if !(value > 0.0 && value <= max) {
                return Err(format!("{path}.{field}: must be within (0, {max}] seconds, got {value}"));
            }
        }
        if !(0.0..=self.backoff_max_s).contains(&self.backoff_initial_s) {
            return Err(format!(
                "{path}.backoff_initial_s: must be within [0, backoff_max_s = {}] seconds, got {}",
                self.backoff_max_s, self.backoff_initial_s
            ));
        }
        if self.max_retries > 10 {
            return Err(format!("{path}.max_retries: must be at most 10, got {}", self.max_retries));
        }
        if !(1..=1000).contains(&self.breaker_failures) {
            return Err(format!("{path}.breaker_failures: must be within [1, 1000], got {}", self.breaker_failures));
        }
        if !(1..=64).contains(&self.max_concurrent_calls) {
            return Err(format!(
                "{path}.max_concurrent_calls: must be within [1, 64], got {}",
                self.max_concurrent_calls
            ));
        }
        if self.hourly_call_budget == 0 {
            return Err(format!("{path}.hourly_call_budget: must be at least 1"));
        }
        if self.refresh_min_changed_nodes == 0 {
            return Err(format!("{path}.refresh_min_changed_nodes: must be at least 1"));
        }
        if !(0.0..=1.0).contains(&self.embedding_min_similarity) {
            return Err(format!(
                "{path}.embedding_min_similarity: must be within [0, 1], got {}",
                self.embedding_min_similarity
            ));
        }
        if !(1..=10_000).contains(&self.max_prompt_items) {
            return Err(format!("{path}.max_prompt_items: must be within [1, 10000], got {}", self.max_prompt_items));
        }
        self.plausibility.validate(&format!("{path}.plausibility"))
    }

    /// `request_timeout_s` as a duration.
    pub fn request_timeout(&self) -> Duration {
        seconds(self.request_timeout_s)
    }
    /// `connect_timeout_s` as a duration.
    pub fn connect_timeout(&self) -> Duration {
        seconds(self.connect_timeout_s)
    }
    /// `backoff_initial_s` as a duration.
    pub fn backoff_initial(&self) -> Duration {
        seconds(self.backoff_initial_s)
    }
    /// `backoff_max_s` as a duration.
    pub fn backoff_max(&self) -> Duration {
        seconds(self.backoff_max_s)
    }
    /// `breaker_cooldown_s` as a duration.
    pub fn breaker_cooldown(&self) -> Duration {
        seconds(self.breaker_cooldown_s)
    }
    /// `refresh_period_s` as a duration.
    pub fn refresh_period(&self) -> Duration {
        seconds(self.refresh_period_s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_pass_and_errors_name_the_field() {
        assert_eq!(LlmConfig::default().validate("reasoner.llm", false), Ok(()));
        assert_eq!(
            LlmConfig::default().validate("reasoner.llm", true),
            Err("reasoner.llm.base_url: required with reasoner.kind = \"llm\"".to_owned())
        );
        let bad = LlmConfig { api_key_env: "sk-abc.def".to_owned(), ..LlmConfig::default() };
        let err = bad.validate("reasoner.llm", false).unwrap_err();
        assert!(err.starts_with("reasoner.llm.api_key_env:") && !err.contains("sk-abc"), "{err}");
        let bad = LlmConfig { request_timeout_s: 0.0, ..LlmConfig::default() };
        assert!(bad.validate("reasoner.llm", false).unwrap_err().starts_with("reasoner.llm.request_timeout_s:"));
        let bad = LlmConfig { base_url: "ftp://x".to_owned(), ..LlmConfig::default() };
        assert!(bad.validate("reasoner.llm", false).unwrap_err().starts_with("reasoner.llm.base_url:"));
    }
}
