//! CDR against an independent implementation, PyPI `rosbags` (its typestores hold each ROS 2
//! distribution's message definitions): its payloads in `tests/data/` (made by
//! `tests/rosbags_cdr.py golden`, see `tests/data/GENERATED_BY`) decode here field for field and
//! re-encode byte for byte; what is encoded here decodes there with the Humble and the Jazzy
//! definitions; the type hashes here are the ones rosbags computes. Malformed payloads are refused
//! with what is wrong.

use std::path::{Path, PathBuf};
use std::process::Command;

use op3dsg_ros2::msg::TOPIC_TYPES;
use op3dsg_ros2::msg::builtin_interfaces::{Duration, Time};
use op3dsg_ros2::msg::geometry_msgs::{Point, Pose, Quaternion, Transform, TransformStamped, Vector3};
use op3dsg_ros2::msg::nav_msgs::{MapMetaData, OccupancyGrid};
use op3dsg_ros2::msg::sensor_msgs::CompressedImage;
use op3dsg_ros2::msg::std_msgs::{self, ColorRGBA, Header};
use op3dsg_ros2::msg::tf2_msgs::TFMessage;
use op3dsg_ros2::msg::visualization_msgs::{Marker, MarkerArray, MeshFile, UVCoordinate};
use op3dsg_ros2::{CdrError, RosMessage, decode, encode};
use serde_json::Value;

fn python() -> PathBuf {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../.venv/bin/python");
    assert!(path.exists(), "{} missing: run ./scripts/setup-python.sh (scripts/test.sh does)", path.display());
    path
}

fn rosbags(args: &[&str]) -> Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/rosbags_cdr.py");
    let output = Command::new(python()).arg(script).args(args).output().expect("run rosbags_cdr.py");
    assert!(output.status.success(), "rosbags_cdr.py {args:?} failed: {}", String::from_utf8_lossy(&output.stderr));
    serde_json::from_slice(&output.stdout).expect("rosbags_cdr.py prints JSON")
}

fn data(name: &str) -> Vec<u8> {
    std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data").join(name)).expect("golden payload")
}

fn header(sec: i32, nanosec: u32, frame_id: &str) -> Header {
    Header { stamp: Time { sec, nanosec }, frame_id: frame_id.to_string() }
}

fn transform(parent: &str, child: &str, sec: i32, nanosec: u32, xyz: [f64; 3], xyzw: [f64; 4]) -> TransformStamped {
    TransformStamped {
        header: header(sec, nanosec, parent),
        child_frame_id: child.to_string(),
        transform: Transform {
            translation: Vector3 { x: xyz[0], y: xyz[1], z: xyz[2] },
            rotation: Quaternion { x: xyzw[0], y: xyzw[1], z: xyzw[2], w: xyzw[3] },
        },
    }
}

/// What `rosbags_cdr.py`'s `golden_tf` builds.
fn golden_tf() -> TFMessage {
    TFMessage {
        transforms: vec![
            transform("map", "odom", 1_700_000_000, 123_456_789, [1.5, -2.25, 0.0], [0.0, 0.0, 0.6, 0.8]),
            transform("odom", "base_link", 1_700_000_000, 123_456_789, [0.1, 0.2, 0.3], [0.0, 0.0, 0.0, 1.0]),
            transform("camera_link", "camera_color_optical_frame", 0, 0, [0.0, 0.015, 0.0], [-0.5, 0.5, -0.5, 0.5]),
        ],
    }
}

fn color(r: f32, g: f32, b: f32, a: f32) -> ColorRGBA {
    ColorRGBA { r, g, b, a }
}

