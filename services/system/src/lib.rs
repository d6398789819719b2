//! The vibrocomp system as child processes of the `vibrocomp` executable: the
//! estimator, the compensator, the recorder, the live view and the bridge, started as
//! `vibrocomp service ...` / `vibrocomp record ...` so that one built binary is all a
//! user needs ([`SystemSpec`], [`Role`]); and two "hosts" on one machine, two iceoryx2
//! roots joined by Zenoh bridges ([`hosts`]).
//!
//! Used by `vibrocomp up` (which supervises the processes), `vibrocomp demo`, the
//! latency harness (`vibro-latency`) and the integration tests. Starting, stopping,
//! watching and restarting a process is `vibro_service::supervise`.
//!
//! The program started is [`SystemSpec::exe`], by default `std::env::current_exe()`:
//! called from the `vibrocomp` binary, that binary itself.
//!
//! A service-side crate: errors are `anyhow`, with context at every I/O boundary.
//!
//! ```no_run
//! use vibro_system::{Role, SystemSpec};
//!
//! let spec = SystemSpec {
//!     prefix: "demo/".into(),
//!     json: true,
//!     ..SystemSpec::default()
//! };
//! let estimator = spec.spawn(Role::Estimator, None)?;
//! # Ok::<(), anyhow::Error>(())
//! ```

pub mod derived;
pub mod hosts;
mod spec;

pub use spec::{Role, SystemSpec};
