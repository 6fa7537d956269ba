//! An image tagger (`[detector.open_vocab.tagger]`): a whole-image multi-label classifier such
//! as RAM (Recognize Anything) whose tags for a keyframe become that keyframe's object tags, the
//! seeds of the knowledge-guided prompts ([`super::open_vocab`], "Prompts"): the detector then
//! looks for the objects the tagger saw and the interactive parts the knowledge base gives them,
//! as the paper's pipeline does, instead of a fixed object list.
//!
//! # Contract (RAM / RAM++ / Tag2Text-style exports)
//!
//! - in `input.name` (`images`) float32 `[1, 3, H, W]`: RGB, `input.resize` (RAM: 384 x 384,
//!   `stretch`), `(v * scale - mean) / std` with ImageNet's mean `[0.485, 0.456, 0.406]` and std
//!   `[0.229, 0.224, 0.225]` on 0..1 values (the defaults);
//! - out `output` float32 `[1, T]` (or `[T]`): one value per tag, logits (`activation =
//!   "sigmoid"`, RAM's) or probabilities (`"none"`);
//! - `tags_path`: a UTF-8 text file with the `T` tag names, one per line in output order (RAM
//!   ships `ram_tag_list.txt`); a tag is normalised like every label (lower case, one space).
//!
//! A tag is kept when its probability reaches its threshold: `threshold` (RAM's default 0.68),
//! or its line in `thresholds_path` (optional, one number per line in the same order, like RAM++'s
//! per-class thresholds). At most `max_tags` are kept, highest first; `ignore` drops tags that
//! are no objects a robot acts on (RAM tags scenes and materials too: "room", "floor", "wood").
//! The object tags of `[detector.open_vocab.prompts] objects` are always added first.
//!
//! Export: the `recognize-anything` package's model traced with `torch.onnx.export` (input
//! `images`, its tag logits as output `logits`, before its own sigmoid and thresholds).

use std::path::{Path, PathBuf};

use op3dsg_drivers::frame::Frame;
use ort::session::Session;
use serde::{Deserialize, Serialize};

use super::image_input::{ImageInput, Resize, prepare, run_on_image};
use crate::onnx::contract::{self, Dim, FLOAT, TensorSpec, user_model};
use crate::onnx::{OnnxError, OnnxRuntime, resolve_path};

/// How the tagger's output becomes probabilities.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TagActivation {
    /// Logits: a sigmoid gives the probability (RAM).
    #[default]
    Sigmoid,
    /// Already probabilities.
    None,
}

/// `[detector.open_vocab.tagger]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TaggerConfig {
    /// The tagger (ONNX). Relative paths in a profile file are relative to that file.
    pub path: PathBuf,
    /// Optional sha256 of `path`, checked at start.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sha256: Option<String>,
    /// The tag names, one per line in output order.
    pub tags_path: PathBuf,
    /// Optional per-tag thresholds, one per line in the same order.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub thresholds_path: Option<PathBuf>,
    /// The image input.
    pub input: ImageInput,
    /// The tag output's name.
    pub output: String,
    /// Logits or probabilities.
    pub activation: TagActivation,
    /// Probability a tag needs (unless `thresholds_path` gives its own). (0, 1).
    pub threshold: f32,
    /// At most this many tags per keyframe, highest first.
    pub max_tags: usize,
    /// Tags never used as object tags (scenes, materials, colours).
    pub ignore: Vec<String>,
    /// ONNX Runtime intra-op threads of the session.
    pub intra_op_threads: usize,
}

impl Default for TaggerConfig {
    fn default() -> Self {
        Self {
            path: PathBuf::from("ram_swin_large_14m.onnx"),
            sha256: None,
            tags_path: PathBuf::from("ram_tag_list.txt"),
            thresholds_path: None,
            input: ImageInput {
                name: "images".to_owned(),
                width: 384,
                height: 384,
                resize: Resize::Stretch,
                scale: 1.0 / 255.0,
                mean: [0.485, 0.456, 0.406],
                std: [0.229, 0.224, 0.225],
                ..ImageInput::default()
            },
            output: "logits".to_owned(),
            activation: TagActivation::Sigmoid,
            threshold: 0.68,
            max_tags: 12,
            ignore: Vec::new(),
            intra_op_threads: 1,
        }
    }
}

