//! The spinner `vfp identify` shows on stderr while a slow family sweeps
//! ([`sysid::identify::Progress`] reports, drawn with indicatif).

use std::sync::Mutex;
use sysid::identify::Progress;

static BAR: Mutex<Option<indicatif::ProgressBar>> = Mutex::new(None);

/// Draws a [`Progress`] report: a spinner prefixed with the family while it works, cleared when
/// it is done. Pass it as [`sysid::identify::Options::progress`].
pub fn spinner(p: Progress<'_>) {
    let Ok(mut bar) = BAR.lock() else { return };
    match p {
        Progress::Working { family, what } => {
            let b = bar.get_or_insert_with(|| {
                let b = indicatif::ProgressBar::new_spinner();
                if let Ok(style) = indicatif::ProgressStyle::with_template(
                    "{prefix:>12} {spinner} {msg} ({elapsed})",
                ) {
                    b.set_style(style);
                }
                b.enable_steady_tick(std::time::Duration::from_millis(200));
                b
            });
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
