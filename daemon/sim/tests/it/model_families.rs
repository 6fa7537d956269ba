//! The open-vocabulary detector's model families through ONNX Runtime on their stand-ins
//! (`.models/standins/`, written by `./scripts/setup-standins.sh` from
//! `scripts/reference/model_standins.py`: the tensor names, shapes and dtypes of the real
//! exports, answers known): CLIP tokens as open_clip's own tokenizer gives them, the CLIP text
//! encoder, YOLO-World (CLIP features in, scores and boxes out) and OWL (tokens in, logits and
//! normalised centre boxes out) decoded to labels and image-pixel boxes through the letterbox; a
//! file whose tensors are not the family's, or whose sha256 differs, refused at start naming the
//! key; and the profiles in `profiles/` loading the stand-ins with only the model paths changed.
//!
//! Needs `./scripts/setup-models.sh` and `./scripts/setup-standins.sh` (`scripts/test.sh` runs
//! both); fails naming them when the files are missing.

use std::path::PathBuf;
use std::sync::Arc;

use op3dsg_drivers::frame::{Frame, Intrinsics};
use op3dsg_ipc_types::NodeKind;
use op3dsg_runtime::knowledge::KnowledgeBase;
use op3dsg_runtime::onnx::clip_text::{ClipTextConfig, ClipTextEncoder, ClipTokenizer, DEFAULT_TOKENIZER_PATH};
use op3dsg_runtime::onnx::text_encoder::TextEncoderConfig;
use op3dsg_runtime::onnx::{OnnxConfig, OnnxRuntime};
use op3dsg_runtime::perception::candidates::CandidateMode;
use op3dsg_runtime::perception::image_input::ImageInput;
use op3dsg_runtime::perception::mask_decoder::MaskDecoderConfig;
use op3dsg_runtime::perception::open_vocab::{Family, OpenVocabConfig, OpenVocabDetector, PromptConfig};
use op3dsg_runtime::perception::{CalibrationKind, Detection, Detector, ScoreCalibration};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..").canonicalize().expect("repository root")
}

fn standin(name: &str) -> PathBuf {
    let path = repo().join(".models/standins").join(name);
    assert!(path.is_file(), "{} missing: run ./scripts/setup-models.sh && ./scripts/setup-standins.sh", path.display());
    path
}

fn expected() -> serde_json::Value {
    let text = std::fs::read_to_string(standin("expected.json")).expect("expected.json");
    serde_json::from_str(&text).expect("expected.json is JSON")
}

fn runtime() -> OnnxRuntime {
    OnnxRuntime::init(&OnnxConfig::default()).expect("ONNX Runtime (run ./scripts/setup-models.sh)")
}

fn clip_config() -> ClipTextConfig {
    ClipTextConfig { model_path: standin("clip_text.onnx"), ..ClipTextConfig::default() }
}

fn prompts(objects: &[&str]) -> PromptConfig {
    PromptConfig {
        objects: objects.iter().map(|s| (*s).to_owned()).collect(),
        part_prompts: CandidateMode::All,
        ..PromptConfig::default()
    }
}

fn yolo_world_config() -> OpenVocabConfig {
    OpenVocabConfig {
        family: Family::YoloWorld,
        model_path: standin("yolo_world.onnx"),
        prompts: prompts(&["cabinet", "stove"]),
        clip: clip_config(),
        ..OpenVocabConfig::default()
    }
}

fn owl_config(objects: &[&str]) -> OpenVocabConfig {
    OpenVocabConfig {
        family: Family::Owl,
        model_path: standin("owl.onnx"),
        input: ImageInput {
            name: "pixel_values".into(),
            width: 960,
            height: 960,
            mean: [0.481_454_66, 0.457_827_5, 0.408_210_73],
            std: [0.268_629_54, 0.261_302_6, 0.275_777_1],
            pad_value: 127.5,
            ..ImageInput::default()
        },
        prompts: prompts(objects),
        ..OpenVocabConfig::default()
    }
}

