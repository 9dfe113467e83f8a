//! How a bake reports progress: the library calls an [`Observer`]; the command line shows
//! progress bars on a terminal and plain log lines otherwise.

/// Receives progress events. All methods have empty defaults.
pub trait Observer: Sync {
    /// A stage begins.
    fn stage(&self, _name: &str) {}
    /// Progress within the current stage.
    fn progress(&self, _done: u64, _total: u64) {}
    /// A step of the current stage finished (a level of the Poisson-disk placement): `done`
    /// of `total` steps, `detail` summarising it. Shown as progress unless overridden.
    fn step(&self, done: u64, total: u64, _detail: &str) {
        self.progress(done, total)
    }
    /// A stage ended after `secs` seconds; `detail` summarises its result.
    fn done(&self, _name: &str, _secs: f64, _detail: &str) {}
    /// Something the user should know.
    fn warn(&self, _message: &str) {}
}

/// Reports nothing.
pub struct Silent;

impl Observer for Silent {}
