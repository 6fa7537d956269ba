use super::projection::{NOWHERE, round_to_i32};
use super::*;
use crate::rotate::copy_depth;

fn bytes(depth: &[u16]) -> Vec<u8> {
    depth.iter().flat_map(|d| d.to_le_bytes()).collect()
}

fn layout(lens: &Lens) -> SourceLayout {
    SourceLayout { width: lens.width as usize, height: lens.height as usize, stride_bytes: lens.width as usize * 2 }
}

fn run(align: &DepthToColour, depth: &[u16], rotation: Rotation) -> Vec<u16> {
    let mut out = vec![0xABCDu16; align.colour().width as usize * align.colour().height as usize];
    align.clone().align(&bytes(depth), layout(align.depth()), rotation, &mut out).unwrap();
    out
}

fn translation(tx: f32) -> Extrinsics {
    Extrinsics { translation_m: [tx, 0.0, 0.0], ..Extrinsics::IDENTITY }
}

/// Units of 1 mm.
const MM: f32 = 0.001;

#[test]
fn the_same_camera_leaves_depth_unchanged_holes_included() {
    let lens = Lens::pinhole(64, 48, 50.0, 51.0, 31.25, 23.75);
    let align = DepthToColour::new(lens, lens, Extrinsics::IDENTITY, MM).unwrap();
    assert!(!align.maps_rectangles(), "equal resolution: one pixel per depth pixel");
    let depth: Vec<u16> = (0..64 * 48).map(|i| if i % 7 == 3 { 0 } else { 500 + (i * 13 % 4000) as u16 }).collect();
    assert_eq!(run(&align, &depth, Rotation::None), depth);
}

#[test]
fn a_plane_seen_from_a_shifted_camera_shifts_by_the_disparity() {
    // Fronto-parallel plane at 2 m, colour camera 5 cm to the right of depth (points move by
    // +5 cm in its frame): every pixel moves by fx * t / z = 400 * 0.05 / 2 = 10 px.
    let lens = Lens::pinhole(80, 40, 400.0, 400.0, 39.3, 19.6);
    let align = DepthToColour::new(lens, lens, translation(0.05), MM).unwrap();
    let depth = vec![2000u16; 80 * 40];
    let out = run(&align, &depth, Rotation::None);
    for v in 0..40 {
        for u in 0..80 {
            let want = if u < 10 { 0 } else { 2000 };
            assert_eq!(out[v * 80 + u], want, "({u}, {v})");
        }
    }
    // A distinct value per depth pixel lands exactly 10 px to the right.
    let depth: Vec<u16> = (0..80 * 40).map(|i| 2000 + (i % 2) as u16).collect();
    let out = run(&align, &depth, Rotation::None);
    for v in 0..40 {
        for u in 10..80 {
            assert_eq!(out[v * 80 + u], depth[v * 80 + u - 10], "({u}, {v})");
        }
    }
}

#[test]
fn a_sharper_colour_camera_gets_every_pixel_of_the_plane() {
    // Colour: twice the resolution and focal length, same field of view: rectangles.
    let depth_lens = Lens::pinhole(60, 40, 50.0, 50.0, 29.5, 19.5);
    let colour_lens = Lens::pinhole(120, 80, 100.0, 100.0, 59.5, 39.5);
    let align = DepthToColour::new(depth_lens, colour_lens, Extrinsics::IDENTITY, MM).unwrap();
    assert!(align.maps_rectangles());
    let out = run(&align, &vec![1500u16; 60 * 40], Rotation::None);
    assert!(out.iter().all(|&z| z == 1500), "no holes on a plane: {:?}", out.iter().filter(|&&z| z == 0).count());
    // A step: the left half nearer; the edge column of the colour image gets the nearer value
    // where both rectangles touch it.
    let depth: Vec<u16> = (0..60 * 40).map(|i| if i % 60 < 30 { 1000 } else { 3000 }).collect();
    let out = run(&align, &depth, Rotation::None);
    for v in 0..80 {
        assert!(out[v * 120..v * 120 + 59].iter().all(|&z| z == 1000), "row {v} left");
        assert!(out[v * 120 + 61..v * 120 + 120].iter().all(|&z| z == 3000), "row {v} right");
    }
}

