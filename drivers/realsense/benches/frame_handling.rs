//! Driver frame handling per 848x480 depth frame, one thread: p50 / p99 over many frames.
//!
//! ```sh
//! taskset -c 1 cargo bench -p op3dsg-realsense --bench frame_handling                 # 1 + 2
//! PKG_CONFIG_PATH=.deps/realsense/lib/pkgconfig LD_LIBRARY_PATH=.deps/realsense/lib \
//!   taskset -c 1 cargo bench -p op3dsg-realsense --features librealsense --bench frame_handling   # 1 - 4
//! ```
//!
//! 1. `copy colour` / `copy depth`: what the source does with the driver's buffers, on
//!    synthetic buffers of the D435i's layout (848x480 RGB8 and Z16 aligned depth, rows padded
//!    to a 64-byte stride): colour and depth copied into a pooled frame's buffers, for each
//!    rotation; for the quarter turns also the portable colour loop (CPUs without SSSE3).
//! 2. `op3dsg align`: [`DepthToColour::align`] alone (depth to colour from the calibration,
//!    rotated 90° on the way into the frame's depth) on a synthetic room (slanted wall, a box in
//!    front, scattered holes) with D435i-like calibration, 848x480 depth to 848x480 and to
//!    1280x720 colour.
//! 3. With `--features librealsense`, on the same frames: recordings of pyrealsense2's software
//!    device (`tests/record_software_device.py --scene`, made with the project venv), 848x480
//!    depth with 848x480 and with 1280x720 colour, read by librealsense's pipeline; per frame set
//!    librealsense's align block (`queue` + `wait`, which run on the calling thread) followed by
//!    the rotate-90 copy of its aligned depth, and ours (align + rotate in one pass) on the same
//!    depth frame.
//! 4. With `--features librealsense`: `RealsenseSource::next_frame` with `align = "op3dsg"` and
//!    with `align = "librealsense"` on those recordings, passes alternating between the two: the
//!    pipeline's wait, the alignment, rotate 90° and the copies into the frame (librealsense reads
//!    and decodes the file on its own thread, not counted here); for 848x480 colour also
//!    unturned (rotate 0, a camera mounted upright).
//!
//! Each line gives the thread's CPU time per frame (what the frame costs the core) and the wall
//! time (which on a shared machine also holds the time other processes had the core). On a
//! loaded machine compare the lines of one run as ratios.
//!
//! Target: <= 3 ms per frame at p99 for the whole driver path (30 Hz then costs under a tenth of
//! a core).

use std::hint::black_box;
use std::time::{Duration, Instant};

use op3dsg_drivers::frame::{Frame, Intrinsics};
use op3dsg_realsense::align::{DepthToColour, Extrinsics, Lens};
use op3dsg_realsense::rotate::{
    ColourOrder, CopyError, Rotation, SourceLayout, copy_colour, copy_colour_portable, copy_depth,
};

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

/// Times `frame` over `warm_up + frames` calls, keeping the last `frames`.
fn time_frames(warm_up: usize, frames: usize, mut frame: impl FnMut()) -> Vec<(Duration, Duration)> {
    let mut samples = Vec::with_capacity(frames);
    for i in 0..warm_up + frames {
        let started = Timer::start();
        frame();
        if i >= warm_up {
            samples.push(started.stop());
        }
    }
    samples
}

/// Prints one line; returns the CPU (p50, p99) in ms.
fn report(name: &str, samples: &[(Duration, Duration)]) -> (f64, f64) {
    let (w50, w99, n) = percentiles(samples.iter().map(|s| s.0).collect());
    let (c50, c99, _) = percentiles(samples.iter().map(|s| s.1).collect());
    println!(
        "{name:<64} cpu p50 {c50:6.3} ms  p99 {c99:6.3} ms | wall p50 {w50:6.3} ms  p99 {w99:6.3} ms  ({n} frames)"
    );
    (c50, c99)
}

#[cfg(feature = "librealsense")]
fn ratio(what: &str, ours: (f64, f64), theirs: (f64, f64)) {
    println!("{what:<64} op3dsg / librealsense: p50 {:.2}  p99 {:.2}", ours.0 / theirs.0, ours.1 / theirs.1);
}

