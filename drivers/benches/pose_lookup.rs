//! Cost of a frame's pose lookup in the keyframe gate's pose buffer: a full buffer of 256 poses
//! at 10 Hz (the base profile's `pose.buffer_len`), looked up at 30 Hz frame stamps
//! (interpolation: binary search, lerp, SLERP), and one push at capacity.
//!
//! `cargo bench -p op3dsg-drivers --bench pose_lookup`

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use glam::{DQuat, DVec3};
use op3dsg_drivers::pose::{Isometry, PoseBuffer, PoseBufferConfig, StampedPose};

fn pose_at(t_s: f64) -> Isometry {
    Isometry::new(
        DQuat::from_rotation_z(0.2 * t_s) * DQuat::from_rotation_x(0.1 * t_s.sin()),
        DVec3::new(0.3 * t_s, 0.0, 1.2),
    )
}

fn full_buffer() -> PoseBuffer {
    let mut buffer = PoseBuffer::new(PoseBufferConfig {
        capacity: 256,
        max_interpolation_gap_ns: 250_000_000,
        hold_tolerance_ns: 50_000_000,
    });
    for j in 0..256u64 {
        let stamp_ns = j * 100_000_000;
        buffer.push(StampedPose { stamp_ns, world_from_camera: pose_at(stamp_ns as f64 * 1e-9) }).expect("in order");
    }
    buffer
}

fn bench(c: &mut Criterion) {
    let buffer = full_buffer();
    let frames: Vec<u64> = (0..765u64).map(|k| k * 33_333_333).collect();
    c.bench_function("pose_at: 256 poses at 10 Hz, one 30 Hz frame", |b| {
        let mut i = 0usize;
        b.iter(|| {
            i = (i + 1) % frames.len();
            black_box(buffer.pose_at(black_box(frames[i]), true))
        })
    });
    c.bench_function("push at capacity (256)", |b| {
        let mut buffer = full_buffer();
        let mut stamp_ns = 256 * 100_000_000u64;
        b.iter(|| {
            stamp_ns += 100_000_000;
            black_box(buffer.push(StampedPose { stamp_ns, world_from_camera: Isometry::IDENTITY }))
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