#[test]
fn a_near_box_hides_the_wall_behind_it_and_leaves_its_shadow_empty() {
    // Wall at 4 m, a box at 1 m over depth columns 40..60; colour 9.6 cm to the right:
    // the wall moves 100 * 0.096 / 4 = 2.4 px (to 2..42 and 62..), the box 9.6 px (to
    // 50..70, hiding the wall that lands on 62..70), and 42..50 is seen by colour only (the
    // box's shadow in depth): no depth there.
    let lens = Lens::pinhole(100, 20, 100.0, 100.0, 49.5, 9.5);
    let align = DepthToColour::new(lens, lens, translation(0.096), MM).unwrap();
    let depth: Vec<u16> = (0..100 * 20).map(|i| if (40..60).contains(&(i % 100)) { 1000 } else { 4000 }).collect();
    let out = run(&align, &depth, Rotation::None);
    for v in 0..20 {
        let row = &out[v * 100..(v + 1) * 100];
        assert!(row[51..69].iter().all(|&z| z == 1000), "box, row {v}: {row:?}");
        assert!(row[44..49].iter().all(|&z| z == 0), "shadow, row {v}: {row:?}");
        assert!(row[4..42].iter().all(|&z| z == 4000), "wall left, row {v}: {row:?}");
        assert!(row[71..].iter().all(|&z| z == 4000), "wall right, row {v}: {row:?}");
    }
}

#[test]
fn rotating_on_the_way_equals_aligning_then_rotating() {
    let depth_lens = Lens::pinhole(48, 36, 40.0, 41.0, 23.0, 18.5);
    let colour_lens = Lens::pinhole(64, 40, 70.0, 70.5, 31.0, 20.5);
    let extrinsics = Extrinsics {
        // 2 degrees about y, then a baseline.
        rotation: {
            let (s, c) = 0.035f32.sin_cos();
            [c, 0.0, -s, 0.0, 1.0, 0.0, s, 0.0, c]
        },
        translation_m: [0.015, 0.001, -0.002],
    };
    let align = DepthToColour::new(depth_lens, colour_lens, extrinsics, 0.00025).unwrap();
    let depth: Vec<u16> = (0..48 * 36).map(|i| if i % 11 == 0 { 0 } else { 4000 + (i * 37 % 9000) as u16 }).collect();
    let upright = run(&align, &depth, Rotation::None);
    assert!(upright.iter().filter(|&&z| z != 0).count() > 64 * 40 / 2, "most of the colour image has depth");
    for rotation in [Rotation::Cw90, Rotation::Cw180, Rotation::Cw270] {
        let mut want = vec![0u16; upright.len()];
        copy_depth(&bytes(&upright), SourceLayout { width: 64, height: 40, stride_bytes: 128 }, rotation, &mut want)
            .unwrap();
        assert_eq!(run(&align, &depth, rotation), want, "{rotation:?}");
    }
}

#[test]
fn strided_rows_and_points_behind_the_colour_camera() {
    let lens = Lens::pinhole(8, 2, 10.0, 10.0, 3.5, 0.5);
    // Colour 1 m in front of depth: points nearer than 1 m are behind it.
    let mut align =
        DepthToColour::new(lens, lens, Extrinsics { translation_m: [0.0, 0.0, -1.0], ..Extrinsics::IDENTITY }, MM)
            .unwrap();
    let mut padded = vec![0xFFu8; 2 * 24];
    for (v, row) in [[500u16; 8], [3000u16; 8]].iter().enumerate() {
        padded[v * 24..v * 24 + 16].copy_from_slice(&bytes(row));
    }
    let mut out = vec![7u16; 16];
    align.align(&padded, SourceLayout { width: 8, height: 2, stride_bytes: 24 }, Rotation::None, &mut out).unwrap();
    // Row 0 (0.5 m) is behind the colour camera: nothing; row 1 (3 m, 2 m from colour) lands
    // nearer the centre, within the image.
    assert!(out.contains(&3000));
    assert!(out.iter().all(|&z| z == 0 || z == 3000), "{out:?}");
}

