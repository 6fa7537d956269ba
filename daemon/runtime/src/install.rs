//! Where op3dsg's own files are: in a checkout, or installed beside the binary.
//!
//! A checkout keeps the files `./scripts/setup-models.sh` fetches (ONNX Runtime, the text
//! encoder, the detector the Stretch profile runs) in `.models/`, and the profiles in
//! `profiles/`. An installed op3dsg (the Debian package, `systemd/install.sh`) keeps them under
//! the prefix its binaries were installed to, found from the running binary
//! (`<prefix>/bin/op3dsgd`), so nothing depends on the checkout it was built from and a staged
//! copy (`dpkg --root`, `install.sh --destdir`) finds its own files:
//!
//! | in a checkout | installed (`/usr/bin/op3dsgd`) |
//! |---|---|
//! | `.models/onnxruntime/libonnxruntime.so.1.31.1` | `/usr/lib/op3dsg/onnxruntime/libonnxruntime.so.1.31.1` |
//! | `.models/<anything>` | `/usr/lib/op3dsg/<anything>` |
//! | `profiles/stretch3-d435i.toml` | `/usr/share/op3dsg/profiles/stretch3-d435i.toml` |
//!
//! A relative path that starts with `.models/` names a file of that store wherever it is
//! written, a profile included ([`in_model_store`]); `onnx::resolve_path` looks for it in the
//! working directory, then in the installed store, then in the source tree. A profile's
//! `extends` that names no file beside the profile is looked up in the installed profiles
//! ([`installed_profiles_dir`]).

use std::path::{Component, Path, PathBuf};

/// The folder of a checkout that holds the fetched runtime library and models.
pub const MODEL_STORE: &str = ".models";
/// The installed model store, below the install prefix.
pub const INSTALLED_MODEL_STORE: &str = "lib/op3dsg";
/// The installed profiles and knowledge base, below the install prefix.
pub const INSTALLED_PROFILES: &str = "share/op3dsg/profiles";

/// The install prefix of the running binary: `<prefix>` for `<prefix>/bin/<binary>`. `None` for
/// a binary that does not sit in a `bin` folder (one in cargo's `target/debug/`), which has no
/// installed files.
pub fn prefix() -> Option<PathBuf> {
    prefix_of(&std::env::current_exe().ok()?)
}

/// [`prefix`] for the binary at `exe`.
pub fn prefix_of(exe: &Path) -> Option<PathBuf> {
    let bin = exe.parent()?;
    if bin.file_name()? != "bin" {
        return None;
    }
    bin.parent().map(Path::to_path_buf)
}

/// The installed model store of the running binary (`/usr/lib/op3dsg` for `/usr/bin/op3dsgd`).
pub fn installed_model_store() -> Option<PathBuf> {
    prefix().map(|p| p.join(INSTALLED_MODEL_STORE))
}

/// The installed profiles of the running binary (`/usr/share/op3dsg/profiles`).
pub fn installed_profiles_dir() -> Option<PathBuf> {
    prefix().map(|p| p.join(INSTALLED_PROFILES))
}

/// The path inside the model store when `path` is relative and starts with `.models/`
/// (`.models/minilm/model.onnx` → `minilm/model.onnx`); `None` otherwise.
pub fn in_model_store(path: &Path) -> Option<&Path> {
    let mut components = path.components();
    match components.next() {
        Some(Component::Normal(first)) if first == MODEL_STORE => {
            let rest = components.as_path();
            (!rest.as_os_str().is_empty()).then_some(rest)
        }
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_prefix_is_the_folder_above_bin() {
        assert_eq!(prefix_of(Path::new("/usr/bin/op3dsgd")), Some(PathBuf::from("/usr")));
        assert_eq!(prefix_of(Path::new("/tmp/root/usr/bin/op3dsg")), Some(PathBuf::from("/tmp/root/usr")));
        // cargo's output folders are no install prefix.
        assert_eq!(prefix_of(Path::new("/src/op3dsg/target/debug/op3dsgd")), None);
        assert_eq!(prefix_of(Path::new("/src/op3dsg/target/debug/deps/onnx-1234")), None);
        assert_eq!(prefix_of(Path::new("op3dsgd")), None);
    }

    #[test]
    fn model_store_paths_start_with_the_store() {
        assert_eq!(in_model_store(Path::new(".models/minilm/model.onnx")), Some(Path::new("minilm/model.onnx")));
        assert_eq!(in_model_store(Path::new("./.models/x.onnx")), None, "only a path that starts with the store");
        assert_eq!(in_model_store(Path::new(".models")), None);
        assert_eq!(in_model_store(Path::new("models/yolox_nano.onnx")), None);
        assert_eq!(in_model_store(Path::new("/opt/.models/x.onnx")), None);
    }
}
