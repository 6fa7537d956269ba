//! Checks that a model file is what its profile section says, before the first frame: the
//! optional `sha256` of the file, and the names, element types and shapes of its inputs and
//! outputs against a model family's contract. A mismatch is an [`OnnxError::BadModel`] naming
//! the profile key and listing every tensor the file has (`"images" float32 [1, 3, 640, 640]`),
//! so a user who exported the wrong graph sees what they exported.

use std::path::Path;

use ort::session::Session;
use ort::value::{TensorElementType, ValueType};

use super::OnnxError;

/// One dimension of a contract.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dim {
    /// Exactly this many (a dynamic dimension in the file is accepted: checked when run).
    Is(i64),
    /// Any size; the letter is how the docs and messages name it (`N`, `A`).
    Any(&'static str),
}

/// A tensor a contract needs.
#[derive(Debug, Clone, PartialEq)]
pub struct TensorSpec {
    /// Tensor name in the file.
    pub name: String,
    /// The profile key that names it (or that selects the contract).
    pub key: String,
    /// Element types accepted.
    pub dtypes: &'static [TensorElementType],
    /// Shape; `None`: any rank.
    pub dims: Option<Vec<Dim>>,
}

/// Float32 only.
pub const FLOAT: &[TensorElementType] = &[TensorElementType::Float32];
/// Int64 only.
pub const INT64: &[TensorElementType] = &[TensorElementType::Int64];
/// Int64 or int32.
pub const INDEX: &[TensorElementType] = &[TensorElementType::Int64, TensorElementType::Int32];

impl TensorSpec {
    /// A tensor of `dtypes` and shape `dims`.
    pub fn new(name: &str, key: &str, dtypes: &'static [TensorElementType], dims: Option<Vec<Dim>>) -> Self {
        Self { name: name.to_owned(), key: key.to_owned(), dtypes, dims }
    }

    fn describe(&self) -> String {
        let dtype = self.dtypes.iter().map(|t| dtype_name(*t)).collect::<Vec<_>>().join(" or ");
        match &self.dims {
            Some(dims) => {
                let dims: Vec<String> = dims
                    .iter()
                    .map(|d| match d {
                        Dim::Is(n) => n.to_string(),
                        Dim::Any(letter) => (*letter).to_owned(),
                    })
                    .collect();
                format!("{:?} {dtype} [{}]", self.name, dims.join(", "))
            }
            None => format!("{:?} {dtype}", self.name),
        }
    }
}

/// The ONNX spelling of an element type (`float32`, `int64`).
pub fn dtype_name(t: TensorElementType) -> String {
    match t {
        TensorElementType::Float32 => "float32".to_owned(),
        TensorElementType::Float16 => "float16".to_owned(),
        TensorElementType::Float64 => "float64".to_owned(),
        TensorElementType::Int64 => "int64".to_owned(),
        TensorElementType::Int32 => "int32".to_owned(),
        TensorElementType::Uint8 => "uint8".to_owned(),
        TensorElementType::Bool => "bool".to_owned(),
        other => other.to_string(),
    }
}

fn describe_value(name: &str, value: &ValueType) -> String {
    match value {
        ValueType::Tensor { ty, shape, dimension_symbols } => {
            let dims: Vec<String> = shape
                .iter()
                .enumerate()
                .map(|(i, d)| match dimension_symbols.get(i).map(String::as_str) {
                    Some(symbol) if *d < 0 && !symbol.is_empty() => symbol.to_owned(),
                    _ if *d < 0 => "?".to_owned(),
                    _ => d.to_string(),
                })
                .collect();
            format!("{name:?} {} [{}]", dtype_name(*ty), dims.join(", "))
        }
        other => format!("{name:?} {other:?}"),
    }
}

/// Every input and output of `session`: `inputs "images" float32 [1, 3, 640, 640], ...;
/// outputs ...`.
pub fn describe(session: &Session) -> String {
    let list = |items: Vec<String>| if items.is_empty() { "none".to_owned() } else { items.join(", ") };
    let inputs = list(session.inputs().iter().map(|i| describe_value(i.name(), i.dtype())).collect());
    let outputs = list(session.outputs().iter().map(|o| describe_value(o.name(), o.dtype())).collect());
    format!("inputs {inputs}; outputs {outputs}")
}

/// Why `value` does not fit `spec`, if it does not.
fn mismatch(spec: &TensorSpec, value: &ValueType) -> Option<String> {
    let ValueType::Tensor { ty, shape, .. } = value else {
        return Some("is not a tensor".to_owned());
    };
    if !spec.dtypes.contains(ty) {
        return Some(format!("has element type {}", dtype_name(*ty)));
    }
    let dims = spec.dims.as_ref()?;
    if shape.len() != dims.len() {
        return Some(format!("has rank {} ({shape:?})", shape.len()));
    }
    for (got, want) in shape.iter().zip(dims) {
        if let Dim::Is(n) = want
            && *got >= 0
            && got != n
        {
            return Some(format!("has shape {shape:?}"));
        }
    }
    None
}

