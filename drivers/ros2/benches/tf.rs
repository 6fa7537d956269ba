//! Cost of the tf input on a 200-frame tree: a Stretch-like chain `map -> odom -> base_link ->
//! link_head_tilt -> camera_link -> camera_color_optical_frame` inside a tree of 200 frames (19
//! arms of 10 links and 4 more frames under `base_link`), 30 dynamic edges at 100 Hz with the
//! default 10 s window (30 000 samples held).
//!
//! - `lookup`: `map <- camera_color_optical_frame` at a 30 Hz frame stamp (five edges, three
//!   interpolated): the per-frame cost.
//! - `decode + insert`: one 100 Hz `/tf` message of the 30 dynamic edges, CDR-decoded and added
//!   (window pruning included): times 100 is the subscription's CPU share per second.
//!
//! `cargo bench -p op3dsg-ros2 --bench tf`

use std::hint::black_box;

use criterion::{BatchSize, Criterion, criterion_group, criterion_main};
use glam::{DQuat, DVec3};
use op3dsg_ros2::msg::builtin_interfaces::Time;
use op3dsg_ros2::msg::geometry_msgs::TransformStamped;
use op3dsg_ros2::msg::std_msgs::Header;
use op3dsg_ros2::msg::tf2_msgs::TFMessage;
use op3dsg_ros2::{RigidTransform, TfBuffer, TfConfig, decode, encode};

const PERIOD_NS: u64 = 10_000_000;

fn edge(parent: &str, child: &str, stamp_ns: u64, angle: f64) -> TransformStamped {
    TransformStamped {
        header: Header { stamp: Time::from_ns(stamp_ns), frame_id: parent.to_string() },
        child_frame_id: child.to_string(),
        transform: RigidTransform::new(DQuat::from_rotation_z(angle), DVec3::new(0.1, angle.sin(), 0.2)).into(),
    }
}

/// The 30 dynamic edges at a stamp: the chain's three and the first joint of 27 links.
fn dynamic(stamp_ns: u64) -> TFMessage {
    let t = stamp_ns as f64 * 1e-9;
    let mut transforms = vec![
        edge("map", "odom", stamp_ns, 0.01 * t),
        edge("odom", "base_link", stamp_ns, 0.3 * t),
        edge("base_link", "link_head_tilt", stamp_ns, 0.5 * t.sin()),
    ];
    for arm in 0..19 {
        for link in 0..10 {
            if transforms.len() < 30 && link < 2 {
                let parent = if link == 0 { "base_link".to_string() } else { format!("arm{arm}_link{}", link - 1) };
                transforms.push(edge(&parent, &format!("arm{arm}_link{link}"), stamp_ns, t + arm as f64));
            }
        }
    }
    TFMessage { transforms }
}

fn statics() -> TFMessage {
    let mut transforms =
        vec![edge("link_head_tilt", "camera_link", 0, 0.1), edge("camera_link", "camera_color_optical_frame", 0, 0.2)];
    for child in ["laser", "imu", "wheel_left", "wheel_right"] {
        transforms.push(edge("base_link", child, 0, 0.0));
    }
    let dynamic_children: Vec<String> = dynamic(0).transforms.into_iter().map(|t| t.child_frame_id).collect();
    for arm in 0..19 {
        for link in 0..10 {
            let child = format!("arm{arm}_link{link}");
            if !dynamic_children.contains(&child) {
                let parent = if link == 0 { "base_link".to_string() } else { format!("arm{arm}_link{}", link - 1) };
                transforms.push(edge(&parent, &child, 0, 0.05));
            }
        }
    }
    TFMessage { transforms }
}

fn full_buffer(end_ns: u64) -> TfBuffer {
    let mut buffer = TfBuffer::new(TfConfig::default());
    assert!(buffer.insert_message(&statics(), true).is_empty());
    let mut stamp_ns = PERIOD_NS;
    while stamp_ns <= end_ns {
        assert!(buffer.insert_message(&dynamic(stamp_ns), false).is_empty());
        stamp_ns += PERIOD_NS;
    }
    assert_eq!(buffer.frame_names().count(), 200);
    buffer
}

fn bench(c: &mut Criterion) {
    let end_ns = 20_000_000_000;
    let mut buffer = full_buffer(end_ns);
    let frames: Vec<u64> = (0..240u64).map(|k| end_ns - 9_000_000_000 + k * 33_333_333).collect();
    c.bench_function("lookup map <- camera_color_optical_frame (200 frames, 30 000 samples)", |b| {
        let mut i = 0usize;
        b.iter(|| {
            i = (i + 1) % frames.len();
            black_box(buffer.lookup("map", "camera_color_optical_frame", black_box(frames[i])).expect("a path"))
        })
    });
    let mut stamp_ns = end_ns;
    c.bench_function("decode + insert one /tf message of 30 transforms (steady window)", |b| {
        b.iter_batched(
            || {
                stamp_ns += PERIOD_NS;
                encode(&dynamic(stamp_ns))
            },
            |payload| {
                let message: TFMessage = decode(black_box(&payload)).expect("decodes");
                black_box(buffer.insert_message(&message, false))
            },
            BatchSize::SmallInput,
        )
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
