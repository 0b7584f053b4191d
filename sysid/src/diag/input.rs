//! Logs as the diagnostics read them: sysid's reader ([`crate::log`]) and per-chamber datasets
//! ([`crate::dataset`], whose documented differentiator supplies v̇ where the file has no flow
//! column). Diagnostics use every sample, so no held-out split is made here.

use super::DiagError;
use crate::dataset::{Dataset, DatasetConfig, FlowSource};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// One chamber's samples in time order (t, v, v̇, P, optional force).
pub type Series = Dataset;

/// A log read for diagnostics: metadata and one dataset per chamber present.
#[derive(Clone, Debug)]
pub struct Log {
    /// Where it came from.
    pub path: PathBuf,
    /// The log as read (comments, rows).
    pub raw: crate::log::Log,
    /// Chamber index → samples.
    pub chambers: BTreeMap<u8, Series>,
    /// Whether v̇ was derived from volume and time (no `flow_mm3_s` column).
    pub flow_derived: bool,
}

impl Log {
    /// The series of `chamber`, or of the lowest chamber present when `None`.
    pub fn chamber(&self, chamber: Option<u8>) -> Result<(u8, &Series), DiagError> {
        let found = match chamber {
            Some(c) => self.chambers.get_key_value(&c),
            None => self.chambers.iter().next(),
        };
        found.map(|(c, s)| (*c, s)).ok_or_else(|| DiagError::Input {
            path: self.path.clone(),
            line: None,
            column: Some("chamber".into()),
            msg: match chamber {
                Some(c) => format!(
                    "no samples for chamber {c} (present: {:?}); choose one with --chamber",
                    self.chambers.keys().collect::<Vec<_>>()
                ),
                None => "the log holds no samples".into(),
            },
        })
    }

    /// `# key=value` metadata.
    pub fn meta(&self, key: &str) -> Option<&str> {
        self.raw.metadata(key)
    }

    /// A short label: the file stem.
    pub fn label(&self) -> String {
        self.path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default()
    }
}

/// Reads and validates a log file and builds every chamber's dataset.
pub fn read_log(path: &Path) -> Result<Log, DiagError> {
    let raw = crate::log::read_log(path)?;
    let cfg = DatasetConfig {
        holdout_every: 0,
        ..DatasetConfig::default()
    };
    let mut chambers = BTreeMap::new();
    let mut flow_derived = false;
    for c in raw.chambers() {
        let d = Dataset::from_log(&raw, c, &cfg).map_err(|e| DiagError::Input {
            path: path.to_path_buf(),
            line: None,
            column: None,
            msg: e.to_string(),
        })?;
        flow_derived |= matches!(d.flow_source, FlowSource::Derived { .. });
        chambers.insert(c, d);
    }
    Ok(Log {
        path: path.to_path_buf(),
        raw,
        chambers,
        flow_derived,
    })
}
