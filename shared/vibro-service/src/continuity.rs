//! The continuity rule of the services' input streams (gaps, jumps, resyncs, and the
//! losses a resync takes back) lives in `vibro_msgs::continuity`, its one home: the
//! recorder, `log info` and the bridge apply it too, and the MCAP codec cannot depend
//! on this crate. Here: its re-export, and the JSON of its totals for the services'
//! summaries.

pub use vibro_msgs::continuity::{
    Arrival, Continuity, StreamCounters, MAX_LOST_MESSAGES, MAX_LOST_SAMPLES, RESYNC_AFTER,
};

/// The JSON object of a stream's totals in a service's summary.
pub trait CountersJson {
    fn to_json(&self) -> crate::JsonObject;
}

impl CountersJson for StreamCounters {
    fn to_json(&self) -> crate::JsonObject {
        let mut o = crate::JsonObject::new();
        for (name, value) in self.fields() {
            o.u64(name, value);
        }
        o
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The summary's keys and values are the counters' (the names the services have
    /// always printed).
    #[test]
    fn the_json_lists_every_counter() {
        let c = StreamCounters {
            received: 1,
            lost_messages: 2,
            lost_samples: 3,
            out_of_order: 4,
            restarts: 5,
            resyncs: 6,
            seq_jumps: 7,
            index_jumps: 8,
            index_backwards: 9,
            malformed: 10,
        };
        assert_eq!(
            c.to_json().finish(),
            "{\"received\":1,\"lost_messages\":2,\"lost_samples\":3,\"out_of_order\":4,\
             \"restarts\":5,\"resyncs\":6,\"seq_jumps\":7,\"index_jumps\":8,\
             \"index_backwards\":9,\"malformed\":10}"
        );
    }
}
