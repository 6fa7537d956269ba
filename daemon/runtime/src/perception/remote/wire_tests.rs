use super::*;

fn frame() -> Frame {
    let mut frame = Frame::new(Intrinsics::d435i_640x480());
    frame.seq = 42;
    frame.stamp_ns = 1_234_567;
    for (i, v) in frame.rgb.iter_mut().enumerate() {
        *v = (i % 251) as u8;
    }
    for (i, d) in frame.depth.iter_mut().enumerate() {
        *d = (i % 4000) as u16;
    }
    frame
}

fn contract() -> Contract {
    Contract { model: "yolox".into(), prompts: vec!["chair".into(), "tv".into()], embedding_dim: 3 }
}

fn reply() -> Reply {
    let mask = Mask { x0: 10, y0: 20, width: 4, height: 3, data: vec![0, 1, 1, 0, 1, 1, 1, 1, 0, 0, 0, 1] };
    Reply {
        request_id: 7,
        frame_seq: 42,
        worker: "gpu0".into(),
        body: ReplyBody::Detections {
            detect_us: 1500,
            embedding_dim: 3,
            detections: vec![
                Detection {
                    label: "chair".into(),
                    kind: NodeKind::Object,
                    score: 0.8,
                    mask: mask.clone(),
                    semantic_feature: Some(vec![0.6, 0.8, 0.0]),
                },
                Detection {
                    label: "handle".into(),
                    kind: NodeKind::Part,
                    score: 0.5,
                    mask: Mask { data: vec![1; 12], ..mask },
                    semantic_feature: None,
                },
            ],
        },
    }
}

#[test]
fn a_request_round_trips_in_every_encoding() {
    let frame = frame();
    for encoding in [ImageEncoding::Raw, ImageEncoding::Png, ImageEncoding::Lz4, ImageEncoding::Zstd] {
        let mut bytes = Vec::new();
        encode_request(&mut bytes, 7, &frame, &contract(), encoding).expect("encode");
        let request = decode_request(&bytes).expect("decode");
        assert_eq!(request.request_id, 7);
        assert_eq!(request.contract, contract());
        assert_eq!((request.frame.seq, request.frame.stamp_ns), (42, 1_234_567));
        assert_eq!(request.frame.intrinsics, frame.intrinsics);
        assert!(request.frame.rgb == frame.rgb, "{encoding:?} colour");
        assert!(request.frame.depth == frame.depth, "{encoding:?} depth");
    }
}

#[test]
fn jpeg_sends_colour_lossy_and_depth_lossless() {
    // A smooth picture (JPEG's case): within a few levels after the round trip.
    let mut frame = frame();
    let width = frame.intrinsics.width as usize;
    for (i, px) in frame.rgb.chunks_exact_mut(3).enumerate() {
        let (x, y) = (i % width, i / width);
        px.copy_from_slice(&[(x / 3) as u8, (y / 2) as u8, ((x + y) / 5) as u8]);
    }
    let mut bytes = Vec::new();
    encode_request(&mut bytes, 7, &frame, &contract(), ImageEncoding::Jpeg).expect("encode");
    let request = decode_request(&bytes).expect("decode");
    assert!(request.frame.depth == frame.depth, "depth is exact");
    let worst = request.frame.rgb.iter().zip(&frame.rgb).map(|(a, b)| a.abs_diff(*b)).max().unwrap_or(0);
    assert!(worst <= 16, "JPEG colour off by {worst} levels");
    assert!(bytes.len() < frame.rgb.len() / 5, "JPEG is small: {} bytes", bytes.len());
}

#[test]
fn a_compressed_image_that_inflates_past_its_size_is_refused() {
    let frame = frame();
    let mut bytes = Vec::new();
    encode_request(&mut bytes, 7, &frame, &contract(), ImageEncoding::Zstd).expect("encode");
    // The same request declaring a 320x240 image: the colour's zstd frame holds 4 times more.
    let width_at = 4 + 4 + 24 + 2 + 5 + 2 + 2 + 5 + 2 + 2 + 2;
    bytes[width_at..width_at + 4].copy_from_slice(&320u32.to_le_bytes());
    bytes[width_at + 4..width_at + 8].copy_from_slice(&240u32.to_le_bytes());
    let e = decode_request(&bytes).expect_err("too big");
    assert!(e.to_string().starts_with("colour: zstd"), "{e}");
    // Depth marked as JPEG: refused by name.
    let mut bytes = Vec::new();
    encode_request(&mut bytes, 7, &frame, &contract(), ImageEncoding::Raw).expect("encode");
    let depth_code_at = bytes.len() - frame.depth.len() * 2 - 5;
    assert_eq!(bytes[depth_code_at], 0);
    bytes[depth_code_at] = 4;
    let e = decode_request(&bytes).expect_err("jpeg depth");
    assert!(e.to_string().starts_with("depth: depth is never sent as JPEG"), "{e}");
}

