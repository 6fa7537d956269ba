//! `[ros2]`: the robot's own ROS 2 software, reached through Zenoh — how (key style, domain,
//! namespace, the Zenoh endpoints of the ROS side) and, in `[ros2.tf]`, which frames give the
//! camera's pose when `pose.source = "ros2"`.

use std::str::FromStr;

#[cfg(feature = "zenoh")]
use ::zenoh::config::{Config, EndPoint};
use op3dsg_ros2::keys::{Distro, KeyStyle, check_node_name, fully_qualified_topic, normalize_namespace};
use serde::{Deserialize, Serialize};

/// `[ros2]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Ros2Config {
    /// Zenoh endpoints of the ROS side to connect to as a client: the `rmw_zenoh` router
    /// (`rmw_zenohd`, `tcp/127.0.0.1:7447` by default) or `zenoh-bridge-ros2dds` (the same port).
    pub connect: Vec<String>,
    /// `rmw_zenoh` (ROS 2's Zenoh middleware) or `bridge` (`zenoh-bridge-ros2dds` in front of a
    /// DDS middleware, the Humble default).
    pub key_style: String,
    /// The ROS distribution on the other side: `humble`, or `jazzy` / `kilted` / `rolling` (type
    /// hashes in `rmw_zenoh` keys).
    pub distro: String,
    /// `ROS_DOMAIN_ID` (`rmw_zenoh` keys start with it; the bridge has its own setting).
    pub domain_id: u32,
    /// With `rmw_zenoh`: the namespace relative topic names resolve in; with `bridge`: the
    /// bridge's `namespace` setting (it prefixes every key). Empty: none.
    pub namespace: String,
    /// The camera's pose from tf (`pose.source = "ros2"`).
    pub tf: TfInputConfig,
    /// The graph and the map out to ROS 2 (each topic off by default).
    pub out: Ros2OutConfig,
}

/// `[ros2.out]`: what the daemon publishes to ROS 2 (RViz, ROS planners). Each topic is off
/// until enabled; with any on, the daemon joins the ROS graph as the node `node_name`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Ros2OutConfig {
    /// `visualization_msgs/MarkerArray` for RViz: a box and a label per node, parts coloured
    /// apart, a line per part-of and functional edge; markers of removed nodes deleted.
    pub markers: bool,
    /// Its topic.
    pub markers_topic: String,
    /// The occupancy map as `nav_msgs/OccupancyGrid` in the world frame.
    pub occupancy: bool,
    /// Its topic.
    pub occupancy_topic: String,
    /// The graph as JSON (`op3dsg dump --json`'s form) in `std_msgs/String`.
    pub graph_json: bool,
    /// Its topic.
    pub graph_json_topic: String,
    /// Shortest time between two markers or JSON messages, milliseconds (the newest graph version
    /// goes out; versions in between are skipped).
    pub period_ms: u64,
    /// Longest time between two occupancy grids, milliseconds: an unchanged map is sent again so
    /// that a late RViz gets it (the topic is volatile).
    pub occupancy_repeat_ms: u64,
    /// The ROS node name the publishers hang under (`ros2 node list`).
    pub node_name: String,
}

impl Default for Ros2OutConfig {
    fn default() -> Self {
        Self {
            markers: false,
            markers_topic: "/op3dsg/markers".to_owned(),
            occupancy: false,
            occupancy_topic: "/op3dsg/occupancy".to_owned(),
            graph_json: false,
            graph_json_topic: "/op3dsg/graph_json".to_owned(),
            period_ms: 500,
            occupancy_repeat_ms: 5000,
            node_name: "op3dsg".to_owned(),
        }
    }
}

impl Ros2OutConfig {
    /// Whether any topic is on (the stage runs).
    pub fn any(&self) -> bool {
        self.markers || self.occupancy || self.graph_json
    }
}

/// `[ros2.tf]`: the camera's pose from the tf tree.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TfInputConfig {
    /// The map frame (the graph's coordinates); empty: `world.frame_id`.
    pub world_frame: String,
    /// The colour camera's optical frame as ROS names it (`camera_color_optical_frame` on the
    /// Stretch's head camera).
    pub camera_frame: String,
    /// Look up `world_frame → base_frame` instead and compose it with `pose.base_from_camera`
    /// (a rigid camera mount whose links are not in the tf tree); empty: use `camera_frame`.
    pub base_frame: String,
    /// The dynamic transforms' topic.
    pub tf_topic: String,
    /// The static transforms' topic.
    pub tf_static_topic: String,
    /// Dynamic transforms kept for lookups, seconds (static ones are kept for ever).
    pub window_s: f64,
}

impl Default for Ros2Config {
    fn default() -> Self {
        Self {
            connect: vec!["tcp/127.0.0.1:7447".to_owned()],
            key_style: "rmw_zenoh".to_owned(),
            distro: "humble".to_owned(),
            domain_id: 0,
            namespace: String::new(),
            tf: TfInputConfig::default(),
            out: Ros2OutConfig::default(),
        }
    }
}

