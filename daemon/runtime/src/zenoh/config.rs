//! `[zenoh]`: the one Zenoh session through which the graph leaves the robot's computer — its
//! mode, endpoints, scouting, an optional Zenoh configuration file, the key prefix and the full
//! graph's period.

#[cfg(feature = "zenoh")]
use std::path::Path;
use std::path::PathBuf;
#[cfg(feature = "zenoh")]
use std::str::FromStr;

#[cfg(feature = "zenoh")]
use ::zenoh::config::{Config, EndPoint};
#[cfg(feature = "zenoh")]
use ::zenoh::key_expr::{KeyExpr, keyexpr};
use serde::{Deserialize, Serialize};

/// The prefix when `key_prefix` is empty: `op3dsg/` and this computer's hostname.
pub const DEFAULT_PREFIX_ROOT: &str = "op3dsg";

/// `[zenoh]`: off-robot consumers (operator laptop, fleet server) over one Zenoh session.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ZenohConfig {
    /// Open the session and publish; off by default (nothing leaves the computer).
    pub enabled: bool,
    /// `peer` (talks to other peers and routers directly) or `client` (through the routers or
    /// peers named in `connect`).
    pub mode: ZenohMode,
    /// Endpoints to connect to, e.g. `tcp/192.168.1.10:7447` (a router or a peer).
    pub connect: Vec<String>,
    /// Endpoints to listen on, e.g. `tcp/127.0.0.1:7447`; empty: nothing listens.
    pub listen: Vec<String>,
    /// Discover peers and routers by UDP multicast on the local network.
    pub multicast_scouting: bool,
    /// A complete Zenoh configuration (JSON5, Zenoh's own format: TLS, access control,
    /// authentication, ...); the keys of this section apply on top of it. Relative to the
    /// profile file that sets it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub config_file: Option<PathBuf>,
    /// Key expression every key starts with; empty: `op3dsg/<hostname>`.
    pub key_prefix: String,
    /// The full graph is published on `<prefix>/graph` this often, seconds (deltas on every
    /// version in between).
    pub full_period_s: f64,
    /// Graph versions waiting for the Zenoh thread; older ones are dropped (latest wins, counted
    /// in the health record's `zenoh` queue).
    pub queue_capacity: usize,
}

/// `zenoh.mode`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum ZenohMode {
    /// A peer.
    #[default]
    Peer,
    /// A client of a router or peer.
    Client,
}

impl ZenohMode {
    /// The mode's name in Zenoh's configuration.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Peer => "peer",
            Self::Client => "client",
        }
    }
}

impl Default for ZenohConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            mode: ZenohMode::Peer,
            connect: Vec::new(),
            listen: Vec::new(),
            multicast_scouting: false,
            config_file: None,
            key_prefix: String::new(),
            full_period_s: 1.0,
            queue_capacity: 1,
        }
    }
}

impl ZenohConfig {
    /// Range and syntax checks; errors are `path.field: message`. Without the feature `zenoh`
    /// the endpoints and the key prefix are not parsed (the library that knows their syntax is
    /// not built); the profile cannot turn the stage on then (`Profile::validate`).
    pub fn validate(&self, path: &str) -> Result<(), String> {
        #[cfg(feature = "zenoh")]
        for (field, endpoints) in [("connect", &self.connect), ("listen", &self.listen)] {
            for endpoint in endpoints {
                EndPoint::from_str(endpoint).map_err(|e| {
                    format!("{path}.{field}: {endpoint:?} is not a Zenoh endpoint (e.g. \"tcp/127.0.0.1:7447\"): {e}")
                })?;
            }
        }
        #[cfg(feature = "zenoh")]
        if !self.key_prefix.is_empty() {
            check_prefix(&self.key_prefix).map_err(|e| format!("{path}.key_prefix: {e}"))?;
        }
        if !(self.full_period_s.is_finite() && (0.05..=3600.0).contains(&self.full_period_s)) {
            return Err(format!("{path}.full_period_s: must be within [0.05, 3600] s, got {}", self.full_period_s));
        }
        if !(1..=64).contains(&self.queue_capacity) {
            return Err(format!("{path}.queue_capacity: must be within [1, 64], got {}", self.queue_capacity));
        }
        if self.enabled && self.mode == ZenohMode::Client && self.connect.is_empty() && self.config_file.is_none() {
            return Err(format!("{path}.connect: mode \"client\" needs an endpoint to connect to"));
        }
        #[cfg(feature = "zenoh")]
        if let Some(file) = &self.config_file
            && self.enabled
        {
            self.session_config_from(file).map_err(|e| format!("{path}.config_file: {e}"))?;
        }
        Ok(())
    }

