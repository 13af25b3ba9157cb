//! Progress events for a caller's progress display. The library never prints.

/// A progress event.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Progress {
    /// A stage starts with this many units of work.
    Stage {
        /// Stage name.
        name: &'static str,
        /// Units of work.
        total: u64,
    },
    /// Units of work done in the current stage.
    Advance(u64),
}

/// A progress callback (may be called from several threads).
pub(crate) type ProgressFn<'a> = &'a (dyn Fn(Progress) + Sync);

/// Reports one event when there is a callback.
pub(crate) fn emit(progress: Option<ProgressFn<'_>>, event: Progress) {
    if let Some(p) = progress {
        p(event);
    }
}