/// A 320 x 240 frame with flat depth (1.5 m), so depth masks fill their boxes.
fn frame() -> Frame {
    let intrinsics = Intrinsics { width: 320, height: 240, fx: 250.0, fy: 250.0, cx: 160.0, cy: 120.0 };
    let mut frame = Frame::new(intrinsics);
    frame.rgb.iter_mut().enumerate().for_each(|(i, v)| *v = (i % 251) as u8);
    frame.depth.iter_mut().for_each(|d| *d = 1500);
    frame
}

fn detect(config: &OpenVocabConfig) -> Vec<Detection> {
    let knowledge = Arc::new(KnowledgeBase::builtin().expect("built-in knowledge base"));
    let mut detector = OpenVocabDetector::new(&runtime(), config, knowledge, &TextEncoderConfig::default())
        .unwrap_or_else(|e| panic!("{e}"));
    let mut out = Vec::new();
    detector.detect(&frame(), &mut out).expect("detects");
    out
}

fn summary(d: &Detection) -> (String, NodeKind, i64, [u32; 4]) {
    let m = &d.mask;
    (d.label.clone(), d.kind, (d.score * 1000.0).round() as i64, [m.x0, m.y0, m.x0 + m.width, m.y0 + m.height])
}

#[test]
fn clip_tokens_are_open_clips() {
    let tokenizer =
        ClipTokenizer::new(&repo().join(DEFAULT_TOKENIZER_PATH), "t").expect("run ./scripts/setup-models.sh");
    let expected = expected();
    let tokens = expected["tokens"].as_object().unwrap();
    assert!(tokens.len() >= 8);
    for (prompt, ids) in tokens {
        let want: Vec<u32> = ids.as_array().unwrap().iter().map(|v| v.as_u64().unwrap() as u32).collect();
        assert_eq!(tokenizer.ids(prompt).unwrap(), want, "{prompt:?}");
    }
    // Padded with zeros, cut with <|endoftext|> last, masked over the real tokens.
    let batch = tokenizer.encode(&["stove", "a photo of a red chair!"], 5).unwrap();
    assert_eq!(batch.ids, [49406, 21423, 49407, 0, 0, 49406, 320, 1125, 539, 49407]);
    assert_eq!(batch.mask, [1, 1, 1, 0, 0, 1, 1, 1, 1, 1]);
}

#[test]
fn clip_text_features_are_the_encoders_normalised() {
    let mut encoder = ClipTextEncoder::new(&runtime(), &clip_config(), "detector.open_vocab.clip").unwrap();
    let expected = expected();
    let want = expected["clip_text_normalised"].as_object().unwrap();
    let texts: Vec<&str> = want.keys().map(String::as_str).collect();
    let got = encoder.encode(&texts).unwrap();
    assert_eq!(got.len(), texts.len() * 512);
    for (row, text) in texts.iter().enumerate() {
        let w: Vec<f32> = want[*text].as_array().unwrap().iter().map(|v| v.as_f64().unwrap() as f32).collect();
        let cosine: f32 = got[row * 512..(row + 1) * 512].iter().zip(&w).map(|(a, b)| a * b).sum();
        assert!(cosine > 0.9999, "{text:?}: cosine {cosine}");
    }
}

#[test]
fn yolo_world_regions_become_labelled_boxes_in_image_pixels() {
    let out = detect(&yolo_world_config());
    // Regions answer prompts 1, 0, 1, 0 ("stove", "cabinet") at 0.9, 0.7, 0.2, 0.65; 0.2 is under
    // the threshold and region 3 overlaps region 1 (IoU 0.83): NMS. Letterbox r = 2 (640 / 320).
    let got: Vec<_> = out.iter().map(summary).collect();
    assert_eq!(
        got,
        [
            ("stove".to_owned(), NodeKind::Object, 900, [40, 30, 120, 150]),
            ("cabinet".to_owned(), NodeKind::Object, 700, [150, 50, 250, 130]),
        ]
    );
    // Masks from depth (the export has none): the flat depth fills each box.
    assert_eq!(out[0].mask.area(), 80 * 120);
}

