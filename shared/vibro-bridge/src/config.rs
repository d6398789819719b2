//! The bridge's configuration file: raw TOML (unknown keys refused with their line) →
//! [`BridgeConfig`], validated with every problem reported at once, and the Zenoh
//! configuration (JSON5) built from it.
//!
//! **Who may connect** (docs/bridge.md). Every link proves who is at its other end:
//! a Unix socket (`unixsock-stream/PATH`) in a directory only this user can enter
//! (the operating system refuses everybody else, checked at start by
//! [`crate::socket`]), or TLS with certificates signed by the configured CA (a
//! `tls/` listen endpoint must ask for the peer's: `mutual = true`). Plain `tcp/` is
//! refused, on loopback too: any local user can connect to a loopback port, and a
//! Zenoh id is whatever the peer says it is, so `[access] allow_zids` filters peers
//! but authenticates nobody.

use serde::Deserialize;
use std::path::{Path, PathBuf};
use std::time::Duration;
use vibro_msgs::{ServiceNames, Stream};
use vibro_service::{check_prefix, check_seconds, parse_toml, read_config_file, ConfigError};

/// Most messages an import queue may hold (each holds one Zenoh sample, up to 12 KB).
pub const MAX_QUEUE_DEPTH: usize = 65_536;

/// Longest `key_prefix`, in bytes. A key names a site and a rig
/// (`vibrocomp/site-1/rig-a`, 22 bytes), and Zenoh keeps one routing node per chunk
/// of every declared key, each holding the whole key up to its chunk, and frees them
/// by one nested call per chunk: a key of n bytes in c chunks costs about n·c bytes
/// and c nested calls (a 1 MB key in 10 000 chunks took 5.1 GB, then overflowed the
/// export thread's stack when its publishers were undeclared).
pub const MAX_KEY_PREFIX_BYTES: usize = 256;
/// Most `/`-separated chunks of `key_prefix` (see [`MAX_KEY_PREFIX_BYTES`]): a site
/// and a rig need two or three. With the stream's one or two, a key is at most 18
/// routing nodes deep.
pub const MAX_KEY_PREFIX_CHUNKS: usize = 16;
/// Most endpoints `zenoh.listen` or `zenoh.connect` may name: a bridge links a few
/// hosts.
pub const MAX_ENDPOINTS: usize = 64;
/// Longest endpoint, in bytes: `tls/` with a DNS name (at most 253 bytes) and a port,
/// or a Unix socket's path (at most [`MAX_SOCKET_PATH_BYTES`]), with room for Zenoh's
/// `?metadata#configuration` suffix.
pub const MAX_ENDPOINT_BYTES: usize = 512;
/// Most names `[access]` may list in each of its lists: the hosts of one site.
pub const MAX_ACCESS_NAMES: usize = 64;
/// Longest certificate common name, in bytes: X.509's `ub-common-name` (RFC 5280).
pub const MAX_COMMON_NAME_BYTES: usize = 64;
/// Longest Zenoh id, in bytes: 16 bytes written as 32 hex digits.
pub const MAX_ZID_BYTES: usize = 32;
/// Longest stream name in `streams` or word in `mode`, `congestion`: the longest
/// stream name (`progress/compensator`) is 20 bytes.
pub const MAX_WORD_BYTES: usize = 64;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Raw {
    /// iceoryx2 service-name prefix of the local system.
    prefix: Option<String>,
    /// Zenoh key prefix: stream `s` travels on `{key_prefix}/{s}`.
    key_prefix: String,
    zenoh: ZenohRaw,
    #[serde(default)]
    export: DirectionRaw,
    #[serde(default)]
    import: DirectionRaw,
    tls: Option<TlsRaw>,
    access: Option<AccessRaw>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ZenohRaw {
    mode: String,
    #[serde(default)]
    listen: Vec<String>,
    #[serde(default)]
    connect: Vec<String>,
    connect_timeout_s: f64,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct DirectionRaw {
    #[serde(default)]
    streams: Vec<String>,
    /// Export only: `block` or `drop`.
    congestion: Option<String>,
    /// Import only: messages between Zenoh and iceoryx2.
    queue_depth: Option<usize>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TlsRaw {
    root_ca_certificate: PathBuf,
    certificate: PathBuf,
    private_key: PathBuf,
    #[serde(default = "yes")]
    mutual: bool,
}

fn yes() -> bool {
    true
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct AccessRaw {
    #[serde(default)]
    allow_cert_common_names: Vec<String>,
    #[serde(default)]
    allow_zids: Vec<String>,
}

/// Zenoh's role in its network.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    Peer,
    Client,
}

impl Mode {
    pub fn as_str(self) -> &'static str {
        match self {
            Mode::Peer => "peer",
            Mode::Client => "client",
        }
    }
}

/// What a full Zenoh transmit queue does with an exported message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Congestion {
    /// Wait (back-pressure reaches the iceoryx2 publisher, whose bounded wait counts
    /// what it cannot deliver).
    Block,
    /// Drop the message; the receiving bridge and services see the sequence gap.
    Drop,
}

/// TLS on every link: our certificate and key, the CA that signs the peers'.
#[derive(Debug, Clone, PartialEq)]
pub struct Tls {
    pub root_ca_certificate: PathBuf,
    pub certificate: PathBuf,
    pub private_key: PathBuf,
    /// Peers must present a certificate too (mTLS), so that access control can name
    /// them by its common name.
    pub mutual: bool,
}

/// Who may exchange messages with this bridge (Zenoh access control, default deny).
#[derive(Debug, Clone, PartialEq)]
pub struct Access {
    /// Common names of the peers' certificates (mutual TLS): authenticated by the CA.
    pub allow_cert_common_names: Vec<String>,
    /// Zenoh ids: a filter, not authentication. A peer chooses its own id (any Zenoh
    /// configuration sets `id`), so naming one admits whoever copies it; it narrows
    /// who of the peers that the link already authenticated may exchange messages.
    pub allow_zids: Vec<String>,
}

/// A validated bridge configuration.
#[derive(Debug, Clone)]
pub struct BridgeConfig {
    /// Where it came from (for messages).
    pub source: String,
    pub names: ServiceNames,
    pub key_prefix: String,
    pub mode: Mode,
    pub listen: Vec<String>,
    pub connect: Vec<String>,
    pub connect_timeout: Duration,
    /// iceoryx2 → Zenoh.
    pub export: Vec<Stream>,
    /// Zenoh → iceoryx2.
    pub import: Vec<Stream>,
    pub congestion: Congestion,
    pub queue_depth: usize,
    pub tls: Option<Tls>,
    pub access: Option<Access>,
}

/// The stream a config name (`vib`, `progress/estimator`, ...) means.
pub fn stream_by_name(name: &str) -> Option<Stream> {
    Stream::all().into_iter().find(|s| s.suffix() == name)
}

fn stream_names() -> String {
    Stream::all()
        .into_iter()
        .map(|s| s.suffix())
        .collect::<Vec<_>>()
        .join(", ")
}

/// Whether an endpoint (`tcp/127.0.0.1:7447`) is on the loopback interface only.
pub fn is_loopback_endpoint(endpoint: &str) -> bool {
    let Some((_, addr)) = endpoint.split_once('/') else {
        return false;
    };
    let addr = addr.split('#').next().unwrap_or(addr);
    let host = match addr.rsplit_once(':') {
        Some((h, _)) => h.trim_start_matches('[').trim_end_matches(']'),
        None => return false,
    };
    if host == "localhost" {
        return true;
    }
    host.parse::<std::net::IpAddr>()
        .is_ok_and(|ip| ip.is_loopback())
}

/// The Zenoh protocol of Unix-domain stream sockets.
pub const UNIXSOCK: &str = "unixsock-stream";

/// The longest path of a Unix socket: Linux's `sun_path` holds 108 bytes with the
/// terminating NUL (unix(7)).
pub const MAX_SOCKET_PATH_BYTES: usize = 107;

/// The socket path of a `unixsock-stream/PATH` endpoint.
pub fn socket_path(endpoint: &str) -> Option<&Path> {
    endpoint
        .strip_prefix(UNIXSOCK)
        .and_then(|rest| rest.strip_prefix('/'))
        .map(Path::new)
}

/// `endpoint` with a socket named without a folder (`unixsock-stream/rig-a.sock`)
/// placed in `dir` ([`crate::socket::default_socket_dir`]); any other unchanged.
pub fn resolve_endpoint(endpoint: &str, dir: &Path) -> String {
    match endpoint
        .strip_prefix(UNIXSOCK)
        .and_then(|rest| rest.strip_prefix('/'))
    {
        Some(name) if !name.is_empty() && !name.contains('/') => {
            format!("{UNIXSOCK}/{}/{name}", dir.display())
        }
        _ => endpoint.to_string(),
    }
}

/// Why a `unixsock-stream/` endpoint's path cannot be used, if it cannot.
fn check_socket_path(path: &str) -> Option<String> {
    let p = Path::new(path);
    let dir = p.parent();
    if !p.is_absolute() {
        Some("must be a file name alone (the socket then goes in this user's own folder, docs/bridge.md) or an absolute path (the bridges of one host may run in different working directories)".into())
    } else if path.contains(['?', '#', '\0']) {
        Some("must not contain ?, # or NUL (Zenoh reads ? and # as the start of the endpoint's metadata and configuration)".into())
    } else if path.ends_with('/')
        || path.contains("//")
        || path.split('/').any(|c| c == "." || c == "..")
    {
        Some("must be a plain path to a file: no trailing /, //, . or ..".into())
    } else if path.len() > MAX_SOCKET_PATH_BYTES {
        Some(format!(
            "is {} bytes: a Unix socket's path holds at most {MAX_SOCKET_PATH_BYTES}",
            path.len()
        ))
    } else if dir.is_none_or(|d| d == Path::new("/")) {
        Some("must be in a directory of the bridge's own, e.g. /run/user/1000/vibrocomp-bridge/rig-a.sock, or the socket's name alone for this user's own folder (the directory, not the socket, keeps other users out)".into())
    } else {
        None
    }
}

/// The endpoints with their keys: `("zenoh.listen[0]", endpoint)`, then `connect`.
fn keyed_endpoints<'a>(
    listen: &'a [String],
    connect: &'a [String],
) -> impl Iterator<Item = (String, &'a str)> {
    let listen = listen
        .iter()
        .enumerate()
        .map(|(i, e)| (format!("zenoh.listen[{i}]"), e.as_str()));
    let connect = connect
        .iter()
        .enumerate()
        .map(|(i, e)| (format!("zenoh.connect[{i}]"), e.as_str()));
    listen.chain(connect)
}

