//! Zenoh key expressions of ROS 2 topics, in the two ways ROS 2 reaches Zenoh, and rmw_zenoh's
//! liveliness tokens (strings only: the daemon declares them on its Zenoh session).
//!
//! **`rmw_zenoh`** (`ros2/rmw_zenoh` `docs/design.md`, "Topic and Service name mapping to Zenoh
//! key expressions" and "Graph Cache"; `liveliness_utils.cpp`): a topic is
//! `<domain_id>/<fully qualified name without its leading '/'>/<DDS type name>/<type hash>`, e.g.
//! `0/tf/tf2_msgs::msg::dds_::TFMessage_/RIHS01_e369…`; the slashes of the name stay (the name is
//! not mangled in the data key). Jazzy and later put the REP-2016 hash (`RIHS01_…`); Humble's
//! rmw_zenoh puts `TypeHashNotSupported`. An rmw_zenoh subscription subscribes to its exact key,
//! so a publisher must use the hash of the subscribers' distribution ([`Distro`]); a subscriber
//! here uses `*` for the hash ([`rmw_zenoh_subscribe_key`]) and hears both.
//!
//! Every ROS entity declares a liveliness token,
//! `@ros2_lv/<domain_id>/<zid>/<node_id>/<entity_id>/<kind>/<enclave>/<namespace>/<node>[/<topic>/<type>/<hash>/<qos>]`,
//! where names are *mangled* (each `/` becomes `%`, so the root namespace `/` is `%` and `/tf`
//! is `%tf`), `<kind>` is `NN` (node), `MP` (publisher) or `MS` (subscription), and `<qos>` is
//! rmw_zenoh's compact form ([`Qos::to_keyexpr`]). `ros2 topic list`, `ros2 node list` and
//! `ros2 topic info` read only these tokens.
//!
//! **`bridge`** (`eclipse-zenoh/zenoh-plugin-ros2dds`, `ros2_utils.rs` `ros2_name_to_key_expr`):
//! the ROS name without its leading `/`, under the bridge's `namespace` setting when it has one:
//! `/tf` is `tf`, or `robot1/tf` with `namespace: "/robot1"`. No type in the key and no
//! attachment; the bridges announce routes among themselves with tokens of their own
//! ([`bridge_publisher_token`]).

use std::fmt;
use std::str::FromStr;

use crate::cdr::MessageType;

/// How ROS 2 topics map to Zenoh keys.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KeyStyle {
    /// ROS 2's Zenoh middleware.
    RmwZenoh,
    /// `zenoh-bridge-ros2dds` in front of a DDS middleware.
    Bridge,
}

impl KeyStyle {
    /// The name in configuration files: `rmw_zenoh` or `bridge`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::RmwZenoh => "rmw_zenoh",
            Self::Bridge => "bridge",
        }
    }
}

impl fmt::Display for KeyStyle {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for KeyStyle {
    type Err = NameError;
    fn from_str(s: &str) -> Result<Self, NameError> {
        match s {
            "rmw_zenoh" => Ok(Self::RmwZenoh),
            "bridge" => Ok(Self::Bridge),
            other => Err(NameError::UnknownKeyStyle(other.to_string())),
        }
    }
}

/// The ROS 2 distribution on the other side, for the type hash of rmw_zenoh keys and tokens.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Distro {
    /// Humble: no type hashes (`TypeHashNotSupported`).
    Humble,
    /// Jazzy and later (Kilted, Rolling): REP-2016 `RIHS01_` hashes.
    JazzyOrLater,
}

impl FromStr for Distro {
    type Err = NameError;
    fn from_str(s: &str) -> Result<Self, NameError> {
        match s {
            "humble" => Ok(Self::Humble),
            "jazzy" | "kilted" | "lyrical" | "rolling" => Ok(Self::JazzyOrLater),
            other => Err(NameError::UnknownDistro(other.to_string())),
        }
    }
}

/// What Humble's rmw_zenoh puts where the type hash goes.
pub const TYPE_HASH_NOT_SUPPORTED: &str = "TypeHashNotSupported";

/// The type hash rmw_zenoh puts in keys and tokens for `ty` on `distro`.
pub fn type_hash(ty: &MessageType, distro: Distro) -> &'static str {
    match distro {
        Distro::Humble => TYPE_HASH_NOT_SUPPORTED,
        Distro::JazzyOrLater => ty.rihs01,
    }
}

