use super::*;

fn kb() -> KnowledgeBase {
    KnowledgeBase::builtin().expect("built-in knowledge base")
}

#[test]
fn builtin_has_paper_scale() {
    let kb = kb();
    assert!(kb.objects().len() >= 85, "{} object categories", kb.objects().len());
    assert!(kb.parts().len() >= 60, "{} part categories", kb.parts().len());
    assert!(kb.pair_count() >= 190, "{} pairs", kb.pair_count());
    // Every part category is used by some object or remote template.
    for (i, part) in kb.parts().iter().enumerate() {
        let id = PartId(i as u16);
        let used = kb.objects().iter().any(|o| o.parts.iter().any(|p| p.part == id))
            || kb.remote_templates().iter().any(|r| r.source == Category::Part(id));
        assert!(used, "part \"{}\" is used nowhere", part.name);
    }
}

#[test]
fn resolution_rules() {
    let kb = kb();
    let name = |label: &str| match kb.resolve(label).map(|r| r.category) {
        Some(Category::Object(id)) => kb.object(id).name.clone(),
        Some(Category::Part(id)) => kb.part(id).name.clone(),
        None => "-".into(),
    };
    assert_eq!(name("  Refrigerator "), "fridge");
    assert_eq!(name("drawers"), "drawer");
    assert_eq!(name("trash_cans"), "trash can");
    assert_eq!(name("Power-Outlet"), "outlet");
    assert_eq!(name("microwave oven"), "microwave");
    assert_eq!(name("cabinet handles"), "handle");
    assert_eq!(name("unicorn"), "-");
    let handle = kb.resolve("cabinet handle").unwrap();
    assert_eq!(handle.object_hint.map(|o| kb.object(o).name.as_str()), Some("cabinet"));
    let deep = kb.resolve("tv stand drawer handle").unwrap();
    assert_eq!(deep.object_hint.map(|o| kb.object(o).name.as_str()), Some("drawer"));
    let brass = kb.resolve("brass knob").unwrap();
    assert_eq!((brass.part().map(|p| kb.part(p).name.as_str()), brass.object_hint), (Some("knob"), None));
}

#[test]
fn affordances_depend_on_the_parent() {
    let kb = kb();
    let knob = kb.resolve("knob").unwrap().part().unwrap();
    let cabinet = kb.object_category("cabinet").unwrap();
    let drawer = kb.object_category("drawer").unwrap();
    let names = |bits| op3dsg_ipc_types::affordance_names(bits).collect::<Vec<_>>();
    assert_eq!(names(kb.part_affordances(knob, Some(cabinet))), ["rotate", "pinch_pull"]);
    assert_eq!(names(kb.part_affordances(knob, Some(drawer))), ["pinch_pull"]);
    assert_eq!(names(kb.part_affordances(knob, None)), ["rotate"]);
}

fn load(objects: &str, parts: &str, remote: &str) -> Result<KnowledgeBase, KnowledgeError> {
    KnowledgeBase::from_sources(KnowledgeSources {
        objects: ("objects.toml", objects),
        parts: ("parts.toml", parts),
        remote: ("remote.toml", remote),
    })
}

const PARTS: &str = "[[part]]\nname = \"knob\"\naffordances = [\"rotate\"]\n";
const OBJECTS: &str = "[[object]]\nname = \"stove\"\nparts = [{ part = \"knob\", relation = \"rotate to adjust the setting or temperature\" }]\n";

