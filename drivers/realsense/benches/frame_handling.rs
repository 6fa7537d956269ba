//! Driver frame handling per 848x480 frame, one thread: p50 / p99 over many frames.
//!
//! ```sh
//! taskset -c 1 cargo bench -p op3dsg-realsense --bench frame_handling                 # rotate + copy
//! PKG_CONFIG_PATH=.deps/realsense/lib/pkgconfig LD_LIBRARY_PATH=.deps/realsense/lib \
//!   taskset -c 1 cargo bench -p op3dsg-realsense --features librealsense --bench frame_handling   # + librealsense
//! ```
//!
//! 1. `rotate+copy`: what the source does with the driver's buffers, on synthetic buffers of
//!    the D435i's layout (848x480 RGB8 and Z16 aligned depth, rows padded to a 64-byte stride):
//!    colour and depth copied into a pooled frame's buffers, for each rotation.
//! 2. With `--features librealsense`: `RealsenseSource::next_frame` on an 848x480 recording of
//!    pyrealsense2's software device (depth Z16 + colour RGB8, made by
//!    `tests/record_software_device.py` with the project venv) played as fast as possible: the
//!    pipeline's wait, librealsense's align block (depth → colour), rotate 90° and the copy into
//!    the frame. It also contains librealsense reading and decoding the file, so it is an upper
//!    bound of what a live camera costs (a camera delivers frames already in memory).
//!
//! Each line gives the thread's CPU time per frame (what the frame costs the core) and the wall
//! time (which on a shared machine also holds the time other processes had the core).
//!
//! Target: <= 3 ms per frame at p99 for the whole driver path (30 Hz then costs under a tenth of
//! a core).

use std::hint::black_box;
use std::time::{Duration, Instant};

use op3dsg_drivers::frame::{Frame, Intrinsics};
use op3dsg_realsense::rotate::{ColourOrder, Rotation, SourceLayout, copy_colour, copy_depth};

const W: usize = 848;
const H: usize = 480;

fn percentiles(mut samples: Vec<Duration>) -> (f64, f64, usize) {
    samples.sort_unstable();
    let at = |q: f64| samples[((samples.len() - 1) as f64 * q).round() as usize].as_secs_f64() * 1e3;
    (at(0.50), at(0.99), samples.len())
}

/// CPU time this thread has used (`CLOCK_THREAD_CPUTIME_ID`): what the frame costs the core,
/// without the time other processes held it.
fn thread_cpu() -> Duration {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: clock_gettime writes one timespec into the valid pointer given.
    #[allow(unsafe_code)]
    unsafe {
        libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts);
    }
    Duration::new(ts.tv_sec as u64, ts.tv_nsec as u32)
}

/// Wall-clock and thread-CPU time of one frame.
#[derive(Clone, Copy)]
struct Timer(Instant, Duration);

impl Timer {
    fn start() -> Self {
        Self(Instant::now(), thread_cpu())
    }
    fn stop(self) -> (Duration, Duration) {
        (self.0.elapsed(), thread_cpu().saturating_sub(self.1))
    }
}

fn report(name: &str, samples: Vec<(Duration, Duration)>) {
    let (w50, w99, n) = percentiles(samples.iter().map(|s| s.0).collect());
    let (c50, c99, _) = percentiles(samples.iter().map(|s| s.1).collect());
    println!(
        "{name:<52} cpu p50 {c50:6.3} ms  p99 {c99:6.3} ms | wall p50 {w50:6.3} ms  p99 {w99:6.3} ms  ({n} frames)"
    );
}

fn rotate_and_copy() {
    let stride_rgb = (W * 3).div_ceil(64) * 64;
    let stride_z = (W * 2).div_ceil(64) * 64;
    let rgb: Vec<u8> = (0..stride_rgb * H).map(|i| (i * 31 % 251) as u8).collect();
    let z16: Vec<u8> = (0..stride_z * H).map(|i| (i * 17 % 253) as u8).collect();
    let k = Intrinsics { width: W as u32, height: H as u32, fx: 421.0, fy: 421.0, cx: 424.0, cy: 240.0 };
    for rotation in [Rotation::None, Rotation::Cw90, Rotation::Cw180, Rotation::Cw270] {
        let mut frame = Frame::new(rotation.intrinsics(&k));
        let mut samples = Vec::with_capacity(2000);
        for i in 0..2200 {
            let started = Timer::start();
            copy_colour(
                black_box(&rgb),
                SourceLayout { width: W, height: H, stride_bytes: stride_rgb },
                ColourOrder::Rgb8,
                rotation,
                &mut frame.rgb,
            )
            .expect("colour layout");
            copy_depth(
                black_box(&z16),
                SourceLayout { width: W, height: H, stride_bytes: stride_z },
                rotation,
                &mut frame.depth,
            )
            .expect("depth layout");
            black_box(&frame);
            if i >= 200 {
                samples.push(started.stop());
            }
        }
        report(&format!("rotate+copy {W}x{H} rgb8+z16, rotate {}", rotation.degrees()), samples);
    }
}

#[cfg(feature = "librealsense")]
fn playback() {
    use op3dsg_drivers::source::{FrameSource, SourceStatus};
    use op3dsg_realsense::{RealsenseConfig, RealsenseSource};
    use std::path::Path;

    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let python = root.join("../../.venv/bin/python");
    if !python.exists() {
        println!("librealsense playback: skipped, {} missing (./scripts/setup-python.sh)", python.display());
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let bag = dir.path().join("bench.bag");
    let frames = 120;
    let out = std::process::Command::new(&python)
        .arg(root.join("tests/record_software_device.py"))
        .arg(&bag)
        .args(["--frames", &frames.to_string(), "--width", &W.to_string(), "--height", &H.to_string()])
        .output()
        .expect("run the recorder");
    assert!(out.status.success(), "recorder: {}", String::from_utf8_lossy(&out.stderr));
    let mut samples = Vec::new();
    for _pass in 0..3 {
        let config = RealsenseConfig {
            bag: bag.display().to_string(),
            bag_real_time: false,
            rotate: Rotation::Cw90,
            ..RealsenseConfig::default()
        };
        let mut source = RealsenseSource::open(&config, None).expect("open the recording");
        let mut frame = Frame::new(source.intrinsics());
        let mut delivered = 0;
        loop {
            let started = Timer::start();
            match source.next_frame(&mut frame).expect("next_frame") {
                SourceStatus::Frame => {
                    // The first frames include the pipeline's start-up.
                    if delivered >= 5 {
                        samples.push(started.stop());
                    }
                    delivered += 1;
                }
                SourceStatus::Pending => {}
                SourceStatus::EndOfStream => break,
            }
        }
    }
    report(&format!("librealsense playback+align+rotate 90+copy {W}x{H}"), samples);
}

#[cfg(not(feature = "librealsense"))]
fn playback() {
    println!("librealsense playback: build with --features librealsense to measure it");
}

fn main() {
    // `cargo test --benches` runs benches with --bench absent; keep that fast.
    if !std::env::args().any(|a| a == "--bench") {
        return;
    }
    rotate_and_copy();
    playback();
}
