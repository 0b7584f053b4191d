//! Progress on stderr, drawn with indicatif: the spinner `vfp identify` shows while a slow family
//! sweeps ([`sysid::identify::Progress`]), the bar of the library's long work
//! ([`sysid::progress::Progress`]: `vfp diagnose`'s stages and candidate searches), and the demo's
//! stage lines. Quiet when stderr is not a terminal or with `--quiet` ([`set_quiet`]).

use std::io::IsTerminal;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;
use sysid::identify::Progress;

static BAR: Mutex<Option<indicatif::ProgressBar>> = Mutex::new(None);
static QUIET: AtomicBool = AtomicBool::new(false);

/// `--quiet`: no progress at all, not even the demo's plain stage lines.
pub fn set_quiet(quiet: bool) {
    QUIET.store(quiet, Ordering::Relaxed);
}

/// Whether `--quiet` was given.
pub fn quiet() -> bool {
    QUIET.load(Ordering::Relaxed)
}

/// Whether progress is drawn: stderr is a terminal and `--quiet` was not given.
pub fn shown() -> bool {
    !quiet() && std::io::stderr().is_terminal()
}

/// A bar or spinner on stderr that draws only when [`shown`].
pub fn new_bar(total: u64, template: &str) -> indicatif::ProgressBar {
    let b = if total == 0 {
        indicatif::ProgressBar::new_spinner()
    } else {
        indicatif::ProgressBar::new(total)
    };
    if !shown() {
        b.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    if let Ok(style) = indicatif::ProgressStyle::with_template(template) {
        b.set_style(style);
    }
    b.enable_steady_tick(std::time::Duration::from_millis(200));
    b
}

/// Draws a [`Progress`] report: a spinner prefixed with the family while it works, cleared when
/// it is done. Pass it as [`sysid::identify::Options::progress`].
pub fn spinner(p: Progress<'_>) {
    let Ok(mut bar) = BAR.lock() else { return };
    match p {
        Progress::Working { family, what } => {
            let b =
                bar.get_or_insert_with(|| new_bar(0, "{prefix:>12} {spinner} {msg} ({elapsed})"));
            b.set_prefix(family.name());
            b.set_message(what.to_string());
        }
        Progress::Done { .. } => {
            if let Some(b) = bar.take() {
                b.finish_and_clear();
            }
        }
    }
}

/// Draws the library's [`sysid::progress::Progress`]: each stage a bar of its steps (a spinner
/// when they are not counted) with the last step finished, cleared when all is done. Pass it as
/// e.g. [`sysid::residual::Config::progress`].
pub fn stages(p: sysid::progress::Progress<'_>) {
    use sysid::progress::Progress as P;
    let Ok(mut bar) = BAR.lock() else { return };
    match p {
        P::Stage { what, total } => {
            if let Some(b) = bar.take() {
                b.finish_and_clear();
            }
            let template = if total == 0 {
                "{spinner} {prefix} ({elapsed})"
            } else {
                "{spinner} {prefix} [{bar:20}] {pos}/{len} {msg} ({elapsed})"
            };
            let b = new_bar(total as u64, template);
            b.set_prefix(what.to_string());
            *bar = Some(b);
        }
        P::Step { done, what } => {
            if let Some(b) = bar.as_ref() {
                b.set_position(done as u64);
                b.set_message(format!("{what} done"));
            }
        }
        P::Done => {
            if let Some(b) = bar.take() {
                b.finish_and_clear();
            }
        }
    }
}
