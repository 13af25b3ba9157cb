//! Progress bars on stderr (hidden when stderr is not a terminal or with --quiet).

use std::sync::Mutex;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use odocal::Progress;

/// A progress display fed by the library's progress events.
pub struct Bars {
    quiet: bool,
    bar: Mutex<Option<ProgressBar>>,
}

impl Bars {
    pub fn new(quiet: bool) -> Self {
        Bars { quiet, bar: Mutex::new(None) }
    }

    fn make(&self, name: &str, total: u64) -> ProgressBar {
        let target = if self.quiet { ProgressDrawTarget::hidden() } else { ProgressDrawTarget::stderr() };
        let pb = ProgressBar::with_draw_target(Some(total), target);
        let style = ProgressStyle::with_template("{prefix:>24} [{bar:30}] {pos}/{len} {elapsed_precise} eta {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> ");
        pb.set_style(style);
        pb.set_prefix(name.to_string());
        pb
    }

    /// Handles one event.
    pub fn event(&self, e: Progress) {
        let Ok(mut guard) = self.bar.lock() else { return };
        match e {
            Progress::Stage { name, total } => {
                if let Some(old) = guard.take() {
                    old.finish_and_clear();
                }
                *guard = Some(self.make(name, total));
            }
            Progress::Advance(n) => {
                if let Some(b) = guard.as_ref() {
                    b.inc(n);
                }
            }
        }
    }

    /// A spinner-like single-step stage.
    pub fn stage(&self, name: &'static str) {
        self.event(Progress::Stage { name, total: 1 });
    }

    /// Clears the bar.
    pub fn finish(&self) {
        if let Ok(mut guard) = self.bar.lock() {
            if let Some(b) = guard.take() {
                b.finish_and_clear();
            }
        }
    }
}
