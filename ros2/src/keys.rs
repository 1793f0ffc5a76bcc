//! Where rmw_zenoh puts a topic's samples, and how it announces a node and its endpoints
//! (rmw_zenoh's `docs/design.md`, "Topic and Service name mapping to Zenoh key
//! expressions" and "Graph Cache"; `liveliness_utils.cpp`, `qos.cpp`).
//!
//! - A topic's data key is `<domain>/<topic>/<type>/<type hash>`: the fully qualified
//!   topic name without its leading slash (a namespace's slashes stay, as more chunks),
//!   the DDS type name (`geometry_msgs::msg::dds_::TwistStamped_`) and the type's RIHS01
//!   hash. Subscribers match it exactly: a wrong name, type or hash delivers nothing.
//! - A liveliness token announces each node and endpoint to the robot's graph cache
//!   (`ros2 node list`, `ros2 topic info -v`): `@ros2_lv/<domain>/<session id>/<node
//!   id>/<entity id>/<kind>/<enclave>/<namespace>/<node>` and, for an endpoint, `/<topic>/
//!   <type>/<type hash>/<qos>`, every `/` inside a name written `%` (an empty namespace
//!   or enclave: `%`).

/// A ROS 2 distribution whose type hashes [`MessageType::type_hash`] knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Distro {
    Jazzy,
    Kilted,
}

impl Distro {
    pub const ALL: [Distro; 2] = [Distro::Jazzy, Distro::Kilted];

    pub fn as_str(self) -> &'static str {
        match self {
            Distro::Jazzy => "jazzy",
            Distro::Kilted => "kilted",
        }
    }

    pub fn parse(name: &str) -> Option<Distro> {
        Distro::ALL.into_iter().find(|d| d.as_str() == name)
    }
}

/// The messages the robot process speaks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MessageType {
    Twist,
    TwistStamped,
    Odometry,
    PoseStamped,
    Path,
    MarkerArray,
    LaserScan,
    TfMessage,
}

impl MessageType {
    pub const ALL: [MessageType; 8] = [
        MessageType::Twist,
        MessageType::TwistStamped,
        MessageType::Odometry,
        MessageType::PoseStamped,
        MessageType::Path,
        MessageType::MarkerArray,
        MessageType::LaserScan,
        MessageType::TfMessage,
    ];

    /// The ROS name, `package/msg/Name`.
    pub fn name(self) -> &'static str {
        match self {
            MessageType::Twist => "geometry_msgs/msg/Twist",
            MessageType::TwistStamped => "geometry_msgs/msg/TwistStamped",
            MessageType::Odometry => "nav_msgs/msg/Odometry",
            MessageType::PoseStamped => "geometry_msgs/msg/PoseStamped",
            MessageType::Path => "nav_msgs/msg/Path",
            MessageType::MarkerArray => "visualization_msgs/msg/MarkerArray",
            MessageType::LaserScan => "sensor_msgs/msg/LaserScan",
            MessageType::TfMessage => "tf2_msgs/msg/TFMessage",
        }
    }

    /// The DDS type name rmw_zenoh keys it by: `package::msg::dds_::Name_`.
    pub fn dds_name(self) -> String {
        let name = self.name();
        let (scope, short) = name.rsplit_once('/').unwrap_or(("", name));
        format!("{}::dds_::{short}_", scope.replace('/', "::"))
    }

    /// The type's hash (REP 2011), `RIHS01_` and 64 hex digits. Jazzy's and Kilted's
    /// are the same for these types (docs/ros2.md: computed with `rosbags` 0.11.9,
    /// `get_typestore(Stores.ROS2_JAZZY).hash_rihs01(name)`, and the same with
    /// `ROS2_KILTED`; each also seen in keys captured from robots).
    pub fn type_hash(self, distro: Distro) -> &'static str {
        match distro {
            Distro::Jazzy | Distro::Kilted => match self {
                MessageType::Twist => {
                    "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a"
                }
                MessageType::TwistStamped => {
                    "RIHS01_5f0fcd4f81d5d06ad9b4c4c63e3ea51b82d6ae4d0558f1d475229b1121db6f64"
                }
                MessageType::Odometry => {
                    "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0"
                }
                MessageType::PoseStamped => {
                    "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8"
                }
                MessageType::Path => {
                    "RIHS01_1957a5bb3cee5da65c4e52e52b65a93df227efce4c20f8458b36e73066ca334b"
                }
                MessageType::MarkerArray => {
                    "RIHS01_86cb8800b6fb05b5eff1abd7a56f62a5641d3ae9a1c29e78e67e704f1d067dcf"
                }
                MessageType::LaserScan => {
                    "RIHS01_64c191398013af96509d518dac71d5164f9382553fce5c1f8cca5be7924bd828"
                }
                MessageType::TfMessage => {
                    "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"
                }
            },
        }
    }
}