fn check_endpoint(key: &str, endpoint: &str, tls: bool, problems: &mut Vec<String>) {
    let Some((proto, addr)) = endpoint.split_once('/') else {
        problems.push(format!(
            "{key} = {endpoint:?}: must be {UNIXSOCK}/NAME (e.g. {UNIXSOCK}/rig-a.sock, in this user's own folder), {UNIXSOCK}/PATH (an absolute path) or tls/HOST:PORT"
        ));
        return;
    };
    match proto {
        UNIXSOCK => {
            if let Some(rule) = check_socket_path(addr) {
                problems.push(format!("{key} = {endpoint:?}: the socket's path {rule}"));
            }
            return;
        }
        "tls" if tls => {}
        "tls" => problems.push(format!(
            "{key} = {endpoint:?}: a tls/ endpoint needs the [tls] table"
        )),
        "tcp" => problems.push(format!(
            "{key} = {endpoint:?}: plain TCP proves nobody's identity, on loopback too (any local user can connect to a loopback port, and a Zenoh id is whatever the peer says): use {UNIXSOCK}/PATH between the bridges of one host, tls/HOST:PORT with [tls] between hosts (docs/bridge.md, \"Who may connect\")"
        )),
        other => problems.push(format!(
            "{key} = {endpoint:?}: protocol {other:?} is not built in ({UNIXSOCK} or tls)"
        )),
    }
    let port_ok = addr
        .rsplit_once(':')
        .is_some_and(|(h, p)| !h.is_empty() && p.parse::<u16>().is_ok());
    if !port_ok {
        problems.push(format!(
            "{key} = {endpoint:?}: must name a host and a port (HOST:PORT)"
        ));
    }
}

