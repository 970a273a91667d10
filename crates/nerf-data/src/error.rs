//! One error type for everything that reads scene inputs. Every variant names the file.

use std::path::{Path, PathBuf};

/// An input problem, always tied to the file or folder it came from.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    /// The file or folder could not be opened or read.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The file exists but its content is wrong: truncated, corrupt, inconsistent or out of range.
    #[error("{}: {msg}", path.display())]
    Invalid { path: PathBuf, msg: String },
}

impl DataError {
    pub fn io(path: impl AsRef<Path>, source: std::io::Error) -> Self {
        DataError::Io {
            path: path.as_ref().to_path_buf(),
            source,
        }
    }

    pub fn invalid(path: impl AsRef<Path>, msg: impl Into<String>) -> Self {
        DataError::Invalid {
            path: path.as_ref().to_path_buf(),
            msg: msg.into(),
        }
    }

    /// The path the error is about.
    pub fn path(&self) -> &Path {
        match self {
            DataError::Io { path, .. } | DataError::Invalid { path, .. } => path,
        }
    }
}

pub type Result<T, E = DataError> = std::result::Result<T, E>;

/// Reads a whole file, turning a missing file into an error that names it.
pub fn read_file(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|e| DataError::io(path, e))
}

/// Fails with a clear message when `path` does not exist.
pub fn require_exists(path: &Path, what: &str) -> Result<()> {
    if path.exists() {
        Ok(())
    } else {
        Err(DataError::invalid(path, format!("{what} not found")))
    }
}