/// A name that ROS 2 would refuse.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum NameError {
    #[error(
        "`{0}` is not a ROS 2 {1} name: tokens of letters, digits and underscores, \
         not starting with a digit, separated by single slashes"
    )]
    Invalid(String, &'static str),
}

/// Whether `token` is a ROS 2 name token: letters, digits and underscores, not starting
/// with a digit.
fn is_token(token: &str) -> bool {
    let mut chars = token.chars();
    chars
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
}

/// `namespace` as a fully qualified namespace: `/` or `/a/b` (a missing leading slash is
/// added, a trailing one dropped).
pub fn namespace(namespace: &str) -> Result<String, NameError> {
    let trimmed = namespace.trim_start_matches('/').trim_end_matches('/');
    if trimmed.is_empty() && namespace.chars().all(|c| c == '/') {
        return Ok("/".into());
    }
    if !trimmed.split('/').all(is_token) {
        return Err(NameError::Invalid(namespace.into(), "namespace"));
    }
    Ok(format!("/{trimmed}"))
}

/// The fully qualified name of `topic` in `namespace` (fully qualified): an absolute
/// topic as it is, a relative one under the namespace.
pub fn qualified_topic(namespace: &str, topic: &str) -> Result<String, NameError> {
    let relative = topic.strip_prefix('/').unwrap_or(topic);
    if relative.is_empty() || !relative.split('/').all(is_token) {
        return Err(NameError::Invalid(topic.into(), "topic"));
    }
    Ok(match (topic.starts_with('/'), namespace) {
        (true, _) | (false, "/") => format!("/{relative}"),
        (false, ns) => format!("{ns}/{relative}"),
    })
}

/// The key of a topic's samples: `<domain>/<topic>/<type>/<type hash>`, the fully
/// qualified `topic` without its leading slash.
pub fn data_key(domain_id: u32, topic: &str, message: MessageType, distro: Distro) -> String {
    format!(
        "{domain_id}/{}/{}/{}",
        topic.trim_start_matches('/'),
        message.dds_name(),
        message.type_hash(distro)
    )
}

/// The key zenoh-bridge-ros2dds gives a topic's samples: its fully qualified name without
/// the leading slash (the bridge's own `namespace`, if it has one, is left out of the
/// topic given here), whatever the type.
pub fn bridge_key(topic: &str) -> String {
    topic.trim_start_matches('/').to_string()
}

/// A name with every `/` as `%` (an empty one is `%`), as in a liveliness token.
fn mangle(name: &str) -> String {
    if name.is_empty() {
        "%".into()
    } else {
        name.replace('/', "%")
    }
}

/// An endpoint's quality of service, as the pipeline uses it: keep-last of `depth`,
/// reliable or best effort, volatile or transient-local; no deadline, lifespan or
/// lease.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Qos {
    pub reliable: bool,
    pub transient_local: bool,
    pub depth: u32,
}

impl Qos {
    /// The QoS as a token's last chunk (`qos_to_keyexpr`):
    /// `<reliability>:<durability>:<history>,<depth>:<deadline>:<lifespan>:<liveliness>`,
    /// each part left empty where it is rmw_zenoh's default (reliable, volatile,
    /// keep-last, depth 42, infinite durations, automatic liveliness).
    pub fn key_chunk(&self) -> String {
        let reliability = if self.reliable { "" } else { "2" };
        let durability = if self.transient_local { "1" } else { "" };
        let depth = if self.depth == 42 {
            String::new()
        } else {
            self.depth.to_string()
        };
        format!("{reliability}:{durability}:,{depth}:,:,:,,")
    }
}

/// What a liveliness token announces.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EntityKind {
    Publisher,
    Subscription,
}

impl EntityKind {
    fn code(self) -> &'static str {
        match self {
            EntityKind::Publisher => "MP",
            EntityKind::Subscription => "MS",
        }
    }
}

/// A node as the robot's graph sees it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Node {
    pub domain_id: u32,
    /// The Zenoh session's id, as its `zid` prints (32 hex digits).
    pub session_id: String,
    /// The node's number within the session.
    pub node_id: u32,
    /// Fully qualified ([`namespace`]).
    pub namespace: String,
    pub name: String,
}

impl Node {
    /// A node of `name` in `namespace` (both checked).
    pub fn new(
        domain_id: u32,
        session_id: &str,
        namespace: &str,
        name: &str,
    ) -> Result<Node, NameError> {
        if !is_token(name) {
            return Err(NameError::Invalid(name.into(), "node"));
        }
        Ok(Node {
            domain_id,
            session_id: session_id.into(),
            node_id: 0,
            namespace: self::namespace(namespace)?,
            name: name.into(),
        })
    }

    /// The part every token of the node shares, up to its kind.
    fn prefix(&self, entity_id: u32) -> String {
        format!(
            "@ros2_lv/{}/{}/{}/{entity_id}",
            self.domain_id, self.session_id, self.node_id
        )
    }

