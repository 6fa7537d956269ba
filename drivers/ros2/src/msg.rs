//! ROS 2 message types, one module per ROS package, every field of the ROS 2 definition in
//! declaration order (the CDR body is the fields in order, so the order is the wire format).
//!
//! Definitions: ROS 2 Humble and Jazzy (`common_interfaces`, `geometry2`, `rcl_interfaces`). The
//! two distributions have the same fields for every type here; they differ only in a constant
//! (Jazzy adds `visualization_msgs/Marker.ARROW_STRIP = 12`), which is not on the wire, and in
//! that Humble computes no type hash (see [`crate::keys::Distro`]). The type hashes in
//! [`MessageType::rihs01`] are Jazzy's (Kilted's are the same).
//!
//! Field names follow ROS, except `visualization_msgs/Marker.type`, which is [`Marker::kind`]
//! here (`type` is a Rust keyword; serde still names it `type`, e.g. in JSON).
//!
//! [`MessageType::rihs01`]: crate::cdr::MessageType::rihs01
//! [`Marker::kind`]: visualization_msgs::Marker::kind

use serde::{Deserialize, Serialize};

use crate::cdr::{MessageType, RosMessage};

/// `builtin_interfaces`: time and duration.
pub mod builtin_interfaces {
    use super::*;

    /// `builtin_interfaces/msg/Time`: seconds and nanoseconds since the clock's epoch.
    #[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
    pub struct Time {
        /// Seconds (negative before the epoch).
        pub sec: i32,
        /// Nanoseconds within the second, `0..1_000_000_000`.
        pub nanosec: u32,
    }

    impl Time {
        /// From nanoseconds since the epoch (seconds beyond `i32::MAX`, in 2038, saturate).
        pub fn from_ns(ns: u64) -> Self {
            let sec = i32::try_from(ns / 1_000_000_000).unwrap_or(i32::MAX);
            Self { sec, nanosec: (ns % 1_000_000_000) as u32 }
        }

        /// Nanoseconds since the epoch; `None` before the epoch or with `nanosec` of a second or
        /// more (not a valid stamp).
        pub fn to_ns(&self) -> Option<u64> {
            let sec = u64::try_from(self.sec).ok()?;
            (self.nanosec < 1_000_000_000).then(|| sec * 1_000_000_000 + u64::from(self.nanosec))
        }
    }

    /// `builtin_interfaces/msg/Duration`.
    #[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
    pub struct Duration {
        /// Seconds.
        pub sec: i32,
        /// Nanoseconds within the second.
        pub nanosec: u32,
    }
}

/// `std_msgs`.
pub mod std_msgs {
    use super::*;

    /// `std_msgs/msg/Header`.
    #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
    pub struct Header {
        /// When the data was valid.
        pub stamp: builtin_interfaces::Time,
        /// The frame the data is expressed in.
        pub frame_id: std::string::String,
    }

    /// `std_msgs/msg/String`.
    #[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
    pub struct String {
        /// The text.
        pub data: std::string::String,
    }

    impl RosMessage for String {
        const TYPE: MessageType = MessageType {
            ros_name: "std_msgs/msg/String",
            dds_name: "std_msgs::msg::dds_::String_",
            rihs01: "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
        };
    }

    /// `std_msgs/msg/ColorRGBA`: components in `0..=1`.
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
    pub struct ColorRGBA {
        /// Red.
        pub r: f32,
        /// Green.
        pub g: f32,
        /// Blue.
        pub b: f32,
        /// Opacity (0 is invisible in RViz).
        pub a: f32,
    }
}

/// `geometry_msgs`.
pub mod geometry_msgs {
    use super::*;

    /// `geometry_msgs/msg/Vector3`.
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
    pub struct Vector3 {
        /// x.
        pub x: f64,
        /// y.
        pub y: f64,
        /// z.
        pub z: f64,
    }

    /// `geometry_msgs/msg/Point`.
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
    pub struct Point {
        /// x.
        pub x: f64,
        /// y.
        pub y: f64,
        /// z.
        pub z: f64,
    }

    /// `geometry_msgs/msg/Quaternion` (its default is the identity, `w = 1`, as in ROS).
    #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
    pub struct Quaternion {
        /// x.
        pub x: f64,
        /// y.
        pub y: f64,
        /// z.
        pub z: f64,
        /// w.
        pub w: f64,
    }

    impl Default for Quaternion {
        fn default() -> Self {
            Self { x: 0.0, y: 0.0, z: 0.0, w: 1.0 }
        }
    }

    /// `geometry_msgs/msg/Pose`.
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
    pub struct Pose {
        /// Position.
        pub position: Point,
        /// Orientation.
        pub orientation: Quaternion,
    }

