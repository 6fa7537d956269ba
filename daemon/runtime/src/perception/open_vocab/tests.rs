use super::*;
use crate::perception::candidates::CandidateMode;

#[test]
fn knowledge_guided_prompts_add_each_tagged_objects_parts() {
    let kb = Arc::new(KnowledgeBase::builtin().unwrap());
    let config = PromptConfig {
        objects: vec!["cabinet".into(), "Stove".into()],
        parts: vec!["Door Handle".into()],
        part_prompts: CandidateMode::Knowledge,
    };
    let prompts = prompt_list(&config, kb.clone());
    let texts: Vec<&str> = prompts.iter().map(|p| p.text.as_str()).collect();
    assert_eq!(&texts[..2], ["cabinet", "stove"]);
    assert!(prompts[..2].iter().all(|p| p.kind == NodeKind::Object));
    let generated = prompts.iter().filter(|p| p.text.starts_with("cabinet ") || p.text.starts_with("stove "));
    assert!(generated.clone().count() >= 3 && generated.clone().all(|p| p.kind == NodeKind::Part));
    assert!(texts.contains(&"light switch"), "small things a tagger misses are added: {texts:?}");
    assert!(
        texts.contains(&"cabinet handle") && texts.contains(&"cabinet knob") && texts.contains(&"stove knob"),
        "{texts:?}"
    );
    assert_eq!(texts.last(), Some(&"door handle"), "listed parts come last, normalised");
    let plain = prompt_list(&PromptConfig { part_prompts: CandidateMode::All, ..config }, kb);
    assert_eq!(plain.iter().map(|p| p.text.as_str()).collect::<Vec<_>>(), ["cabinet", "stove", "door handle"]);
}

#[test]
fn masks_are_sampled_through_the_placement() {
    // 4x4 mask over an 8x8 input; the frame was letterboxed at r = 0.5 (16x16 image).
    let mut plane = vec![0.0f32; 16];
    plane[5] = 0.9; // mask cell (1, 1) = input pixels 2..4 = image pixels 4..8
    let spec = ImageInput { width: 8, height: 8, ..ImageInput::default() };
    let bbox = PixelBox { x0: 0, y0: 0, x1: 16, y1: 16 };
    let mask = mask_from_probabilities(&plane, 4, 4, bbox, Placement { sx: 0.5, sy: 0.5 }, &spec, 0.5).unwrap();
    assert_eq!(mask.area(), 16);
    assert!(mask.contains(4, 4) && mask.contains(7, 7) && !mask.contains(8, 8) && !mask.contains(3, 4));
    assert!(mask_from_probabilities(&plane, 4, 4, bbox, Placement { sx: 0.5, sy: 0.5 }, &spec, 0.95).is_none());
}

#[test]
fn validation_names_the_field() {
    let config = OpenVocabConfig::default();
    assert_eq!(
        config.validate("detector.open_vocab").unwrap_err(),
        "detector.open_vocab.prompts: list at least one object tag or part prompt (or set a tagger)"
    );
    let config = OpenVocabConfig {
        prompts: PromptConfig { objects: vec!["tv".into()], ..PromptConfig::default() },
        mask_threshold: 1.0,
        ..OpenVocabConfig::default()
    };
    assert!(config.validate("detector.open_vocab").unwrap_err().starts_with("detector.open_vocab.mask_threshold"));
}
