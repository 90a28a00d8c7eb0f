//! One error type for the whole library (ndarray's pattern: one enum, a clear
//! message per kind). Messages name the file or the parameter at fault.

use std::path::PathBuf;

/// Every fallible library call returns this.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The file could not be opened or read at the OS level.
    #[error("{}: cannot read: {source}", path.display())]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    /// The file could not be written.
    #[error("{}: cannot write: {source}", path.display())]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    /// The file was read but its content is not what we support.
    #[error("{}: {reason}", path.display())]
    Format { path: PathBuf, reason: String },
    /// A parameter is out of range or inconsistent with another.
    #[error("invalid parameter `{name}`: {reason}")]
    Param { name: String, reason: String },
    /// The data itself cannot be analysed (constant image, too small, ...).
    #[error("invalid input: {0}")]
    Input(String),
}

impl Error {
    /// Shorthand for [`Error::Param`].
    pub fn param(name: impl Into<String>, reason: impl Into<String>) -> Self {
        Error::Param {
            name: name.into(),
            reason: reason.into(),
        }
    }

    /// Shorthand for [`Error::Format`].
    pub fn format(path: impl Into<PathBuf>, reason: impl Into<String>) -> Self {
        Error::Format {
            path: path.into(),
            reason: reason.into(),
        }
    }
}

/// Library result alias.
pub type Result<T> = std::result::Result<T, Error>;