impl TaggerConfig {
    /// Range checks; errors are `path.field: message`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        for (field, value) in [("path", &self.path), ("tags_path", &self.tags_path)] {
            if value.as_os_str().is_empty() {
                return Err(format!("{path}.{field}: must not be empty"));
            }
        }
        contract::validate_sha256(&format!("{path}.sha256"), self.sha256.as_deref())?;
        self.input.validate(&format!("{path}.input"))?;
        if self.output.trim().is_empty() {
            return Err(format!("{path}.output: must not be empty"));
        }
        if !(self.threshold > 0.0 && self.threshold < 1.0) {
            return Err(format!("{path}.threshold: must be within (0, 1), got {}", self.threshold));
        }
        if !(1..=256).contains(&self.max_tags) {
            return Err(format!("{path}.max_tags: must be within [1, 256], got {}", self.max_tags));
        }
        if !(1..=64).contains(&self.intra_op_threads) {
            return Err(format!("{path}.intra_op_threads: must be within [1, 64], got {}", self.intra_op_threads));
        }
        Ok(())
    }
}

/// One worker's tagger session, its tag names and thresholds.
pub struct ImageTagger {
    session: Session,
    config: TaggerConfig,
    path: PathBuf,
    tags: Vec<String>,
    thresholds: Vec<f32>,
    /// Whether each tag is in `ignore`.
    ignored: Vec<bool>,
    input: Vec<f32>,
    /// The last output, reused.
    values: Vec<f32>,
}

impl std::fmt::Debug for ImageTagger {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ImageTagger").field("path", &self.path).field("tags", &self.tags.len()).finish_non_exhaustive()
    }
}

/// The lines of a text file, trimmed, or an error naming the file and the key.
fn lines(path: &Path, key: &str) -> Result<Vec<String>, OnnxError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| OnnxError::InvalidConfig(format!("{key}: cannot read {}: {e}", path.display())))?;
    Ok(text.lines().map(str::trim).filter(|l| !l.is_empty()).map(str::to_owned).collect())
}

