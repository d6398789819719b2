//! The bridge's configuration file: raw TOML (unknown keys refused with their line) →
//! [`BridgeConfig`], validated with every problem reported at once, and the Zenoh
//! configuration (JSON5) built from it.

use serde::Deserialize;
use std::path::{Path, PathBuf};
use std::time::Duration;
use vibro_msgs::{ServiceNames, Stream};
use vibro_service::{check_prefix, check_seconds, parse_toml, read_config_file, ConfigError};

/// Most messages an import queue may hold (each holds one Zenoh sample, up to 12 KB).
pub const MAX_QUEUE_DEPTH: usize = 65_536;

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
    pub allow_cert_common_names: Vec<String>,
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

fn check_endpoint(key: &str, endpoint: &str, tls: bool, problems: &mut Vec<String>) {
    let Some((proto, addr)) = endpoint.split_once('/') else {
        problems.push(format!(
            "{key} = {endpoint:?}: must be PROTOCOL/HOST:PORT, e.g. tcp/127.0.0.1:7447"
        ));
        return;
    };
    match proto {
        "tcp" => {}
        "tls" if tls => {}
        "tls" => problems.push(format!(
            "{key} = {endpoint:?}: a tls/ endpoint needs the [tls] table"
        )),
        other => problems.push(format!(
            "{key} = {endpoint:?}: protocol {other:?} is not built in (tcp or tls)"
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

impl BridgeConfig {
    /// Reads and validates `path`.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = read_config_file(path)?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Validates the TOML `text` of the file `file`; relative certificate paths are
    /// taken relative to the working directory.
    pub fn parse(text: &str, file: &str) -> Result<Self, ConfigError> {
        let raw: Raw = parse_toml(text, file)?;
        let mut p = Vec::new();
        let prefix = raw.prefix.unwrap_or_else(vibro_service::default_prefix);
        let names = check_prefix("prefix", &prefix, &mut p);
        check_key_prefix(&raw.key_prefix, &mut p);
        let mode = match raw.zenoh.mode.as_str() {
            "peer" => Some(Mode::Peer),
            "client" => Some(Mode::Client),
            other => {
                p.push(format!("zenoh.mode = {other:?}: must be peer or client"));
                None
            }
        };
        let tls_on = raw.tls.is_some();
        for (i, e) in raw.zenoh.listen.iter().enumerate() {
            check_endpoint(&format!("zenoh.listen[{i}]"), e, tls_on, &mut p);
        }
        for (i, e) in raw.zenoh.connect.iter().enumerate() {
            check_endpoint(&format!("zenoh.connect[{i}]"), e, tls_on, &mut p);
        }
        if raw.zenoh.listen.is_empty() && raw.zenoh.connect.is_empty() {
            p.push(
                "zenoh: listen and connect are both empty: name at least one endpoint (multicast scouting is off)"
                    .to_string(),
            );
        }
        if mode == Some(Mode::Client) && raw.zenoh.connect.is_empty() {
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
            for (i, e) in raw
                .zenoh
                .listen
                .iter()
                .chain(&raw.zenoh.connect)
                .enumerate()
            {
                if e.starts_with("tcp/") {
                    p.push(format!(
                        "endpoint {i} {e:?}: with [tls], every endpoint is tls/ (a tcp/ one would bypass it)"
                    ));
                }
            }
        }
        // README, "Several hosts": a bridge reachable from other hosts names who may
        // connect, and checks it with certificates.
        for (i, e) in raw.zenoh.listen.iter().enumerate() {
            if is_loopback_endpoint(e) {
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
                listen: raw.zenoh.listen,
                connect: raw.zenoh.connect,
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
connect = ["tcp/127.0.0.1:7447"]
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
        // The JSON5 is one Zenoh accepts.
        zenoh::Config::from_json5(&c.zenoh_json5()).unwrap();
    }

    #[test]
    fn every_problem_is_reported_at_once() {
        let text = r#"
prefix = "bad prefix"
key_prefix = "vibrocomp/*/x"
[zenoh]
mode = "router"
listen = ["udp/127.0.0.1:7447", "tcp/0.0.0.0:7447"]
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
            "zenoh.listen[1] = \"tcp/0.0.0.0:7447\": listens beyond loopback",
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