#[test]
fn bad_calibration_and_buffers_are_refused_naming_what() {
    let lens = Lens::pinhole(8, 2, 10.0, 10.0, 3.5, 0.5);
    let e = DepthToColour::new(Lens { fx: 0.0, ..lens }, lens, Extrinsics::IDENTITY, MM).unwrap_err();
    assert_eq!(e.to_string(), "depth intrinsics: fx = 0 (need a finite value, focal lengths and sizes above 0)");
    let e = DepthToColour::new(lens, Lens { ppy: f32::NAN, ..lens }, Extrinsics::IDENTITY, MM).unwrap_err();
    assert!(e.to_string().starts_with("colour intrinsics: ppy = NaN"), "{e}");
    let skewed = Extrinsics { rotation: [1.0, 0.0, 0.0, 0.5, 1.0, 0.0, 0.0, 0.0, 1.0], ..Extrinsics::IDENTITY };
    let e = DepthToColour::new(lens, lens, skewed, MM).unwrap_err();
    assert!(e.to_string().contains("not orthonormal"), "{e}");
    assert!(matches!(DepthToColour::new(lens, lens, Extrinsics::IDENTITY, 0.0), Err(AlignError::DepthScale(_))));
    let mut align = DepthToColour::new(lens, lens, Extrinsics::IDENTITY, MM).unwrap();
    let mut out = vec![0u16; 16];
    let e = align.align(&[0u8; 31], layout(&lens), Rotation::None, &mut out).unwrap_err();
    assert!(e.to_string().starts_with("depth: driver buffer holds 31 bytes"), "{e}");
    let mut short = vec![0u16; 15];
    let e = align.align(&[0u8; 32], layout(&lens), Rotation::None, &mut short).unwrap_err();
    assert!(e.to_string().contains("aligned depth: frame buffer holds 15 values"), "{e}");
}

#[test]
fn a_depth_lens_with_coefficients_uses_full_ray_tables_indexed_alike() {
    // Inverse Brown-Conrady coefficients too small to move a corner by a pixel: the full
    // per-corner tables must give what the separable ones give.
    let depth_lens = Lens::pinhole(48, 36, 40.0, 41.0, 23.0, 18.5);
    let colour_lens = Lens::pinhole(64, 40, 70.0, 70.5, 31.0, 20.5);
    let distorted = Lens { model: Distortion::InverseBrownConrady, coeffs: [1e-9, 0.0, 0.0, 0.0, 0.0], ..depth_lens };
    let e = translation(0.02);
    let plain = DepthToColour::new(depth_lens, colour_lens, e, 0.00025).unwrap();
    let full = DepthToColour::new(distorted, colour_lens, e, 0.00025).unwrap();
    assert!(full.rays.full_stride > 0 && plain.rays.full_stride == 0);
    let depth: Vec<u16> = (0..48 * 36).map(|i| if i % 13 == 0 { 0 } else { 6000 + (i * 31 % 5000) as u16 }).collect();
    for rotation in [Rotation::None, Rotation::Cw90] {
        assert_eq!(run(&full, &depth, rotation), run(&plain, &depth, rotation), "{rotation:?}");
    }
}