/// A ROS name, key style or Zenoh id that cannot be used.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum NameError {
    /// Not a valid ROS 2 name (topic, namespace or node).
    #[error("{what} {name:?} is not a valid ROS 2 name: {why}")]
    Invalid {
        /// `topic`, `namespace`, `node name`.
        what: &'static str,
        /// The name given.
        name: String,
        /// The rule it breaks.
        why: &'static str,
    },
    /// Not `rmw_zenoh` or `bridge`.
    #[error("key style {0:?} is neither \"rmw_zenoh\" nor \"bridge\"")]
    UnknownKeyStyle(String),
    /// Not a distribution name.
    #[error("ROS 2 distribution {0:?} is not one of humble, jazzy, kilted, lyrical, rolling")]
    UnknownDistro(String),
    /// A Zenoh session id is lower-case hex digits.
    #[error("Zenoh id {0:?} is not lower-case hexadecimal digits")]
    BadZenohId(String),
}

fn invalid(what: &'static str, name: &str, why: &'static str) -> NameError {
    NameError::Invalid { what, name: name.to_string(), why }
}

/// Checks the tokens of an absolute name (`/a/b`), ROS 2's rules (`rmw_validate_full_topic_name`).
fn check_absolute(what: &'static str, name: &str, allow_root: bool) -> Result<(), NameError> {
    if name.contains(['~', '{', '}']) {
        return Err(invalid(what, name, "private (~) and substitution ({}) names are not supported here"));
    }
    let Some(rest) = name.strip_prefix('/') else {
        return Err(invalid(what, name, "it must start with '/'"));
    };
    if rest.is_empty() {
        return if allow_root { Ok(()) } else { Err(invalid(what, name, "it is empty")) };
    }
    for token in rest.split('/') {
        if token.is_empty() {
            return Err(invalid(what, name, "it has an empty part ('//' or a trailing '/')"));
        }
        if !token.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
            return Err(invalid(what, name, "only letters, digits, '_' and '/' are allowed"));
        }
        if token.starts_with(|c: char| c.is_ascii_digit()) {
            return Err(invalid(what, name, "a part starts with a digit"));
        }
    }
    Ok(())
}

/// A namespace as ROS writes it: `""` and `"/"` are the root `/`; `robot1` is `/robot1`.
pub fn normalize_namespace(namespace: &str) -> Result<String, NameError> {
    let trimmed = namespace.trim_end_matches('/');
    let absolute = if trimmed.starts_with('/') { trimmed.to_string() } else { format!("/{trimmed}") };
    check_absolute("namespace", &absolute, true)?;
    Ok(absolute)
}

/// The fully qualified name of `topic`: itself when absolute (`/tf`), else under `namespace`
/// (`tf` in `/robot1` is `/robot1/tf`).
pub fn fully_qualified_topic(namespace: &str, topic: &str) -> Result<String, NameError> {
    let name = if topic.starts_with('/') {
        topic.to_string()
    } else {
        let ns = normalize_namespace(namespace)?;
        if ns == "/" { format!("/{topic}") } else { format!("{ns}/{topic}") }
    };
    check_absolute("topic", &name, false)?;
    Ok(name)
}

/// rmw_zenoh's data key of a topic (`fq_topic` from [`fully_qualified_topic`]).
pub fn rmw_zenoh_key(domain_id: u32, fq_topic: &str, ty: &MessageType, distro: Distro) -> String {
    format!("{domain_id}/{}/{}/{}", fq_topic.trim_start_matches('/'), ty.dds_name, type_hash(ty, distro))
}

/// The key that hears a topic's rmw_zenoh publishers of any distribution: the hash is `*`.
pub fn rmw_zenoh_subscribe_key(domain_id: u32, fq_topic: &str, ty: &MessageType) -> String {
    format!("{domain_id}/{}/{}/*", fq_topic.trim_start_matches('/'), ty.dds_name)
}

/// zenoh-bridge-ros2dds's key of a topic: the name without its leading `/`, under the bridge's
/// namespace (`""` or `"/"`: none).
pub fn bridge_key(bridge_namespace: &str, fq_topic: &str) -> Result<String, NameError> {
    check_absolute("topic", fq_topic, false)?;
    let ns = normalize_namespace(bridge_namespace)?;
    Ok(format!("{}/{}", ns.trim_start_matches('/'), &fq_topic[1..]).trim_start_matches('/').to_string())
}