fn check_key_prefix(key_prefix: &str, problems: &mut Vec<String>) {
    let rule = "must be a Zenoh key of one or more '/'-separated chunks, none empty, without wildcards or the characters * $ # ? (e.g. vibrocomp/site-1/rig-a)";
    let bad = key_prefix.is_empty()
        || key_prefix.split('/').any(|c| c.is_empty())
        || key_prefix
            .chars()
            .any(|c| matches!(c, '*' | '$' | '#' | '?') || c.is_whitespace());
    if bad || zenoh::key_expr::KeyExpr::try_from(key_prefix.to_string()).is_err() {
        problems.push(format!("key_prefix = {key_prefix:?}: {rule}"));
    }
}

fn check_streams(key: &str, names: &[String], problems: &mut Vec<String>) -> Vec<Stream> {
    let mut out = Vec::new();
    for name in names {
        match stream_by_name(name) {
            Some(s) if out.contains(&s) => {
                problems.push(format!("{key}: {name:?} is named twice"));
            }
            Some(s) => out.push(s),
            None => problems.push(format!(
                "{key}: {name:?} is not a stream (one of: {})",
                stream_names()
            )),
        }
    }
    out
}

fn check_file(key: &str, path: &Path, problems: &mut Vec<String>) {
    if !path.is_file() {
        problems.push(format!(
            "{key} = {:?}: no such file (a PEM file)",
            path.display()
        ));
    }
}

/// Every string and list of the file against its bound (the constants above, and
/// `vibro_toml::bounds`): whether all are within, each one over added to `p`.
fn check_sizes(raw: &Raw, p: &mut Vec<String>) -> bool {
    use vibro_toml::bounds::{path, text, texts, MAX_PATH_BYTES};
    let mut ok = true;
    if let Some(prefix) = &raw.prefix {
        ok &= text("prefix", prefix, vibro_msgs::MAX_SERVICE_NAME_LEN, p);
    }
    ok &= text("key_prefix", &raw.key_prefix, MAX_KEY_PREFIX_BYTES, p);
    let chunks = raw.key_prefix.split('/').count();
    if chunks > MAX_KEY_PREFIX_CHUNKS {
        p.push(format!(
            "key_prefix = {} ({chunks} '/'-separated chunks): at most {MAX_KEY_PREFIX_CHUNKS} chunks",
            vibro_toml::bounds::quote(&raw.key_prefix)
        ));
        ok = false;
    }
    ok &= text("zenoh.mode", &raw.zenoh.mode, MAX_WORD_BYTES, p);
    let z = &raw.zenoh;
    ok &= texts(
        "zenoh.listen",
        &z.listen,
        MAX_ENDPOINTS,
        MAX_ENDPOINT_BYTES,
        p,
    );
    ok &= texts(
        "zenoh.connect",
        &z.connect,
        MAX_ENDPOINTS,
        MAX_ENDPOINT_BYTES,
        p,
    );
    for (key, d) in [("export", &raw.export), ("import", &raw.import)] {
        let streams = Stream::all().len();
        ok &= texts(
            &format!("{key}.streams"),
            &d.streams,
            streams,
            MAX_WORD_BYTES,
            p,
        );
        if let Some(c) = &d.congestion {
            ok &= text(&format!("{key}.congestion"), c, MAX_WORD_BYTES, p);
        }
    }
    if let Some(t) = &raw.tls {
        for (key, v) in [
            ("tls.root_ca_certificate", &t.root_ca_certificate),
            ("tls.certificate", &t.certificate),
            ("tls.private_key", &t.private_key),
        ] {
            ok &= path(key, v, MAX_PATH_BYTES, p);
        }
    }
    if let Some(a) = &raw.access {
        ok &= texts(
            "access.allow_cert_common_names",
            &a.allow_cert_common_names,
            MAX_ACCESS_NAMES,
            MAX_COMMON_NAME_BYTES,
            p,
        );
        ok &= texts(
            "access.allow_zids",
            &a.allow_zids,
            MAX_ACCESS_NAMES,
            MAX_ZID_BYTES,
            p,
        );
    }
    ok
}

impl BridgeConfig {
    /// The socket paths of the `unixsock-stream/` endpoints, with their keys
    /// (`zenoh.listen[0]`).
    pub fn sockets(&self) -> Vec<(String, &Path)> {
        keyed_endpoints(&self.listen, &self.connect)
            .filter_map(|(k, e)| socket_path(e).map(|p| (k, p)))
            .collect()
    }

