//! The library and model files a profile names, as the daemon will open them (`--print-config`).
//!
//! Model and library paths are found when a stage opens them (`crate::onnx::resolve_path`: the
//! working directory, the installed model store, the source tree), not when the profile loads;
//! [`LoadedProfile::effective_with_files`] does that search for each, so what `--print-config`
//! prints is the file the daemon will read, or a note saying where it looked.

use std::path::Path;

use super::LoadedProfile;
use crate::onnx::{ORT_LIB_ENV, OnnxError, resolve_path};

/// Keys whose file is looked up by `crate::onnx::resolve_path` when a stage opens it.
pub const LOOKUP_KEYS: &[&str] = &[
    "onnx.library_path",
    "text_encoder.model_path",
    "text_encoder.tokenizer_path",
    "detector.yolox.model_path",
    "detector.yolox.mask_decoder.encoder_path",
    "detector.yolox.mask_decoder.decoder_path",
    "detector.open_vocab.model_path",
    "detector.open_vocab.clip.model_path",
    "detector.open_vocab.clip.tokenizer_path",
    "detector.open_vocab.mask_decoder.encoder_path",
    "detector.open_vocab.mask_decoder.decoder_path",
    "detector.open_vocab.tagger.path",
    "detector.open_vocab.tagger.tags_path",
    "detector.open_vocab.tagger.thresholds_path",
    "detector.region_encoder.path",
];

impl LoadedProfile {
    /// The effective profile with each path of [`LOOKUP_KEYS`] it holds replaced by the file the
    /// daemon will open, and one note per path that was not found (`key "path" not found:
    /// looked for ...`) or is overridden (`OP3DSG_ORT_LIB`).
    pub fn effective_with_files(&self) -> (toml::Table, Vec<String>) {
        let mut table = self.effective.clone();
        let mut notes = Vec::new();
        for key in LOOKUP_KEYS {
            let Some(toml::Value::String(value)) = lookup_mut(&mut table, key) else { continue };
            let mut configured = value.clone();
            if *key == "onnx.library_path"
                && let Some(env) = std::env::var_os(ORT_LIB_ENV).filter(|v| !v.is_empty())
            {
                configured = env.to_string_lossy().into_owned();
                notes.push(format!("{key}: {ORT_LIB_ENV}={configured} overrides {value:?}"));
            }
            match resolve_path(Path::new(&configured), "file", key) {
                Ok(found) => *value = found.display().to_string(),
                Err(OnnxError::FileMissing { looked_for, .. }) => notes.push(format!(
                    "{key} {configured:?} not found: looked for {}",
                    looked_for.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
                )),
                Err(other) => notes.push(format!("{key}: {other}")),
            }
        }
        (table, notes)
    }
}

/// The value at a dotted key of `table`, if every table on the way exists.
fn lookup_mut<'a>(table: &'a mut toml::Table, key: &str) -> Option<&'a mut toml::Value> {
    let (parents, last) = match key.rsplit_once('.') {
        Some((parents, last)) => (Some(parents), last),
        None => (None, key),
    };
    let mut current = table;
    for part in parents.into_iter().flat_map(|p| p.split('.')) {
        current = current.get_mut(part)?.as_table_mut()?;
    }
    current.get_mut(last)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn found_files_replace_the_configured_path_and_missing_ones_are_noted() {
        let dir = tempfile::tempdir().unwrap();
        let model = dir.path().join("model.onnx");
        std::fs::write(&model, b"x").unwrap();
        let overrides = [
            "text_encoder.model_path=\"profiles/base.toml\"".to_owned(),
            format!("text_encoder.tokenizer_path={:?}", model.display().to_string()),
            "onnx.library_path=\"no/such/libonnxruntime.so\"".to_owned(),
        ];
        let loaded = super::super::load(None, &overrides).unwrap();
        let (table, notes) = loaded.effective_with_files();
        let text_encoder = table["text_encoder"].as_table().unwrap();
        // A relative path found in the source tree becomes that absolute file.
        let found = Path::new(text_encoder["model_path"].as_str().unwrap());
        assert!(found.is_absolute() && found.ends_with("profiles/base.toml"), "{}", found.display());
        assert_eq!(text_encoder["tokenizer_path"].as_str(), Some(model.display().to_string().as_str()));
        // A missing one keeps its value and gets a note naming the key and the places.
        assert_eq!(table["onnx"]["library_path"].as_str(), Some("no/such/libonnxruntime.so"));
        let note = notes.iter().find(|n| n.starts_with("onnx.library_path")).expect("a note on the library");
        assert!(note.contains("\"no/such/libonnxruntime.so\" not found: looked for /"), "{note}");
    }
}
