//! Renderer speed: the kitchen at 640x480 with depth noise, one core.
//!
//! `cargo bench -p op3dsg-drivers --bench render` prints criterion's time per frame and a
//! one-line frames/s summary.

use criterion::{Criterion, criterion_group, criterion_main};
use op3dsg_drivers::frame::{Frame, Intrinsics};
use op3dsg_synthetic::{CameraPath, DepthNoiseConfig, Renderer, RoomKind, Scene};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

fn bench_render(c: &mut Criterion) {
    let scene = Scene::generate(RoomKind::Kitchen, 1);
    let path = CameraPath::new(&scene, 1, 30.0);
    let intrinsics = Intrinsics::d435i_640x480();
    let noise = DepthNoiseConfig::default();
    let mut renderer = Renderer::new();
    let mut frame = Frame::new(intrinsics);
    let mut instance_ids = Vec::new();
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let period = path.period_frames();

    // Plain summary over one sub-sampled loop of the path.
    let frames: Vec<u64> = (0..period).step_by(7).collect();
    let start = std::time::Instant::now();
    for &k in &frames {
        renderer.render(
            &scene,
            &path.pose_at(k),
            &intrinsics,
            Some((&noise, &mut rng)),
            &mut frame,
            Some(&mut instance_ids),
        );
    }
    let seconds = start.elapsed().as_secs_f64();
    eprintln!(
        "render summary: kitchen 640x480 with noise, {} views over the path: {:.2} ms/frame, {:.1} frames/s",
        frames.len(),
        1e3 * seconds / frames.len() as f64,
        frames.len() as f64 / seconds
    );

    let mut k = 0u64;
    c.bench_function("render kitchen 640x480 noisy", |b| {
        b.iter(|| {
            k = (k + 13) % period;
            renderer.render(
                &scene,
                &path.pose_at(k),
                &intrinsics,
                Some((&noise, &mut rng)),
                &mut frame,
                Some(&mut instance_ids),
            );
            std::hint::black_box(frame.depth[1000])
        })
    });
}

criterion_group!(benches, bench_render);
criterion_main!(benches);
