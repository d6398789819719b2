//! Compiles `proto/vibrocomp/v1/*.proto` without a `protoc` binary: `protox` parses them
//! into a `FileDescriptorSet`, `prost-build` generates the Rust types from it, and each
//! message's schema (its file and the files it imports, as a serialised
//! `FileDescriptorSet`, the form Foxglove and `mcap-protobuf-support` read) is written to
//! `OUT_DIR` for `include_bytes!`.

use prost::Message;
use prost_types::{FileDescriptorProto, FileDescriptorSet};
use std::collections::BTreeMap;
use std::error::Error;
use std::path::PathBuf;

/// The files, one message each; `src/schema.rs` embeds `<stem>.fds.bin` for each.
const FILES: [&str; 11] = [
    "vibrocomp/v1/accel_block.proto",
    "vibrocomp/v1/vib_block.proto",
    "vibrocomp/v1/vib_estimate.proto",
    "vibrocomp/v1/compensated_block.proto",
    "vibrocomp/v1/truth_block.proto",
    "vibrocomp/v1/heartbeat.proto",
    "vibrocomp/v1/log_line.proto",
    // The view channels for people (docs/view.md).
    "vibrocomp/view/v1/unit_stages.proto",
    "vibrocomp/view/v1/vibration_axis.proto",
    "vibrocomp/view/v1/service_health.proto",
    // Foxglove's well-known log schema, for the view's `/log`.
    "foxglove/Log.proto",
];

fn main() -> Result<(), Box<dyn Error>> {
    println!("cargo:rerun-if-changed=proto");
    let out_dir = PathBuf::from(std::env::var("OUT_DIR")?);
    let fds = protox::compile(FILES, ["proto"])?;

    // Schemas in recordings carry no source info: comments would only add bytes.
    let by_name: BTreeMap<&str, &FileDescriptorProto> =
        fds.file.iter().map(|f| (f.name(), f)).collect();
    for name in FILES {
        let mut set = FileDescriptorSet::default();
        add_with_imports(name, &by_name, &mut set)?;
        for file in &mut set.file {
            file.source_code_info = None;
        }
        let stem = name
            .rsplit('/')
            .next()
            .and_then(|f| f.strip_suffix(".proto"))
            .ok_or("proto file name without .proto")?;
        std::fs::write(out_dir.join(format!("{stem}.fds.bin")), set.encode_to_vec())?;
    }

    prost_build::Config::new().compile_fds(fds)?;
    Ok(())
}

/// Appends `name`'s imports (depth first) and then `name` itself, once each.
fn add_with_imports(
    name: &str,
    by_name: &BTreeMap<&str, &FileDescriptorProto>,
    set: &mut FileDescriptorSet,
) -> Result<(), Box<dyn Error>> {
    if set.file.iter().any(|f| f.name() == name) {
        return Ok(());
    }
    let file = by_name
        .get(name)
        .ok_or_else(|| format!("{name} is imported but was not compiled"))?;
    for dep in &file.dependency {
        add_with_imports(dep, by_name, set)?;
    }
    set.file.push((*file).clone());
    Ok(())
}
