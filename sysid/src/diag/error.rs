//! The one error type of the diagnostics commands.

use std::path::PathBuf;

/// Why a diagnostics command stopped. Every variant names where the problem is and what to do.
#[derive(Debug, thiserror::Error)]
pub enum DiagError {
    /// A log could not be read or does not follow `docs/log-format.md`.
    #[error("{path}{}{}: {msg}", line.map(|l| format!(", line {l}")).unwrap_or_default(),
            column.as_ref().map(|c| format!(", column `{c}`")).unwrap_or_default())]
    Input {
        /// The file.
        path: PathBuf,
        /// 1-based line number, when the problem sits on one line.
        line: Option<usize>,
        /// Column name, when the problem sits in one column.
        column: Option<String>,
        /// What is wrong and what to do.
        msg: String,
    },
    /// A log could not be read (sysid's reader names file, line and column).
    #[error(transparent)]
    Log(#[from] crate::log::LogError),
    /// The data do not determine the requested model (too few samples, a term never excited).
    #[error("{context}: {msg}")]
    Fit {
        /// Which log / chamber / fit.
        context: String,
        /// What is missing.
        msg: String,
    },
    /// A command-line value is out of its range.
    #[error("invalid option: {0}")]
    Usage(String),
}

impl DiagError {
    pub(crate) fn fit(context: impl Into<String>, msg: impl Into<String>) -> Self {
        DiagError::Fit {
            context: context.into(),
            msg: msg.into(),
        }
    }
}
