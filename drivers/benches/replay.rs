//! Replay speed: reading and decoding one frame of the ICL-NUIM sequence (640x480 JPEG colour +
//! 16-bit PNG depth) into a pooled frame, one core. Needs `../shared/data` beside the repository;
//! without it the bench prints a message and measures nothing.
//!
//! `cargo bench -p op3dsg-drivers --bench replay` prints criterion's time per frame and a
//! one-line ms/frame summary over the whole sequence.

use criterion::{Criterion, criterion_group, criterion_main};
use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::replay::{PlaybackMode, ReplayConfig, ReplaySource};
use op3dsg_drivers::source::{FrameSource, SourceStatus};

fn bench_replay(c: &mut Criterion) {
    let Some(dir) = op3dsg_shared_data::shared_data("rgbd/icl_livingroom1") else { return };
    let config = ReplayConfig { mode: PlaybackMode::Fast, looping: true, ..ReplayConfig::new(dir) };
    let mut source = ReplaySource::new(&config).expect("the ICL sequence opens");
    let mut frame = Frame::new(source.intrinsics());

    // Plain summary over one pass of the sequence.
    let count = source.frame_count();
    let start = std::time::Instant::now();
    for _ in 0..count {
        assert_eq!(source.next_frame(&mut frame).expect("ICL frames decode"), SourceStatus::Frame);
    }
    let seconds = start.elapsed().as_secs_f64();
    eprintln!(
        "replay summary: ICL living room 1, {count} frames 640x480 (JPEG + 16-bit PNG): {:.2} ms/frame, {:.0} frames/s",
        1e3 * seconds / count as f64,
        count as f64 / seconds
    );

    c.bench_function("replay ICL frame 640x480 (decode JPEG + PNG16)", |b| {
        b.iter(|| {
            let status = source.next_frame(&mut frame).expect("ICL frames decode");
            std::hint::black_box((status, frame.depth[1000]))
        })
    });
}

criterion_group!(benches, bench_replay);
criterion_main!(benches);