fn rotate_and_copy() {
    let stride_rgb = (W * 3).div_ceil(64) * 64;
    let stride_z = (W * 2).div_ceil(64) * 64;
    let rgb: Vec<u8> = (0..stride_rgb * H).map(|i| (i * 31 % 251) as u8).collect();
    let z16: Vec<u8> = (0..stride_z * H).map(|i| (i * 17 % 253) as u8).collect();
    let k = Intrinsics { width: W as u32, height: H as u32, fx: 421.0, fy: 421.0, cx: 424.0, cy: 240.0 };
    let colour_layout = SourceLayout { width: W, height: H, stride_bytes: stride_rgb };
    type CopyColour = fn(&[u8], SourceLayout, ColourOrder, Rotation, &mut [u8]) -> Result<(), CopyError>;
    for rotation in [Rotation::None, Rotation::Cw90, Rotation::Cw180, Rotation::Cw270] {
        let mut frame = Frame::new(rotation.intrinsics(&k));
        let mut copies: Vec<(&str, CopyColour)> = vec![("copy colour", copy_colour)];
        if rotation.swaps_axes() {
            // What CPUs without SSSE3 run (the quarter turns only differ there).
            copies.push(("copy colour, portable loop", copy_colour_portable));
        }
        for (name, copy) in copies {
            let samples = time_frames(200, 2000, || {
                copy(black_box(&rgb), colour_layout, ColourOrder::Rgb8, rotation, &mut frame.rgb)
                    .expect("colour layout");
                black_box(&frame);
            });
            report(&format!("{name} {W}x{H} rgb8, rotate {}", rotation.degrees()), &samples);
        }
        let depth_layout = SourceLayout { width: W, height: H, stride_bytes: stride_z };
        let samples = time_frames(200, 2000, || {
            copy_depth(black_box(&z16), depth_layout, rotation, &mut frame.depth).expect("depth layout");
            black_box(&frame);
        });
        report(&format!("copy depth {W}x{H} z16, rotate {}", rotation.degrees()), &samples);
    }
}

/// D435i-like calibration: 848x480 depth (fx 421), colour at `cw x ch` with the 1280x720
/// colour's field of view (fx 910 at 1280), 15 mm baseline, 0.4 degrees of yaw.
fn d435i_like(cw: u32, ch: u32) -> (Lens, Lens, Extrinsics) {
    let depth = Lens::pinhole(W as u32, H as u32, 421.0, 421.0, 422.75, 239.75);
    let f = 910.0 * cw as f32 / 1280.0;
    let colour = Lens::pinhole(cw, ch, f, f, (cw as f32 - 1.0) / 2.0 + 0.4, (ch as f32 - 1.0) / 2.0 - 0.3);
    let (s, c) = 0.4f32.to_radians().sin_cos();
    let extrinsics =
        Extrinsics { rotation: [c, 0.0, -s, 0.0, 1.0, 0.0, s, 0.0, c], translation_m: [0.015, 0.0003, -0.0002] };
    (depth, colour, extrinsics)
}

/// The recorder's `--scene` room at 0.25 mm units, rows padded to 64 bytes.
fn room_z16(stride: usize) -> Vec<u8> {
    let mut z16 = vec![0u8; stride * H];
    for v in 0..H {
        for u in 0..W {
            let in_box = (u as f64) >= 0.35 * W as f64
                && (u as f64) < 0.6 * W as f64
                && (v as f64) >= 0.3 * H as f64
                && (v as f64) < 0.7 * H as f64;
            let metres = if in_box { 0.9 } else { 2.0 + u as f64 / W as f64 };
            let z = if (7 * u + 3 * v) % 53 == 0 { 0 } else { (metres / 0.00025) as u16 };
            z16[v * stride + u * 2..v * stride + u * 2 + 2].copy_from_slice(&z.to_le_bytes());
        }
    }
    z16
}

fn align_kernel() {
    let stride = (W * 2).div_ceil(64) * 64;
    let z16 = room_z16(stride);
    for (cw, ch, rotation) in [
        (848u32, 480u32, Rotation::None),
        (848, 480, Rotation::Cw90),
        (1280, 720, Rotation::None),
        (1280, 720, Rotation::Cw90),
    ] {
        let (depth, colour, extrinsics) = d435i_like(cw, ch);
        let mut aligner = DepthToColour::new(depth, colour, extrinsics, 0.00025).expect("calibration");
        let mut out = vec![0u16; cw as usize * ch as usize];
        let layout = SourceLayout { width: W, height: H, stride_bytes: stride };
        let samples = time_frames(60, 600, || {
            aligner.align(black_box(&z16), layout, rotation, &mut out).expect("layout");
            black_box(&out);
        });
        report(&format!("op3dsg align {W}x{H} -> {cw}x{ch}, rotate {} (synthetic room)", rotation.degrees()), &samples);
    }
}

