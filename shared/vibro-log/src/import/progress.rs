//! Progress of an import: what a progress bar is told, and the bytes read over the
//! files and passes.

/// What an import tells a progress bar as it goes. Every method does nothing unless
/// implemented; `()` is no progress at all.
pub trait ImportProgress {
    /// Called first, once: the bytes both passes will read (the inputs' size, twice).
    fn start(&mut self, _total_bytes: u64) {}
    /// A pass begins: `"checking"` (the first) or `"importing"` (the second).
    fn pass(&mut self, _name: &'static str) {}
    /// Bytes read so far, over both passes.
    fn position(&mut self, _bytes: u64) {}
    /// Reading is over: the log is being finished, or the input was refused.
    fn finish(&mut self) {}
}

impl ImportProgress for () {}

/// Bytes read over the files and passes, reported to an [`ImportProgress`].
pub(super) struct Tracker<'a> {
    pub(super) sink: &'a mut dyn ImportProgress,
    /// Bytes of earlier files and passes.
    done: u64,
}

impl<'a> Tracker<'a> {
    pub(super) fn new(sink: &'a mut dyn ImportProgress) -> Self {
        Self { sink, done: 0 }
    }

    /// `bytes` read of the current file.
    pub(super) fn set_current(&mut self, bytes: u64) {
        self.sink.position(self.done + bytes);
    }

    /// The current file's pass is over, `bytes` read.
    pub(super) fn finish_part(&mut self, bytes: u64) {
        self.done += bytes;
        self.sink.position(self.done);
    }
}
