//! # Test data beside the checkout
//!
//! Some tests and benches read the development data in `../shared/data` (a real RGB-D sequence,
//! a small YOLOX model), which is not part of the repository. [`shared_data`] finds a file or
//! folder there. When it is missing:
//! - in CI (`CI=true`) the test **fails**, naming the path, so that a missing data set can never
//!   pass as a green run;
//! - elsewhere the caller skips, and a line on stderr says what was skipped and why.
//!
//! ```no_run
//! let Some(sequence) = op3dsg_shared_data::shared_data("rgbd/icl_livingroom1") else { return };
//! assert!(sequence.join("rgb.txt").exists());
//! ```

use std::path::PathBuf;

/// `../shared/data` beside the checkout (the folder that holds the repository).
pub fn shared_data_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data")
}

/// Whether this is a CI run (`CI=true`, as CI systems set it).
pub fn in_ci() -> bool {
    std::env::var("CI").is_ok_and(|v| v.eq_ignore_ascii_case("true") || v == "1")
}

/// `../shared/data/<relative>` when it exists. When it does not: a panic naming the path in CI,
/// else `None` after a line on stderr (the caller then skips its checks).
///
/// # Panics
/// In CI (`CI=true`) when the path is missing.
pub fn shared_data(relative: &str) -> Option<PathBuf> {
    let path = shared_data_dir().join(relative);
    if path.exists() {
        return Some(path);
    }
    let shown = path.display();
    assert!(
        !in_ci(),
        "the shared development data is missing: {shown} (CI runs with ../shared beside the clone; this test needs it)"
    );
    eprintln!("skipped: {shown} is missing (../shared/data beside the checkout); outside CI this test checks nothing");
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_path_that_exists_is_returned_and_a_missing_one_is_not() {
        if shared_data_dir().exists() {
            assert!(shared_data("").is_some());
        }
        if !in_ci() {
            assert!(shared_data("no/such/file").is_none());
        }
    }
}