#[test]
fn field_of_view_and_rounding_follow_librealsense() {
    // rs2_fov of a 848x480 D435i-like depth stream.
    let lens = Lens::pinhole(848, 480, 421.0, 421.0, 423.5, 239.5);
    let [h, v] = lens.fov_deg();
    assert!((h - 90.4).abs() < 0.1 && (v - 59.4).abs() < 0.1, "{h} {v}");
    // Ties round to even, as _mm_cvtps_epi32.
    for (x, want) in
        [(2.5f32, 2), (3.5, 4), (-0.5, 0), (-1.5, -2), (-2.7, -3), (7.49, 7), (7.51, 8), (-999_999.4, -999_999)]
    {
        assert_eq!(round_to_i32(x), want, "{x}");
    }
    // Coefficients of models the align does not apply are reported.
    let colour = Lens { model: Distortion::InverseBrownConrady, coeffs: [0.1, 0.0, 0.0, 0.0, 0.0], ..lens };
    let align = DepthToColour::new(lens, colour, Extrinsics::IDENTITY, MM).unwrap();
    assert_eq!(align.ignored_coefficients(), [("colour", Distortion::InverseBrownConrady)]);
}

#[test]
fn turned_lines_write_what_the_sized_loop_writes() {
    // The D435i's 848x480 depth to 848x480 colour (1.43 colour pixels per depth pixel): 3
    // lines; to 1280x720 (2.16): 4 lines; and 1280x720 held to 3 lines, so that every
    // rectangle 4 wide is left to the sized loop. The depth's field of view is the wider:
    // rectangles reach the colour image's corners, where lines would run past the ends of
    // the output (left to the sized loop too). A near box over a slanted wall, holes, and a
    // yawed, shifted colour camera (parallax, occlusion, shadows).
    let depth_lens = Lens::pinhole(848, 480, 421.0, 421.0, 422.75, 239.75);
    let colour = |w: u32, h: u32| {
        let f = 910.0 * w as f32 / 1280.0;
        Lens::pinhole(w, h, f, f, (w as f32 - 1.0) / 2.0 + 0.4, (h as f32 - 1.0) / 2.0 - 0.3)
    };
    let extrinsics = Extrinsics {
        rotation: {
            let (s, c) = 0.4f32.to_radians().sin_cos();
            [c, 0.0, -s, 0.0, 1.0, 0.0, s, 0.0, c]
        },
        translation_m: [0.015, 0.0003, -0.0002],
    };
    let depth: Vec<u16> = (0..848 * 480)
        .map(|i: usize| {
            let (u, v) = (i % 848, i / 848);
            if (7 * u + 3 * v) % 53 == 0 {
                0
            } else if (300..510).contains(&u) && (140..340).contains(&v) {
                3600 + (i * 7919 % 97) as u16
            } else {
                8000 + (u * 4) as u16 + (i * 104_729 % 31) as u16
            }
        })
        .collect();
    let narrow = DepthToColour::new(depth_lens, colour(848, 480), extrinsics, 0.00025).unwrap();
    let wide = DepthToColour::new(depth_lens, colour(1280, 720), extrinsics, 0.00025).unwrap();
    assert!(narrow.blocks && !narrow.wide && wide.blocks && wide.wide);
    let held = DepthToColour { wide: false, ..wide.clone() };
    for (name, lines) in [("848x480, 3 lines", narrow), ("1280x720, 4 lines", wide), ("1280x720, 3 lines", held)] {
        let loops = DepthToColour { blocks: false, ..lines.clone() };
        // Unturned and 180°: aligned turned 90° and turned the rest of the way.
        for rotation in [Rotation::Cw90, Rotation::Cw270, Rotation::None, Rotation::Cw180] {
            let want = run(&loops, &depth, rotation);
            assert!(want.iter().filter(|&&z| z != 0).count() > want.len() * 9 / 10, "{name} {rotation:?}");
            assert!(want[..4].iter().chain(&want[want.len() - 4..]).all(|&z| z != 0), "corners {name}");
            assert_eq!(run(&lines, &depth, rotation), want, "{name} {rotation:?}");
        }
    }
}

