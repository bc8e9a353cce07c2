//! What stops a dataset from being written or read; every variant names the file.

use std::path::PathBuf;

/// A dataset error.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// A file or folder could not be written, synced or renamed (a full disk lands here).
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A Parquet file could not be written or read.
    #[error("{}: {source}", path.display())]
    Parquet {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: parquet::errors::ParquetError,
    },
    /// Arrow refused the columns (a bug: the writer builds them).
    #[error("{path}: {source}")]
    Arrow {
        /// The file.
        path: String,
        /// The cause.
        source: arrow::error::ArrowError,
    },
    /// A file is not what the layout says it should be.
    #[error("{path}: {what}")]
    Invalid {
        /// The file (relative to the dataset root).
        path: String,
        /// What is wrong.
        what: String,
    },
    /// An episode does not fit the dataset (another feature shape, no frame).
    #[error("episode {episode}: {what}")]
    Episode {
        /// Its index.
        episode: u64,
        /// What is wrong.
        what: String,
    },
}

impl DatasetError {
    pub(crate) fn io(path: impl Into<PathBuf>) -> impl FnOnce(std::io::Error) -> Self {
        let path = path.into();
        move |source| Self::Io { path, source }
    }

    pub(crate) fn parquet(
        path: impl Into<PathBuf>,
    ) -> impl FnOnce(parquet::errors::ParquetError) -> Self {
        let path = path.into();
        move |source| Self::Parquet { path, source }
    }

    pub(crate) fn arrow(path: &str) -> impl FnOnce(arrow::error::ArrowError) -> Self + '_ {
        move |source| Self::Arrow {
            path: path.to_owned(),
            source,
        }
    }

    pub(crate) fn invalid(path: &str, what: impl Into<String>) -> Self {
        Self::Invalid {
            path: path.to_owned(),
            what: what.into(),
        }
    }
}
