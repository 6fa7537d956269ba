use super::*;

const ALL: [Rotation; 4] = [Rotation::None, Rotation::Cw90, Rotation::Cw180, Rotation::Cw270];

fn k() -> Intrinsics {
    Intrinsics { width: 848, height: 480, fx: 421.5, fy: 420.25, cx: 425.75, cy: 238.5 }
}

#[test]
fn ninety_degrees_maps_the_corners_and_a_known_pixel() {
    let r = Rotation::Cw90;
    // The top-left corner goes to the top-right, the bottom-left to the top-left.
    assert_eq!(r.map_pixel(0, 0, 848, 480), (479, 0));
    assert_eq!(r.map_pixel(0, 479, 848, 480), (0, 0));
    assert_eq!(r.map_pixel(847, 479, 848, 480), (0, 847));
    assert_eq!(r.map_pixel(100, 30, 848, 480), (449, 100));
    assert_eq!(Rotation::Cw270.map_pixel(100, 30, 848, 480), (30, 747));
    assert_eq!(Rotation::Cw180.map_pixel(100, 30, 848, 480), (747, 449));
}

#[test]
fn rotated_intrinsics_are_exact_for_ninety_degrees() {
    let r = Rotation::Cw90.intrinsics(&k());
    assert_eq!(r, Intrinsics { width: 480, height: 848, fx: 420.25, fy: 421.5, cx: 479.0 - 238.5, cy: 425.75 });
    let r = Rotation::Cw270.intrinsics(&k());
    assert_eq!(r, Intrinsics { width: 480, height: 848, fx: 420.25, fy: 421.5, cx: 238.5, cy: 847.0 - 425.75 });
    let r = Rotation::Cw180.intrinsics(&k());
    assert_eq!(r, Intrinsics { cx: 847.0 - 425.75, cy: 479.0 - 238.5, ..k() });
    assert_eq!(Rotation::None.intrinsics(&k()), k());
}

#[test]
fn rotation_keeps_back_projection_consistent() {
    // A pixel and its rotated twin back-project to the same point once the upright camera
    // frame is turned back into the physical one.
    let k = k();
    for r in ALL {
        let kr = r.intrinsics(&k);
        let camera_from_upright = r.camera_from_upright();
        for (u, v) in [(0u32, 0u32), (100, 30), (847, 479), (424, 240), (5, 470)] {
            let depth_m = 1.7;
            let p = k.point_in_camera(u as f32, v as f32, depth_m).as_dvec3();
            let (ur, vr) = r.map_pixel(u, v, k.width, k.height);
            let q = camera_from_upright.transform_point(kr.point_in_camera(ur as f32, vr as f32, depth_m).as_dvec3());
            assert!((p - q).length() < 1e-5, "{r:?} pixel ({u}, {v}): {p} vs {q}");
        }
    }
}

#[test]
fn parses_degrees_and_refuses_others() {
    assert_eq!(Rotation::try_from(270), Ok(Rotation::Cw270));
    assert!(Rotation::try_from(45).unwrap_err().contains("got 45"));
}

fn test_image(w: usize, h: usize, stride: usize) -> (Vec<u8>, Vec<u8>) {
    let mut rgb = vec![0xEEu8; stride * h];
    let mut z16 = vec![0xEEu8; (stride * 2 / 3).max(w * 2) * h];
    let zstride = z16.len() / h;
    for v in 0..h {
        for u in 0..w {
            let i = v * stride + u * 3;
            rgb[i..i + 3].copy_from_slice(&[u as u8, v as u8, (u * 7 + v) as u8]);
            let d = (1000 + u * 10 + v) as u16;
            z16[v * zstride + u * 2..v * zstride + u * 2 + 2].copy_from_slice(&d.to_le_bytes());
        }
    }
    (rgb, z16)
}

#[test]
fn copies_land_every_pixel_where_map_pixel_says() {
    // One partial tile of rows, and two whole tiles plus a partial one; widths with none,
    // one and three of depth's 8-value blocks, the last with columns past them.
    for (w, h) in [(7usize, 5usize), (11, 2 * TILE_ROWS + 5), (8, TILE_ROWS), (27, TILE_ROWS + 1)] {
        copies_land_where_map_pixel_says(w, h);
    }
}

fn copies_land_where_map_pixel_says(w: usize, h: usize) {
    let stride = w * 3 + 9;
    let (rgb, z16) = test_image(w, h, stride);
    let zstride = z16.len() / h;
    for r in ALL {
        let mut out_rgb = vec![0u8; w * h * 3];
        let mut out_depth = vec![0u16; w * h];
        copy_colour(
            &rgb,
            SourceLayout { width: w, height: h, stride_bytes: stride },
            ColourOrder::Rgb8,
            r,
            &mut out_rgb,
        )
        .unwrap();
        copy_depth(&z16, SourceLayout { width: w, height: h, stride_bytes: zstride }, r, &mut out_depth).unwrap();
        let out_w = if r.swaps_axes() { h } else { w };
        for v in 0..h {
            for u in 0..w {
                let (ur, vr) = r.map_pixel(u as u32, v as u32, w as u32, h as u32);
                let i = vr as usize * out_w + ur as usize;
                assert_eq!(&out_rgb[i * 3..i * 3 + 3], &[u as u8, v as u8, (u * 7 + v) as u8], "{r:?} ({u},{v})");
                assert_eq!(out_depth[i], (1000 + u * 10 + v) as u16, "{r:?} ({u},{v})");
            }
        }
    }
}