impl ImageTagger {
    /// Loads `config`'s model, tags and thresholds (section `key`), checking the sha256, the
    /// tensors, and that the files have one line per output.
    pub fn new(runtime: &OnnxRuntime, config: &TaggerConfig, key: &str) -> Result<Self, OnnxError> {
        config.validate(key).map_err(OnnxError::InvalidConfig)?;
        let (session, path) = contract::open_user_model(
            runtime,
            &config.path,
            config.sha256.as_deref(),
            "image tagger",
            (&format!("{key}.path"), &format!("{key}.sha256")),
            config.intra_op_threads,
        )?;
        let image =
            Some(vec![Dim::Is(1), Dim::Is(3), Dim::Is(config.input.height.into()), Dim::Is(config.input.width.into())]);
        contract::check(
            &session,
            &path,
            &format!("the image tagger layout ({key})"),
            &[TensorSpec::new(&config.input.name, &format!("{key}.input.name"), FLOAT, image)],
            &[TensorSpec::new(&config.output, &format!("{key}.output"), FLOAT, None)],
        )?;
        let tags_key = format!("{key}.tags_path");
        let tags_path = resolve_path(&config.tags_path, "image tagger's tag list", &tags_key).map_err(user_model)?;
        let tags: Vec<String> = lines(&tags_path, &tags_key)?.iter().map(|t| crate::knowledge::normalise(t)).collect();
        if tags.is_empty() {
            return Err(OnnxError::InvalidConfig(format!("{tags_key}: {} lists no tag", tags_path.display())));
        }
        // The output's tag count, when the file fixes it.
        let width = session
            .outputs()
            .iter()
            .find(|o| o.name() == config.output)
            .and_then(|o| o.dtype().tensor_shape().and_then(|s| s.last().copied()))
            .filter(|d| *d > 0);
        if let Some(t) = width
            && t as usize != tags.len()
        {
            return Err(OnnxError::InvalidConfig(format!(
                "{tags_key}: {} lists {} tags, the model's output \"{}\" has {t} ({})",
                tags_path.display(),
                tags.len(),
                config.output,
                path.display()
            )));
        }
        let thresholds = match &config.thresholds_path {
            None => vec![config.threshold; tags.len()],
            Some(p) => {
                let k = format!("{key}.thresholds_path");
                let resolved = resolve_path(p, "image tagger's thresholds", &k).map_err(user_model)?;
                let values = lines(&resolved, &k)?;
                if values.len() != tags.len() {
                    return Err(OnnxError::InvalidConfig(format!(
                        "{k}: {} has {} lines, the tag list {}",
                        resolved.display(),
                        values.len(),
                        tags.len()
                    )));
                }
                values
                    .iter()
                    .enumerate()
                    .map(|(i, v)| match v.parse::<f32>() {
                        Ok(t) if t > 0.0 && t < 1.0 => Ok(t),
                        _ => Err(OnnxError::InvalidConfig(format!(
                            "{k}: {} line {}: {v:?} is not a threshold within (0, 1)",
                            resolved.display(),
                            i + 1
                        ))),
                    })
                    .collect::<Result<_, _>>()?
            }
        };
        let ignore: Vec<String> = config.ignore.iter().map(|t| crate::knowledge::normalise(t)).collect();
        let ignored = tags.iter().map(|t| ignore.contains(t)).collect();
        Ok(Self {
            session,
            config: config.clone(),
            path,
            tags,
            thresholds,
            ignored,
            input: Vec::new(),
            values: Vec::new(),
        })
    }

    /// The tag names, in output order.
    pub fn tags(&self) -> &[String] {
        &self.tags
    }

    /// The tags of `frame` (probability at or above the tag's threshold, not ignored), highest
    /// first, at most `max_tags`, each with its probability.
    pub fn tag(&mut self, frame: &Frame) -> Result<Vec<(String, f32)>, String> {
        let intr = frame.intrinsics;
        let spec = &self.config.input;
        prepare(&frame.rgb, intr.width, intr.height, spec, &mut self.input);
        let output = self.config.output.as_str();
        let shape =
            run_on_image(&mut self.session, spec, &self.input, (output, &mut self.values), "image tagger", &self.path)?;
        let values = &self.values;
        let path = self.path.display();
        if values.len() != self.tags.len() || shape.len() > 2 {
            return Err(format!(
                "image tagger ({path}): output \"{}\" has shape {shape:?}, the tag list {} tags",
                self.config.output,
                self.tags.len()
            ));
        }
        let mut kept: Vec<(usize, f32)> = values
            .iter()
            .enumerate()
            .map(|(i, &v)| {
                let p = match self.config.activation {
                    TagActivation::Sigmoid => 1.0 / (1.0 + (-v).exp()),
                    TagActivation::None => v,
                };
                (i, p)
            })
            .filter(|&(i, p)| p >= self.thresholds[i] && !self.ignored[i])
            .collect();
        // Highest first; ties in output order.
        kept.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        kept.truncate(self.config.max_tags);
        Ok(kept.into_iter().map(|(i, p)| (self.tags[i].clone(), p)).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_settings_are_refused_naming_the_field() {
        let check = |c: TaggerConfig| c.validate("detector.open_vocab.tagger").unwrap_err();
        let base = TaggerConfig::default();
        assert!(check(TaggerConfig { tags_path: PathBuf::new(), ..base.clone() }).contains(".tags_path"));
        assert!(check(TaggerConfig { threshold: 1.0, ..base.clone() }).contains(".threshold"));
        assert!(check(TaggerConfig { max_tags: 0, ..base.clone() }).contains(".max_tags"));
        assert!(check(TaggerConfig { output: String::new(), ..base }).contains(".output"));
    }
}
