//! Writing a log file safely: the file rule of `vibro-files` (README, "Files"), named
//! here for this crate's writers (the CSV import, `vibrocomp log recover`, a simulated
//! flight). The rule has one home, `vibro_files`; this module only re-exports it.

pub use vibro_files::{check_output, same_file, PartFile};
