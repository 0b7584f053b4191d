//! The one error type of the tool.

use std::path::PathBuf;

/// Why a `vfp` command stopped: printed as `vfp: <message>` with exit status 1. Every message
/// names the file (with line and column where the problem sits in one) or the option at fault.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A failure described in one sentence.
    #[error("{0}")]
    Msg(String),
    /// A command-line value out of its range.
    #[error("invalid option: {0}")]
    Usage(String),
    /// An output (figure, directory, file) could not be written.
    #[error("cannot write {path}: {msg}")]
    Output {
        /// The file or directory.
        path: PathBuf,
        /// The underlying reason.
        msg: String,
    },
    /// A log could not be read or turned into datasets.
    #[error(transparent)]
    Load(#[from] sysid::dataset::LoadError),
    /// A log could not be read or written.
    #[error(transparent)]
    Log(#[from] sysid::log::LogError),
    /// A §IV analysis failed.
    #[error(transparent)]
    Diag(#[from] sysid::diag::DiagError),
    /// A model could not be exported.
    #[error(transparent)]
    Export(#[from] sysid::board::export::ExportError),
    /// A telemetry capture could not be converted.
    #[error(transparent)]
    Record(#[from] sysid::board::record::RecordError),
    /// Model lines could not be parsed or sent.
    #[error(transparent)]
    Deploy(#[from] sysid::board::deploy::DeployError),
}

impl Error {
    /// An output failure at `path`.
    pub fn output(path: impl Into<PathBuf>, msg: impl ToString) -> Self {
        Error::Output {
            path: path.into(),
            msg: msg.to_string(),
        }
    }
}

impl From<std::io::Error> for Error {
    fn from(e: std::io::Error) -> Self {
        Error::Msg(format!("I/O error: {e}"))
    }
}

macro_rules! from_display {
    ($($t:ty),*) => {$(
        impl From<$t> for Error {
            fn from(e: $t) -> Self {
                Error::Msg(e.to_string())
            }
        }
    )*};
}
from_display!(
    sysid::dataset::DataError,
    sysid::poly::PolyError,
    sysid::metrics::MetricsError,
    model_core::ModelError
);