    /// Reads and validates `path`, including the directories of its Unix sockets as
    /// they are now ([`crate::socket::check_dir`]; nothing is created).
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = read_config_file(path)?;
        Self::validate(&text, &path.display().to_string(), true)
    }

    /// Validates the TOML `text` of the file `file`; relative certificate paths are
    /// taken relative to the working directory. The socket directories are left to
    /// [`Self::load`] and to the bridge's start.
    pub fn parse(text: &str, file: &str) -> Result<Self, ConfigError> {
        Self::validate(text, file, false)
    }

    fn validate(text: &str, file: &str, socket_dirs: bool) -> Result<Self, ConfigError> {
        let raw: Raw = parse_toml(text, file)?;
        let mut p = Vec::new();
        // Sizes first: a value over its bound is not looked at further (every such
        // value at once).
        if !check_sizes(&raw, &mut p) {
            return Err(ConfigError::new(file, p));
        }
        let prefix = raw.prefix.unwrap_or_else(vibro_service::default_prefix);
        let names = check_prefix("prefix", &prefix, &mut p);
        check_key_prefix(&raw.key_prefix, &mut p);
        // A socket named without a folder goes in this user's own.
        let socket_dir = crate::socket::default_socket_dir();
        let resolve = |list: &[String]| -> Vec<String> {
            list.iter()
                .map(|e| resolve_endpoint(e, &socket_dir))
                .collect()
        };
        let (listen, connect) = (resolve(&raw.zenoh.listen), resolve(&raw.zenoh.connect));
        let mode = match raw.zenoh.mode.as_str() {
            "peer" => Some(Mode::Peer),
            "client" => Some(Mode::Client),
            other => {
                p.push(format!("zenoh.mode = {other:?}: must be peer or client"));
                None
            }
        };
        let tls_on = raw.tls.is_some();
        for (i, e) in listen.iter().enumerate() {
            check_endpoint(&format!("zenoh.listen[{i}]"), e, tls_on, &mut p);
        }
        for (i, e) in connect.iter().enumerate() {
            check_endpoint(&format!("zenoh.connect[{i}]"), e, tls_on, &mut p);
        }
        if socket_dirs {
            // Each directory once (both sides of one host name the same socket).
            let mut seen: Vec<&Path> = Vec::new();
            for (key, e) in keyed_endpoints(&listen, &connect) {
                let Some(path) = socket_path(e) else { continue };
                let Some(dir) = path.parent() else { continue };
                // A path already refused above, or a directory already looked at.
                if check_socket_path(&path.to_string_lossy()).is_some() || seen.contains(&dir) {
                    continue;
                }
                seen.push(dir);
                if let Err(why) = crate::socket::check_dir(dir) {
                    p.push(format!("{key} = {e:?}: {why}"));
                }
            }
        }
        if listen.is_empty() && connect.is_empty() {
            p.push(
                "zenoh: listen and connect are both empty: name at least one endpoint (multicast scouting is off)"
                    .to_string(),
            );
        }
        if mode == Some(Mode::Client) && connect.is_empty() {
            p.push("zenoh.connect = []: a client must connect to at least one endpoint".into());
        }
        let connect_timeout = check_seconds(
            "zenoh.connect_timeout_s",
            raw.zenoh.connect_timeout_s,
            0.1,
            3600.0,
            &mut p,
        );
        let export = check_streams("export.streams", &raw.export.streams, &mut p);
        let import = check_streams("import.streams", &raw.import.streams, &mut p);
        for s in &export {
            if import.contains(s) {
                p.push(format!(
                    "export.streams and import.streams both name {:?}: a stream goes one way",
                    s.suffix()
                ));
            }
        }
        if export.is_empty() && import.is_empty() {
            p.push("export.streams and import.streams are both empty: nothing to bridge".into());
        }
        if raw.import.congestion.is_some() {
            p.push("import.congestion: set on the exporting side (export.congestion)".into());
        }
        if raw.export.queue_depth.is_some() {
            p.push(
                "export.queue_depth: the queue is the importing side's (import.queue_depth)".into(),
            );
        }
        let congestion = match raw.export.congestion.as_deref() {
            None | Some("block") => Congestion::Block,
            Some("drop") => Congestion::Drop,
            Some(other) => {
                p.push(format!(
                    "export.congestion = {other:?}: must be block or drop"
                ));
                Congestion::Block
            }
        };
        let queue_depth = raw.import.queue_depth.unwrap_or(256);
        if !(1..=MAX_QUEUE_DEPTH).contains(&queue_depth) {
            p.push(format!(
                "import.queue_depth = {queue_depth}: must be 1 <= n <= {MAX_QUEUE_DEPTH}"
            ));
        }
        let tls = raw.tls.map(|t| {
            check_file("tls.root_ca_certificate", &t.root_ca_certificate, &mut p);
            check_file("tls.certificate", &t.certificate, &mut p);
            check_file("tls.private_key", &t.private_key, &mut p);
            Tls {
                root_ca_certificate: t.root_ca_certificate,
                certificate: t.certificate,
                private_key: t.private_key,
                mutual: t.mutual,
            }
        });
        let access = raw.access.map(|a| {
            if a.allow_cert_common_names.is_empty() && a.allow_zids.is_empty() {
                p.push("access: names nobody (allow_cert_common_names and allow_zids are empty): every peer would be refused".into());
            }
            for (i, z) in a.allow_zids.iter().enumerate() {
                let ok = !z.is_empty()
                    && z.len() <= 32
                    && z.chars().all(|c| c.is_ascii_hexdigit() && !c.is_ascii_uppercase());
                if !ok {
                    p.push(format!(
                        "access.allow_zids[{i}] = {z:?}: must be a Zenoh id, 1..32 lower-case hex digits"
                    ));
                }
            }
            if !a.allow_cert_common_names.is_empty() && !tls_on {
                p.push("access.allow_cert_common_names: names certificates, which needs the [tls] table with mutual = true".into());
            }
            Access {
                allow_cert_common_names: a.allow_cert_common_names,
                allow_zids: a.allow_zids,
            }
        });
        if let Some(t) = &tls {
            if !t.mutual
                && access
                    .as_ref()
                    .is_some_and(|a| !a.allow_cert_common_names.is_empty())
            {
                p.push("tls.mutual = false: access.allow_cert_common_names needs the peers' certificates (mutual = true)".into());
            }
            // A TLS listener that asks for no certificate admits whoever reaches its
            // port (on loopback: every local user).
            if !t.mutual {
                for (i, e) in listen.iter().enumerate() {
                    if e.starts_with("tls/") {
                        p.push(format!(
                            "tls.mutual = false: zenoh.listen[{i}] = {e:?} would admit any peer that reaches it (on loopback, every local user): the peers must prove who they are with a certificate (mutual = true)"
                        ));
                    }
                }
            }
        }
        // README, "Several hosts": a bridge reachable from other hosts names who may
        // connect, and checks it with certificates. (A Unix socket is this host's.)
        for (i, e) in listen.iter().enumerate() {
            if is_loopback_endpoint(e) || socket_path(e).is_some() {
                continue;
            }
            let named = access
                .as_ref()
                .is_some_and(|a| !a.allow_cert_common_names.is_empty());
            let mtls = tls.as_ref().is_some_and(|t| t.mutual);
            if !(named && mtls) {
                p.push(format!(
                    "zenoh.listen[{i}] = {e:?}: listens beyond loopback, so it needs [tls] with mutual = true and [access] allow_cert_common_names naming the hosts that may connect"
                ));
            }
        }
        match (names, mode, connect_timeout, p.is_empty()) {
            (Some(names), Some(mode), Some(connect_timeout), true) => Ok(Self {
                source: file.to_string(),
                names,
                key_prefix: raw.key_prefix,
                mode,
                listen,
                connect,
                connect_timeout,
                export,
                import,
                congestion,
                queue_depth,
                tls,
                access,
            }),
            _ => Err(ConfigError::new(file, p)),
        }
    }

    /// The same configuration on another iceoryx2 prefix (`--prefix`).
    pub fn with_prefix(mut self, prefix: &str) -> Result<Self, ConfigError> {
        let mut p = Vec::new();
        match check_prefix("--prefix", prefix, &mut p) {
            Some(n) => {
                self.names = n;
                Ok(self)
            }
            None => Err(ConfigError::new(self.source.clone(), p)),
        }
    }

    /// The Zenoh key of `stream`.
    pub fn key(&self, stream: Stream) -> String {
        format!("{}/{}", self.key_prefix, stream.suffix())
    }

    /// The Zenoh configuration (JSON5) this file stands for: no multicast or gossip
    /// scouting (only the endpoints named), a failed connection at start an error after
    /// `connect_timeout`, TLS and access control where configured.
    pub fn zenoh_json5(&self) -> String {
        let q = |v: &[String]| serde_json::to_string(v).unwrap_or_else(|_| "[]".into());
        let timeout_ms = self.connect_timeout.as_millis();
        let mut out = format!(
            r#"{{
  mode: "{mode}",
  connect: {{
    endpoints: {connect},
    timeout_ms: {timeout_ms},
    exit_on_failure: true,
  }},
  listen: {{ endpoints: {listen}, exit_on_failure: true }},
  scouting: {{ multicast: {{ enabled: false }}, gossip: {{ enabled: false }} }},
  transport: {{
    shared_memory: {{ enabled: false }},"#,
            mode = self.mode.as_str(),
            connect = q(&self.connect),
            listen = q(&self.listen),
        );
        if let Some(t) = &self.tls {
            let s = |p: &Path| serde_json::to_string(&p.display().to_string()).unwrap_or_default();
            out.push_str(&format!(
                r#"
    link: {{ tls: {{
      root_ca_certificate: {ca},
      listen_private_key: {key},
      listen_certificate: {cert},
      connect_private_key: {key},
      connect_certificate: {cert},
      enable_mtls: {mtls},
    }} }},"#,
                ca = s(&t.root_ca_certificate),
                key = s(&t.private_key),
                cert = s(&t.certificate),
                mtls = t.mutual,
            ));
        }
        out.push_str("\n  },\n");
        if let Some(a) = &self.access {
            let mut subject = String::new();
            if !a.allow_cert_common_names.is_empty() {
                subject.push_str(&format!(
                    "cert_common_names: {}, ",
                    q(&a.allow_cert_common_names)
                ));
            }
            if !a.allow_zids.is_empty() {
                subject.push_str(&format!("zids: {}, ", q(&a.allow_zids)));
            }
            out.push_str(&format!(
                r#"  access_control: {{
    enabled: true,
    default_permission: "deny",
    rules: [{{
      id: "vibrocomp",
      messages: ["put", "delete", "declare_subscriber", "query", "reply", "declare_queryable", "liveliness_token", "declare_liveliness_subscriber", "liveliness_query"],
      flows: ["egress", "ingress"],
      permission: "allow",
      key_exprs: ["{key}/**"],
    }}],
    subjects: [{{ id: "named", {subject}}}],
    policies: [{{ rules: ["vibrocomp"], subjects: ["named"] }}],
  }},
"#,
                key = self.key_prefix,
            ));
        }
        out.push('}');
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
prefix = "host-a/"
key_prefix = "vibrocomp/site-1/rig-a"
[zenoh]
mode = "peer"
connect = ["unixsock-stream//tmp/vibrocomp-bridge/rig-a.sock"]
connect_timeout_s = 2.0
[export]
streams = ["vib", "accel", "truth"]
[import]
streams = ["estimate", "compensated", "progress/estimator"]
queue_depth = 64
"#;

    #[test]
    fn a_good_file_is_read() {
        let c = BridgeConfig::parse(GOOD, "a.toml").unwrap();
        assert_eq!(c.names.prefix(), "host-a/");
        assert_eq!(c.export, vec![Stream::Vib, Stream::Accel, Stream::Truth]);
        assert_eq!(c.import.len(), 3);
        assert_eq!(c.queue_depth, 64);
        assert_eq!(c.key(Stream::Vib), "vibrocomp/site-1/rig-a/vib");
        assert_eq!(c.congestion, Congestion::Block);
        assert_eq!(
            c.sockets(),
            [(
                "zenoh.connect[0]".to_string(),
                Path::new("/tmp/vibrocomp-bridge/rig-a.sock")
            )]
        );
        // The JSON5 is one Zenoh accepts.
        zenoh::Config::from_json5(&c.zenoh_json5()).unwrap();
    }

    /// Issue 31, item 2: plain TCP lets in any local user, whatever `allow_zids` says;
    /// it is refused in `listen` and `connect`, on loopback and beyond, with the way
    /// out in the message.
    #[test]
    fn plain_tcp_is_refused_on_loopback_too_and_in_connect() {
        let text = GOOD.replace(
            "connect = [\"unixsock-stream//tmp/vibrocomp-bridge/rig-a.sock\"]",
            "listen = [\"tcp/127.0.0.1:7447\"]\nconnect = [\"tcp/127.0.0.1:7448\", \"tcp/192.168.1.2:7447\"]",
        ) + "[access]\nallow_zids = [\"1f\"]\n";
        let e = BridgeConfig::parse(&text, "t.toml").unwrap_err();
        let all = e.problems.join("\n");
        for key in [
            "zenoh.listen[0] = \"tcp/127.0.0.1:7447\": plain TCP proves nobody's identity, on loopback too",
            "zenoh.connect[0] = \"tcp/127.0.0.1:7448\": plain TCP",
            "zenoh.connect[1] = \"tcp/192.168.1.2:7447\": plain TCP",
        ] {
            assert!(all.contains(key), "missing {key:?} in:\n{all}");
        }
        assert!(all.contains("use unixsock-stream/PATH"), "{all}");
        assert_eq!(e.problems.len(), 3, "{all}");
    }

    /// A TLS listener must ask for the peer's certificate, on loopback too.
    #[test]
    fn a_tls_listener_without_mutual_is_refused() {
        let dir = std::env::temp_dir().join(format!("vbc-tls-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for f in ["ca.pem", "b.pem", "b.key"] {
            std::fs::write(dir.join(f), "").unwrap();
        }
        let tls = format!(
            "[tls]\nroot_ca_certificate = {:?}\ncertificate = {:?}\nprivate_key = {:?}\nmutual = false\n",
            dir.join("ca.pem"),
            dir.join("b.pem"),
            dir.join("b.key")
        );
        let listen = GOOD.replace(
            "connect = [\"unixsock-stream//tmp/vibrocomp-bridge/rig-a.sock\"]",
            "listen = [\"tls/127.0.0.1:7447\"]",
        ) + &tls;
        let e = BridgeConfig::parse(&listen, "l.toml").unwrap_err();
        assert!(
            e.problems.join("\n").contains(
                "tls.mutual = false: zenoh.listen[0] = \"tls/127.0.0.1:7447\" would admit any peer"
            ),
            "{e}"
        );
        // Connecting, the server's certificate is checked: mutual is the listener's call.
        let connect = GOOD.replace(
            "connect = [\"unixsock-stream//tmp/vibrocomp-bridge/rig-a.sock\"]",
            "connect = [\"tls/compute-1.lab:7447\"]",
        ) + &tls;
        let c = BridgeConfig::parse(&connect, "c.toml");
        std::fs::remove_dir_all(&dir).unwrap();
        c.unwrap();
    }

    /// Loading a file looks at its sockets' directories too, with every other problem.
    #[test]
    fn load_refuses_a_socket_directory_others_may_enter_with_the_rest() {
        use std::os::unix::fs::PermissionsExt;
        let dir = std::env::temp_dir().join(format!("vbc-load-{}", std::process::id()));
        let open = dir.join("open");
        std::fs::create_dir_all(&open).unwrap();
        std::fs::set_permissions(&open, std::fs::Permissions::from_mode(0o755)).unwrap();
        let file = dir.join("b.toml");
        let text = GOOD
            .replace("/tmp/vibrocomp-bridge", &open.display().to_string())
            .replace("queue_depth = 64", "queue_depth = 0");
        std::fs::write(&file, text).unwrap();
        let e = BridgeConfig::load(&file).unwrap_err();
        let missing = dir.join("missing");
        std::fs::write(
            &file,
            GOOD.replace("/tmp/vibrocomp-bridge", &missing.display().to_string()),
        )
        .unwrap();
        let ok = BridgeConfig::load(&file);
        let created = missing.exists();
        std::fs::remove_dir_all(&dir).unwrap();
        let all = e.problems.join("\n");
        assert!(
            all.contains(&format!(
                "zenoh.connect[0] = \"unixsock-stream/{}/rig-a.sock\": the directory {} belongs to uid",
                open.display(),
                open.display()
            )) && all.contains("with mode 0755")
                && all.contains("(mode 0700"),
            "{all}"
        );
        assert!(all.contains("import.queue_depth = 0"), "{all}");
        assert_eq!(e.file, file.display().to_string());
        // A directory still to be made passes, and loading does not make it.
        ok.unwrap();
        assert!(!created);
    }

    #[test]
    fn socket_paths_are_checked_with_their_rule() {
        let long = format!("/tmp/{}/b.sock", "x".repeat(MAX_SOCKET_PATH_BYTES));
        let cases = [
            (
                "tmp/b/b.sock",
                "or an absolute path (the bridges of one host",
            ),
            ("/b.sock", "in a directory of the bridge's own"),
            ("/tmp/b/b.sock?x=1", "must not contain ?, #"),
            ("/tmp/b/../b.sock", "no trailing /, //, . or .."),
            ("/tmp/b/", "no trailing /"),
            (long.as_str(), "a Unix socket's path holds at most 107"),
        ];
        for (path, rule) in cases {
            let text = GOOD.replace("/tmp/vibrocomp-bridge/rig-a.sock", path);
            let e = BridgeConfig::parse(&text, "s.toml").unwrap_err();
            let all = e.problems.join("\n");
            assert!(
                all.contains(&format!(
                    "zenoh.connect[0] = \"unixsock-stream/{path}\": the socket's path"
                )) && all.contains(rule),
                "{path}: {all}"
            );
        }
        // The longest path that fits.
        let path = format!("/tmp/b/{}", "x".repeat(MAX_SOCKET_PATH_BYTES - 7));
        assert_eq!(path.len(), MAX_SOCKET_PATH_BYTES);
        let text = GOOD.replace("/tmp/vibrocomp-bridge/rig-a.sock", &path);
        BridgeConfig::parse(&text, "s.toml").unwrap();
    }

    #[test]
    fn every_problem_is_reported_at_once() {
        let text = r#"
prefix = "bad prefix"
key_prefix = "vibrocomp/*/x"
[zenoh]
mode = "router"
listen = ["udp/127.0.0.1:7447", "tls/0.0.0.0:7447"]
connect_timeout_s = -1
[export]
streams = ["vib", "vibe", "vib"]
congestion = "maybe"
[import]
streams = ["vib"]
queue_depth = 0
"#;
        let e = BridgeConfig::parse(text, "b.toml").unwrap_err();
        let all = e.problems.join("\n");
        for needle in [
            "prefix = \"bad prefix\"",
            "key_prefix = \"vibrocomp/*/x\"",
            "zenoh.mode = \"router\"",
            "zenoh.listen[0] = \"udp/127.0.0.1:7447\": protocol \"udp\"",
            "zenoh.listen[1] = \"tls/0.0.0.0:7447\": a tls/ endpoint needs the [tls] table",
            "zenoh.listen[1] = \"tls/0.0.0.0:7447\": listens beyond loopback",
            "zenoh.connect_timeout_s = -1",
            "export.streams: \"vibe\" is not a stream",
            "export.streams: \"vib\" is named twice",
            "export.congestion = \"maybe\"",
            "both name \"vib\"",
            "import.queue_depth = 0",
        ] {
            assert!(all.contains(needle), "missing {needle:?} in:\n{all}");
        }
        assert_eq!(e.file, "b.toml");
    }

    #[test]
    fn unknown_keys_are_refused_with_their_line() {
        let text = GOOD.replace("queue_depth = 64", "queue_dept = 64");
        let e = BridgeConfig::parse(&text, "c.toml").unwrap_err();
        let loc = e.location();
        assert_eq!(loc.line, Some(12), "{e}");
        assert!(
            e.to_string()
                .contains("import.queue_dept: unknown key (did you mean queue_depth?)"),
            "{e}"
        );
    }

    /// The `key_prefix` of issue 46, item 7: 1 MB in 10 000 chunks. It was accepted,
    /// and the bridge then took 5.1 GB in 8 s and overflowed its export thread's stack
    /// (Zenoh keeps a node per chunk holding the key up to it, and frees them by one
    /// nested call per chunk). Refused at once, with both of its sizes.
    fn megabyte_key_prefix() -> String {
        // One chunk of 100 bytes, 9 999 of 99, and 9 999 slashes: 1 000 000 bytes.
        let chunks: Vec<String> = (0..10_000)
            .map(|i| "a".repeat(if i == 0 { 100 } else { 99 }))
            .collect();
        let key = chunks.join("/");
        assert_eq!((key.len(), key.split('/').count()), (1_000_000, 10_000));
        key
    }

    #[test]
    fn a_key_prefix_of_a_megabyte_in_ten_thousand_chunks_is_refused_at_once() {
        let text = GOOD.replace("vibrocomp/site-1/rig-a", &megabyte_key_prefix());
        let started = std::time::Instant::now();
        let e = BridgeConfig::parse(&text, "big.toml").unwrap_err();
        let elapsed = started.elapsed();
        let msg = e.to_string();
        assert!(elapsed.as_secs_f64() < 2.0, "{elapsed:?}");
        assert_eq!(e.problems.len(), 2, "{msg}");
        assert!(msg.starts_with("big.toml: key_prefix = \"aaaa"), "{msg}");
        assert!(
            e.problems[0].ends_with("more bytes cut)\" (1000000 bytes): at most 256 bytes"),
            "{msg}"
        );
        assert!(
            e.problems[1].ends_with("(10000 '/'-separated chunks): at most 16 chunks"),
            "{msg}"
        );
        assert!(msg.len() < 1024, "{} bytes", msg.len());
    }

    /// Every string and list of the file has a bound, checked before anything else,
    /// each value over it reported at once with its key, an excerpt and the rule.
    #[test]
    fn every_string_and_list_is_bounded() {
        let many = |n: usize, item: &str| {
            let items: Vec<String> = (0..n).map(|_| format!("{item:?}")).collect();
            format!("[{}]", items.join(", "))
        };
        let long_path = format!("/etc/{}", "p".repeat(5000));
        let text = format!(
            r#"
prefix = "{prefix}"
key_prefix = "{chunks}"
[zenoh]
mode = "{mode}"
listen = {listen}
connect = ["unixsock-stream//tmp/b/{socket}"]
connect_timeout_s = 2.0
[export]
streams = {streams}
congestion = "{mode}"
[import]
streams = ["vib"]
[tls]
root_ca_certificate = "{long_path}"
certificate = "/etc/b.pem"
private_key = "/etc/b.key"
[access]
allow_cert_common_names = ["{cn}"]
allow_zids = {zids}
"#,
            prefix = "p".repeat(300) + "/",
            chunks = ["k"; 17].join("/"),
            mode = "m".repeat(65),
            listen = many(65, "unixsock-stream//tmp/b/a.sock"),
            socket = "s".repeat(600),
            streams = many(100, "vib"),
            cn = "c".repeat(65),
            zids = many(65, "1f"),
        );
        let e = BridgeConfig::parse(&text, "sizes.toml").unwrap_err();
        let wanted = [
            "prefix = \"pppp",
            "(301 bytes): at most 255 bytes",
            "key_prefix = \"k/k/k/k/k/k/k/k/k/k/k/k/k/k/k/k/k\" (17 '/'-separated chunks): at most 16 chunks",
            "zenoh.mode = \"mmmm",
            "(65 bytes): at most 64 bytes",
            "zenoh.listen: 65 entries: at most 64",
            "zenoh.connect[0] = \"unixsock-stream//tmp/b/ssss",
            "(623 bytes): at most 512 bytes",
            "export.streams: 100 entries: at most",
            "export.congestion = \"mmmm",
            "tls.root_ca_certificate = \"/etc/pppp",
            "(5005 bytes): at most 4095 bytes",
            "access.allow_cert_common_names[0] = \"cccc",
            "access.allow_zids: 65 entries: at most 64",
        ];
        let all = e.problems.join("\n");
        for w in wanted {
            assert!(all.contains(w), "missing {w:?} in:\n{all}");
        }
        assert_eq!(e.problems.len(), 10, "{all}");
        // Sizes first: nothing else was looked at (the tls files do not exist).
        assert!(!all.contains("no such file"), "{all}");
        // The largest key passes.
        let key = longest_key_prefix();
        let text = GOOD.replace("vibrocomp/site-1/rig-a", &key);
        let c = BridgeConfig::parse(&text, "max.toml").unwrap();
        assert_eq!(c.key_prefix, key);
    }

    /// The longest `key_prefix` validation lets through: 256 bytes in 16 chunks.
    fn longest_key_prefix() -> String {
        let mut chunks = vec!["k".repeat(15); MAX_KEY_PREFIX_CHUNKS];
        chunks[0].push('k');
        let key = chunks.join("/");
        assert_eq!(key.len(), MAX_KEY_PREFIX_BYTES);
        key
    }

    /// Whatever passes validation cannot do what the megabyte key did: the longest
    /// key of every stream is declared, used and undeclared (where Zenoh's nested
    /// calls ran out of stack) on a thread with an eighth of a thread's default stack.
    #[test]
    fn the_longest_key_is_declared_and_undeclared_on_a_small_stack() {
        use zenoh::Wait;
        let key_prefix = longest_key_prefix();
        let config = zenoh::Config::from_json5(
            r#"{ mode: "peer", listen: { endpoints: [] }, connect: { endpoints: [] },
                 scouting: { multicast: { enabled: false }, gossip: { enabled: false } } }"#,
        )
        .unwrap();
        let session = zenoh::open(config).wait().unwrap();
        std::thread::Builder::new()
            .stack_size(256 << 10)
            .spawn(move || {
                for s in Stream::all() {
                    let key = format!("{key_prefix}/{}", s.suffix());
                    let publisher = session.declare_publisher(key.clone()).wait().unwrap();
                    let subscriber = session.declare_subscriber(key).wait().unwrap();
                    publisher.put(vec![1u8; 8]).wait().unwrap();
                    publisher.undeclare().wait().unwrap();
                    subscriber.undeclare().wait().unwrap();
                }
                session.close().wait().unwrap();
            })
            .unwrap()
            .join()
            .unwrap();
    }

    /// A socket named without a folder goes in this user's own (issue 46, item 8:
    /// the shared `/tmp/vibrocomp-bridge` let another user lock everybody out); the
    /// shipped files name theirs so.
    #[test]
    fn a_socket_named_alone_goes_in_this_users_folder() {
        let dir = crate::socket::default_socket_dir();
        assert_ne!(dir, Path::new("/tmp/vibrocomp-bridge"));
        for shipped in [
            include_str!("../../../config/bridge/compute-host.toml"),
            include_str!("../../../config/bridge/rig-host.toml"),
        ] {
            let c = BridgeConfig::parse(shipped, "shipped.toml").unwrap();
            let sockets = c.sockets();
            assert_eq!(sockets.len(), 1);
            assert_eq!(sockets[0].1, dir.join("site-1-rig-a.sock"));
        }
        assert_eq!(
            resolve_endpoint("unixsock-stream/a.sock", Path::new("/run/user/7/vb")),
            "unixsock-stream//run/user/7/vb/a.sock"
        );
        for unchanged in [
            "unixsock-stream//tmp/b/a.sock",
            "unixsock-stream/b/a.sock",
            "tls/h:1",
        ] {
            assert_eq!(resolve_endpoint(unchanged, Path::new("/x")), unchanged);
        }
        let e = BridgeConfig::parse(
            &GOOD.replace("/tmp/vibrocomp-bridge/rig-a.sock", "b/rig-a.sock"),
            "rel.toml",
        )
        .unwrap_err();
        assert!(e.problems[0].contains("must be a file name alone"), "{e}");
    }

    #[test]
    fn loopback_endpoints_are_told_apart() {
        assert!(is_loopback_endpoint("tcp/127.0.0.1:7447"));
        assert!(is_loopback_endpoint("tcp/[::1]:7447"));
        assert!(is_loopback_endpoint("tls/localhost:7447"));
        assert!(!is_loopback_endpoint("tcp/0.0.0.0:7447"));
        assert!(!is_loopback_endpoint("tcp/192.168.1.2:7447"));
        assert!(!is_loopback_endpoint("tcp/[::]:7447"));
    }
}
