//! The service's configuration file (`csmetro serve --config config/csmetro.toml`).
//!
//! ```toml
//! [server]
//! bind = "127.0.0.1:8463"       # a non-loopback address needs token or token_file
//! # token = "..."               # clients send `Authorization: Bearer <token>`
//! # token_file = "token"        # first line of the file (keeps the secret out of the config)
//! # allowed_hosts = ["lab-pc.example"]  # names browsers may reach it by besides its address and
//!                               # localhost (`name` on the bound port, or `name:port`)
//!
//! [storage]
//! db = "../var/csmetro.db"       # SQLite store: campaigns, samples, events, results
//! results_dir = "../var/results" # relative `[outputs] dir` of campaigns resolve from here
//! # max_store_mb = 4096          # submissions get 507 while the store is larger
//!
//! [campaigns]
//! base_dir = "campaigns"         # relative paths in submitted campaigns (stage models) resolve here
//! models_dir = "sim"             # optional: relative paths of submitted campaigns may also
//!                                # lead here (`../sim/demo_xy.toml`)
//! # max_queued = 100             # campaigns waiting per stage; one more gets 409
//!
//! [hardware]                     # what submitted real-rig campaigns may open (none by default)
//! serial_ports = ["/dev/serial/by-id/usb-PI_C-863_0115500001-if00-port0"]
//! tcp_endpoints = ["127.0.0.1:50863"]   # terminal servers, the simulated rig
//!
//! [log]
//! filter = "info"                # tracing filter; RUST_LOG overrides it
//! ```
//!
//! Relative paths resolve from the directory of the configuration file. Every error names the
//! file, the line and the key. A submitted campaign reads files only inside `base_dir` and
//! `models_dir` and writes only below `results_dir`.
use std::net::SocketAddr;
use std::ops::Range;
use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::campaign::spec::SubmitPolicy;
use crate::tomlpos::{line_of, read_bounded, span_of_deepest, TomlError, MAX_TOML_BYTES};

/// Port of the service when the configuration does not say.
pub const DEFAULT_PORT: u16 = 8463;

/// A configuration error pointing into the file: `file:line: key: message` (the error type of
/// campaign files too).
pub type ConfigError = TomlError;

/// Largest token file read.
const MAX_TOKEN_FILE_BYTES: u64 = 4096;