#[test]
fn quarter_turns_put_every_pixel_of_every_channel_order_where_map_pixel_says() {
    // Whole tiles and a partial one; widths leaving 0 to 3 columns past the 4x4 blocks, and
    // one too narrow for any block.
    for (w, h) in [(37usize, 2 * TILE_ROWS + 3), (40, TILE_ROWS), (42, TILE_ROWS), (5, TILE_ROWS)] {
        for order in [ColourOrder::Rgb8, ColourOrder::Bgr8, ColourOrder::Rgba8, ColourOrder::Bgra8] {
            let bpp = order.bytes_per_pixel();
            let stride = w * bpp + 5;
            let src: Vec<u8> = (0..stride * h).map(|i| (i * 131 % 251) as u8).collect();
            for r in [Rotation::Cw90, Rotation::Cw270] {
                let mut out = vec![0u8; w * h * 3];
                let layout = SourceLayout { width: w, height: h, stride_bytes: stride };
                copy_colour(&src, layout, order, r, &mut out).unwrap();
                let mut portable = vec![0u8; w * h * 3];
                copy_colour_portable(&src, layout, order, r, &mut portable).unwrap();
                assert!(out == portable, "{w}x{h} {order:?} {r:?}: SIMD blocks and portable loop differ");
                for v in 0..h {
                    for u in 0..w {
                        let i = v * stride + u * bpp;
                        let px = &src[i..i + 3];
                        let want = if order.swaps_red_blue() { [px[2], px[1], px[0]] } else { [px[0], px[1], px[2]] };
                        let (ur, vr) = r.map_pixel(u as u32, v as u32, w as u32, h as u32);
                        let at = (vr as usize * h + ur as usize) * 3;
                        assert_eq!(out[at..at + 3], want, "{w}x{h} {order:?} {r:?} ({u},{v})");
                    }
                }
            }
        }
    }
}

#[test]
fn channel_orders_convert_to_rgb() {
    let layout = SourceLayout { width: 2, height: 1, stride_bytes: 8 };
    let mut out = vec![0u8; 6];
    copy_colour(&[3, 2, 1, 255, 6, 5, 4, 255], layout, ColourOrder::Bgra8, Rotation::None, &mut out).unwrap();
    assert_eq!(out, [1, 2, 3, 4, 5, 6]);
    // Turned a quarter (the tiled path): the row becomes a column, top to bottom.
    copy_colour(&[3, 2, 1, 255, 6, 5, 4, 255], layout, ColourOrder::Bgra8, Rotation::Cw90, &mut out).unwrap();
    assert_eq!(out, [1, 2, 3, 4, 5, 6]);
    copy_colour(&[3, 2, 1, 255, 6, 5, 4, 255], layout, ColourOrder::Bgra8, Rotation::Cw270, &mut out).unwrap();
    assert_eq!(out, [4, 5, 6, 1, 2, 3]);
    let layout = SourceLayout { width: 2, height: 1, stride_bytes: 6 };
    copy_colour(&[3, 2, 1, 6, 5, 4], layout, ColourOrder::Bgr8, Rotation::Cw180, &mut out).unwrap();
    assert_eq!(out, [4, 5, 6, 1, 2, 3]);
}

#[test]
fn values_turned_in_memory_land_where_map_pixel_says() {
    for (w, h) in [(5usize, 3usize), (24, TILE_ROWS), (19, 2 * TILE_ROWS + 7)] {
        let src: Vec<u16> = (0..w * h).map(|i| (i * 40_503 % 65_521) as u16).collect();
        for r in ALL {
            let mut out = vec![0u16; w * h];
            turn_u16(&src, w, h, r, &mut out);
            let out_w = if r.swaps_axes() { h } else { w };
            for v in 0..h {
                for u in 0..w {
                    let (ur, vr) = r.map_pixel(u as u32, v as u32, w as u32, h as u32);
                    assert_eq!(out[vr as usize * out_w + ur as usize], src[v * w + u], "{w}x{h} {r:?} ({u},{v})");
                }
            }
        }
    }
}

#[test]
fn short_buffers_are_refused_naming_the_stream() {
    let layout = SourceLayout { width: 4, height: 4, stride_bytes: 8 };
    let mut out = vec![0u16; 16];
    let e = copy_depth(&[0; 30], layout, Rotation::Cw90, &mut out).unwrap_err();
    assert!(e.to_string().starts_with("depth: driver buffer holds 30 bytes"), "{e}");
    let mut out = vec![0u16; 15];
    let e = copy_depth(&[0; 32], layout, Rotation::None, &mut out).unwrap_err();
    assert!(e.to_string().contains("frame buffer holds 15 values"), "{e}");
}