    /// `geometry_msgs/msg/Transform`: `parent_from_child` of a [`TransformStamped`].
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
    pub struct Transform {
        /// Translation, metres.
        pub translation: Vector3,
        /// Rotation.
        pub rotation: Quaternion,
    }

    /// `geometry_msgs/msg/TransformStamped`: `header.frame_id` is the parent frame, and
    /// `transform` maps points of `child_frame_id` into it.
    #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
    pub struct TransformStamped {
        /// Stamp and parent frame.
        pub header: std_msgs::Header,
        /// The child frame.
        pub child_frame_id: std::string::String,
        /// `parent_from_child`.
        pub transform: Transform,
    }

    impl From<Transform> for crate::rigid::RigidTransform {
        /// The quaternion is normalised; check it first (the tf buffer refuses one far from unit).
        fn from(t: Transform) -> Self {
            let q = t.rotation;
            Self::new(
                glam::DQuat::from_xyzw(q.x, q.y, q.z, q.w),
                glam::DVec3::new(t.translation.x, t.translation.y, t.translation.z),
            )
        }
    }

    impl From<crate::rigid::RigidTransform> for Transform {
        fn from(t: crate::rigid::RigidTransform) -> Self {
            let (q, v) = (t.rotation, t.translation);
            Self {
                translation: Vector3 { x: v.x, y: v.y, z: v.z },
                rotation: Quaternion { x: q.x, y: q.y, z: q.z, w: q.w },
            }
        }
    }

    impl From<crate::rigid::RigidTransform> for Pose {
        fn from(t: crate::rigid::RigidTransform) -> Self {
            let Transform { translation: v, rotation } = t.into();
            Self { position: Point { x: v.x, y: v.y, z: v.z }, orientation: rotation }
        }
    }
}

/// `tf2_msgs`.
pub mod tf2_msgs {
    use super::*;

    /// `tf2_msgs/msg/TFMessage`: what `/tf` and `/tf_static` carry.
    #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
    pub struct TFMessage {
        /// The transforms.
        pub transforms: Vec<geometry_msgs::TransformStamped>,
    }

    impl RosMessage for TFMessage {
        const TYPE: MessageType = MessageType {
            ros_name: "tf2_msgs/msg/TFMessage",
            dds_name: "tf2_msgs::msg::dds_::TFMessage_",
            rihs01: "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
        };
    }
}

/// `sensor_msgs` (only what a Marker holds).
pub mod sensor_msgs {
    use super::*;

    /// `sensor_msgs/msg/CompressedImage`.
    #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
    pub struct CompressedImage {
        /// Stamp and optical frame.
        pub header: std_msgs::Header,
        /// `jpeg`, `png`, ...
        pub format: std::string::String,
        /// The compressed bytes.
        pub data: Vec<u8>,
    }
}

/// `visualization_msgs` (what RViz draws).
pub mod visualization_msgs {
    use super::*;

    /// `visualization_msgs/msg/UVCoordinate`: a texture coordinate.
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
    pub struct UVCoordinate {
        /// u.
        pub u: f32,
        /// v.
        pub v: f32,
    }

    /// `visualization_msgs/msg/MeshFile`: a mesh sent inline.
    #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
    pub struct MeshFile {
        /// Its file name (the extension tells the format).
        pub filename: std::string::String,
        /// The file's bytes.
        pub data: Vec<u8>,
    }

    /// `visualization_msgs/msg/Marker`.
    #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
    pub struct Marker {
        /// Stamp and the frame `pose` is in.
        pub header: std_msgs::Header,
        /// Namespace: with `id`, what a later marker replaces or deletes.
        pub ns: std::string::String,
        /// Id within the namespace.
        pub id: i32,
        /// The shape (`type` in ROS): [`Marker::CUBE`], [`Marker::TEXT_VIEW_FACING`], ...
        #[serde(rename = "type")]
        pub kind: i32,
        /// [`Marker::ADD`], [`Marker::DELETE`] or [`Marker::DELETEALL`].
        pub action: i32,
        /// Pose of the shape in `header.frame_id`.
        pub pose: geometry_msgs::Pose,
        /// Size, metres (for text, `z` is the letter height).
        pub scale: geometry_msgs::Vector3,
        /// Colour.
        pub color: std_msgs::ColorRGBA,
        /// How long RViz keeps it (zero: until replaced or deleted).
        pub lifetime: builtin_interfaces::Duration,
        /// Follows its frame when the frame moves.
        pub frame_locked: bool,
        /// Points of line, list and point types.
        pub points: Vec<geometry_msgs::Point>,
        /// Per-point colours (empty: `color` for all).
        pub colors: Vec<std_msgs::ColorRGBA>,
        /// Texture URI for triangle lists.
        pub texture_resource: std::string::String,
        /// Inline texture.
        pub texture: sensor_msgs::CompressedImage,
        /// Texture coordinates per point.
        pub uv_coordinates: Vec<UVCoordinate>,
        /// Text of [`Marker::TEXT_VIEW_FACING`].
        pub text: std::string::String,
        /// Mesh URI of [`Marker::MESH_RESOURCE`].
        pub mesh_resource: std::string::String,
        /// Inline mesh.
        pub mesh_file: MeshFile,
        /// Use the mesh's own materials.
        pub mesh_use_embedded_materials: bool,
    }