#[test]
fn owl_regions_follow_the_prompts_tokens_in_any_order() {
    // Region a answers the prompt whose first CLIP token is that of "stove", "cabinet", "tv"
    // (logits 2, 1, -1 → sigmoid 0.881, 0.731, 0.269 < 0.3). Letterbox r = 3 (960 / 320).
    let want = [
        ("stove".to_owned(), NodeKind::Object, 881, [64, 48, 96, 80]),
        ("cabinet".to_owned(), NodeKind::Object, 731, [128, 80, 192, 112]),
    ];
    for objects in [["cabinet", "stove", "tv"], ["tv", "stove", "cabinet"]] {
        let got: Vec<_> = detect(&owl_config(&objects)).iter().map(summary).collect();
        assert_eq!(got, want, "prompts {objects:?}");
    }
    // A logistic calibration (+1 in logit space) maps every score before the threshold: the
    // stove's to sigmoid(3), the cabinet's to sigmoid(2). The tv region (now 0.5, above the
    // threshold) lies in the letterbox padding (input rows 720..816 of an image 720 high), so it
    // is no detection.
    let mut calibrated = owl_config(&["cabinet", "stove", "tv"]);
    calibrated.calibration = ScoreCalibration { kind: CalibrationKind::Logistic, a: 1.0, b: 1.0 };
    let got: Vec<_> =
        detect(&calibrated).iter().map(|d| (d.label.clone(), (d.score * 1000.0).round() as i64)).collect();
    assert_eq!(got, [("stove".to_owned(), 953), ("cabinet".to_owned(), 881)]);
    // Knowledge-guided part prompts ("cabinet handle" starts with cabinet's token too): the
    // object prompt comes first and keeps the region.
    let mut guided = owl_config(&["cabinet", "stove"]);
    guided.prompts.part_prompts = CandidateMode::Knowledge;
    let labels: Vec<String> = detect(&guided).into_iter().map(|d| d.label).collect();
    assert!(labels.contains(&"stove".to_owned()), "{labels:?}");
}

