//! # vibro-bridge
//!
//! Forwards chosen vibrocomp streams between the local iceoryx2 system (its service-name
//! prefix) and Zenoh key expressions (`{key_prefix}/{stream}`, e.g.
//! `vibrocomp/site-1/rig-a/vib`), in either direction, so that the rig, the services and
//! the recorder can run on different hosts (docs/bridge.md).
//!
//! - **Bytes unchanged.** A message travels as its wire bytes (docs/messages.md), with
//!   its iceoryx2 type name (`vibrocomp::AccelBlock::v5`) as the Zenoh encoding's
//!   schema; the receiving bridge refuses (and counts) another type name or size, and
//!   republishes the very bytes, producer's `seq` included, so the services downstream
//!   see a network loss as a gap in `seq` exactly as a local one.
//! - **Never silent.** Each stream counts what it forwarded, what it sent while nobody
//!   was listening on the other side (`unmatched`), the gaps and reorderings in `seq`
//!   it received, what its bounded import queue dropped, and what iceoryx2 could not
//!   deliver ([`BridgeSummary`]).
//! - **Threads.** One thread per direction, each with its own iceoryx2 node; the Zenoh
//!   callbacks only push into a bounded queue. Nothing here runs on a tokio worker.
//! - **Who may connect.** Only peers that prove who they are: on one host a Unix
//!   socket in a directory of this user's alone (mode 0700, created and checked at
//!   start, [`secure_sockets`]), so the operating system refuses other users; between
//!   hosts mutual TLS, with Zenoh's access control naming the certificates that may
//!   connect. Plain TCP is refused, on loopback too. Both built from the same TOML file
//!   ([`BridgeConfig::zenoh_json5`]); `[access] allow_zids` is a filter, not
//!   authentication (a peer chooses its own Zenoh id).
//!
//! ```no_run
//! use std::sync::atomic::AtomicBool;
//! let config = vibro_bridge::BridgeConfig::load("config/bridge/rig-host.toml".as_ref())?;
//! let stop = AtomicBool::new(false);
//! let summary = vibro_bridge::run(&config, &stop)?;
//! println!("{}", summary.to_json());
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! References: Zenoh 1.10 (`zenoh` crate, same version as the `eclipse-zenoh` Python
//! package); iceoryx2 0.10 through `vibro-ipc`.

mod bridge;
mod config;
pub mod socket;

pub use bridge::{
    encoding_of, open_session, run, run_on, secure_sockets, BridgeSummary, Direction, StreamReport,
    StreamStats,
};
pub use config::{
    is_loopback_endpoint, resolve_endpoint, socket_path, stream_by_name, Access, BridgeConfig,
    Congestion, Mode, Tls, MAX_ACCESS_NAMES, MAX_COMMON_NAME_BYTES, MAX_ENDPOINTS,
    MAX_ENDPOINT_BYTES, MAX_KEY_PREFIX_BYTES, MAX_KEY_PREFIX_CHUNKS, MAX_QUEUE_DEPTH,
    MAX_SOCKET_PATH_BYTES, MAX_WORD_BYTES, MAX_ZID_BYTES, UNIXSOCK,
};

/// Errors of the bridge; each names the file, endpoint or key concerned.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Config(#[from] vibro_service::ConfigError),
    #[error("{file}: the Zenoh configuration built from it was refused: {reason}")]
    ZenohConfig { file: String, reason: String },
    #[error("opening the Zenoh session of {file} (listen [{listen}], connect [{connect}], connect_timeout_s = {timeout_s}): {reason}; is the peer at [{connect}] running and reachable, and is no other process listening on [{listen}]?")]
    Open {
        file: String,
        listen: String,
        connect: String,
        timeout_s: f64,
        reason: String,
    },
    #[error("{operation} on Zenoh key {key:?}: {reason}")]
    Zenoh {
        operation: &'static str,
        key: String,
        reason: String,
    },
    #[error(transparent)]
    Ipc(#[from] vibro_ipc::Error),
    #[error("bridge thread: {0}")]
    Thread(String),
}

/// Result of the bridge.
pub type Result<T> = std::result::Result<T, Error>;