/// What `rosbags_cdr.py`'s `golden_marker` builds.
fn golden_marker() -> Marker {
    Marker {
        header: header(12, 500, "map"),
        ns: "objects".into(),
        id: 42,
        kind: Marker::CUBE,
        action: Marker::ADD,
        pose: Pose { position: Point { x: 1.0, y: 2.0, z: 0.5 }, orientation: Quaternion::default() },
        scale: Vector3 { x: 0.5, y: 0.25, z: 0.75 },
        color: color(1.0, 0.5, 0.25, 0.75),
        lifetime: Duration { sec: 2, nanosec: 250_000_000 },
        frame_locked: true,
        points: vec![Point::default(), Point { x: 1.0, y: -1.0, z: 2.0 }],
        colors: vec![color(0.0, 1.0, 0.0, 1.0)],
        texture_resource: "package://op3dsg/texture.png".into(),
        texture: CompressedImage { header: header(12, 500, "map"), format: "png".into(), data: vec![137, 80, 78, 71] },
        uv_coordinates: vec![UVCoordinate { u: 0.5, v: 0.25 }],
        text: "chair (part of: table)".into(),
        mesh_resource: String::new(),
        mesh_file: MeshFile { filename: "box.stl".into(), data: vec![1, 2, 3] },
        mesh_use_embedded_materials: false,
    }
}

#[test]
fn rosbags_tf_messages_decode_in_both_byte_orders_and_reencode_exactly() {
    let little = data("tfmessage_le.cdr");
    assert_eq!(decode::<TFMessage>(&little).unwrap(), golden_tf());
    assert_eq!(decode::<TFMessage>(&data("tfmessage_be.cdr")).unwrap(), golden_tf());
    assert_eq!(encode(&golden_tf()), little);
}

#[test]
fn a_rosbags_marker_decodes_field_for_field_and_reencodes_exactly() {
    let bytes = data("marker.cdr");
    assert_eq!(decode::<Marker>(&bytes).unwrap(), golden_marker());
    assert_eq!(encode(&golden_marker()), bytes);
}

#[test]
fn malformed_payloads_are_refused_with_what_is_wrong() {
    let good = data("tfmessage_le.cdr");
    let err = |bytes: &[u8]| decode::<TFMessage>(bytes).unwrap_err();
    assert_eq!(err(&good[..3]), CdrError::ShortPayload { type_name: "tf2_msgs/msg/TFMessage", len: 3 });
    let mut xcdr2 = good.clone();
    xcdr2[1] = 0x07;
    let message = err(&xcdr2).to_string();
    assert!(message.contains("[00, 07, 00, 00]") && message.contains("XCDR2"), "{message}");
    let message = err(&good[..good.len() - 9]).to_string();
    assert!(
        message.starts_with("tf2_msgs/msg/TFMessage: CDR body of 287 bytes does not decode: the payload ends"),
        "{message}"
    );
    // Up to 3 bytes of padding are fine; more are another type's bytes.
    let mut padded = good.clone();
    padded.extend_from_slice(&[0, 0, 0]);
    assert_eq!(decode::<TFMessage>(&padded).unwrap(), golden_tf());
    padded.push(0);
    assert_eq!(err(&padded), CdrError::TrailingBytes { type_name: "tf2_msgs/msg/TFMessage", count: 4 });
    // A string without its bytes, a boolean that is 2, text that is not UTF-8.
    let mut huge_string = good.clone();
    huge_string[16..20].copy_from_slice(&1000u32.to_le_bytes());
    assert!(matches!(err(&huge_string), CdrError::Malformed { .. }));
    let mut marker = data("marker.cdr");
    let text_at = marker.windows(5).position(|w| w == b"chair").unwrap();
    marker[text_at] = 0xff;
    let message = decode::<Marker>(&marker).unwrap_err().to_string();
    assert!(message.starts_with("visualization_msgs/msg/Marker: CDR body") && message.contains("UTF-8"), "{message}");
    let mut bad_bool = encode(&Marker { frame_locked: true, ..Marker::default() });
    let unlocked = encode(&Marker::default());
    let bool_at = bad_bool.iter().zip(&unlocked).position(|(a, b)| a != b).unwrap();
    bad_bool[bool_at] = 2;
    let message = decode::<Marker>(&bad_bool).unwrap_err().to_string();
    assert!(message.contains("Boolean"), "{message}");
}

