//! Progress of long work, reported through a plain function the caller passes in (the library
//! never prints; the `vfp` tool draws the reports as bars on a terminal). A report costs one call:
//! `None` where a [`ProgressFn`] is optional means silence.

/// One report of work in progress.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Progress<'a> {
    /// A stage begins: `what` it does, in `total` steps (0 when not counted).
    Stage {
        /// What the stage does, a few words.
        what: &'a str,
        /// Its number of steps, 0 if unknown.
        total: usize,
    },
    /// `done` of the current stage's steps are finished, the last being `what`.
    Step {
        /// Steps finished.
        done: usize,
        /// What just finished.
        what: &'a str,
    },
    /// All the work is finished.
    Done,
}

/// Receives [`Progress`] reports; called from worker threads too, so it must be thread-safe (a
/// `fn` holds no state of its own).
pub type ProgressFn = fn(Progress<'_>);

/// Sends `p` to `f` when there is one.
pub fn tell(f: Option<ProgressFn>, p: Progress<'_>) {
    if let Some(f) = f {
        f(p);
    }
}