    /// The key prefix in use: `key_prefix`, or `op3dsg/<hostname>` when it is empty.
    pub fn prefix(&self) -> String {
        if self.key_prefix.is_empty() {
            let host = hostname();
            let prefix = format!("{DEFAULT_PREFIX_ROOT}/{host}");
            #[cfg(feature = "zenoh")]
            if check_prefix(&prefix).is_err() {
                return format!("{DEFAULT_PREFIX_ROOT}/unnamed");
            }
            prefix
        } else {
            self.key_prefix.clone()
        }
    }

    /// The session's Zenoh configuration: `config_file` (or Zenoh's defaults), then this
    /// section's keys on top. Errors name the key (`zenoh.<key>: ...`).
    #[cfg(feature = "zenoh")]
    pub fn session_config(&self) -> Result<Config, (String, String)> {
        match &self.config_file {
            Some(file) => self.session_config_from(file).map_err(|e| ("zenoh.config_file".to_owned(), e)),
            None => self.apply(Config::default()),
        }
    }

    #[cfg(feature = "zenoh")]
    fn session_config_from(&self, file: &Path) -> Result<Config, String> {
        let config = Config::from_file(file).map_err(|e| format!("{}: {e}", file.display()))?;
        self.apply(config).map_err(|(key, e)| format!("{key}: {e}"))
    }

    /// This section's keys on top of `config`. Without a configuration file an empty `listen`
    /// means no listener at all (a Zenoh peer otherwise listens on every interface).
    #[cfg(feature = "zenoh")]
    fn apply(&self, mut config: Config) -> Result<Config, (String, String)> {
        let mut set = |key: &str, zenoh_key: &str, value: String| {
            config.insert_json5(zenoh_key, &value).map_err(|e| (format!("zenoh.{key}"), e.to_string()))
        };
        set("mode", "mode", format!("{:?}", self.mode.as_str()))?;
        set("multicast_scouting", "scouting/multicast/enabled", self.multicast_scouting.to_string())?;
        if !self.connect.is_empty() {
            set("connect", "connect/endpoints", json_list(&self.connect))?;
        }
        if !self.listen.is_empty() || self.config_file.is_none() {
            set("listen", "listen/endpoints", json_list(&self.listen))?;
        }
        Ok(config)
    }

    /// Listen endpoints that are reachable from beyond this computer (not loopback).
    #[cfg(feature = "zenoh")]
    pub fn open_listeners(&self) -> Vec<&str> {
        self.listen.iter().map(String::as_str).filter(|e| !is_loopback_endpoint(e)).collect()
    }
}

/// Checks a publishing key prefix: a valid key expression without wildcards.
#[cfg(feature = "zenoh")]
pub fn check_prefix(prefix: &str) -> Result<(), String> {
    let key = KeyExpr::try_from(prefix).map_err(|e| format!("{prefix:?} is not a valid key expression: {e}"))?;
    if key.is_wild() {
        return Err(format!("{prefix:?} holds a wildcard; a publishing prefix must name keys, not match them"));
    }
    let _: &keyexpr = &key;
    Ok(())
}