#[test]
fn a_reply_round_trips_with_masks_and_embeddings() {
    let mut bytes = Vec::new();
    encode_reply(&mut bytes, &reply()).expect("encode");
    assert_eq!(decode_reply(&bytes).expect("decode"), reply());
    let refused = Reply { body: ReplyBody::Refused("model \"owl\": this worker runs yolox".into()), ..reply() };
    encode_reply(&mut bytes, &refused).expect("encode");
    assert_eq!(decode_reply(&bytes).expect("decode"), refused);
}

#[test]
fn every_truncation_and_trailing_byte_is_an_error_naming_a_field() {
    let mut bytes = Vec::new();
    encode_reply(&mut bytes, &reply()).expect("encode");
    for end in 0..bytes.len() {
        let e = decode_reply(&bytes[..end]).expect_err("a truncated reply");
        assert!(matches!(e, WireError::Truncated { .. } | WireError::Magic { .. }), "{end}: {e}");
    }
    bytes.push(0);
    assert_eq!(decode_reply(&bytes), Err(WireError::Trailing(1)));
    let mut request = Vec::new();
    encode_request(&mut request, 1, &frame(), &contract(), ImageEncoding::Raw).expect("encode");
    for end in [0, 3, 10, 40, request.len() - 1] {
        assert!(decode_request(&request[..end]).is_err(), "{end}");
    }
}

#[test]
fn bad_fields_are_named() {
    let mut bytes = Vec::new();
    encode_reply(&mut bytes, &reply()).expect("encode");
    // Another message, another version.
    let e = decode_request(&bytes).expect_err("a reply is no request");
    assert!(e.to_string().starts_with("not a request"), "{e}");
    let mut newer = bytes.clone();
    newer[4] = 9;
    assert_eq!(decode_reply(&newer), Err(WireError::Version { found: 9 }));
    // Status 7.
    let mut status = bytes.clone();
    status[6] = 7;
    assert!(decode_reply(&status).expect_err("status").to_string().starts_with("status: unknown status 7"));
    // A run that covers more than the box: the mask size is wrong.
    let mut wide = reply();
    if let ReplyBody::Detections { detections, .. } = &mut wide.body {
        detections[0].mask.height = 2;
        detections[0].mask.data.truncate(8);
    }
    encode_reply(&mut bytes, &wide).expect("encode");
    // Claim the box is 4x1 while the runs cover 8 pixels.
    let e = decode_reply(&corrupt_first_box_height(&bytes, 1)).expect_err("mask size");
    assert!(matches!(e, WireError::MaskSize { index: 0, covered: 8, width: 4, height: 1, expected: 4 }), "{e}");
    // A score beyond 1.
    let mut loud = reply();
    if let ReplyBody::Detections { detections, .. } = &mut loud.body {
        detections[1].score = 3.0;
    }
    encode_reply(&mut bytes, &loud).expect("encode");
    let e = decode_reply(&bytes).expect_err("score");
    assert!(e.to_string().starts_with("detections[1].score: must be within [0, 1]"), "{e}");
    // An embedding of another length than the reply declares cannot be written.
    let mut odd = reply();
    if let ReplyBody::Detections { detections, .. } = &mut odd.body {
        detections[0].semantic_feature = Some(vec![1.0; 5]);
    }
    assert!(encode_reply(&mut bytes, &odd).expect_err("dim").to_string().starts_with("embedding: 5 values"));
    // A request whose image is 1 pixel wide.
    let mut request = Vec::new();
    encode_request(&mut request, 1, &frame(), &contract(), ImageEncoding::Raw).expect("encode");
    let width_at = 4 + 4 + 24 + 2 + 5 + 2 + 2 + 5 + 2 + 2 + 2;
    request[width_at..width_at + 4].copy_from_slice(&1u32.to_le_bytes());
    let e = decode_request(&request).expect_err("width");
    assert!(e.to_string().starts_with("width: image 1x480"), "{e}");
}

/// `bytes` (a reply whose first detection is labelled "chair") with that detection's box height
/// set to `height`.
fn corrupt_first_box_height(bytes: &[u8], height: u32) -> Vec<u8> {
    let label = bytes.windows(5).position(|w| w == b"chair").expect("label");
    let height_at = label + 5 + 1 + 4 + 12;
    let mut out = bytes.to_vec();
    out[height_at..height_at + 4].copy_from_slice(&height.to_le_bytes());
    out
}