#[cfg(feature = "librealsense")]
mod with_librealsense {
    use std::path::{Path, PathBuf};

    use op3dsg_drivers::source::{FrameSource, SourceStatus};
    use op3dsg_realsense::config::AlignMode;
    use op3dsg_realsense::device::lens;
    use op3dsg_realsense::{RealsenseConfig, RealsenseSource};
    use realsense_rust::config::Config;
    use realsense_rust::context::Context;
    use realsense_rust::frame::DepthFrame;
    use realsense_rust::kind::{Rs2Format, Rs2StreamKind};
    use realsense_rust::pipeline::InactivePipeline;
    use realsense_rust::processing_blocks::align::Align;

    use super::*;

    /// Recordings: 848x480 depth with 848x480 and with 1280x720 colour.
    pub fn recordings(dir: &Path) -> Option<Vec<(PathBuf, u32, u32)>> {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let python = root.join("../../.venv/bin/python");
        if !python.exists() {
            println!("librealsense lines: skipped, {} missing (./scripts/setup-python.sh)", python.display());
            return None;
        }
        let mut bags = Vec::new();
        for (cw, ch) in [(848u32, 480u32), (1280, 720)] {
            let (_, colour, _) = d435i_like(cw, ch);
            let bag = dir.join(format!("room-{cw}x{ch}.bag"));
            let out = std::process::Command::new(&python)
                .arg(root.join("tests/record_software_device.py"))
                .arg(&bag)
                .args(["--frames", "100", "--width", &W.to_string(), "--height", &H.to_string()])
                .args(["--fx", "421", "--fy", "421", "--scene", "--yaw-deg", "0.4"])
                .args(["--translation", "0.015", "0.0003", "-0.0002"])
                .args(["--colour-width", &cw.to_string(), "--colour-height", &ch.to_string()])
                .args(["--colour-fx", &colour.fx.to_string(), "--colour-fy", &colour.fy.to_string()])
                .output()
                .expect("run the recorder");
            assert!(out.status.success(), "recorder: {}", String::from_utf8_lossy(&out.stderr));
            bags.push((bag, cw, ch));
        }
        Some(bags)
    }

    #[allow(unsafe_code)]
    fn bytes_of(frame: &DepthFrame) -> &[u8] {
        // SAFETY: librealsense keeps the frame's buffer (get_data_size bytes) alive while the
        // frame object lives; the slice borrows the frame.
        unsafe {
            std::slice::from_raw_parts(
                (frame.get_data() as *const std::ffi::c_void).cast::<u8>(),
                frame.get_data_size(),
            )
        }
    }