    impl Marker {
        /// Shape: arrow.
        pub const ARROW: i32 = 0;
        /// Shape: box.
        pub const CUBE: i32 = 1;
        /// Shape: sphere.
        pub const SPHERE: i32 = 2;
        /// Shape: cylinder.
        pub const CYLINDER: i32 = 3;
        /// Shape: connected line through `points`.
        pub const LINE_STRIP: i32 = 4;
        /// Shape: a segment per pair of `points`.
        pub const LINE_LIST: i32 = 5;
        /// Shape: a box per point.
        pub const CUBE_LIST: i32 = 6;
        /// Shape: a sphere per point.
        pub const SPHERE_LIST: i32 = 7;
        /// Shape: points.
        pub const POINTS: i32 = 8;
        /// Shape: text facing the viewer.
        pub const TEXT_VIEW_FACING: i32 = 9;
        /// Shape: a mesh.
        pub const MESH_RESOURCE: i32 = 10;
        /// Shape: triangles of `points`.
        pub const TRIANGLE_LIST: i32 = 11;
        /// Shape: arrows along `points` (Jazzy and later; RViz on Humble does not draw it).
        pub const ARROW_STRIP: i32 = 12;
        /// Action: add or replace.
        pub const ADD: i32 = 0;
        /// Action: the same as [`Marker::ADD`].
        pub const MODIFY: i32 = 0;
        /// Action: delete the marker of this `ns` and `id`.
        pub const DELETE: i32 = 2;
        /// Action: delete every marker (of this `ns`, or all when `ns` is empty).
        pub const DELETEALL: i32 = 3;
    }

    impl RosMessage for Marker {
        const TYPE: MessageType = MessageType {
            ros_name: "visualization_msgs/msg/Marker",
            dds_name: "visualization_msgs::msg::dds_::Marker_",
            rihs01: "RIHS01_45b13ccf791f225962bf74e746f9644518855d783a6f42ba0cc14fde2b4f3ce0",
        };
    }

    /// `visualization_msgs/msg/MarkerArray`.
    #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
    pub struct MarkerArray {
        /// The markers, applied in order.
        pub markers: Vec<Marker>,
    }

    impl RosMessage for MarkerArray {
        const TYPE: MessageType = MessageType {
            ros_name: "visualization_msgs/msg/MarkerArray",
            dds_name: "visualization_msgs::msg::dds_::MarkerArray_",
            rihs01: "RIHS01_86cb8800b6fb05b5eff1abd7a56f62a5641d3ae9a1c29e78e67e704f1d067dcf",
        };
    }
}

/// `nav_msgs` (the occupancy grid).
pub mod nav_msgs {
    use super::*;

    /// `nav_msgs/msg/MapMetaData`.
    #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
    pub struct MapMetaData {
        /// When the map was loaded.
        pub map_load_time: builtin_interfaces::Time,
        /// Cell size, metres.
        pub resolution: f32,
        /// Cells along x.
        pub width: u32,
        /// Cells along y.
        pub height: u32,
        /// Pose of cell (0, 0)'s corner in the grid's frame.
        pub origin: geometry_msgs::Pose,
    }

    /// `nav_msgs/msg/OccupancyGrid`: row-major cells, row 0 at `origin`, values 0 (free) to 100
    /// (occupied), -1 unknown.
    #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
    pub struct OccupancyGrid {
        /// Stamp and the grid's frame.
        pub header: std_msgs::Header,
        /// Size and placement.
        pub info: MapMetaData,
        /// `width * height` cells.
        pub data: Vec<i8>,
    }

    impl RosMessage for OccupancyGrid {
        const TYPE: MessageType = MessageType {
            ros_name: "nav_msgs/msg/OccupancyGrid",
            dds_name: "nav_msgs::msg::dds_::OccupancyGrid_",
            rihs01: "RIHS01_8d348150c12913a31ee0ec170fbf25089e4745d17035792a1ba94d6f0bc0cfc7",
        };
    }
}

/// The types this crate puts on or takes from topics, for tables and tests.
pub const TOPIC_TYPES: [MessageType; 5] = [
    <tf2_msgs::TFMessage as RosMessage>::TYPE,
    <visualization_msgs::MarkerArray as RosMessage>::TYPE,
    <visualization_msgs::Marker as RosMessage>::TYPE,
    <nav_msgs::OccupancyGrid as RosMessage>::TYPE,
    <std_msgs::String as RosMessage>::TYPE,
];