#[test]
fn frames_after_the_first_reuse_the_turned_buffer_and_keep_nothing_of_the_last() {
    // Unturned blocks go through the turned buffer kept from frame to frame: a frame's image
    // must not depend on the frame before (near depth there, holes here), whatever the
    // rotations in between.
    let depth_lens = Lens::pinhole(96, 64, 48.0, 48.0, 47.5, 31.5);
    let colour_lens = Lens::pinhole(160, 100, 96.0, 96.0, 79.5, 49.5);
    let fresh = DepthToColour::new(depth_lens, colour_lens, translation(0.015), MM).unwrap();
    assert!(fresh.blocks);
    let mut align = fresh.clone();
    let near: Vec<u16> = vec![300; 96 * 64];
    let far: Vec<u16> = (0..96 * 64).map(|i| if i % 5 == 0 { 0 } else { 2000 + (i % 96) as u16 }).collect();
    let mut out = vec![0u16; 160 * 100];
    for rotation in [Rotation::None, Rotation::Cw180, Rotation::Cw90, Rotation::None] {
        align.align(&bytes(&near), layout(&depth_lens), Rotation::None, &mut out).unwrap();
        align.align(&bytes(&far), layout(&depth_lens), rotation, &mut out).unwrap();
        assert_eq!(out, run(&fresh, &far, rotation), "{rotation:?} after a near frame");
        assert!(out.contains(&0) && !out.contains(&300), "{rotation:?}");
    }
}

#[test]
fn blocks_and_per_pixel_rectangles_write_the_same_image() {
    // Colour with 2.2 times the depth's pixels per degree: rectangle corners 2 or 3 pixels
    // apart, so both the fixed blocks (3 a side) and the fallback loop (4) are used; a near
    // box over a far wall (parallax, occlusion, shadows) and holes.
    let depth_lens = Lens::pinhole(40, 30, 30.0, 30.0, 19.5, 14.5);
    let colour_lens = Lens::pinhole(88, 66, 66.0, 66.0, 43.5, 32.5);
    let blocks = DepthToColour::new(depth_lens, colour_lens, translation(0.05), MM).unwrap();
    assert!(blocks.maps_rectangles() && blocks.blocks);
    let loops = DepthToColour { blocks: false, ..blocks.clone() };
    let depth: Vec<u16> = (0..40 * 30)
        .map(|i| {
            let (u, v) = (i % 40, i / 40);
            if i % 17 == 0 {
                0
            } else if (12..26).contains(&u) && (8..20).contains(&v) {
                400 + (u * 7) as u16
            } else {
                3000 + (v * 11) as u16
            }
        })
        .collect();
    for rotation in [Rotation::None, Rotation::Cw90, Rotation::Cw180, Rotation::Cw270] {
        let want = run(&loops, &depth, rotation);
        assert!(want.iter().filter(|&&z| z != 0).count() > 70 * 50, "{rotation:?}");
        assert_eq!(run(&blocks, &depth, rotation), want, "{rotation:?}");
    }
    // The D435i's 848x480 depth to 848x480 colour (1.44 colour pixels per depth pixel):
    // blocks; nearer 1 (1.1), rectangles written by the sized loop.
    let d435i = Lens::pinhole(848, 480, 421.0, 421.0, 423.5, 239.5);
    let colour = |f: f32| Lens::pinhole(848, 480, f, f, 423.5, 239.5);
    let same = DepthToColour::new(d435i, colour(605.0), translation(0.015), MM).unwrap();
    assert!(same.maps_rectangles() && same.blocks);
    let near_one = DepthToColour::new(d435i, colour(463.0), translation(0.015), MM).unwrap();
    assert!(near_one.maps_rectangles() && !near_one.blocks);
}

/// A rotation by `yaw` about y then `pitch` about x (degrees).
fn turned(yaw: f32, pitch: f32, translation_m: [f32; 3]) -> Extrinsics {
    let (sy, cy) = yaw.to_radians().sin_cos();
    let (sp, cp) = pitch.to_radians().sin_cos();
    let about_y = [[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]];
    let about_x = [[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]];
    let mut rotation = [0.0; 9];
    for i in 0..3 {
        for j in 0..3 {
            rotation[3 * i + j] = (0..3).map(|k| about_x[i][k] * about_y[k][j]).sum();
        }
    }
    Extrinsics { rotation, translation_m }
}