/// Encodes `message`, has rosbags decode it with both distributions' definitions, and checks it
/// reads the same fields and re-encodes the same bytes.
fn rosbags_reads<T: RosMessage + serde::Serialize>(message: &T) {
    let dir = tempfile::tempdir().expect("a temporary directory");
    let file = dir.path().join("payload.cdr");
    std::fs::write(&file, encode(message)).expect("write the payload");
    let read = rosbags(&["decode", T::TYPE.ros_name, file.to_str().expect("a UTF-8 path")]);
    let ours = serde_json::to_value(message).expect("JSON of the message");
    assert_eq!(read["humble"], ours, "{}: Humble's definition", T::TYPE.ros_name);
    assert_eq!(read["jazzy"], ours, "{}: Jazzy's definition", T::TYPE.ros_name);
    assert_eq!(read["reencoded_equal"], true, "{}: rosbags re-encodes other bytes", T::TYPE.ros_name);
}

#[test]
fn rosbags_reads_what_is_encoded_here() {
    let cube = Marker {
        header: header(1_700_000_001, 5, "map"),
        ns: "op3dsg/nodes".into(),
        id: 7,
        kind: Marker::CUBE,
        pose: Pose {
            position: Point { x: 0.5, y: -1.25, z: 0.375 },
            orientation: Quaternion { x: 0.0, y: 0.0, z: 0.6, w: 0.8 },
        },
        scale: Vector3 { x: 0.5, y: 0.5, z: 1.0 },
        color: color(0.25, 0.5, 0.75, 1.0),
        ..Marker::default()
    };
    let label = Marker {
        id: 8,
        kind: Marker::TEXT_VIEW_FACING,
        text: "tasse à café".into(),
        scale: Vector3 { x: 0.0, y: 0.0, z: 0.125 },
        ..cube.clone()
    };
    let edges = Marker {
        id: 9,
        kind: Marker::LINE_LIST,
        points: vec![Point { x: 0.0, y: 0.0, z: 0.0 }, Point { x: 1.0, y: 2.0, z: 3.0 }],
        colors: vec![color(1.0, 0.0, 0.0, 1.0), color(0.0, 0.0, 1.0, 0.5)],
        ..cube.clone()
    };
    let removed = Marker { ns: "op3dsg/nodes".into(), id: 3, action: Marker::DELETE, ..Marker::default() };
    rosbags_reads(&MarkerArray { markers: vec![cube, label, edges, removed] });
    rosbags_reads(&OccupancyGrid {
        header: header(1_700_000_002, 0, "map"),
        info: MapMetaData {
            map_load_time: Time { sec: 1_700_000_000, nanosec: 0 },
            resolution: 0.0625,
            width: 3,
            height: 2,
            origin: Pose { position: Point { x: -1.5, y: -2.0, z: 0.0 }, orientation: Quaternion::default() },
        },
        data: vec![-1, 0, 100, 50, 0, -1],
    });
    rosbags_reads(&std_msgs::String { data: r#"{"version": 3, "nodes": ["chaise"]}"#.into() });
    rosbags_reads(&MarkerArray::default());
}

#[test]
fn type_hashes_are_the_ones_rosbags_computes() {
    let names: Vec<&str> = TOPIC_TYPES.iter().map(|t| t.ros_name).collect();
    let computed = rosbags(&[&["rihs01"][..], &names].concat());
    for ty in TOPIC_TYPES {
        assert_eq!(computed[ty.ros_name]["jazzy"], ty.rihs01, "{}: Jazzy", ty.ros_name);
        assert_eq!(computed[ty.ros_name]["kilted"], ty.rihs01, "{}: Kilted", ty.ros_name);
        let bare = ty.ros_name.rsplit('/').next().unwrap();
        assert_eq!(ty.dds_name, format!("{}::msg::dds_::{bare}_", ty.ros_name.split('/').next().unwrap()));
    }
}