    /// Same frame sets: librealsense's align block + rotate-copy vs ours.
    pub fn align_on_recording(bag: &Path, cw: u32, ch: u32) {
        let (mut ours, mut theirs) = (Vec::new(), Vec::new());
        let (mut equal, mut total) = (0usize, 0usize);
        for _pass in 0..2 {
            let context = Context::new().expect("context");
            let mut cfg = Config::new();
            cfg.enable_device_from_file(bag, false).expect("bag");
            cfg.enable_stream(Rs2StreamKind::Depth, None, 0, 0, Rs2Format::Z16, 0).expect("depth");
            cfg.enable_stream(Rs2StreamKind::Color, None, 0, 0, Rs2Format::Any, 0).expect("colour");
            let mut pipeline = InactivePipeline::try_from(&context).expect("pipeline").start(Some(cfg)).expect("start");
            let streams = pipeline.profile().streams();
            let depth_stream = streams.iter().find(|s| s.kind() == Rs2StreamKind::Depth).expect("depth stream");
            let colour_stream = streams.iter().find(|s| s.kind() == Rs2StreamKind::Color).expect("colour stream");
            let e = depth_stream.extrinsics(colour_stream).expect("extrinsics");
            let mut aligner = DepthToColour::new(
                lens(&depth_stream.intrinsics().expect("depth intrinsics").0),
                lens(&colour_stream.intrinsics().expect("colour intrinsics").0),
                Extrinsics { rotation: e.rotation(), translation_m: e.translation() },
                0.00025,
            )
            .expect("calibration");
            let mut block = Align::new(Rs2StreamKind::Color, 1).expect("align block");
            let n = cw as usize * ch as usize;
            let (mut ours_out, mut theirs_out) = (vec![0u16; n], vec![0u16; n]);
            let mut seen = 0;
            while let Ok(set) = pipeline.wait(Some(Duration::from_secs(3))) {
                let Some(depth) = set.frames_of_type::<DepthFrame>().into_iter().next() else { continue };
                let layout =
                    SourceLayout { width: depth.width(), height: depth.height(), stride_bytes: depth.stride() };
                let started = Timer::start();
                aligner.align(bytes_of(&depth), layout, Rotation::Cw90, &mut ours_out).expect("our align");
                let ours_time = started.stop();
                let started = Timer::start();
                block.queue(set).expect("align queue");
                let aligned = block.wait(Duration::from_secs(1)).expect("align wait");
                let aligned_depth = aligned.frames_of_type::<DepthFrame>().into_iter().next().expect("aligned depth");
                let layout = SourceLayout {
                    width: aligned_depth.width(),
                    height: aligned_depth.height(),
                    stride_bytes: aligned_depth.stride(),
                };
                copy_depth(bytes_of(&aligned_depth), layout, Rotation::Cw90, &mut theirs_out).expect("copy");
                let theirs_time = started.stop();
                seen += 1;
                if seen > 3 {
                    ours.push(ours_time);
                    theirs.push(theirs_time);
                }
                equal += ours_out.iter().zip(&theirs_out).filter(|(a, b)| a == b).count();
                total += n;
            }
        }
        let what = format!("{W}x{H} -> {cw}x{ch}, rotate 90, same frame sets");
        let t = report(&format!("librealsense align block + rotate-copy {what}"), &theirs);
        let o = report(&format!("op3dsg align+rotate {what}"), &ours);
        ratio(&format!("  align {W}x{H} -> {cw}x{ch}"), o, t);
        println!("  aligned depth equal in {:.4} % of the pixels", 100.0 * equal as f64 / total.max(1) as f64);
    }

    /// The whole `next_frame`, both modes, passes alternating.
    pub fn next_frame(bag: &Path, cw: u32, ch: u32, rotate: Rotation) {
        let (mut ours, mut theirs) = (Vec::new(), Vec::new());
        for _pass in 0..2 {
            for align in [AlignMode::Librealsense, AlignMode::Op3dsg] {
                let config = RealsenseConfig {
                    bag: bag.display().to_string(),
                    bag_real_time: true,
                    rotate,
                    align,
                    ..RealsenseConfig::default()
                };
                let mut source = RealsenseSource::open(&config, None).expect("open the recording");
                let mut frame = Frame::new(source.intrinsics());
                let samples = if align == AlignMode::Op3dsg { &mut ours } else { &mut theirs };
                let mut delivered = 0;
                loop {
                    let started = Timer::start();
                    match source.next_frame(&mut frame).expect("next_frame") {
                        SourceStatus::Frame => {
                            // The first frames include the pipeline's start-up.
                            if delivered >= 3 {
                                samples.push(started.stop());
                            }
                            delivered += 1;
                        }
                        SourceStatus::Pending => {}
                        SourceStatus::EndOfStream => break,
                    }
                }
            }
        }
        let what = format!("{W}x{H} -> {cw}x{ch}, rotate {}", rotate.degrees());
        let t = report(&format!("next_frame, align = librealsense, {what}"), &theirs);
        let o = report(&format!("next_frame, align = op3dsg, {what}"), &ours);
        ratio("  next_frame", o, t);
    }
}

#[cfg(feature = "librealsense")]
fn playback() {
    let dir = tempfile::tempdir().expect("tempdir");
    let Some(bags) = with_librealsense::recordings(dir.path()) else { return };
    for (bag, cw, ch) in &bags {
        with_librealsense::align_on_recording(bag, *cw, *ch);
    }
    for (bag, cw, ch) in &bags {
        with_librealsense::next_frame(bag, *cw, *ch, Rotation::Cw90);
    }
    // A camera mounted upright (rotate 0), at the D435i's usual 848x480 pair.
    let (bag, cw, ch) = &bags[0];
    with_librealsense::next_frame(bag, *cw, *ch, Rotation::None);
}

#[cfg(not(feature = "librealsense"))]
fn playback() {
    println!("librealsense lines: build with --features librealsense to measure them");
}

fn main() {
    // `cargo test --benches` runs benches with --bench absent; keep that fast.
    if !std::env::args().any(|a| a == "--bench") {
        return;
    }
    rotate_and_copy();
    align_kernel();
    playback();
}
