//! The process's one Zenoh session on the robot's network (`[zenoh]`): the composition opens it
//! once when the Zenoh stage (`zenoh.enabled`) or remote detection (`detector.kind = "remote"`)
//! needs it, and both declare what they serve on it. One session means one set of listeners and
//! connections: a worker that connects to the robot's `zenoh.listen`, or listens where the
//! robot's `zenoh.connect` points, reaches every feature at once. (The ROS 2 side's session,
//! `[ros2]`, is another network's and stays its own.)

#[cfg(feature = "zenoh")]
use ::zenoh::Wait;
#[cfg(feature = "zenoh")]
use tracing::{debug, info, warn};

use super::config::ZenohConfig;

/// The open session, shared by clone (a clone is a handle to the same session).
#[cfg(feature = "zenoh")]
#[derive(Clone)]
pub struct ZenohSession {
    session: ::zenoh::Session,
}

/// Without the feature `zenoh` there is no session to open (`Profile::validate` refuses what
/// would need one), so the type has no value.
#[cfg(not(feature = "zenoh"))]
#[derive(Clone, Debug)]
pub enum ZenohSession {}

#[cfg(feature = "zenoh")]
impl std::fmt::Debug for ZenohSession {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ZenohSession").field("zid", &self.session.zid().to_string()).finish()
    }
}

#[cfg(feature = "zenoh")]
impl ZenohSession {
    /// Opens the session `config` describes; errors name the keys.
    pub fn open(config: &ZenohConfig) -> Result<Self, String> {
        let zenoh_config = config.session_config().map_err(|(key, e)| format!("{key}: {e}"))?;
        let session = ::zenoh::open(zenoh_config).wait().map_err(|e| {
            format!("zenoh: the session did not open (zenoh.listen, zenoh.connect, zenoh.config_file): {e}")
        })?;
        let open = config.open_listeners();
        if !open.is_empty() {
            warn!(
                endpoints = ?open,
                "zenoh listens beyond loopback: anyone who reaches these endpoints reads the graph and can answer detection requests"
            );
        }
        info!(
            mode = config.mode.as_str(),
            listen = ?config.listen,
            connect = ?config.connect,
            zid = %session.zid(),
            "zenoh session open"
        );
        Ok(Self { session })
    }

    /// The session, for declaring publishers, subscribers and queryables on it.
    pub fn session(&self) -> &::zenoh::Session {
        &self.session
    }

    /// Closes the session for every holder (after the stages that use it have ended).
    pub fn close(&self) {
        if let Err(e) = self.session.close().wait() {
            debug!(error = %e, "zenoh session close failed");
        }
    }
}

#[cfg(not(feature = "zenoh"))]
impl ZenohSession {
    /// Never called: there is no value of the type.
    pub fn open(_config: &ZenohConfig) -> Result<Self, String> {
        Err("zenoh: this build leaves Zenoh out (cargo feature `zenoh`)".to_owned())
    }

    /// Never called: there is no value of the type.
    pub fn close(&self) {
        match *self {}
    }
}