/// Depth with holes, rows and whole chunks without any, a near box and a far slanted wall,
/// from a seeded generator.
fn scattered_depth(lens: &Lens, near: u16, far: u16, seed: u64) -> Vec<u16> {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut next = move || rng.random::<u64>();
    let (w, h) = (lens.width as usize, lens.height as usize);
    (0..w * h)
        .map(|i| {
            let (u, v) = (i % w, i / w);
            let spread = u64::from(far - near) + 1;
            if v % 11 == 5 || (v % 7 == 2 && u < CHUNK) || next() % 10 == 0 {
                0
            } else if (w / 3..w / 2).contains(&u) && (h / 4..h / 2).contains(&v) {
                near + (next() % (spread / 8 + 1)) as u16
            } else {
                near + (spread * u as u64 / w as u64) as u16 / 2 + (next() % (spread / 2)) as u16
            }
        })
        .collect()
}

#[test]
fn passing_over_chunks_that_miss_the_colour_image_changes_nothing() {
    // Calibrations where much of the depth falls outside the colour image, and where little
    // does: the D435i's (depth wider and taller than colour), a colour camera turned 25° and
    // 10° and 30 cm away, one 1 m in front of the depth camera (points behind it), a wider
    // colour camera, and a distorting depth lens (full ray tables). Each aligned with and
    // without the pass-over, all four rotations: the same image.
    let d435i = Lens::pinhole(848, 480, 421.0, 421.0, 422.75, 239.75);
    let small = Lens::pinhole(160, 96, 80.0, 80.0, 79.5, 47.5);
    let colour =
        |w: u32, h: u32, f: f32| Lens::pinhole(w, h, f, f, (w as f32 - 1.0) / 2.0 + 0.4, (h as f32 - 1.0) / 2.0 - 0.3);
    let distorting =
        Lens { model: Distortion::InverseBrownConrady, coeffs: [0.08, -0.02, 0.001, -0.002, 0.0], ..small };
    let cases = [
        ("D435i 1280x720", d435i, colour(1280, 720, 910.0), turned(0.4, 0.0, [0.015, 0.0003, -0.0002]), 300, 9000),
        ("D435i 848x480", d435i, colour(848, 480, 603.0), turned(0.4, 0.0, [0.015, 0.0003, -0.0002]), 300, 9000),
        ("turned, 30 cm", small, colour(200, 150, 220.0), turned(25.0, 10.0, [0.3, -0.1, 0.05]), 200, 2500),
        ("colour 1 m ahead", small, colour(120, 90, 100.0), turned(0.0, 0.0, [0.0, 0.0, -1.0]), 400, 4000),
        ("wider colour", small, colour(160, 96, 40.0), turned(-3.0, 2.0, [0.05, 0.0, 0.0]), 300, 6000),
        ("distorting depth", distorting, colour(320, 240, 400.0), turned(15.0, -5.0, [-0.1, 0.02, 0.0]), 250, 3000),
    ];
    let mut passed_over = 0;
    for (seed, (name, depth_lens, colour_lens, extrinsics, near, far)) in cases.into_iter().enumerate() {
        let skipping = DepthToColour::new(depth_lens, colour_lens, extrinsics, MM).unwrap();
        assert!(skipping.skips);
        let depth = scattered_depth(&depth_lens, near, far, seed as u64);
        let (w, h) = (depth_lens.width as usize, depth_lens.height as usize);
        for v in 0..h {
            for start in (0..w).step_by(CHUNK) {
                let raw = &depth[v * w + start..v * w + (start + CHUNK).min(w)];
                let (nearest, farthest) = (raw.iter().filter(|&&z| z != 0).min(), raw.iter().max());
                if let (Some(&nearest), Some(&farthest)) = (nearest, farthest) {
                    let b = skipping.rays.chunk_box(v, start);
                    let [cw, ch] = [colour_lens.width, colour_lens.height];
                    let (near_m, far_m) = (f32::from(nearest) * MM, f32::from(farthest) * MM);
                    passed_over += usize::from(skipping.projection.misses(b, near_m, far_m, cw, ch));
                }
            }
        }
        let full = DepthToColour { skips: false, ..skipping.clone() };
        for rotation in [Rotation::None, Rotation::Cw90, Rotation::Cw180, Rotation::Cw270] {
            let want = run(&full, &depth, rotation);
            assert!(want.iter().any(|&z| z != 0), "{name} {rotation:?}");
            assert_eq!(run(&skipping, &depth, rotation), want, "{name} {rotation:?}");
        }
    }
    // The D435i's rows above and below the colour image, and its chunks left and right.
    assert!(passed_over > 480 * 7 / 4, "{passed_over} chunks passed over");
}