    /// The node's own token (its entity id is its node id; the enclave is the default,
    /// `/`).
    pub fn token(&self) -> String {
        format!(
            "{}/NN/%/{}/{}",
            self.prefix(self.node_id),
            mangle(&self.namespace),
            self.name
        )
    }

    /// The token of the node's endpoint `entity_id` (unique within the session) on the
    /// fully qualified `topic`.
    pub fn endpoint_token(
        &self,
        entity_id: u32,
        kind: EntityKind,
        topic: &str,
        message: MessageType,
        distro: Distro,
        qos: Qos,
    ) -> String {
        format!(
            "{}/{}/%/{}/{}/{}/{}/{}/{}",
            self.prefix(entity_id),
            kind.code(),
            mangle(&self.namespace),
            self.name,
            mangle(topic),
            message.dds_name(),
            message.type_hash(distro),
            qos.key_chunk()
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_data_key_is_the_domain_the_topic_the_dds_type_and_its_hash() {
        assert_eq!(
            data_key(0, "/cmd_vel", MessageType::TwistStamped, Distro::Jazzy),
            "0/cmd_vel/geometry_msgs::msg::dds_::TwistStamped_/\
             RIHS01_5f0fcd4f81d5d06ad9b4c4c63e3ea51b82d6ae4d0558f1d475229b1121db6f64"
        );
        // A namespace's slashes stay: more chunks.
        let topic = qualified_topic("/robot1", "odom").unwrap();
        assert_eq!(topic, "/robot1/odom");
        assert!(
            data_key(3, &topic, MessageType::Odometry, Distro::Kilted)
                .starts_with("3/robot1/odom/nav_msgs::msg::dds_::Odometry_/RIHS01_3cc97dc7")
        );
        assert_eq!(
            MessageType::MarkerArray.dds_name(),
            "visualization_msgs::msg::dds_::MarkerArray_"
        );
    }

    #[test]
    fn tokens_are_those_of_rmw_zenohs_design_document() {
        // design.md's node: `@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener`.
        let zid = "aac3178e146ba6f1fc6e6a4085e77f21";
        let listener = Node::new(2, zid, "/", "listener").unwrap();
        assert_eq!(
            listener.token(),
            format!("@ros2_lv/2/{zid}/0/0/NN/%/%/listener")
        );
        // And a publisher like its talker's, on a TwistStamped topic, depth 7.
        let qos = Qos {
            reliable: true,
            transient_local: false,
            depth: 7,
        };
        let token = listener.endpoint_token(
            10,
            EntityKind::Publisher,
            "/cmd_vel",
            MessageType::TwistStamped,
            Distro::Jazzy,
            qos,
        );
        assert_eq!(
            token,
            format!(
                "@ros2_lv/2/{zid}/0/10/MP/%/%/listener/%cmd_vel/\
                 geometry_msgs::msg::dds_::TwistStamped_/\
                 RIHS01_5f0fcd4f81d5d06ad9b4c4c63e3ea51b82d6ae4d0558f1d475229b1121db6f64/::,7:,:,:,,"
            )
        );
        let ns = Node::new(0, zid, "robot1/", "scmpc").unwrap();
        assert!(
            ns.token().ends_with("/NN/%/%robot1/scmpc"),
            "{}",
            ns.token()
        );
    }

    #[test]
    fn the_qos_chunk_leaves_rmw_zenohs_defaults_empty() {
        let qos = |reliable, transient_local, depth| Qos {
            reliable,
            transient_local,
            depth,
        };
        assert_eq!(qos(true, false, 10).key_chunk(), "::,10:,:,:,,");
        assert_eq!(qos(false, false, 1).key_chunk(), "2::,1:,:,:,,");
        assert_eq!(qos(true, true, 1).key_chunk(), ":1:,1:,:,:,,");
        assert_eq!(qos(true, false, 42).key_chunk(), "::,:,:,:,,");
    }

    #[test]
    fn names_ros_2_would_refuse_are_refused() {
        for bad in [
            "",
            "/",
            "1cmd",
            "cmd vel",
            "cmd//vel",
            "~/cmd_vel",
            "cmd-vel",
        ] {
            assert!(qualified_topic("/", bad).is_err(), "topic {bad:?}");
        }
        for bad in ["1robot", "a//b", "a b"] {
            assert!(namespace(bad).is_err(), "namespace {bad:?}");
        }
        assert!(Node::new(0, "z", "/", "scmpc-1").is_err());
        assert_eq!(qualified_topic("/r", "/odom").unwrap(), "/odom");
        assert_eq!(namespace("").unwrap(), "/");
        assert_eq!(Distro::parse("jazzy"), Some(Distro::Jazzy));
        assert_eq!(Distro::parse("humble"), None);
    }
}
