//! One log through the cores into a session, timed: what `vibrocomp log compensate`
//! runs, without the command line (and without its build: a release build of this
//! example needs the cores and the log format only).
//!
//! ```text
//! vibrocomp sim cyclone-4 --out /tmp/cyclone-4.mcap
//! cargo build --release -p vibro-offline --example compensate
//! taskset -c 0 target/release/examples/compensate /tmp/cyclone-4.mcap /tmp/session.mcap [--no-view] [--no-compression] [--no-chunk-copy] [--no-output]
//! ```
//!
//! Run from the repository's root: the configurations are the services' default rule
//! (`config/services/*.toml`).

use std::path::PathBuf;
use vibro_offline::{compensate_log, OutputOptions, Setup};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (files, flags): (Vec<&String>, Vec<&String>) =
        args.iter().partition(|a| !a.starts_with("--"));
    let [log, out] = files.as_slice() else {
        anyhow::bail!(
            "usage: compensate LOG OUT.mcap [--no-view] [--no-compression] [--no-chunk-copy] [--no-output]"
        );
    };
    let has = |f: &str| flags.iter().any(|a| *a == f);
    let options = OutputOptions {
        force: true,
        view: !has("--no-view"),
        compress: !has("--no-compression"),
        copy_chunks: !has("--no-chunk-copy"),
    };
    let setup = Setup::derive(None, None, None, None)?;
    let (log, out) = (PathBuf::from(log), PathBuf::from(out));
    if has("--no-output") {
        // The cores alone: the blocks in memory, no session written.
        let t = std::time::Instant::now();
        let (blocks, s) = vibro_offline::compensate_blocks(&log, &setup)?;
        let wall_s = t.elapsed().as_secs_f64();
        println!(
            "{:.1} s of data in {wall_s:.3} s wall, no output: {:.0}x real time; {} blocks",
            s.flight_s,
            s.flight_s / wall_s,
            blocks.len()
        );
        return Ok(());
    }
    let s = compensate_log(&log, &setup, &out, &options, &|| None, &mut |_, _| {})?;
    println!(
        "{:.1} s of data in {:.3} s wall: {:.0}x real time; {} estimates, {} blocks, {:.1} MB written, {} chunks copied",
        s.flight_s,
        s.wall_s,
        s.real_time_factor,
        s.estimates,
        s.compensated_blocks,
        s.bytes as f64 / 1e6,
        s.copied_chunks
    );
    Ok(())
}