#[test]
fn a_chunk_said_to_miss_has_no_corner_on_the_colour_image() {
    // Every chunk's corner rays at depths across its range (its ends included), projected
    // as the align projects them: none of a chunk that misses lands on the image or the
    // pixel around it. The depth lens sees far wider and taller than the colour one (5
    // chunks a row across 158°); the colour camera, shifted, is turned in small steps so
    // that chunk edges sweep across all four edges of its image and barely miss.
    let depth_lens = Lens::pinhole(640, 48, 60.0, 60.0, 319.5, 23.5);
    let colour_lens = Lens::pinhole(96, 64, 110.0, 110.0, 47.3, 31.8);
    let (cw, ch) = (colour_lens.width, colour_lens.height);
    let mut tried = [0usize; 2];
    let mut sides = [false; 4];
    for step in 0..48 {
        let (yaw, pitch) = (-70.0 + 2.93 * step as f32, -9.0 + 0.41 * step as f32);
        let extrinsics = turned(yaw, pitch, [0.04 - 0.002 * step as f32, 0.01, -0.03]);
        let align = DepthToColour::new(depth_lens, colour_lens, extrinsics, MM).unwrap();
        let (rays, p) = (&align.rays, &align.projection);
        let (mut x, mut y) = ([0i32; CHUNK], [0i32; CHUNK]);
        for v in 0..48 {
            for start in (0..640).step_by(CHUNK) {
                for (near, far) in [(300u16, 320u16), (500, 4000), (1200, 1200), (120, 9000)] {
                    let b = rays.chunk_box(v, start);
                    let misses = p.misses(b, f32::from(near) * MM, f32::from(far) * MM, cw, ch);
                    tried[usize::from(misses)] += 1;
                    if !misses {
                        continue;
                    }
                    let steps = 9u16.min(far - near + 1);
                    for i in 0..steps {
                        let z = near + ((u32::from(far - near) * u32::from(i)) / u32::from((steps - 1).max(1))) as u16;
                        let raw = [z; CHUNK];
                        for (r, at) in [(v, rays.row_start(v) + start), (v + 1, rays.row_start(v + 1) + start + 1)] {
                            p.corners::<false>(rays, at, rays.row[r], &raw, &mut x, &mut y);
                            for (&x, &y) in x.iter().zip(&y).filter(|&(&x, _)| x != NOWHERE) {
                                let on = (-1..=cw as i32).contains(&x) && (-1..=ch as i32).contains(&y);
                                assert!(!on, "turn {step} row {v} chunk {start} depth {z}: corner at ({x}, {y})");
                                // Within 5 pixels outside a side of the image: a near miss there.
                                let (w, h) = (cw as i32, ch as i32);
                                let near_side = [
                                    (-5..0).contains(&x),
                                    (w + 1..=w + 5).contains(&x),
                                    (-5..0).contains(&y),
                                    (h + 1..=h + 5).contains(&y),
                                ];
                                for (seen, near_side) in sides.iter_mut().zip(near_side) {
                                    *seen |= near_side;
                                }
                            }
                        }
                    }
                }
            }
        }
    }
    assert!(tried[0] > 1000 && tried[1] > 1000, "hits and misses: {tried:?}");
    assert_eq!(sides, [true; 4], "near misses left, right, above, below");
}