#[test]
fn load_dir_reads_the_three_files_and_names_the_path_in_errors() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join(OBJECTS_FILE), BUILTIN_OBJECTS_TOML).unwrap();
    std::fs::write(dir.path().join(PARTS_FILE), BUILTIN_PARTS_TOML).unwrap();
    std::fs::write(dir.path().join(REMOTE_FILE), BUILTIN_REMOTE_TOML).unwrap();
    let kb = KnowledgeBase::load_dir(dir.path()).unwrap();
    assert_eq!(kb.pair_count(), KnowledgeBase::builtin().unwrap().pair_count());
    let bad = BUILTIN_REMOTE_TOML.replace("\"remote to control\"", "\"beam to control\"");
    std::fs::write(dir.path().join(REMOTE_FILE), bad).unwrap();
    let error = KnowledgeBase::load_dir(dir.path()).unwrap_err();
    assert_eq!(error.file, dir.path().join(REMOTE_FILE).display().to_string());
    assert!(error.path.ends_with(".relation"), "{error}");
    std::fs::remove_file(dir.path().join(PARTS_FILE)).unwrap();
    let missing = KnowledgeBase::load_dir(dir.path()).unwrap_err();
    assert!(missing.file.ends_with(PARTS_FILE), "{missing}");
}

#[test]
fn minimal_tables_load() {
    let kb = load(OBJECTS, PARTS, "").unwrap();
    assert_eq!(kb.pair_count(), 1);
}

#[test]
fn validation_errors_name_file_entry_and_field() {
    let cases: [(&str, &str, &str, &str); 9] = [
        (
            OBJECTS,
            "[[part]]\nname = \"knob\"\naffordances = [\"twist\"]\n",
            "",
            "parts.toml: part \"knob\".affordances[0]: \"twist\" is not a canonical affordance",
        ),
        (
            "[[object]]\nname = \"stove\"\nparts = [{ part = \"knob\", relation = \"twist it\" }]\n",
            PARTS,
            "",
            "objects.toml: object \"stove\".parts[0].relation: \"twist it\" is not a canonical functional relation",
        ),
        (
            "[[object]]\nname = \"stove\"\nparts = [{ part = \"dial\" }]\n",
            PARTS,
            "",
            "objects.toml: object \"stove\".parts[0].part: unknown part category \"dial\"",
        ),
        (
            "[[object]]\nname = \"stove\"\nsynonyms = [\"knob\"]\n",
            PARTS,
            "",
            "objects.toml: object \"stove\".synonyms[0]: \"knob\" is already defined at parts.toml: part \"knob\".name",
        ),
        (
            "[[object]]\nname = \"stove\"\nparts = [{ part = \"knob\" }, { part = \"knob\" }]\n",
            PARTS,
            "",
            "objects.toml: object \"stove\".parts[1].part: duplicate pair",
        ),
        (
            OBJECTS,
            PARTS,
            "[[remote]]\nsource = \"knob\"\ntargets = [\"oven\"]\nrelation = \"provide power\"\nmax_distance_m = 1.0\nconfidence = 0.5\n",
            "remote.toml: remote[0] \"knob\".targets[0]: unknown object category \"oven\"",
        ),
        (
            OBJECTS,
            PARTS,
            "[[remote]]\nsource = \"remote\"\ntargets = [\"stove\"]\nrelation = \"provide power\"\nmax_distance_m = 1.0\nconfidence = 0.5\n",
            "remote.toml: remote[0] \"remote\".source: unknown object or part category",
        ),
        (
            OBJECTS,
            PARTS,
            "[[remote]]\nsource = \"knob\"\ntargets = [\"stove\"]\nrelation = \"part of\"\nmax_distance_m = 1.0\nconfidence = 0.5\n",
            "remote.toml: remote[0] \"knob\".relation: \"part of\" is not a canonical functional relation",
        ),
        (OBJECTS, "[[part]]\nname = \"Knob\"\n", "", "parts.toml: part \"Knob\".name: \"Knob\" is not normalised"),
    ];
    for (objects, parts, remote, expected) in cases {
        let error = load(objects, parts, remote).expect_err(expected).to_string();
        assert!(error.starts_with(expected), "got: {error}\nexpected: {expected}");
    }
    let unknown_field = load("[[object]]\nname = \"stove\"\ncolour = \"red\"\n", PARTS, "").unwrap_err();
    assert_eq!(unknown_field.file, "objects.toml");
    assert!(unknown_field.message.contains("colour"), "{unknown_field}");
}
