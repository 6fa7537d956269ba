//! Tests of the oracle detector, wired as the simulator wires it: each frame's instance ids go
//! in through an [`InstanceIdChannel`], each detection's ground-truth instance comes back
//! through an [`InstanceLog`].

use std::collections::{HashMap, HashSet};

use op3dsg_drivers::frame::Intrinsics;
use op3dsg_synthetic::InstanceKind;

use op3dsg_runtime::embedding::normalise;
use op3dsg_runtime::perception::Mask;

use super::config::SEMANTIC_DIM;
use super::masks::Morph;
use super::*;

/// A detection and the ground-truth instance the log gives for it (`None`: false positive).
type Found = (Detection, Option<u16>);

fn intrinsics(width: u32, height: u32) -> Intrinsics {
    Intrinsics { width, height, fx: width as f32, fy: width as f32, cx: width as f32 / 2.0, cy: height as f32 / 2.0 }
}

fn info(id: u16, label: &str, kind: InstanceKind, parent: Option<u16>, synonyms: &[&str]) -> InstanceInfo {
    InstanceInfo {
        id,
        label: label.into(),
        kind,
        parent,
        box_min_m: glam::Vec3::ZERO,
        box_max_m: glam::Vec3::ONE,
        synonyms: synonyms.iter().map(|s| s.to_string()).collect(),
        material: "wood".into(),
    }
}

/// A frame and the instance-id image the synthetic source would render beside it.
#[derive(Debug, Clone)]
struct Shot {
    frame: Frame,
    /// Row-major instance ids, one per pixel; 0 = background.
    ids: Vec<u16>,
}

impl Shot {
    /// A zeroed `width` x `height` frame, all background.
    fn new(width: u32, height: u32) -> Self {
        let frame = Frame::new(intrinsics(width, height));
        let ids = vec![0; frame.depth.len()];
        Self { frame, ids }
    }
}

/// Paints `id` at `depth_m` over the rectangle `[x0, x0 + w) x [y0, y0 + h)`.
fn paint(shot: &mut Shot, id: u16, x0: u32, y0: u32, w: u32, h: u32, depth_m: f32) {
    let width = shot.frame.intrinsics.width;
    for y in y0..y0 + h {
        for x in x0..x0 + w {
            let i = (y * width + x) as usize;
            shot.ids[i] = id;
            shot.frame.depth[i] = (depth_m * shot.frame.depth_units_per_m) as u16;
        }
    }
}

/// An oracle reading its instance ids from `channel` and recording provenance in `log`.
#[derive(Debug)]
struct Oracle {
    detector: OracleDetector,
    channel: InstanceIdChannel,
    log: InstanceLog,
}

impl Oracle {
    fn new(config: OracleConfig, instances: Vec<InstanceInfo>, worker_index: u32) -> Self {
        Self::wire(OracleDetector::new(config, instances, worker_index))
    }

    /// Gives `detector` a fresh channel and log.
    fn wire(detector: OracleDetector) -> Self {
        let (channel, log) = (InstanceIdChannel::new(), InstanceLog::new());
        let detector = detector.with_instance_ids(channel.clone()).with_instance_log(log.clone());
        Self { detector, channel, log }
    }

    /// Hands `shot.ids` to the channel as the instance ids of `shot.frame` at its current `seq`.
    fn publish(&self, shot: &mut Shot) {
        let Shot { frame, ids } = shot;
        self.channel.write(frame, |_, slot| {
            slot.clear();
            slot.extend_from_slice(ids);
        });
    }

    /// Publishes `shot`, detects on its frame and pairs each detection with its instance.
    fn detect(&mut self, shot: &mut Shot) -> Vec<Found> {
        self.publish(shot);
        let mut out = Vec::new();
        self.detector.detect(&shot.frame, &mut out).unwrap();
        let instances = self.log.get();
        assert_eq!(instances.len(), out.len(), "one log entry per detection");
        out.into_iter().zip(instances).collect()
    }
}

fn no_noise() -> OracleConfig {
    OracleConfig { min_visible_px: 1, ..OracleConfig::clean() }
}

/// Runs `frames` frames (seq 0..frames) and returns all detections.
fn run(oracle: &mut Oracle, shot: &mut Shot, frames: u64) -> Vec<Vec<Found>> {
    (0..frames)
        .map(|seq| {
            shot.frame.seq = seq;
            oracle.detect(shot)
        })
        .collect()
}

fn detection_rate(all: &[Vec<Found>], id: u16) -> f64 {
    let hits = all.iter().filter(|d| d.iter().any(|(_, instance)| *instance == Some(id))).count();
    hits as f64 / all.len() as f64
}

/// A kitchen-like scene on a 640x480 frame.
fn kitchen() -> (Shot, Vec<InstanceInfo>) {
    let mut shot = Shot::new(640, 480);
    let instances = vec![
        info(1, "cabinet", InstanceKind::Object, None, &["cupboard"]),
        info(2, "cabinet handle", InstanceKind::Part, Some(1), &[]),
        info(3, "stove", InstanceKind::Object, None, &[]),
        info(4, "stove knob", InstanceKind::Part, Some(3), &["dial"]),
        info(5, "light switch", InstanceKind::Object, None, &[]),
    ];
    paint(&mut shot, 1, 0, 0, 300, 400, 2.0);
    paint(&mut shot, 2, 250, 150, 10, 60, 1.95);
    paint(&mut shot, 3, 320, 200, 300, 280, 2.5);
    paint(&mut shot, 4, 400, 220, 12, 12, 2.4);
    paint(&mut shot, 5, 600, 10, 3, 3, 2.0); // 9 px: below min_visible_px
    (shot, instances)
}