#[test]
fn a_file_with_another_familys_tensors_is_refused_listing_what_it_has() {
    let knowledge = Arc::new(KnowledgeBase::builtin().unwrap());
    let open = |config: &OpenVocabConfig| {
        OpenVocabDetector::new(&runtime(), config, knowledge.clone(), &TextEncoderConfig::default())
            .map(|_| ())
            .unwrap_err()
            .to_string()
    };
    // The OWL export named as YOLO-World.
    let mut wrong = yolo_world_config();
    wrong.model_path = standin("owl.onnx");
    let err = open(&wrong);
    println!("{err}");
    assert!(err.contains("owl.onnx") && err.contains("yolo_world family"), "{err}");
    assert!(err.contains(r#"no input "images" (detector.open_vocab.input.name"#), "{err}");
    assert!(err.contains(r#"no input "text_features" (detector.open_vocab.family = "yolo_world""#), "{err}");
    assert!(
        err.contains(r#""input_ids" int64 [P, 16]"#) && err.contains(r#""pixel_values" float32 [1, 3, 960, 960]"#),
        "lists the file's tensors: {err}"
    );
    assert!(err.contains(r#""logits" float32 [1, 3, P]"#), "{err}");

    // The right family at the wrong input size: the shape is named.
    let mut wrong = owl_config(&["stove"]);
    wrong.input.width = 768;
    wrong.input.height = 768;
    let err = open(&wrong);
    assert!(
        err.contains(r#"input "pixel_values" (detector.open_vocab.input.name) has shape [1, 3, 960, 960], expected "pixel_values" float32 [1, 3, 768, 768]"#),
        "{err}"
    );

    // A CLIP encoder of another width.
    let mut wrong = yolo_world_config();
    wrong.clip.dim = 768;
    let err = open(&wrong);
    assert!(err.contains("detector.open_vocab.family = \"yolo_world\"") && err.contains("[1, P, 768]"), "{err}");

    // sha256 of the detector and of the CLIP encoder.
    let mut wrong = yolo_world_config();
    wrong.sha256 = Some("0".repeat(64));
    let err = open(&wrong);
    assert!(err.contains("detector.open_vocab.sha256") && err.contains(&"0".repeat(64)), "{err}");
    let mut wrong = yolo_world_config();
    wrong.clip.sha256 = Some("f".repeat(64));
    let err = open(&wrong);
    assert!(err.contains("detector.open_vocab.clip.sha256"), "{err}");

    // A model that is not there: no setup script can fetch it.
    let mut wrong = yolo_world_config();
    wrong.model_path = "/no/such/yolo_world.onnx".into();
    let err = open(&wrong);
    assert!(err.contains("detector.open_vocab.model_path") && err.contains("Bringing your own models"), "{err}");

    // A family fixes text and outputs.
    let mut wrong = yolo_world_config();
    wrong.outputs.scores = "logits".into();
    assert!(open(&wrong).starts_with("detector.open_vocab.outputs: only with family = \"generic\""));
}

#[test]
fn the_family_profiles_load_their_stand_ins_with_only_the_model_paths_changed() {
    for (profile, sets) in [
        (
            "replay-icl-yolo-world.toml",
            vec![
                format!("detector.open_vocab.model_path={}", standin("yolo_world.onnx").display()),
                format!("detector.open_vocab.clip.model_path={}", standin("clip_text.onnx").display()),
            ],
        ),
        ("replay-icl-owl.toml", vec![format!("detector.open_vocab.model_path={}", standin("owl.onnx").display())]),
    ] {
        let loaded = op3dsg_sim::load_profile(Some(&repo().join("profiles").join(profile)), &sets)
            .unwrap_or_else(|e| panic!("{profile}: {e}"));
        let config = &loaded.profile.detector.open_vocab;
        let knowledge = Arc::new(KnowledgeBase::builtin().unwrap());
        let mut detector = OpenVocabDetector::new(&runtime(), config, knowledge, &loaded.profile.text_encoder)
            .unwrap_or_else(|e| panic!("{profile}: {e}"));
        let mut out = Vec::new();
        detector.detect(&frame(), &mut out).unwrap();
        let labels: Vec<&str> = out.iter().map(|d| d.label.as_str()).collect();
        let texts: Vec<&str> = detector.prompts().iter().map(|p| p.text.as_str()).collect();
        // YOLO-World's stand-in answers prompts 1 and 0; OWL's the prompts starting with
        // "stove", "cabinet" (and "tv", under the threshold): of the profile's, only cabinet.
        let want = if profile.contains("yolo") { vec![texts[1], texts[0]] } else { vec!["cabinet"] };
        assert_eq!(labels, want, "{profile}");
        assert!(detector.prompts().iter().any(|p| p.text == "cabinet handle"), "{profile}: knowledge-guided parts");
    }
}

#[test]
fn a_sam_decoder_gives_the_masks_of_the_boxes() {
    let mut config = yolo_world_config();
    config.mask_decoder = Some(MaskDecoderConfig {
        encoder_path: standin("sam_encoder.onnx"),
        decoder_path: standin("sam_decoder.onnx"),
        ..MaskDecoderConfig::default()
    });
    let out = detect(&config);
    // Same detections as with depth masks; the stand-in decoder's mask is the top half of each
    // prompt box, given to it in the encoder's 1024 x 1024 letterbox (r = 3.2) and answered at
    // the image size: so the boxes went there and back.
    let got: Vec<_> = out.iter().map(summary).collect();
    assert_eq!(got[0], ("stove".to_owned(), NodeKind::Object, 900, [40, 30, 120, 150]));
    let m = &out[0].mask;
    assert_eq!(m.area(), 80 * 60);
    assert!(m.contains(40, 30) && m.contains(119, 89) && !m.contains(60, 90) && !m.contains(60, 149));
    let m = &out[1].mask; // cabinet, box [150, 50, 250, 130]
    assert_eq!(m.area(), 100 * 40);

    // The decoder file swapped for the encoder: refused naming the layout and listing the file.
    let mut wrong = yolo_world_config();
    wrong.mask_decoder = Some(MaskDecoderConfig {
        encoder_path: standin("sam_encoder.onnx"),
        decoder_path: standin("sam_encoder.onnx"),
        ..MaskDecoderConfig::default()
    });
    let knowledge = Arc::new(KnowledgeBase::builtin().unwrap());
    let err = OpenVocabDetector::new(&runtime(), &wrong, knowledge, &TextEncoderConfig::default())
        .map(|_| ())
        .unwrap_err()
        .to_string();
    assert!(err.contains("SAM mask decoder layout") && err.contains(r#"no input "point_coords""#), "{err}");
    assert!(err.contains(r#"the file has inputs "images" float32 [1, 3, 1024, 1024]"#), "{err}");
}

/// Stands in for any detector: the detections given, without features.
struct Given(Vec<Detection>);

impl Detector for Given {
    fn detect(
        &mut self,
        _frame: &Frame,
        out: &mut Vec<Detection>,
    ) -> Result<(), op3dsg_runtime::perception::DetectorError> {
        out.clear();
        out.extend(self.0.iter().cloned());
        Ok(())
    }

    fn name(&self) -> &str {
        "given"
    }
}

fn square(label: &str, x0: u32, y0: u32, size: u32) -> Detection {
    Detection {
        label: label.into(),
        kind: NodeKind::Object,
        score: 0.9,
        mask: op3dsg_runtime::perception::Mask {
            x0,
            y0,
            width: size,
            height: size,
            data: vec![1; (size * size) as usize],
        },
        semantic_feature: None,
    }
}

/// The stand-in's embedding of a crop of one colour, worked out here from CLIP's published
/// mean and standard deviation: each plane's normalised value, repeated over the 512 entries
/// (`scripts/reference/model_standins.py`, `clip_image`), L2-normalised.
fn clip_embedding_of(rgb: [u8; 3]) -> Vec<f32> {
    let mean = [0.481_454_66f32, 0.457_827_5, 0.408_210_73];
    let std = [0.268_629_54f32, 0.261_302_6, 0.275_777_1];
    let plane: Vec<f32> = (0..3).map(|c| (f32::from(rgb[c]) / 255.0 - mean[c]) / std[c]).collect();
    let mut e: Vec<f32> = (0..512).map(|j| plane[j % 3]).collect();
    let norm = e.iter().map(|v| v * v).sum::<f32>().sqrt();
    e.iter_mut().for_each(|v| *v /= norm);
    e
}

fn close(a: &[f32], b: &[f32]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-4)
}

#[test]
fn a_region_encoder_gives_each_crop_its_clip_embedding_and_fusion_keeps_it() {
    use op3dsg_runtime::fusion::Fusion as _;
    use op3dsg_runtime::fusion::multiview::MultiViewFusion;
    use op3dsg_runtime::perception::image_input::Resize;
    use op3dsg_runtime::perception::region_encoder::{
        CropBackground, RegionEncoder, RegionEncoderConfig, WithRegionEncoder,
    };

    // Two cabinets on a grey wall 1.5 m away: one red, one blue, each detected exactly.
    let (red, blue) = ([200u8, 30, 40], [20u8, 60, 220]);
    let mut frame = frame();
    frame.rgb.fill(128);
    for (x0, colour) in [(40u32, red), (200, blue)] {
        for y in 60..100u32 {
            for x in x0..x0 + 40 {
                let i = ((y * 320 + x) * 3) as usize;
                frame.rgb[i..i + 3].copy_from_slice(&colour);
            }
        }
    }
    let given = Given(vec![square("cabinet", 40, 60, 40), square("cabinet", 200, 60, 40)]);
    let config = RegionEncoderConfig {
        path: standin("clip_image.onnx"),
        input: ImageInput { resize: Resize::Stretch, ..RegionEncoderConfig::default().input },
        padding_px: 0,
        ..RegionEncoderConfig::default()
    };
    let encoder = RegionEncoder::new(&runtime(), &config, "detector.region_encoder").unwrap_or_else(|e| panic!("{e}"));
    let mut detector = WithRegionEncoder::new(Box::new(given), encoder);
    let mut out = Vec::new();
    detector.detect(&frame, &mut out).expect("detects");
    assert_eq!(detector.name(), "given");
    let features: Vec<&[f32]> = out.iter().map(|d| d.semantic_feature.as_deref().expect("a feature")).collect();
    assert!(close(features[0], &clip_embedding_of(red)), "red crop: {:?}", &features[0][..3]);
    assert!(close(features[1], &clip_embedding_of(blue)), "blue crop: {:?}", &features[1][..3]);

    // The features reach fusion: each node's running mean is its crop's embedding.
    let mut fusion = MultiViewFusion::new(op3dsg_sim::load_profile(None, &[]).unwrap().profile.fusion);
    for _ in 0..3 {
        fusion.integrate(&frame, &op3dsg_drivers::pose::Isometry::IDENTITY, &out);
    }
    let state = fusion.export_state().expect("the map's state");
    assert_eq!(state.nodes.len(), 2, "two cabinets, apart");
    let mut nodes: Vec<_> = state.nodes.iter().collect();
    nodes.sort_by(|a, b| a.points[0][0].total_cmp(&b.points[0][0]));
    assert!(close(&nodes[0].semantic, &clip_embedding_of(red)), "left node: {:?}", &nodes[0].semantic[..3]);
    assert!(close(&nodes[1].semantic, &clip_embedding_of(blue)), "right node");

    // With a grey background and padding the crop holds the wall around the mask too, painted
    // grey: the embedding is then between the colour's and the grey's, no longer the colour's.
    let grey_config = RegionEncoderConfig { padding_px: 20, background: CropBackground::Grey, ..config.clone() };
    let mut encoder = RegionEncoder::new(&runtime(), &grey_config, "detector.region_encoder").unwrap();
    let padded = encoder.encode(&frame, &out[0].mask).unwrap().expect("a feature");
    assert!(!close(&padded, &clip_embedding_of(red)));
    // Crops under min_crop_px give no feature: the detection keeps its detector's.
    let tiny = RegionEncoderConfig { padding_px: 0, min_crop_px: 41, ..config.clone() };
    let mut encoder = RegionEncoder::new(&runtime(), &tiny, "detector.region_encoder").unwrap();
    assert_eq!(encoder.encode(&frame, &out[0].mask).unwrap(), None);

    // Another model in its place is refused at start, naming the key and listing the file.
    let wrong = RegionEncoderConfig { path: standin("sam_encoder.onnx"), ..config };
    let err = RegionEncoder::new(&runtime(), &wrong, "detector.region_encoder").map(|_| ()).unwrap_err().to_string();
    assert!(err.contains("CLIP image encoder layout (detector.region_encoder)"), "{err}");
    assert!(
        err.contains(r#"no input "pixel_values""#) && err.contains(r#""images" float32 [1, 3, 1024, 1024]"#),
        "{err}"
    );
}

#[test]
fn the_region_encoder_profile_loads_its_stand_in_with_only_the_model_path_changed() {
    use op3dsg_runtime::perception::region_encoder::RegionEncoder;
    let set = format!("detector.region_encoder.path={}", standin("clip_image.onnx").display());
    let loaded = op3dsg_sim::load_profile(Some(&repo().join("profiles/replay-icl-clip-regions.toml")), &[set])
        .unwrap_or_else(|e| panic!("{e}"));
    let config = loaded.profile.detector.region_encoder.as_ref().expect("[detector.region_encoder]");
    let mut encoder =
        RegionEncoder::new(&runtime(), config, "detector.region_encoder").unwrap_or_else(|e| panic!("{e}"));
    let mut frame = frame();
    frame.rgb.fill(90);
    let mask = square("chair", 100, 80, 30).mask;
    let feature = encoder.encode(&frame, &mask).unwrap().expect("a feature");
    // The crop and its letterbox padding are both grey-ish; the profile's letterbox pads with
    // CLIP's mean grey, which normalises to about 0, so the direction is the crop's.
    assert!(close(&feature, &clip_embedding_of([90, 90, 90])), "{:?}", &feature[..3]);
}

fn tagger_config() -> op3dsg_runtime::perception::tagger::TaggerConfig {
    op3dsg_runtime::perception::tagger::TaggerConfig {
        path: standin("tagger.onnx"),
        tags_path: standin("tagger_tags.txt"),
        ..Default::default()
    }
}

fn painted(rgb: [u8; 3]) -> Frame {
    let mut frame = frame();
    frame.rgb.chunks_exact_mut(3).for_each(|px| px.copy_from_slice(&rgb));
    frame
}

#[test]
fn an_image_tagger_seeds_each_keyframes_object_tags_and_their_part_prompts() {
    use op3dsg_runtime::perception::tagger::{ImageTagger, TaggerConfig};
    const KEY: &str = "detector.open_vocab.tagger";
    let (red, blue) = (painted([200, 30, 40]), painted([20, 60, 220]));
    let names = |tags: Vec<(String, f32)>| tags.into_iter().map(|(t, _)| t).collect::<Vec<_>>();

    // The tagger alone: the stand-in's logits from the image's mean colour (model_standins.py),
    // sigmoid, RAM's threshold 0.68, highest first.
    let mut tagger = ImageTagger::new(&runtime(), &tagger_config(), KEY).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(names(tagger.tag(&red).unwrap()), ["cabinet", "room", "lamp"]);
    assert_eq!(names(tagger.tag(&blue).unwrap()), ["stove", "room", "lamp"]);
    let config = TaggerConfig { ignore: vec!["Room".into()], max_tags: 1, ..tagger_config() };
    let mut tagger = ImageTagger::new(&runtime(), &config, KEY).unwrap();
    assert_eq!(names(tagger.tag(&red).unwrap()), ["cabinet"]);

    // In the detector: no fixed object list; each keyframe's tags give its prompts, the
    // knowledge base their parts. YOLO-World's stand-in answers prompts 1 and 0.
    let mut config = yolo_world_config();
    config.prompts.objects.clear();
    config.prompts.part_prompts = CandidateMode::Knowledge;
    config.tagger = Some(TaggerConfig { ignore: vec!["room".into()], ..tagger_config() });
    let knowledge = Arc::new(KnowledgeBase::builtin().unwrap());
    let mut detector = OpenVocabDetector::new(&runtime(), &config, knowledge, &TextEncoderConfig::default())
        .unwrap_or_else(|e| panic!("{e}"));
    for (frame, object, part, other) in [
        (&red, "cabinet", "cabinet handle", "stove"),
        (&blue, "stove", "stove knob", "cabinet"),
        (&red, "cabinet", "cabinet handle", "stove"),
    ] {
        let mut out = Vec::new();
        detector.detect(frame, &mut out).expect("detects");
        let texts: Vec<String> = detector.prompts().iter().map(|p| p.text.clone()).collect();
        assert_eq!(texts[..2], [object.to_owned(), "lamp".to_owned()], "{texts:?}");
        assert!(texts.iter().any(|t| t == part), "{object}: knowledge-guided parts in {texts:?}");
        assert!(!texts.iter().any(|t| t.starts_with(other)), "{object}: no {other} prompts in {texts:?}");
        let labels: Vec<&str> = out.iter().map(|d| d.label.as_str()).collect();
        assert_eq!(labels, ["lamp", object]);
    }

    // A tag list that does not fit the model, and a model with its vocabulary built in, are
    // refused at start naming the key.
    let dir = std::env::temp_dir().join(format!("op3dsg-tagger-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let short = dir.join("tags.txt");
    std::fs::write(&short, "cabinet\nstove\n").unwrap();
    let err = ImageTagger::new(&runtime(), &TaggerConfig { tags_path: short, ..tagger_config() }, KEY)
        .map(|_| ())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("detector.open_vocab.tagger.tags_path") && err.contains("lists 2 tags") && err.contains("has 5"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).ok();
    let mut baked = OpenVocabConfig { tagger: Some(tagger_config()), ..OpenVocabConfig::default() };
    baked.text.kind = op3dsg_runtime::perception::open_vocab::TextInputKind::None;
    baked.prompts.objects = vec!["cabinet".into()];
    let err = baked.validate("detector.open_vocab").unwrap_err();
    assert!(err.starts_with("detector.open_vocab.tagger: needs a model that takes its vocabulary"), "{err}");
}

#[test]
fn the_tagged_profile_loads_its_stand_ins_with_only_the_model_paths_changed() {
    let sets = vec![
        format!("detector.open_vocab.model_path={}", standin("yolo_world.onnx").display()),
        format!("detector.open_vocab.clip.model_path={}", standin("clip_text.onnx").display()),
        format!("detector.open_vocab.tagger.path={}", standin("tagger.onnx").display()),
        format!("detector.open_vocab.tagger.tags_path={}", standin("tagger_tags.txt").display()),
    ];
    let profile = repo().join("profiles/replay-icl-yolo-world-tagged.toml");
    let loaded = op3dsg_sim::load_profile(Some(&profile), &sets).unwrap_or_else(|e| panic!("{e}"));
    let knowledge = Arc::new(KnowledgeBase::builtin().unwrap());
    let config = &loaded.profile.detector.open_vocab;
    let mut detector = OpenVocabDetector::new(&runtime(), config, knowledge, &loaded.profile.text_encoder)
        .unwrap_or_else(|e| panic!("{e}"));
    let mut out = Vec::new();
    detector.detect(&painted([20, 60, 220]), &mut out).unwrap();
    // "room" is ignored by the profile: stove and lamp are the tags.
    let labels: Vec<&str> = out.iter().map(|d| d.label.as_str()).collect();
    assert_eq!(labels, ["lamp", "stove"]);
    assert!(detector.prompts().iter().any(|p| p.text == "stove knob"));
}

#[test]
fn an_efficient_sam_decoder_gives_the_best_candidate_mask_of_each_box() {
    use op3dsg_runtime::perception::image_input::Resize;
    use op3dsg_runtime::perception::mask_decoder::MaskDecoderLayout;
    let efficient = || MaskDecoderConfig {
        layout: MaskDecoderLayout::EfficientSam,
        encoder_path: standin("efficient_sam_encoder.onnx"),
        decoder_path: standin("efficient_sam_decoder.onnx"),
        input: ImageInput {
            name: "batched_images".into(),
            width: 1024,
            height: 1024,
            resize: Resize::Stretch,
            scale: 1.0 / 255.0,
            mean: [0.0; 3],
            std: [1.0; 3],
            ..ImageInput::default()
        },
        ..MaskDecoderConfig::default()
    };
    let mut config = yolo_world_config();
    config.mask_decoder = Some(efficient());
    let out = detect(&config);
    // The stand-in's candidates are the box, its left half and its top half, with predicted IoUs
    // 0.5, 0.9, 0.7: the left half is taken, and it is the left half of the box in image pixels
    // only if the corners went in unscaled.
    let got: Vec<_> = out.iter().map(summary).collect();
    assert_eq!(got[0], ("stove".to_owned(), NodeKind::Object, 900, [40, 30, 120, 150]));
    let m = &out[0].mask;
    assert_eq!(m.area(), 40 * 120);
    assert!(m.contains(40, 30) && m.contains(79, 149) && !m.contains(80, 30));
    assert_eq!(out[1].mask.area(), 50 * 80); // cabinet, box [150, 50, 250, 130]

    // SAM's decoder with the EfficientSAM layout set: refused naming the layout key.
    let mut wrong = yolo_world_config();
    wrong.mask_decoder = Some(MaskDecoderConfig { decoder_path: standin("sam_decoder.onnx"), ..efficient() });
    let knowledge = Arc::new(KnowledgeBase::builtin().unwrap());
    let err = OpenVocabDetector::new(&runtime(), &wrong, knowledge, &TextEncoderConfig::default())
        .map(|_| ())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("EfficientSAM mask decoder layout") && err.contains(r#"no input "batched_point_coords""#),
        "{err}"
    );
    assert!(err.contains(r#"layout = "efficient_sam""#), "{err}");
}