/// The validated service configuration, paths resolved.
#[derive(Debug, Clone)]
pub struct ServiceConfig {
    /// The file it was read from.
    pub path: PathBuf,
    pub bind: SocketAddr,
    /// Bearer token every request must carry; None = no authentication (loopback only).
    pub token: Option<String>,
    /// Host names the service answers to besides its address and `localhost` (`[server]
    /// allowed_hosts`, lower case; `name` or `name:port`).
    pub allowed_hosts: Vec<String>,
    pub db: PathBuf,
    pub results_dir: PathBuf,
    /// Where relative paths in submitted campaign files resolve.
    pub campaigns_dir: PathBuf,
    /// Where else relative paths of submitted campaigns may lead (stage models).
    pub models_dir: Option<PathBuf>,
    /// What clients may fill (`[storage] max_store_mb`, `[campaigns] max_queued`).
    pub limits: super::Limits,
    /// Serial devices submitted real-rig campaigns may open (`[hardware] serial_ports`).
    pub serial_ports: Vec<String>,
    /// `host:port` submitted real-rig campaigns may connect to (`[hardware] tcp_endpoints`).
    pub tcp_endpoints: Vec<String>,
    /// `target=level` directives, comma separated (tracing-subscriber `Targets`), e.g. `info,csmetro=debug`.
    pub log_filter: String,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Raw {
    #[serde(default)]
    server: RawServer,
    #[serde(default)]
    hardware: RawHardware,
    storage: RawStorage,
    #[serde(default)]
    campaigns: RawCampaigns,
    #[serde(default)]
    log: RawLog,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawServer {
    bind: Option<String>,
    token: Option<String>,
    token_file: Option<String>,
    #[serde(default)]
    allowed_hosts: Vec<String>,
}

/// What real-rig campaigns submitted to the service may open.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawHardware {
    #[serde(default)]
    serial_ports: Vec<String>,
    #[serde(default)]
    tcp_endpoints: Vec<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawStorage {
    db: String,
    results_dir: String,
    max_store_mb: Option<u64>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCampaigns {
    base_dir: Option<String>,
    models_dir: Option<String>,
    max_queued: Option<usize>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawLog {
    #[serde(default = "default_filter")]
    filter: String,
}

impl Default for RawLog {
    fn default() -> Self {
        Self {
            filter: default_filter(),
        }
    }
}

fn default_filter() -> String {
    "info".into()
}

impl ServiceConfig {
    /// Reads and validates a configuration file (reads `token_file` too).
    pub fn load(path: &Path) -> Result<ServiceConfig, ConfigError> {
        let origin = path.display().to_string();
        let text = read_bounded(path, MAX_TOML_BYTES).map_err(|e| ConfigError {
            origin: origin.clone(),
            line: 0,
            key: "-".into(),
            message: format!("cannot read: {e}"),
        })?;
        let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Self::parse(&text, &origin, &base)
    }

    /// Parses and validates configuration text; `origin` names it in errors, relative paths
    /// resolve from `base_dir`.
    pub fn parse(text: &str, origin: &str, base_dir: &Path) -> Result<ServiceConfig, ConfigError> {
        let err = |span: Option<Range<usize>>, key: &str, message: String| ConfigError {
            origin: origin.into(),
            line: span.map(|s| line_of(text, s.start)).unwrap_or(0),
            key: key.into(),
            message,
        };
        let raw: Raw = toml::from_str(text).map_err(|e| TomlError::from_toml(text, origin, &e))?;
        let fail = |key: &str, message: String| err(span_of_deepest(text, key), key, message);
        let resolve = |p: &str| {
            let p = Path::new(p);
            if p.is_absolute() {
                p.to_path_buf()
            } else {
                base_dir.join(p)
            }
        };

        let bind_text = raw
            .server
            .bind
            .unwrap_or_else(|| format!("127.0.0.1:{DEFAULT_PORT}"));
        let bind: SocketAddr = bind_text.parse().map_err(|e| {
            fail(
                "server.bind",
                format!("{bind_text:?} is not an IP:port address ({e})"),
            )
        })?;
        let token = match (raw.server.token, raw.server.token_file) {
            (Some(_), Some(_)) => {
                return Err(fail(
                    "server.token_file",
                    "give token or token_file, not both".into(),
                ))
            }
            (Some(t), None) => Some((t, "server.token")),
            (None, Some(f)) => {
                let p = resolve(&f);
                let t = read_bounded(&p, MAX_TOKEN_FILE_BYTES).map_err(|e| {
                    fail(
                        "server.token_file",
                        format!("cannot read {}: {e}", p.display()),
                    )
                })?;
                Some((
                    t.lines().next().unwrap_or("").to_string(),
                    "server.token_file",
                ))
            }
            (None, None) => None,
        };
        let token = match token {
            Some((t, key)) => {
                let t = t.trim().to_string();
                if t.len() < 16 || t.chars().any(|c| !c.is_ascii_graphic()) {
                    return Err(fail(
                        key,
                        "the token must be at least 16 printable ASCII characters without spaces"
                            .into(),
                    ));
                }
                Some(t)
            }
            None => None,
        };
        if !bind.ip().is_loopback() && token.is_none() {
            return Err(fail(
                "server.bind",
                format!(
                    "{bind} is not a loopback address: set server.token or server.token_file \
                     (clients then send `Authorization: Bearer <token>`), or bind 127.0.0.1"
                ),
            ));
        }
        if raw.server.allowed_hosts.len() > 64 {
            return Err(fail("server.allowed_hosts", "at most 64 names".into()));
        }
        let mut allowed_hosts = Vec::new();
        for h in &raw.server.allowed_hosts {
            let h = h.trim().to_ascii_lowercase();
            let (name, port) = match h.rsplit_once(':') {
                Some((n, p)) if !n.ends_with(']') && !n.contains(':') => (n, Some(p)),
                _ => (h.as_str(), None),
            };
            let name_ok = !name.is_empty()
                && name.len() <= 253
                && name
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '.');
            if !name_ok || port.is_some_and(|p| p.parse::<u16>().is_err()) {
                return Err(fail(
                    "server.allowed_hosts",
                    "each entry is a host name or `name:port` (letters, digits, `-`, `.`),                      no scheme or path"
                        .into(),
                ));
            }
            allowed_hosts.push(h);
        }
        if raw.storage.max_store_mb == Some(0) {
            return Err(fail("storage.max_store_mb", "must be at least 1 MB".into()));
        }
        if raw.campaigns.max_queued == Some(0) {
            return Err(fail("campaigns.max_queued", "must be at least 1".into()));
        }
        for p in &raw.hardware.serial_ports {
            if !p.starts_with("/dev/") || p.len() > 1024 || p.contains("/../") {
                return Err(fail(
                    "hardware.serial_ports",
                    "each entry is a device path under /dev".into(),
                ));
            }
        }
        for a in &raw.hardware.tcp_endpoints {
            let ok = a
                .rsplit_once(':')
                .is_some_and(|(h, p)| !h.is_empty() && h.len() <= 253 && p.parse::<u16>().is_ok());
            if !ok {
                return Err(fail(
                    "hardware.tcp_endpoints",
                    "each entry is `host:port`".into(),
                ));
            }
        }
        for (key, v) in [
            ("storage.db", &raw.storage.db),
            ("storage.results_dir", &raw.storage.results_dir),
        ] {
            if v.trim().is_empty() {
                return Err(fail(key, "must not be empty".into()));
            }
        }
        if let Err(e) = parse_log_filter(&raw.log.filter) {
            return Err(fail("log.filter", format!("not a tracing filter: {e}")));
        }
        let campaigns_dir = raw
            .campaigns
            .base_dir
            .as_deref()
            .map(resolve)
            .unwrap_or_else(|| base_dir.to_path_buf());
        let db = resolve(&raw.storage.db);
        let models_dir = match raw.campaigns.models_dir.as_deref() {
            Some(d) if d.trim().is_empty() => {
                return Err(fail("campaigns.models_dir", "must not be empty".into()))
            }
            d => d.map(resolve),
        };
        Ok(ServiceConfig {
            path: PathBuf::from(origin),
            bind,
            token,
            allowed_hosts,
            limits: {
                let d = super::Limits::default();
                super::Limits {
                    max_store_bytes: raw
                        .storage
                        .max_store_mb
                        .map_or(d.max_store_bytes, |mb| mb.saturating_mul(1 << 20)),
                    max_queued_per_stage: raw
                        .campaigns
                        .max_queued
                        .unwrap_or(d.max_queued_per_stage),
                }
            },
            serial_ports: raw.hardware.serial_ports,
            tcp_endpoints: raw.hardware.tcp_endpoints,
            db,
            results_dir: resolve(&raw.storage.results_dir),
            campaigns_dir,
            models_dir,
            log_filter: raw.log.filter,
        })
    }

    /// What campaigns submitted to this service may read and write.
    pub fn submit_policy(&self) -> SubmitPolicy {
        SubmitPolicy {
            base_dir: self.campaigns_dir.clone(),
            read_roots: std::iter::once(self.campaigns_dir.clone())
                .chain(self.models_dir.clone())
                .collect(),
            results_dir: self.results_dir.clone(),
            serial_ports: self.serial_ports.clone(),
            tcp_endpoints: self.tcp_endpoints.clone(),
        }
    }
}

/// A log filter: comma-separated `level` or `target=level` directives (`info,csmetro=debug`).
/// Stricter than `Targets`' own parser, which takes any word as a target name: a typo must not
/// silently log everything of a target nobody has.
pub fn parse_log_filter(s: &str) -> Result<tracing_subscriber::filter::Targets, LogFilterError> {
    const LEVELS: [&str; 6] = ["trace", "debug", "info", "warn", "error", "off"];
    let is_level = |l: &str| LEVELS.contains(&l.to_ascii_lowercase().as_str());
    let is_target = |t: &str| {
        !t.is_empty()
            && t.chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == ':' || c == '-')
    };
    for d in s.split(',').map(str::trim).filter(|d| !d.is_empty()) {
        let ok = match d.split_once('=') {
            Some((t, l)) => is_target(t.trim()) && is_level(l.trim()),
            None => is_level(d),
        };
        if !ok {
            return Err(LogFilterError::Directive(d.to_string()));
        }
    }
    Ok(s.parse()?)
}

/// A log filter that does not parse.
#[derive(Debug, thiserror::Error)]
pub enum LogFilterError {
    #[error(
        "`{0}` is not `level` or `target=level` (levels: trace, debug, info, warn, error, off)"
    )]
    Directive(String),
    #[error(transparent)]
    Parse(#[from] tracing_subscriber::filter::ParseError),
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = "[server]\nbind = \"127.0.0.1:0\"\n\n[storage]\ndb = \"var/c.db\"\nresults_dir = \"var/results\"\n";

    fn parse(t: &str) -> Result<ServiceConfig, ConfigError> {
        ServiceConfig::parse(t, "svc.toml", Path::new("/etc/csmetro"))
    }

    #[test]
    fn paths_resolve_from_the_config_directory() {
        let c = parse(GOOD).unwrap();
        assert_eq!(c.db, Path::new("/etc/csmetro/var/c.db"));
        assert_eq!(c.results_dir, Path::new("/etc/csmetro/var/results"));
        assert_eq!(c.campaigns_dir, Path::new("/etc/csmetro"));
        assert_eq!(c.models_dir, None);
        let p = c.submit_policy();
        assert_eq!(p.read_roots, vec![PathBuf::from("/etc/csmetro")]);
        assert_eq!(p.results_dir, Path::new("/etc/csmetro/var/results"));
        assert!(c.bind.ip().is_loopback());
        assert_eq!(c.token, None);
        assert_eq!(c.log_filter, "info");
        assert!(c.allowed_hosts.is_empty());
    }

    #[test]
    fn allowed_hosts_are_names_not_urls() {
        let t = GOOD.replace(
            "[server]\n",
            "[server]\nallowed_hosts = [\"Lab-PC.example\", \"x:8080\"]\n",
        );
        assert_eq!(
            parse(&t).unwrap().allowed_hosts,
            ["lab-pc.example", "x:8080"]
        );
        for bad in ["http://evil", "a/b", "", "x:port"] {
            let t = GOOD.replace(
                "[server]\n",
                &format!("[server]\nallowed_hosts = [\"{bad}\"]\n"),
            );
            let e = parse(&t).unwrap_err();
            assert_eq!(
                (e.key.as_str(), e.line),
                ("server.allowed_hosts", 2),
                "{bad}: {e}"
            );
        }
    }

    #[test]
    fn default_bind_is_loopback_on_the_service_port() {
        let c = parse("[storage]\ndb = \"a.db\"\nresults_dir = \"r\"\n").unwrap();
        assert_eq!(c.bind.to_string(), format!("127.0.0.1:{DEFAULT_PORT}"));
    }

    #[test]
    fn non_loopback_without_token_is_refused_naming_the_line() {
        let t = GOOD.replace("127.0.0.1:0", "0.0.0.0:8463");
        let e = parse(&t).unwrap_err();
        assert_eq!((e.key.as_str(), e.line), ("server.bind", 2), "{e}");
        assert!(e.to_string().starts_with("svc.toml:2: server.bind:"), "{e}");
        assert!(e.message.contains("token"), "{e}");

        let t = t.replace("[server]\n", "[server]\ntoken = \"0123456789abcdef0123\"\n");
        assert_eq!(
            parse(&t).unwrap().token.as_deref(),
            Some("0123456789abcdef0123")
        );
    }

    #[test]
    fn short_tokens_unknown_keys_and_bad_addresses_name_the_key() {
        let t = GOOD.replace("[server]\n", "[server]\ntoken = \"short\"\n");
        assert_eq!(parse(&t).unwrap_err().key, "server.token");

        let t = GOOD.replace("results_dir", "result_dir");
        let e = parse(&t).unwrap_err();
        assert_eq!((e.key.as_str(), e.line), ("storage.result_dir", 6), "{e}");

        let t = GOOD.replace("127.0.0.1:0", "localhost");
        let e = parse(&t).unwrap_err();
        assert_eq!((e.key.as_str(), e.line), ("server.bind", 2), "{e}");

        let t = format!("{GOOD}\n[log]\nfilter = \"[[[\"\n");
        assert_eq!(parse(&t).unwrap_err().key, "log.filter");
        let t = format!("{GOOD}\n[log]\nfilter = \"info,csmetro=debug\"\n");
        assert_eq!(parse(&t).unwrap().log_filter, "info,csmetro=debug");
        let t = format!("{GOOD}\n[log]\nfilter = \"csmetro=loud\"\n");
        assert_eq!(parse(&t).unwrap_err().key, "log.filter");
    }

    #[test]
    fn token_file_is_read_and_trimmed() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("tok"), "abcdefghijklmnopqrstuvwxyz\n").unwrap();
        let t = GOOD.replace("[server]\n", "[server]\ntoken_file = \"tok\"\n");
        let c = ServiceConfig::parse(&t, "svc.toml", dir.path()).unwrap();
        assert_eq!(c.token.as_deref(), Some("abcdefghijklmnopqrstuvwxyz"));

        let t = GOOD.replace("[server]\n", "[server]\ntoken_file = \"missing\"\n");
        let e = ServiceConfig::parse(&t, "svc.toml", dir.path()).unwrap_err();
        assert_eq!((e.key.as_str(), e.line), ("server.token_file", 2), "{e}");
    }
}
