//! A file or folder that could not be created or written, named: the one I/O error of the modules that write
//! outputs (`demo`, `sim::output`), which carry it as their `Io` variant.

use std::path::{Path, PathBuf};

/// A file or folder that could not be created or written.
#[derive(Debug, thiserror::Error)]
#[error("{what} {}", path.display())]
pub struct FileError {
    /// `creating` or `writing`.
    pub what: &'static str,
    /// The file or folder.
    pub path: PathBuf,
    /// The cause.
    #[source]
    pub source: std::io::Error,
}

impl FileError {
    /// The error of creating `path`, for `map_err`.
    pub fn creating(path: &Path) -> impl FnOnce(std::io::Error) -> Self + '_ {
        move |source| Self {
            what: "creating",
            path: path.to_path_buf(),
            source,
        }
    }

    /// The error of writing `path`, for `map_err`.
    pub fn writing(path: &Path) -> impl FnOnce(std::io::Error) -> Self + '_ {
        move |source| Self {
            what: "writing",
            path: path.to_path_buf(),
            source,
        }
    }
}
