//! The MCAP schema of each message type, following the Foxglove protobuf convention
//! (<https://mcap.dev/spec/registry#protobuf>): schema `encoding = "protobuf"`,
//! `name` = the fully qualified message name, `data` = a serialised
//! `google.protobuf.FileDescriptorSet` holding the message's `.proto` file and everything
//! it imports; channel `message_encoding = "protobuf"`.

use vibro_msgs::MessageKind;

/// Schema encoding of every channel written here.
pub const SCHEMA_ENCODING: &str = "protobuf";
/// Message encoding of every channel written here.
pub const MESSAGE_ENCODING: &str = "protobuf";
/// The protobuf package of the messages.
pub const PROTO_PACKAGE: &str = "vibrocomp.v1";

/// One message type's MCAP schema.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Schema {
    /// The wire type it describes.
    pub kind: MessageKind,
    /// Fully qualified protobuf name, e.g. `vibrocomp.v1.AccelBlock`.
    pub name: &'static str,
    /// Serialised `FileDescriptorSet` (the message's file and its imports, no source info).
    pub data: &'static [u8],
}

macro_rules! fds {
    ($stem:literal) => {
        include_bytes!(concat!(env!("OUT_DIR"), "/", $stem, ".fds.bin"))
    };
}

/// The schema of `kind`.
pub const fn schema(kind: MessageKind) -> Schema {
    let (name, data): (&str, &[u8]) = match kind {
        MessageKind::AccelBlock => ("vibrocomp.v1.AccelBlock", fds!("accel_block")),
        MessageKind::VibBlock => ("vibrocomp.v1.VibBlock", fds!("vib_block")),
        MessageKind::VibEstimate => ("vibrocomp.v1.VibEstimate", fds!("vib_estimate")),
        MessageKind::CompensatedBlock => {
            ("vibrocomp.v1.CompensatedBlock", fds!("compensated_block"))
        }
        MessageKind::TruthBlock => ("vibrocomp.v1.TruthBlock", fds!("truth_block")),
        MessageKind::Heartbeat => ("vibrocomp.v1.Heartbeat", fds!("heartbeat")),
        MessageKind::LogLine => ("vibrocomp.v1.LogLine", fds!("log_line")),
    };
    Schema { kind, name, data }
}

/// The start of every view schema's name (`vibrocomp.view.v1.UnitStages`, ...).
pub const VIEW_PACKAGE_PREFIX: &str = "vibrocomp.view.";

/// A view channel's schema (docs/view.md): fully qualified name and serialised
/// `FileDescriptorSet`, as for the wire types.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ViewSchema {
    pub name: &'static str,
    pub data: &'static [u8],
}

/// The view channels' schemas: per unit and stage, per vibration axis, per service.
pub const VIEW_UNIT_STAGES: ViewSchema = ViewSchema {
    name: "vibrocomp.view.v1.UnitStages",
    data: fds!("unit_stages"),
};
pub const VIEW_VIBRATION_AXIS: ViewSchema = ViewSchema {
    name: "vibrocomp.view.v1.VibrationAxis",
    data: fds!("vibration_axis"),
};
pub const VIEW_SERVICE_HEALTH: ViewSchema = ViewSchema {
    name: "vibrocomp.view.v1.ServiceHealth",
    data: fds!("service_health"),
};
/// Foxglove's well-known log schema (the view's `/log`: the services' log lines).
pub const FOXGLOVE_LOG: ViewSchema = ViewSchema {
    name: "foxglove.Log",
    data: fds!("Log"),
};

/// Whether `name` is a view channel's schema (docs/view.md): a `vibrocomp.view.v1`
/// message, or Foxglove's `foxglove.Log` of the view's `/log`.
pub fn is_view_schema(name: &str) -> bool {
    name.starts_with(VIEW_PACKAGE_PREFIX) || name == FOXGLOVE_LOG.name
}

/// The message kind whose schema is named `name` (e.g. `vibrocomp.v1.VibBlock`).
pub fn kind_of_schema(name: &str) -> Option<MessageKind> {
    MessageKind::ALL
        .into_iter()
        .find(|&k| schema(k).name == name)
}

/// Schema ID used for `kind` in files written by this crate (MCAP IDs start at 1).
pub(crate) const fn schema_id(kind: MessageKind) -> u16 {
    match kind {
        MessageKind::AccelBlock => 1,
        MessageKind::VibBlock => 2,
        MessageKind::VibEstimate => 3,
        MessageKind::CompensatedBlock => 4,
        MessageKind::TruthBlock => 5,
        MessageKind::Heartbeat => 6,
        MessageKind::LogLine => 7,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use prost::Message;
    use prost_types::FileDescriptorSet;

    #[test]
    fn each_schema_is_a_descriptor_set_holding_its_message() {
        for kind in MessageKind::ALL {
            let s = schema(kind);
            assert_eq!(s.name, format!("{PROTO_PACKAGE}.{}", kind.name()));
            assert_eq!(kind_of_schema(s.name), Some(kind));
            let set = FileDescriptorSet::decode(s.data).unwrap();
            assert_eq!(set.file.len(), 1, "{kind}: one file, no imports");
            let file = &set.file[0];
            assert_eq!(file.package(), PROTO_PACKAGE);
            assert_eq!(file.syntax(), "proto3");
            assert!(file.source_code_info.is_none());
            let names: Vec<&str> = file.message_type.iter().map(|m| m.name()).collect();
            assert_eq!(names, [kind.name()]);
        }
        assert_eq!(kind_of_schema("vibrocomp.v1.Nope"), None);
        let ids: std::collections::BTreeSet<u16> =
            MessageKind::ALL.into_iter().map(schema_id).collect();
        assert_eq!(ids.len(), MessageKind::ALL.len());
        assert!(!ids.contains(&0));
    }
}