/// Checks `session` (the file `model_path`) against a contract: every tensor of `inputs` and
/// `outputs` must exist with an accepted element type and a compatible shape. `what` names the
/// contract in the message ("the yolo_world family (detector.open_vocab.family)").
pub fn check(
    session: &Session,
    model_path: &Path,
    what: &str,
    inputs: &[TensorSpec],
    outputs: &[TensorSpec],
) -> Result<(), OnnxError> {
    let mut problems = Vec::new();
    for (side, specs, have) in [("input", inputs, session.inputs()), ("output", outputs, session.outputs())] {
        for spec in specs {
            match have.iter().find(|o| o.name() == spec.name) {
                None => {
                    problems.push(format!("no {side} {:?} ({}: expected {})", spec.name, spec.key, spec.describe()))
                }
                Some(found) => {
                    if let Some(why) = mismatch(spec, found.dtype()) {
                        problems.push(format!(
                            "{side} {:?} ({}) {why}, expected {}",
                            spec.name,
                            spec.key,
                            spec.describe()
                        ));
                    }
                }
            }
        }
    }
    if problems.is_empty() {
        return Ok(());
    }
    Err(OnnxError::BadModel {
        path: model_path.to_path_buf(),
        message: format!("does not match {what}: {}; the file has {}", problems.join("; "), describe(session)),
    })
}

/// Checks the sha256 of `path` when `expected` is set (64 hex digits, either case); `key` is the
/// profile key of the digest.
pub fn verify_sha256(path: &Path, expected: Option<&str>, key: &str) -> Result<(), OnnxError> {
    let Some(expected) = expected else {
        return Ok(());
    };
    let bad = |message: String| OnnxError::BadModel { path: path.to_path_buf(), message };
    let bytes = std::fs::read(path).map_err(|e| bad(format!("cannot read it to check {key}: {e}")))?;
    let digest = ring::digest::digest(&ring::digest::SHA256, &bytes);
    let actual: String = digest.as_ref().iter().map(|b| format!("{b:02x}")).collect();
    if actual != expected.trim().to_ascii_lowercase() {
        return Err(bad(format!(
            "sha256 is {actual}, but {key} expects {expected}: the file is not the one the profile was written for"
        )));
    }
    Ok(())
}

/// Range check of an optional digest field; errors are `path: message`.
pub fn validate_sha256(path: &str, value: Option<&str>) -> Result<(), String> {
    match value {
        Some(v) if v.len() != 64 || !v.bytes().all(|b| b.is_ascii_hexdigit()) => {
            Err(format!("{path}: must be 64 hexadecimal digits (a sha256), got {v:?}"))
        }
        _ => Ok(()),
    }
}

/// A user's model file: `configured` resolved (profile key `path_key`), its optional sha256
/// checked (`sha_key`), and a session opened on the runtime's execution provider with
/// `threads` intra-op threads. Returns the session and the resolved path.
pub fn open_user_model(
    runtime: &super::OnnxRuntime,
    configured: &Path,
    sha256: Option<&str>,
    what: &'static str,
    keys: (&str, &str),
    threads: usize,
) -> Result<(Session, std::path::PathBuf), OnnxError> {
    let (path_key, sha_key) = keys;
    let path = super::resolve_path(configured, what, path_key).map_err(user_model)?;
    verify_sha256(&path, sha256, sha_key)?;
    let (session, _) = super::open_session(
        runtime,
        super::SessionSpec { what, model_path: &path, provider: runtime.execution_provider(), intra_threads: threads },
    )?;
    Ok((session, path))
}

/// A missing user-supplied model: the setup script cannot fetch it, so say where it comes from.
pub(crate) fn user_model(error: OnnxError) -> OnnxError {
    match error {
        OnnxError::FileMissing { what, looked_for, setting } => OnnxError::ModelMissing {
            what,
            looked_for,
            setting,
            hint: "no package registry ships these weights: export the model (docs/models.md, \"Bringing your own models\") and point the profile at the file",
        },
        other => other,
    }
}
#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_digest_that_differs_names_the_key_and_both_digests() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("m.onnx");
        std::fs::write(&file, b"abc").unwrap();
        let abc = "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad";
        verify_sha256(&file, Some(abc), "x.sha256").unwrap();
        verify_sha256(&file, Some(&abc.to_ascii_uppercase()), "x.sha256").unwrap();
        verify_sha256(&file, None, "x.sha256").unwrap();
        let other = "0".repeat(64);
        let err = verify_sha256(&file, Some(&other), "detector.open_vocab.sha256").unwrap_err().to_string();
        assert!(err.contains(abc) && err.contains(&other) && err.contains("detector.open_vocab.sha256"), "{err}");
        assert!(validate_sha256("k", Some("12")).unwrap_err().starts_with("k: must be 64"));
        assert!(validate_sha256("k", Some(abc)).is_ok());
    }
}
