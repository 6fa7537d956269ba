//! Why a checkout could not be checked at all (as opposed to a violation, which `check` lists).

use std::path::PathBuf;

/// A file that could not be read or understood; the check stops on it.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{}: {message}", path.display())]
    Manifest { path: PathBuf, message: String },
    #[error("{}:{line}: not Rust that syn parses: {message}", path.display())]
    Parse { path: PathBuf, line: usize, message: String },
    #[error("{}:{line}: module `{module}` is declared but none of {tried} exists", path.display())]
    MissingModule { path: PathBuf, line: usize, module: String, tried: String },
}

impl Error {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io { path: path.into(), source }
    }
}