/// The liveliness token by which a zenoh-bridge-ros2dds announces a publisher route to the other
/// bridges (`liveliness_mgt.rs`, `new_ke_liveliness_pub`): a bridge that sees it makes a DDS
/// writer for the topic, so ROS nodes behind it see the topic before anything subscribes. It is
/// `@/<zid>/@ros2_lv/MP/<key>/<ROS type>/<qos>`, `/` written `§` in key and type, and `<qos>`
/// `<keyless>:<reliability>:<durability>:<history>,<depth>[:<USER_DATA>]` with DDS's numbers
/// (reliable 1, volatile 0, transient local 1, keep last 0); ROS messages are keyless (empty), and
/// from Iron on USER_DATA carries `typehash=<RIHS01>;`.
///
/// Not needed for data: a bridge with a ROS subscriber of the topic subscribes to its key anyway.
pub fn bridge_publisher_token(zid: &str, key: &str, ty: &MessageType, distro: Distro, qos: &Qos) -> String {
    let reliability = match qos.reliability {
        Reliability::Reliable => 1,
        Reliability::BestEffort => 0,
    };
    let durability = match qos.durability {
        Durability::Volatile => 0,
        Durability::TransientLocal => 1,
    };
    let user_data = match distro {
        Distro::Humble => String::new(),
        Distro::JazzyOrLater => format!(":typehash={};", ty.rihs01),
    };
    format!(
        "@/{zid}/@ros2_lv/MP/{}/{}/:{reliability}:{durability}:0,{}{user_data}",
        key.replace('/', "§"),
        ty.ros_name.replace('/', "§"),
        qos.depth
    )
}

/// The keys of one topic.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TopicKeys {
    /// The fully qualified ROS name (`/tf`).
    pub fq_topic: String,
    /// Where a publisher of ours puts.
    pub publish: String,
    /// What a subscriber of ours subscribes to.
    pub subscribe: String,
}

/// The keys of `topic` in `style`.
///
/// `namespace` is, with [`KeyStyle::RmwZenoh`], the ROS namespace relative topic names resolve in
/// (absolute ones such as `/tf` ignore it, as in ROS); with [`KeyStyle::Bridge`], the bridge's
/// `namespace` setting, which prefixes every key (relative topic names resolve in `/`). `distro`
/// matters to rmw_zenoh publish keys only.
pub fn topic_keys(
    style: KeyStyle,
    domain_id: u32,
    namespace: &str,
    topic: &str,
    ty: &MessageType,
    distro: Distro,
) -> Result<TopicKeys, NameError> {
    match style {
        KeyStyle::RmwZenoh => {
            let fq_topic = fully_qualified_topic(namespace, topic)?;
            Ok(TopicKeys {
                publish: rmw_zenoh_key(domain_id, &fq_topic, ty, distro),
                subscribe: rmw_zenoh_subscribe_key(domain_id, &fq_topic, ty),
                fq_topic,
            })
        }
        KeyStyle::Bridge => {
            let fq_topic = fully_qualified_topic("/", topic)?;
            let key = bridge_key(namespace, &fq_topic)?;
            Ok(TopicKeys { publish: key.clone(), subscribe: key, fq_topic })
        }
    }
}

/// The first chunk of every rmw_zenoh liveliness token.
pub const LIVELINESS_ADMIN_SPACE: &str = "@ros2_lv";

/// The key that hears every liveliness token of a domain (the ROS graph).
pub fn liveliness_subscribe_key(domain_id: u32) -> String {
    format!("{LIVELINESS_ADMIN_SPACE}/{domain_id}/**")
}

/// rmw_zenoh's mangling of a name inside a token: each `/` becomes `%`.
pub fn mangle(name: &str) -> String {
    name.replace('/', "%")
}

/// What a token announces.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EntityKind {
    /// A node (`NN`).
    Node,
    /// A message publisher (`MP`).
    Publisher,
    /// A message subscription (`MS`).
    Subscription,
}

impl EntityKind {
    /// The token's entity chunk.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Node => "NN",
            Self::Publisher => "MP",
            Self::Subscription => "MS",
        }
    }
}

/// Reliability of an endpoint (`rmw_qos_reliability_policy_e`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reliability {
    /// `RELIABLE` (1), rmw_zenoh's default.
    Reliable,
    /// `BEST_EFFORT` (2).
    BestEffort,
}

/// Durability of an endpoint (`rmw_qos_durability_policy_e`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Durability {
    /// `TRANSIENT_LOCAL` (1): late subscribers get the kept messages (`/tf_static`).
    TransientLocal,
    /// `VOLATILE` (2), rmw_zenoh's default.
    Volatile,
}

/// The QoS a token announces.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Qos {
    /// Reliability.
    pub reliability: Reliability,
    /// Durability.
    pub durability: Durability,
    /// `KEEP_LAST` depth (KEEP_ALL is not used here).
    pub depth: u32,
}