fn cosine(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

#[test]
fn semantic_features_are_noisy_label_vectors() {
    let v = label_vector("cabinet", 64);
    assert_eq!(v, label_vector("cabinet", 64), "deterministic");
    assert!((cosine(&v, &v) - 1.0).abs() < 1e-5, "unit length");
    assert!(cosine(&v, &label_vector("stove", 64)).abs() < 0.5, "different labels are far apart");
    assert!(label_vector("cabinet", 0).is_empty());

    let (mut shot, instances) = kitchen();
    let mut oracle = Oracle::new(OracleConfig { semantic_noise: 0.3, ..OracleConfig::clean() }, instances, 0);
    let mut cosines = Vec::new();
    for seq in 0..50 {
        shot.frame.seq = seq;
        for (d, instance) in &oracle.detect(&mut shot) {
            let feature = d.semantic_feature.as_deref().unwrap();
            assert!((cosine(feature, feature) - 1.0).abs() < 1e-4);
            let label = oracle.detector.instances.iter().find(|i| Some(i.id) == *instance).unwrap();
            cosines.push(cosine(feature, &label_vector(&label.label, SEMANTIC_DIM)));
        }
    }
    let mean = cosines.iter().sum::<f32>() / cosines.len() as f32;
    // E[cos] ≈ 1 / sqrt(1 + 0.3²) = 0.958.
    assert!((mean - 0.958).abs() < 0.02, "mean cosine {mean}");
    let off = OracleConfig { semantic_dim: 0, ..OracleConfig::clean() };
    shot.frame.seq = 0;
    let out = Oracle::new(off, oracle.detector.instances.clone(), 0).detect(&mut shot);
    assert!(out.iter().all(|(d, _)| d.semantic_feature.is_none()));
}

#[test]
fn clean_preset_detects_every_visible_instance_exactly() {
    let (mut shot, instances) = kitchen();
    shot.frame.seq = 7;
    let mut oracle = Oracle::new(OracleConfig::clean(), instances.clone(), 0);
    assert_eq!(oracle.detector.name(), "oracle");
    let out = oracle.detect(&mut shot);
    assert_eq!(out.len(), 4, "{out:?}");
    let ids = &shot.ids;
    for (d, instance) in &out {
        let id = instance.unwrap();
        let inst = instances.iter().find(|i| i.id == id).unwrap();
        assert_eq!(d.label, inst.label);
        assert_eq!(d.kind, node_kind(inst.kind));
        assert_eq!(d.score, 1.0);
        // Clean: the feature is exactly the canonical label's vector.
        assert_eq!(d.semantic_feature.as_deref(), Some(label_vector(&inst.label, SEMANTIC_DIM).as_slice()));
        for y in 0..480 {
            for x in 0..640 {
                assert_eq!(d.mask.contains(x, y), ids[(y * 640 + x) as usize] == id, "id {id} at ({x}, {y})");
            }
        }
        let area = ids.iter().filter(|v| **v == id).count();
        assert_eq!(d.mask.area(), area);
        assert_eq!(d.mask.data.len(), (d.mask.width * d.mask.height) as usize);
    }
    // The cabinet's box is tight although the handle cuts into it.
    let (cabinet, _) = out.iter().find(|(_, instance)| *instance == Some(1)).unwrap();
    assert_eq!((cabinet.mask.x0, cabinet.mask.y0, cabinet.mask.width, cabinet.mask.height), (0, 0, 300, 400));
    assert_eq!(oracle.detector.unknown_instance_pixels(), 0);
}

#[test]
fn instances_below_min_visible_px_are_never_detected() {
    let mut shot = Shot::new(64, 48);
    paint(&mut shot, 1, 0, 0, 5, 5, 1.0); // 25 px
    paint(&mut shot, 2, 20, 20, 6, 5, 1.0); // 30 px
    let instances =
        vec![info(1, "knob", InstanceKind::Part, None, &[]), info(2, "button", InstanceKind::Part, None, &[])];
    let config = OracleConfig {
        part_miss_rate: 0.0,
        small_miss_boost: 0.0,
        far_miss_boost: 0.0,
        false_positives_per_frame: 0.0,
        ..OracleConfig::realistic()
    };
    let mut oracle = Oracle::new(config, instances, 0);
    let all = run(&mut oracle, &mut shot, 200);
    assert_eq!(detection_rate(&all, 1), 0.0);
    // Erosion can swallow nothing here (5x6 survives 2 px erosion), so the 30 px one is
    // always there.
    assert_eq!(detection_rate(&all, 2), 1.0);
}

#[test]
fn miss_rates_match_configuration() {
    let mut shot = Shot::new(64, 48);
    let mut instances = Vec::new();
    for k in 0..4u16 {
        paint(&mut shot, 1 + k, k as u32 * 16, 0, 15, 20, 1.0);
        instances.push(info(1 + k, "box", InstanceKind::Object, None, &[]));
        paint(&mut shot, 5 + k, k as u32 * 16, 24, 15, 20, 1.0);
        instances.push(info(5 + k, "knob", InstanceKind::Part, None, &[]));
    }
    let config = OracleConfig {
        object_miss_rate: 0.1,
        part_miss_rate: 0.3,
        small_area_px: 100, // all are 300 px: no boost
        small_miss_boost: 0.5,
        far_distance_m: 3.0, // all at 1 m: no boost
        far_miss_boost: 0.5,
        ..no_noise()
    };
    let mut oracle = Oracle::new(config, instances, 0);
    let all = run(&mut oracle, &mut shot, 1000);
    let object_rate = (1..=4).map(|id| 1.0 - detection_rate(&all, id)).sum::<f64>() / 4.0;
    let part_rate = (5..=8).map(|id| 1.0 - detection_rate(&all, id)).sum::<f64>() / 4.0;
    // Standard errors: 0.0047 and 0.0072 over 4000 trials each.
    assert!((object_rate - 0.1).abs() < 0.025, "object miss rate {object_rate}");
    assert!((part_rate - 0.3).abs() < 0.035, "part miss rate {part_rate}");
}

#[test]
fn small_and_far_parts_are_missed_more() {
    let mut shot = Shot::new(64, 48);
    paint(&mut shot, 1, 0, 0, 10, 10, 1.0); // small (100 px), near
    paint(&mut shot, 2, 12, 0, 30, 20, 1.0); // large (600 px), near
    paint(&mut shot, 3, 0, 24, 30, 20, 4.5); // large, far (4.5 m)
    let instances = vec![
        info(1, "knob", InstanceKind::Part, None, &[]),
        info(2, "knob", InstanceKind::Part, None, &[]),
        info(3, "knob", InstanceKind::Part, None, &[]),
    ];
    let config = OracleConfig {
        part_miss_rate: 0.1,
        small_area_px: 400,
        small_miss_boost: 0.4,
        far_distance_m: 3.0,
        far_miss_boost: 0.4,
        ..no_noise()
    };
    let mut oracle = Oracle::new(config, instances, 0);
    let all = run(&mut oracle, &mut shot, 2000);
    let small = 1.0 - detection_rate(&all, 1);
    let large = 1.0 - detection_rate(&all, 2);
    let far = 1.0 - detection_rate(&all, 3);
    // Expected: 0.1 + 0.4 * (1 - 100/400) = 0.4; 0.1; 0.1 + 0.4 * 0.5 = 0.3.
    assert!((small - 0.4).abs() < 0.04, "small miss rate {small}");
    assert!((large - 0.1).abs() < 0.03, "large miss rate {large}");
    assert!((far - 0.3).abs() < 0.04, "far miss rate {far}");
    assert!(small > large + 0.2 && far > large + 0.1);
}

#[test]
fn synonyms_follow_the_rate_and_the_instance_and_parent_lists() {
    let mut shot = Shot::new(64, 48);
    paint(&mut shot, 1, 0, 0, 30, 40, 1.0);
    paint(&mut shot, 2, 10, 10, 5, 10, 1.0);
    paint(&mut shot, 3, 32, 0, 30, 40, 1.0);
    paint(&mut shot, 4, 40, 10, 8, 8, 1.0);
    let instances = vec![
        info(1, "cabinet", InstanceKind::Object, None, &["cupboard", "closet"]),
        info(2, "cabinet handle", InstanceKind::Part, Some(1), &[]),
        info(3, "stove", InstanceKind::Object, None, &[]),
        info(4, "stove knob", InstanceKind::Part, Some(3), &["dial"]),
    ];
    let config = OracleConfig { synonym_rate: 0.3, ..no_noise() };
    let mut oracle = Oracle::new(config, instances.clone(), 0);
    let all = run(&mut oracle, &mut shot, 2000);
    let mut labels: HashMap<u16, HashMap<String, usize>> = HashMap::new();
    for (d, instance) in all.iter().flatten() {
        *labels.entry(instance.unwrap()).or_default().entry(d.label.clone()).or_default() += 1;
    }
    let allowed: HashMap<u16, Vec<&str>> = HashMap::from([
        (1, vec!["cabinet", "cupboard", "closet"]),
        (2, vec!["cabinet handle", "cupboard handle", "closet handle"]),
        (3, vec!["stove"]),
        (4, vec!["stove knob", "dial"]),
    ]);
    for (id, counts) in &labels {
        let possible = possible_labels(&instances, &instances[usize::from(*id) - 1]);
        assert_eq!(possible, allowed[id], "id {id}: possible_labels");
        let total: usize = counts.values().sum();
        assert_eq!(total, 2000);
        for label in counts.keys() {
            assert!(allowed[id].contains(&label.as_str()), "id {id}: unexpected label {label}");
        }
        let canonical = counts.get(allowed[id][0]).copied().unwrap_or(0);
        let rate = 1.0 - canonical as f64 / total as f64;
        let expected = if *id == 3 { 0.0 } else { 0.3 };
        assert!((rate - expected).abs() < 0.04, "id {id}: synonym rate {rate}");
        // Every synonym is used.
        assert_eq!(counts.len(), allowed[id].len(), "id {id}: {counts:?}");
    }
}

#[test]
fn find_word_respects_word_boundaries() {
    assert_eq!(find_word("cabinet handle", "cabinet"), Some(0));
    assert_eq!(find_word("upper cabinet handle", "cabinet"), Some(6));
    assert_eq!(find_word("cabinetry handle", "cabinet"), None);
    assert_eq!(find_word("handle", ""), None);
}

#[test]
fn erosion_and_dilation_of_a_square_are_exact() {
    let mut shot = Shot::new(64, 48);
    paint(&mut shot, 1, 20, 20, 10, 10, 1.0);
    let ids = &shot.ids;
    let s = Stats { count: 100, x0: 20, y0: 20, x1: 29, y1: 29 };
    let exact = instance_mask(ids, 64, 48, 1, s, None).unwrap();
    assert_eq!((exact.x0, exact.y0, exact.width, exact.height, exact.area()), (20, 20, 10, 10, 100));
    let eroded = instance_mask(ids, 64, 48, 1, s, Some(Morph::Erode(1))).unwrap();
    assert_eq!((eroded.x0, eroded.y0, eroded.width, eroded.height, eroded.area()), (21, 21, 8, 8, 64));
    let dilated = instance_mask(ids, 64, 48, 1, s, Some(Morph::Dilate(2))).unwrap();
    assert_eq!((dilated.x0, dilated.y0, dilated.width, dilated.height, dilated.area()), (18, 18, 14, 14, 196));
    assert!(instance_mask(ids, 64, 48, 1, s, Some(Morph::Erode(5))).is_none());
    // At the image corner, the border does not erode and dilation is clipped.
    let mut corner = Shot::new(64, 48);
    paint(&mut corner, 1, 0, 0, 10, 10, 1.0);
    let ids = &corner.ids;
    let s = Stats { count: 100, x0: 0, y0: 0, x1: 9, y1: 9 };
    let eroded = instance_mask(ids, 64, 48, 1, s, Some(Morph::Erode(1))).unwrap();
    assert_eq!((eroded.x0, eroded.y0, eroded.width, eroded.height), (0, 0, 9, 9));
    let dilated = instance_mask(ids, 64, 48, 1, s, Some(Morph::Dilate(1))).unwrap();
    assert_eq!((dilated.x0, dilated.y0, dilated.width, dilated.height), (0, 0, 11, 11));
}

#[test]
fn configured_erosion_shrinks_and_dilation_grows_masks() {
    let mut shot = Shot::new(64, 48);
    paint(&mut shot, 1, 20, 20, 10, 10, 1.0);
    paint(&mut shot, 2, 30, 20, 10, 10, 1.0); // neighbour: dilation bleeds into it
    let instances =
        vec![info(1, "box", InstanceKind::Object, None, &[]), info(2, "box", InstanceKind::Object, None, &[])];
    let areas = |config: OracleConfig| -> HashSet<usize> {
        let mut oracle = Oracle::new(config, instances.clone(), 0);
        run(&mut oracle, &mut shot.clone(), 200)
            .iter()
            .flatten()
            .filter(|(_, instance)| *instance == Some(1))
            .map(|(d, _)| d.mask.area())
            .collect()
    };
    let eroded = areas(OracleConfig { mask_erode_px_max: 1, ..no_noise() });
    assert_eq!(eroded, HashSet::from([100, 64]));
    let dilated = areas(OracleConfig { mask_dilate_px_max: 2, ..no_noise() });
    assert_eq!(dilated, HashSet::from([100, 144, 196]));
    let both = areas(OracleConfig { mask_erode_px_max: 1, mask_dilate_px_max: 1, ..no_noise() });
    assert_eq!(both, HashSet::from([64, 100, 144]));
}

#[test]
fn false_positives_follow_the_poisson_mean() {
    let mut shot = Shot::new(64, 48);
    paint(&mut shot, 1, 0, 0, 20, 20, 1.0);
    paint(&mut shot, 2, 30, 0, 8, 8, 1.0);
    let instances = vec![
        info(1, "cabinet", InstanceKind::Object, None, &[]),
        info(2, "cabinet handle", InstanceKind::Part, Some(1), &[]),
        info(3, "fridge", InstanceKind::Object, None, &[]), // not visible, still in the scene
    ];
    let config = OracleConfig { false_positives_per_frame: 0.7, score_std: 0.1, ..no_noise() };
    let mut oracle = Oracle::new(config, instances, 0);
    let all = run(&mut oracle, &mut shot, 2000);
    let counts: Vec<f64> =
        all.iter().map(|d| d.iter().filter(|(_, instance)| instance.is_none()).count() as f64).collect();
    let mean = counts.iter().sum::<f64>() / counts.len() as f64;
    let variance = counts.iter().map(|c| (c - mean).powi(2)).sum::<f64>() / counts.len() as f64;
    // Standard error of the mean: sqrt(0.7 / 2000) = 0.019.
    assert!((mean - 0.7).abs() < 0.07, "mean false positives {mean}");
    assert!((variance - 0.7).abs() < 0.15, "variance {variance}");
    let fps: Vec<&Detection> =
        all.iter().flatten().filter(|(_, instance)| instance.is_none()).map(|(d, _)| d).collect();
    let labels: HashSet<&str> = fps.iter().map(|d| d.label.as_str()).collect();
    assert_eq!(labels, HashSet::from(["cabinet", "cabinet handle", "fridge"]));
    for d in &fps {
        assert!(d.mask.area() > 0 && d.mask.x0 + d.mask.width <= 64 && d.mask.y0 + d.mask.height <= 48);
        let expected_kind = if d.label == "cabinet handle" { NodeKind::Part } else { NodeKind::Object };
        assert_eq!(d.kind, expected_kind);
    }
    let fp_score = fps.iter().map(|d| f64::from(d.score)).sum::<f64>() / fps.len() as f64;
    assert!((fp_score - 0.35).abs() < 0.02, "false-positive score mean {fp_score}");
    // True detections are untouched by the false positives.
    assert_eq!(detection_rate(&all, 1), 1.0);
}

#[test]
fn scores_follow_the_configured_distribution() {
    let mut shot = Shot::new(64, 48);
    for k in 0..4u16 {
        paint(&mut shot, 1 + k, k as u32 * 16, 0, 15, 40, 1.0);
    }
    let instances = (1..=4).map(|id| info(id, "box", InstanceKind::Object, None, &[])).collect();
    let config = OracleConfig { score_mean: 0.7, score_std: 0.1, ..no_noise() };
    let mut oracle = Oracle::new(config, instances, 0);
    let scores: Vec<f64> =
        run(&mut oracle, &mut shot, 1000).iter().flatten().map(|(d, _)| f64::from(d.score)).collect();
    assert_eq!(scores.len(), 4000);
    let mean = scores.iter().sum::<f64>() / scores.len() as f64;
    let std = (scores.iter().map(|s| (s - mean).powi(2)).sum::<f64>() / scores.len() as f64).sqrt();
    assert!((mean - 0.7).abs() < 0.01, "score mean {mean}");
    assert!((std - 0.1).abs() < 0.01, "score std {std}");
    assert!(scores.iter().all(|s| (0.05..=1.0).contains(s)));
}

#[test]
fn output_is_a_pure_function_of_config_and_frame() {
    let (mut shot, instances) = kitchen();
    let config = OracleConfig { false_positives_per_frame: 2.0, seed: 42, ..OracleConfig::realistic() };
    let mut a = Oracle::new(config.clone(), instances.clone(), 0);
    let mut b = Oracle::new(config.clone(), instances.clone(), 3);
    let mut outputs = Vec::new();
    for seq in [5u64, 9, 5] {
        shot.frame.seq = seq;
        let (out_a, out_b) = (a.detect(&mut shot), b.detect(&mut shot));
        assert_eq!(out_a, out_b, "seq {seq}");
        outputs.push(out_a);
    }
    assert_eq!(outputs[0], outputs[2], "same frame twice");
    assert_ne!(outputs[0], outputs[1], "different frames draw different noise");
    // A different seed draws different noise.
    let mut c = Oracle::new(OracleConfig { seed: 43, ..config }, instances, 0);
    shot.frame.seq = 5;
    let out_c = c.detect(&mut shot);
    assert_ne!(out_c, outputs[0]);
}

/// `detector.detect(frame)` fails for want of instance ids (`frame.seq` must be 17) and clears
/// the output.
fn assert_no_instance_ids(detector: &mut OracleDetector, frame: &Frame) {
    let mut out = vec![Detection {
        label: "stale".into(),
        kind: NodeKind::Object,
        score: 1.0,
        mask: Mask::default(),
        semantic_feature: None,
    }];
    let error = detector.detect(frame, &mut out).unwrap_err();
    assert!(matches!(error, DetectorError::Frame { seq: 17, .. }), "{error:?}");
    let message = error.to_string();
    assert!(message.contains("frame 17") && message.contains("no instance ids"), "{message}");
    assert!(out.is_empty());
}

#[test]
fn a_frame_the_channel_has_no_ids_for_is_an_error() {
    let mut shot = Shot::new(64, 48);
    paint(&mut shot, 1, 0, 0, 10, 10, 1.0);
    shot.frame.seq = 17;
    // No channel at all.
    assert_no_instance_ids(&mut OracleDetector::new(OracleConfig::clean(), Vec::new(), 0), &shot.frame);
    // A channel that was handed nothing for the frame.
    let mut oracle = Oracle::new(no_noise(), vec![info(1, "box", InstanceKind::Object, None, &[])], 0);
    assert_no_instance_ids(&mut oracle.detector, &shot.frame);
    assert!(oracle.log.get().is_empty());
    // A channel that holds the ids of the buffer's previous frame, not of this one.
    shot.frame.seq = 16;
    assert_eq!(oracle.detect(&mut shot).len(), 1);
    assert_eq!(oracle.log.get(), [Some(1)]);
    shot.frame.seq = 17;
    assert_no_instance_ids(&mut oracle.detector, &shot.frame);
    assert!(oracle.log.get().is_empty(), "a failed detect leaves the log empty");
    // A copy of a frame the channel has ids for.
    oracle.publish(&mut shot);
    assert_no_instance_ids(&mut oracle.detector, &shot.frame.clone());
    assert_eq!(oracle.detect(&mut shot).len(), 1);
}

#[test]
fn unknown_instance_ids_are_ignored_but_counted() {
    let mut shot = Shot::new(64, 48);
    paint(&mut shot, 1, 0, 0, 10, 10, 1.0);
    paint(&mut shot, 99, 20, 20, 5, 4, 1.0);
    let mut oracle = Oracle::new(no_noise(), vec![info(1, "box", InstanceKind::Object, None, &[])], 0);
    oracle.publish(&mut shot);
    let mut out = Vec::new();
    oracle.detector.detect(&shot.frame, &mut out).unwrap();
    assert_eq!(out.len(), 1);
    assert_eq!(oracle.log.get(), [Some(1)]);
    assert_eq!(oracle.detector.unknown_instance_pixels(), 20);
    oracle.detector.detect(&shot.frame, &mut out).unwrap();
    assert_eq!(out.len(), 1, "out is replaced, not appended to");
    assert_eq!(oracle.log.get(), [Some(1)], "the log is replaced, not appended to");
    assert_eq!(oracle.detector.unknown_instance_pixels_total(), 40);
}

#[test]
fn validate_names_the_field() {
    assert_eq!(OracleConfig::clean().validate("detector.oracle"), Ok(()));
    assert_eq!(OracleConfig::realistic().validate("detector.oracle"), Ok(()));
    let bad = OracleConfig { part_miss_rate: 1.5, ..OracleConfig::realistic() };
    assert_eq!(
        bad.validate("detector.oracle"),
        Err("detector.oracle.part_miss_rate: must be within [0, 1], got 1.5".into())
    );
    let nan = OracleConfig { synonym_rate: f64::NAN, ..OracleConfig::realistic() };
    assert!(nan.validate("d").unwrap_err().starts_with("d.synonym_rate:"));
    let far = OracleConfig { far_distance_m: 0.0, ..OracleConfig::realistic() };
    assert!(far.validate("d").unwrap_err().starts_with("d.far_distance_m:"));
    let erode = OracleConfig { mask_erode_px_max: 1000, ..OracleConfig::realistic() };
    assert!(erode.validate("d").unwrap_err().starts_with("d.mask_erode_px_max:"));
    let fp = OracleConfig { false_positives_per_frame: -1.0, ..OracleConfig::realistic() };
    assert!(fp.validate("d").unwrap_err().starts_with("d.false_positives_per_frame:"));
    let visible = OracleConfig { min_visible_px: 0, ..OracleConfig::realistic() };
    assert!(visible.validate("").unwrap_err().starts_with("min_visible_px:"));
}

#[test]
fn presets_and_serde() {
    assert_eq!(OracleConfig::preset("clean"), Some(OracleConfig::clean()));
    assert_eq!(OracleConfig::preset("realistic"), Some(OracleConfig::realistic()));
    assert_eq!(OracleConfig::preset("noisy"), None);
    assert_eq!(OracleConfig::default(), OracleConfig::realistic());
    let parsed: OracleConfig = toml::from_str("part_miss_rate = 0.2\nseed = 7").unwrap();
    assert_eq!(parsed, OracleConfig { part_miss_rate: 0.2, seed: 7, ..OracleConfig::realistic() });
    assert!(toml::from_str::<OracleConfig>("part_mis_rate = 0.2").is_err());
    let text = toml::to_string(&OracleConfig::clean()).unwrap();
    assert_eq!(toml::from_str::<OracleConfig>(&text).unwrap(), OracleConfig::clean());
}

#[test]
fn realistic_preset_runs_on_a_full_frame() {
    let (mut shot, instances) = kitchen();
    let mut oracle = Oracle::new(OracleConfig::realistic(), instances, 1);
    let all = run(&mut oracle, &mut shot, 20);
    let detections: usize = all.iter().map(Vec::len).sum();
    assert!(detections > 40, "{detections}");
    assert!(all.iter().flatten().all(|(d, _)| d.mask.area() > 0 && (0.05..=1.0).contains(&d.score)));
    assert_eq!(detection_rate(&all, 5), 0.0);
}

fn labels_of(oracle: &mut Oracle, shot: &mut Shot) -> Vec<(u16, String)> {
    oracle.detect(shot).into_iter().filter_map(|(d, instance)| Some((instance?, d.label))).collect()
}

#[test]
fn prompt_lists_decide_which_parts_are_reported_and_how() {
    use op3dsg_runtime::knowledge::KnowledgeBase;
    let kb = Arc::new(KnowledgeBase::builtin().unwrap());
    let (mut shot, instances) = kitchen();
    let with = |mode| {
        Oracle::wire(
            OracleDetector::new(no_noise(), instances.clone(), 0)
                .with_candidates(Arc::new(PartCandidates::new(kb.clone(), mode))),
        )
    };
    let all = labels_of(&mut Oracle::new(no_noise(), instances.clone(), 0), &mut shot);
    let knowledge = labels_of(&mut with(CandidateMode::Knowledge), &mut shot);
    let generic = labels_of(&mut with(CandidateMode::Generic), &mut shot);
    let label = |list: &[(u16, String)], id: u16| list.iter().find(|(i, _)| *i == id).map(|(_, l)| l.clone());
    // Objects are always reported; with the knowledge list every part under its own name.
    assert_eq!(knowledge, all);
    assert_eq!(label(&knowledge, 2).as_deref(), Some("cabinet handle"));
    assert_eq!(label(&knowledge, 4).as_deref(), Some("stove knob"));
    // The generic vocabulary finds them under generic names.
    assert_eq!(label(&generic, 2).as_deref(), Some("handle"));
    assert_eq!(label(&generic, 4).as_deref(), Some("knob"));
    assert_eq!(label(&generic, 1).as_deref(), Some("cabinet"));
    // Without the stove in view its knob is not asked for (the knob alone is visible).
    let mut no_stove = shot.clone();
    for id in no_stove.ids.iter_mut().filter(|id| **id == 3) {
        *id = 0;
    }
    let knowledge = labels_of(&mut with(CandidateMode::Knowledge), &mut no_stove);
    assert_eq!(label(&knowledge, 4), None);
    assert_eq!(label(&knowledge, 2).as_deref(), Some("cabinet handle"));
    // "all" changes nothing.
    assert_eq!(labels_of(&mut with(CandidateMode::All), &mut shot), all);
}

#[test]
fn label_vectors_can_be_replaced() {
    let (mut shot, instances) = kitchen();
    let mut vectors = HashMap::new();
    let mut v = vec![0.0f32; 8];
    v[3] = 1.0;
    vectors.insert("cabinet".to_owned(), v.clone());
    let mut oracle = Oracle::wire(OracleDetector::new(no_noise(), instances, 0).with_label_vectors(&vectors));
    let out = oracle.detect(&mut shot);
    let (cabinet, _) = out.iter().find(|(_, instance)| *instance == Some(1)).unwrap();
    assert_eq!(cabinet.semantic_feature.as_deref(), Some(v.as_slice()));
    let (stove, _) = out.iter().find(|(_, instance)| *instance == Some(3)).unwrap();
    assert_eq!(stove.semantic_feature.as_ref().map(Vec::len), Some(SEMANTIC_DIM));
}

// ---- Perception as it is on a robot (the `field` preset's knobs) ----

/// A confusion table given directly: cabinet ↔ drawer, knob → button / dial.
fn small_table() -> ConfusionTable {
    let mut neighbours = HashMap::new();
    neighbours.insert("cabinet".to_owned(), vec![("drawer".to_owned(), 0.7)]);
    neighbours.insert("knob".to_owned(), vec![("button".to_owned(), 0.6), ("dial".to_owned(), 0.55)]);
    ConfusionTable::from_neighbours(neighbours)
}

#[test]
fn confusion_is_only_between_the_chosen_neighbours_at_the_rate() {
    let (mut shot, instances) = kitchen();
    let config = OracleConfig { confusion_rate: 0.3, ..no_noise() };
    let mut oracle = Oracle::wire(OracleDetector::new(config, instances.clone(), 0).with_confusions(&small_table()));
    assert_eq!(oracle.detector.confusions_of(0), ["drawer"]);
    assert_eq!(oracle.detector.confusions_of(3), ["stove button", "stove dial"]);
    assert!(oracle.detector.confusions_of(2).is_empty(), "the stove has no neighbour");
    let all = run(&mut oracle, &mut shot, 600);
    let mut seen: HashMap<u16, HashMap<String, usize>> = HashMap::new();
    for (d, instance) in all.iter().flatten() {
        *seen.entry(instance.unwrap()).or_default().entry(d.label.clone()).or_default() += 1;
    }
    let allowed: HashMap<u16, &[&str]> = HashMap::from([
        (1, &["cabinet", "drawer"][..]),
        (2, &["cabinet handle"][..]),
        (3, &["stove"][..]),
        (4, &["stove knob", "stove button", "stove dial"][..]),
        (5, &["light switch"][..]),
    ]);
    for (id, labels) in &seen {
        for label in labels.keys() {
            assert!(allowed[id].contains(&label.as_str()), "instance {id} labelled {label}");
        }
    }
    let rate = |id: u16, canonical: &str| {
        let labels = &seen[&id];
        1.0 - labels[canonical] as f64 / labels.values().sum::<usize>() as f64
    };
    assert!((rate(1, "cabinet") - 0.3).abs() < 0.06, "cabinet confused at {}", rate(1, "cabinet"));
    assert!((rate(4, "stove knob") - 0.3).abs() < 0.06, "knob confused at {}", rate(4, "stove knob"));
    // Both neighbours of the knob are drawn.
    assert!(seen[&4].contains_key("stove button") && seen[&4].contains_key("stove dial"));
}

#[test]
fn field_noise_has_its_own_stream_so_a_knob_changes_only_what_it_is_about() {
    let (mut shot, instances) = kitchen();
    let base = OracleConfig { min_visible_px: 1, ..OracleConfig::realistic() };
    let confused = OracleConfig { confusion_rate: 0.5, ..base.clone() };
    let mut a = Oracle::new(base, instances.clone(), 0);
    let mut b = Oracle::wire(OracleDetector::new(confused, instances, 0).with_confusions(&small_table()));
    let (ra, rb) = (run(&mut a, &mut shot, 100), run(&mut b, &mut shot, 100));
    let mut relabelled = 0;
    for (fa, fb) in ra.iter().zip(&rb) {
        assert_eq!(fa.len(), fb.len());
        for ((da, ia), (db, ib)) in fa.iter().zip(fb) {
            assert_eq!((ia, &da.mask, da.score, da.kind), (ib, &db.mask, db.score, db.kind));
            relabelled += usize::from(da.label != db.label);
        }
    }
    assert!(relabelled > 20, "{relabelled} labels changed");
}

#[test]
fn confusion_table_keeps_near_names_of_other_categories_only() {
    use op3dsg_runtime::knowledge::KnowledgeBase;
    let kb = KnowledgeBase::builtin().unwrap();
    // Pseudo-random 64-d vectors (cosines about ±0.25) except where set: drawer and cupboard
    // (a synonym of cabinet in the tables) are near cabinet, button near knob.
    let near = |base: &str, salt: &str, w: f32| {
        let (a, b) = (label_vector(base, 64), label_vector(salt, 64));
        let mut v: Vec<f32> = a.iter().zip(&b).map(|(x, y)| x + w * y).collect();
        normalise(&mut v);
        v
    };
    let mut embed = |texts: &[&str]| -> Result<Vec<Vec<f32>>, String> {
        Ok(texts
            .iter()
            .map(|t| match *t {
                "drawer" => near("cabinet", "drawer", 0.6),
                "cupboard" => near("cabinet", "cupboard", 0.1),
                "button" => near("knob", "button", 0.8),
                other => label_vector(other, 64),
            })
            .collect())
    };
    let words = vec![("cabinet".to_owned(), false), ("knob".to_owned(), true), ("stove".to_owned(), false)];
    let table = ConfusionTable::build(&kb, &words, &mut embed).unwrap();
    let names = |w: &str| table.neighbours(w).iter().map(|(n, _)| n.clone()).collect::<Vec<_>>();
    assert_eq!(names("cabinet"), ["drawer"], "{:?}", table.entries());
    assert_eq!(names("knob"), ["button"], "{:?}", table.entries());
    assert!(names("stove").is_empty(), "{:?}", table.entries());
    assert!(
        table
            .entries()
            .iter()
            .all(|(_, n)| n.len() <= CONFUSION_MAX_NEIGHBOURS && n.iter().all(|(_, c)| *c >= CONFUSION_MIN_COSINE))
    );
}

/// Two objects side by side (boxes touching) on a 200 x 100 frame, and a part of the first.
fn side_by_side() -> (Shot, Vec<InstanceInfo>) {
    let mut shot = Shot::new(200, 100);
    let instances = vec![
        info(1, "cabinet", InstanceKind::Object, None, &[]),
        info(2, "dishwasher", InstanceKind::Object, None, &[]),
        info(3, "cabinet handle", InstanceKind::Part, Some(1), &[]),
    ];
    paint(&mut shot, 1, 10, 10, 80, 80, 2.0);
    paint(&mut shot, 2, 90, 10, 80, 80, 2.0);
    paint(&mut shot, 3, 40, 40, 10, 20, 1.95);
    (shot, instances)
}

#[test]
fn splits_and_merges_follow_their_rates() {
    let (mut shot, instances) = side_by_side();
    let frames = 800;
    let mut split = Oracle::new(OracleConfig { split_rate: 0.2, ..no_noise() }, instances.clone(), 0);
    let all = run(&mut split, &mut shot, frames);
    let mut splits = 0;
    for f in &all {
        for id in [1u16, 2] {
            let pieces: Vec<&Detection> = f.iter().filter(|(_, i)| *i == Some(id)).map(|(d, _)| d).collect();
            assert!(pieces.len() <= 2);
            if pieces.len() == 2 {
                splits += 1;
                // The halves share the label and cover the object.
                assert_eq!(pieces[0].label, pieces[1].label);
                let area: usize = pieces.iter().map(|d| d.mask.data.iter().filter(|v| **v != 0).count()).sum();
                assert_eq!(area, shot.ids.iter().filter(|i| **i == id).count());
            }
        }
        // Parts are never split.
        assert_eq!(f.iter().filter(|(_, i)| *i == Some(3)).count(), 1);
    }
    let rate = splits as f64 / (2 * frames) as f64;
    assert!((rate - 0.2).abs() < 0.04, "split rate {rate}");

    let mut merge = Oracle::new(OracleConfig { merge_rate: 0.2, ..no_noise() }, instances, 0);
    let all = run(&mut merge, &mut shot, frames);
    let mut merges = 0;
    for f in &all {
        let objects: Vec<&Detection> = f.iter().map(|(d, _)| d).filter(|d| d.kind == NodeKind::Object).collect();
        if objects.len() == 1 {
            merges += 1;
            let both = shot.ids.iter().filter(|i| **i == 1 || **i == 2).count();
            assert_eq!(objects[0].mask.data.iter().filter(|v| **v != 0).count(), both);
        } else {
            assert_eq!(objects.len(), 2);
        }
        // The part never merges with an object.
        assert_eq!(f.iter().filter(|(d, _)| d.kind == NodeKind::Part).count(), 1);
    }
    let rate = merges as f64 / frames as f64;
    assert!((rate - 0.2).abs() < 0.04, "merge rate {rate}");
}

#[test]
fn kind_errors_report_parts_as_objects_at_the_rate() {
    let (mut shot, instances) = side_by_side();
    let mut oracle = Oracle::new(OracleConfig { kind_error_rate: 0.25, ..no_noise() }, instances, 0);
    let all = run(&mut oracle, &mut shot, 800);
    let mut as_object = 0;
    for (d, i) in all.iter().flatten() {
        match i {
            Some(3) => as_object += usize::from(d.kind == NodeKind::Object),
            _ => assert_eq!(d.kind, NodeKind::Object, "objects stay objects"),
        }
        if *i == Some(3) {
            assert_eq!(d.label, "cabinet handle");
        }
    }
    let rate = as_object as f64 / 800.0;
    assert!((rate - 0.25).abs() < 0.05, "kind error rate {rate}");
}

#[test]
fn masks_bleed_into_the_background_at_depth_edges_only() {
    // A cabinet at 2 m; left of it a wall 2 m behind, right of it a dishwasher 2 cm behind.
    let mut shot = Shot::new(200, 100);
    let instances = vec![
        info(1, "cabinet", InstanceKind::Object, None, &[]),
        info(2, "dishwasher", InstanceKind::Object, None, &[]),
        info(3, "wall", InstanceKind::Object, None, &[]),
    ];
    paint(&mut shot, 3, 0, 0, 50, 100, 4.0);
    paint(&mut shot, 1, 50, 20, 60, 60, 2.0);
    paint(&mut shot, 2, 110, 20, 60, 60, 2.02);
    let config = OracleConfig { depth_bleed_rate: 1.0, depth_bleed_px: 4, ..no_noise() };
    let mut oracle = Oracle::new(config, instances, 0);
    let mut grew_left = false;
    for f in run(&mut oracle, &mut shot, 20) {
        let (d, _) = f.iter().find(|(_, i)| *i == Some(1)).unwrap();
        let m = &d.mask;
        assert!(m.x0 >= 46 && m.x0 <= 49, "bleeds 1..=4 px into the wall: x0 {}", m.x0);
        grew_left |= m.x0 < 50;
        // Never into the dishwasher just behind it; above and below it is depth 0 (no
        // return), which counts as background.
        for y in 20..80 {
            for x in 110..(m.x0 + m.width) {
                if y >= m.y0 && y < m.y0 + m.height {
                    let inside = m.data[((y - m.y0) * m.width + (x - m.x0)) as usize] != 0;
                    assert!(!inside, "bled into the near neighbour at ({x}, {y})");
                }
            }
        }
        assert!(m.y0 < 20 && m.y0 + m.height > 80);
    }
    assert!(grew_left);
}

#[test]
fn the_tagger_misses_and_adds_tags() {
    use op3dsg_runtime::knowledge::KnowledgeBase;
    let kb = Arc::new(KnowledgeBase::builtin().unwrap());
    let (mut shot, instances) = kitchen();
    let with = |config: OracleConfig| {
        Oracle::wire(
            OracleDetector::new(config, instances.clone(), 0)
                .with_candidates(Arc::new(PartCandidates::new(kb.clone(), CandidateMode::Knowledge))),
        )
    };
    // Every tag missed: no part is asked for, objects are still detected.
    let mut blind = with(OracleConfig { tag_miss_rate: 1.0, ..no_noise() });
    let found = blind.detect(&mut shot);
    assert!(found.iter().all(|(d, _)| d.kind == NodeKind::Object), "{found:?}");
    assert_eq!(found.len(), 3);
    // Added tags: about tag_add_per_frame a frame, from the tables' object names.
    let mut chatty = with(OracleConfig { tag_add_per_frame: 2.0, ..no_noise() });
    let mut added = 0;
    for seq in 0..400 {
        shot.frame.seq = seq;
        chatty.detect(&mut shot);
        let tags = chatty.detector.last_tags();
        assert!(tags.len() >= 3, "the visible objects are tagged");
        added += tags.len() - 3;
        assert!(tags[3..].iter().all(|t| kb.object_category(t).is_some()), "{tags:?}");
    }
    let mean = added as f64 / 400.0;
    assert!((mean - 2.0).abs() < 0.25, "added tags per frame {mean}");
}

#[test]
fn pose_drift_grows_with_distance_within_its_bounds_and_jitter_does_not_accumulate() {
    let truth = |x: f64| op3dsg_drivers::pose::Isometry {
        rotation: glam::DQuat::IDENTITY,
        translation: glam::DVec3::new(x, 0.0, 1.0),
    };
    let config = OracleConfig { pose_drift_fraction: 0.02, pose_drift_deg_per_m: 0.5, ..OracleConfig::clean() };
    let mut noise = PoseNoise::new(&config).unwrap();
    let mut again = PoseNoise::new(&config).unwrap();
    for i in 0..=200 {
        let pose = noise.apply(&truth(f64::from(i) * 0.1));
        assert_eq!(pose, again.apply(&truth(f64::from(i) * 0.1)), "deterministic");
    }
    let travelled = noise.travelled_m();
    assert!((travelled - 20.0).abs() < 1e-9);
    let per_m = noise.drift_m() / travelled;
    assert!((0.005..=0.02 + 1e-12).contains(&per_m), "translation drift {per_m} of distance");
    assert!((noise.heading_error_deg().abs() - 10.0).abs() < 1e-9, "{} deg", noise.heading_error_deg());
    // Standing still: no drift.
    let mut still = PoseNoise::new(&config).unwrap();
    for _ in 0..50 {
        assert_eq!(still.apply(&truth(3.0)), truth(3.0));
    }
    // Jitter alone: independent per keyframe, about pose_jitter_m per axis.
    let jitter = OracleConfig { pose_jitter_m: 0.01, pose_jitter_deg: 0.5, ..OracleConfig::clean() };
    let mut noise = PoseNoise::new(&jitter).unwrap();
    let errors: Vec<f64> = (0..2000).map(|i| noise.apply(&truth(f64::from(i) * 0.1)).translation.y).collect();
    let std = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
    assert!((std - 0.01).abs() < 0.001, "jitter std {std}");
    assert!(noise.drift_m() == 0.0);
    assert!(PoseNoise::new(&OracleConfig::realistic()).is_none());
}

#[test]
fn field_preset_is_realistic_plus_robot_noise_and_validates() {
    let field = OracleConfig::preset("field").unwrap();
    field.validate("detector.oracle").unwrap();
    assert!(field.confusion_rate > 0.0 && field.split_rate > 0.0 && field.has_pose_noise());
    let back = OracleConfig { ..field.clone() };
    assert_eq!(back.object_miss_rate, OracleConfig::realistic().object_miss_rate);
    let bad = OracleConfig { pose_drift_fraction: 0.9, ..field.clone() };
    assert!(bad.validate("detector.oracle").unwrap_err().starts_with("detector.oracle.pose_drift_fraction"));
    let bad = OracleConfig { depth_bleed_px: 0, ..field };
    assert!(bad.validate("detector.oracle").unwrap_err().starts_with("detector.oracle.depth_bleed_px"));
}