impl Default for TfInputConfig {
    fn default() -> Self {
        Self {
            world_frame: String::new(),
            camera_frame: "camera_color_optical_frame".to_owned(),
            base_frame: String::new(),
            tf_topic: "/tf".to_owned(),
            tf_static_topic: "/tf_static".to_owned(),
            window_s: 10.0,
        }
    }
}

/// The highest `ROS_DOMAIN_ID` ROS 2 allows.
pub const MAX_DOMAIN_ID: u32 = 232;

impl Ros2Config {
    /// Range and format checks; messages start with `path.field`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        if self.connect.is_empty() {
            return Err(format!(
                "{path}.connect: needs the Zenoh endpoint of the ROS side (e.g. \"tcp/127.0.0.1:7447\")"
            ));
        }
        #[cfg(feature = "zenoh")]
        for endpoint in &self.connect {
            EndPoint::from_str(endpoint).map_err(|e| {
                format!("{path}.connect: {endpoint:?} is not a Zenoh endpoint (e.g. \"tcp/127.0.0.1:7447\"): {e}")
            })?;
        }
        self.key_style()
            .map_err(|_| format!("{path}.key_style: {:?}: must be \"rmw_zenoh\" or \"bridge\"", self.key_style))?;
        self.distro().map_err(|_| {
            format!("{path}.distro: {:?}: must be \"humble\", \"jazzy\", \"kilted\" or \"rolling\"", self.distro)
        })?;
        if self.domain_id > MAX_DOMAIN_ID {
            return Err(format!("{path}.domain_id: must be within [0, {MAX_DOMAIN_ID}], got {}", self.domain_id));
        }
        normalize_namespace(&self.namespace).map_err(|e| format!("{path}.namespace: {:?}: {e}", self.namespace))?;
        let tf = &self.tf;
        for (field, frame) in
            [("world_frame", &tf.world_frame), ("camera_frame", &tf.camera_frame), ("base_frame", &tf.base_frame)]
        {
            if frame.trim() != frame.as_str() || frame.contains(char::is_whitespace) {
                return Err(format!("{path}.tf.{field}: {frame:?}: a frame id has no spaces"));
            }
        }
        if tf.camera_frame.is_empty() && tf.base_frame.is_empty() {
            return Err(format!(
                "{path}.tf.camera_frame: empty; name the camera's frame (or set {path}.tf.base_frame)"
            ));
        }
        for (field, topic) in [("tf_topic", &tf.tf_topic), ("tf_static_topic", &tf.tf_static_topic)] {
            fully_qualified_topic("/", topic).map_err(|e| format!("{path}.tf.{field}: {topic:?}: {e}"))?;
        }
        if !(tf.window_s > 0.0 && tf.window_s <= 3600.0) {
            return Err(format!("{path}.tf.window_s: must be within (0, 3600] seconds, got {}", tf.window_s));
        }
        let out = &self.out;
        for (field, topic) in [
            ("markers_topic", &out.markers_topic),
            ("occupancy_topic", &out.occupancy_topic),
            ("graph_json_topic", &out.graph_json_topic),
        ] {
            fully_qualified_topic("/", topic).map_err(|e| format!("{path}.out.{field}: {topic:?}: {e}"))?;
        }
        if !(10..=60_000).contains(&out.period_ms) {
            return Err(format!("{path}.out.period_ms: must be within [10, 60000] ms, got {}", out.period_ms));
        }
        if !(100..=3_600_000).contains(&out.occupancy_repeat_ms) {
            return Err(format!(
                "{path}.out.occupancy_repeat_ms: must be within [100, 3600000] ms, got {}",
                out.occupancy_repeat_ms
            ));
        }
        check_node_name(&out.node_name).map_err(|e| format!("{path}.out.node_name: {e}"))?;
        Ok(())
    }

    /// [`Self::key_style`] parsed (checked by [`Self::validate`]).
    pub fn key_style(&self) -> Result<KeyStyle, op3dsg_ros2::keys::NameError> {
        KeyStyle::from_str(&self.key_style)
    }

    /// [`Self::distro`] parsed (checked by [`Self::validate`]).
    pub fn distro(&self) -> Result<Distro, op3dsg_ros2::keys::NameError> {
        Distro::from_str(&self.distro)
    }

    /// The Zenoh configuration of the session: a client of `connect`, multicast scouting off.
    #[cfg(feature = "zenoh")]
    pub fn session_config(&self) -> Result<Config, String> {
        let mut config = Config::default();
        let endpoints = serde_json::to_string(&self.connect).unwrap_or_default();
        for (key, value) in
            [("mode", "\"client\""), ("connect/endpoints", endpoints.as_str()), ("scouting/multicast/enabled", "false")]
        {
            config.insert_json5(key, value).map_err(|e| format!("ros2.connect: {e}"))?;
        }
        Ok(config)
    }
}