impl Qos {
    /// tf2's `/tf` endpoints: reliable, volatile, keep last 100.
    pub const TF: Self = Self { reliability: Reliability::Reliable, durability: Durability::Volatile, depth: 100 };
    /// tf2's static broadcaster: reliable, transient local, keep last 1 (its listener keeps 100).
    pub const TF_STATIC: Self =
        Self { reliability: Reliability::Reliable, durability: Durability::TransientLocal, depth: 1 };
    /// ROS's default for topics (`rmw_qos_profile_default`): reliable, volatile, keep last 10.
    pub const DEFAULT: Self = Self { reliability: Reliability::Reliable, durability: Durability::Volatile, depth: 10 };

    /// rmw_zenoh's `qos_to_keyexpr`: `reliability:durability:history,depth:deadline_s,deadline_ns:
    /// lifespan_s,lifespan_ns:liveliness,lease_s,lease_ns`, each value left empty when it is
    /// rmw_zenoh's default (reliable, volatile, keep last, depth 42, infinite durations,
    /// automatic liveliness). [`Qos::TF`] is `::,100:,:,:,,`.
    pub fn to_keyexpr(&self) -> String {
        let reliability = match self.reliability {
            Reliability::Reliable => "",
            Reliability::BestEffort => "2",
        };
        let durability = match self.durability {
            Durability::Volatile => "",
            Durability::TransientLocal => "1",
        };
        let depth = if self.depth == 42 { String::new() } else { self.depth.to_string() };
        format!("{reliability}:{durability}:,{depth}:,:,:,,")
    }
}

/// Checks a ROS node name: letters, digits and `_`, not starting with a digit.
pub fn check_node_name(name: &str) -> Result<(), NameError> {
    let ok = !name.is_empty()
        && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
        && !name.starts_with(|c: char| c.is_ascii_digit());
    if ok {
        Ok(())
    } else {
        Err(invalid("node name", name, "it must be letters, digits and '_', not starting with a digit"))
    }
}

/// The ROS node the daemon's tokens hang under.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeIdentity {
    /// `ROS_DOMAIN_ID`.
    pub domain_id: u32,
    /// The Zenoh session id as Zenoh prints it (`session.zid().to_string()`: lower-case hex).
    pub zid: String,
    /// The node's id within the session (rmw_zenoh counts from 0).
    pub node_id: u32,
    /// The node's namespace (`/` for none).
    pub namespace: String,
    /// The node's name.
    pub name: String,
}

impl NodeIdentity {
    /// Checks the names and the id (the namespace is normalised: `""` becomes `/`).
    pub fn new(domain_id: u32, zid: &str, node_id: u32, namespace: &str, name: &str) -> Result<Self, NameError> {
        if zid.is_empty() || !zid.chars().all(|c| matches!(c, '0'..='9' | 'a'..='f')) {
            return Err(NameError::BadZenohId(zid.to_string()));
        }
        check_node_name(name)?;
        Ok(Self {
            domain_id,
            zid: zid.to_string(),
            node_id,
            namespace: normalize_namespace(namespace)?,
            name: name.to_string(),
        })
    }

    fn prefix(&self, entity_id: u32, kind: EntityKind) -> String {
        // The SROS enclave is "/" (none), mangled "%".
        format!(
            "{LIVELINESS_ADMIN_SPACE}/{}/{}/{}/{entity_id}/{}/%/{}/{}",
            self.domain_id,
            self.zid,
            self.node_id,
            kind.as_str(),
            mangle(&self.namespace),
            self.name
        )
    }

    /// The node's own token (`NN`; rmw_zenoh gives it the node id as entity id).
    pub fn node_token(&self) -> String {
        self.prefix(self.node_id, EntityKind::Node)
    }

    /// The token of a publisher or subscription of this node on `fq_topic`.
    pub fn endpoint_token(
        &self,
        entity_id: u32,
        kind: EntityKind,
        fq_topic: &str,
        ty: &MessageType,
        distro: Distro,
        qos: &Qos,
    ) -> String {
        format!(
            "{}/{}/{}/{}/{}",
            self.prefix(entity_id, kind),
            mangle(fq_topic),
            ty.dds_name,
            type_hash(ty, distro),
            qos.to_keyexpr()
        )
    }
}

/// The GID rmw_zenoh derives for the entity of a token: XXH3-128 of the token's key expression,
/// its low 64 bits then its high 64 bits, each in little-endian byte order
/// (`liveliness_utils.cpp`, `Entity::Entity`). Put it in the entity's [`Attachment`]s.
///
/// [`Attachment`]: crate::attachment::Attachment
pub fn gid_of_token(token: &str) -> [u8; 16] {
    let hash = xxhash_rust::xxh3::xxh3_128(token.as_bytes());
    let mut gid = [0u8; 16];
    gid[..8].copy_from_slice(&(hash as u64).to_le_bytes());
    gid[8..].copy_from_slice(&((hash >> 64) as u64).to_le_bytes());
    gid
}