#[cfg(feature = "zenoh")]
fn json_list(items: &[String]) -> String {
    serde_json::to_string(items).unwrap_or_else(|_| "[]".to_owned())
}

/// Whether an endpoint's address is loopback (`127.0.0.0/8`, `[::1]`, `localhost`).
#[cfg(feature = "zenoh")]
fn is_loopback_endpoint(endpoint: &str) -> bool {
    let Some((_, address)) = endpoint.split_once('/') else { return false };
    let address = address.split(['?', '#']).next().unwrap_or(address);
    let host = match address.rsplit_once(':') {
        Some((host, _port)) => host.trim_start_matches('[').trim_end_matches(']'),
        None => address,
    };
    host == "localhost" || host.parse::<std::net::IpAddr>().is_ok_and(|ip| ip.is_loopback())
}

/// This computer's hostname (`/proc/sys/kernel/hostname`), `unnamed` when it cannot be read.
fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|s| s.trim().to_owned())
        .ok()
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "unnamed".to_owned())
}

#[cfg(all(test, feature = "zenoh"))]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_off_and_listen_nowhere() {
        let config = ZenohConfig::default();
        assert!(!config.enabled);
        config.validate("zenoh").unwrap();
        assert!(config.prefix().starts_with("op3dsg/"));
        let session = config.session_config().unwrap();
        assert_eq!(session.get_json("listen/endpoints").unwrap(), "[]", "a peer listens nowhere");
        assert_eq!(session.get_json("scouting/multicast/enabled").unwrap(), "false");
    }

    #[test]
    fn bad_values_name_their_key() {
        let bad = |change: fn(&mut ZenohConfig)| {
            let mut config = ZenohConfig { enabled: true, ..ZenohConfig::default() };
            change(&mut config);
            config.validate("zenoh").unwrap_err()
        };
        assert!(bad(|c| c.listen = vec!["127.0.0.1:7447".into()]).starts_with("zenoh.listen: "));
        assert!(bad(|c| c.connect = vec!["tcp/".into()]).starts_with("zenoh.connect: "));
        assert!(bad(|c| c.key_prefix = "op3dsg/*".into()).starts_with("zenoh.key_prefix: "));
        assert!(bad(|c| c.key_prefix = "op3dsg//robot".into()).starts_with("zenoh.key_prefix: "));
        assert!(bad(|c| c.full_period_s = 0.0).starts_with("zenoh.full_period_s: "));
        assert!(bad(|c| c.mode = ZenohMode::Client).starts_with("zenoh.connect: "));
        assert!(bad(|c| c.config_file = Some("/nonexistent/zenoh.json5".into())).starts_with("zenoh.config_file: "));
    }

    #[test]
    fn the_section_applies_on_top_of_a_config_file() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("zenoh.json5");
        std::fs::write(&file, r#"{ mode: "client", listen: { endpoints: ["tcp/127.0.0.1:7999"] } }"#).unwrap();
        let config = ZenohConfig {
            enabled: true,
            connect: vec!["tcp/127.0.0.1:7448".into()],
            config_file: Some(file),
            ..ZenohConfig::default()
        };
        config.validate("zenoh").unwrap();
        let session = config.session_config().unwrap();
        assert_eq!(session.get_json("mode").unwrap(), r#""peer""#);
        assert!(session.get_json("connect/endpoints").unwrap().contains("tcp/127.0.0.1:7448"));
        // An empty `listen` keeps the file's listeners.
        assert!(session.get_json("listen/endpoints").unwrap().contains("tcp/127.0.0.1:7999"));
    }

    #[test]
    fn loopback_listeners_are_told_apart() {
        let config = ZenohConfig {
            listen: vec!["tcp/127.0.0.1:7447".into(), "tcp/[::1]:7447".into(), "tcp/0.0.0.0:7447".into()],
            ..ZenohConfig::default()
        };
        assert_eq!(config.open_listeners(), ["tcp/0.0.0.0:7447"]);
    }
}
