//! The browser is a client too: any page a lab user has open can send "simple" requests to the
//! service on 127.0.0.1, and a DNS-rebound name can even read the answers. Every request passes
//! [`Guard::check_source`] (before authentication) and [`Guard::check_body`] (after it) before its route:
//!
//! - `Host` must name the service: the bound address (any loopback address when bound to one,
//!   any IP literal when bound to all), `localhost`, or a name from `[server] allowed_hosts`, on
//!   the bound port. A rebound DNS name is refused (421) whatever it resolves to.
//! - `Origin`, when a browser sends one, must be the service's own (`http(s)://` + an allowed
//!   host); `Origin: null` and foreign origins are refused (403), reads included.
//! - State-changing requests (anything but GET/HEAD) are refused when the browser says it is a
//!   cross-site or no-cors/navigation request (`Sec-Fetch-*`), and accept only their own content
//!   types: JSON or TOML for bodies (a browser must preflight them, and no CORS is ever
//!   answered), no body at all for control routes. A body-less request from a browser (it sends
//!   `Origin`) must still say `application/json`.
//!
//! Responses never carry CORS headers; every one says `nosniff`.
use std::net::{IpAddr, SocketAddr};

use axum::http::{header, HeaderMap, Method, StatusCode};

use super::ApiError;

/// Which body a state-changing route takes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BodyKind {
    /// A campaign file: `application/toml` or `application/json` (`{"toml": .., "name": ..}`).
    Campaign,
    /// `application/json`.
    Json,
    /// No body (pause, resume, abort); a browser sends `application/json` with `{}` or nothing.
    None,
}

/// The media types a campaign submission may carry (never a CORS "simple" type).
pub const CAMPAIGN_TYPES: [&str; 2] = ["application/toml", "application/json"];

/// The Host/Origin/content-type policy of one bound service.
#[derive(Debug, Clone)]
pub struct Guard {
    bind: SocketAddr,
    /// `[server] allowed_hosts`, lower case: `name` (on the bound port) or `name:port`.
    names: Vec<String>,
}

/// A host and optional port from a `Host` header or an origin's authority.
fn split_host(authority: &str) -> Option<(String, Option<u16>)> {
    let a = authority.trim();
    if a.is_empty() || a.contains(['/', '@', ' ']) {
        return None;
    }
    let (host, port) = if let Some(rest) = a.strip_prefix('[') {
        let (h, after) = rest.split_once(']')?;
        let port = match after {
            "" => None,
            p => Some(p.strip_prefix(':')?.parse().ok()?),
        };
        (format!("[{h}]"), port)
    } else {
        match a.rsplit_once(':') {
            Some((h, p)) => (h.to_string(), Some(p.parse().ok()?)),
            None => (a.to_string(), None),
        }
    };
    let host = host.to_ascii_lowercase();
    let host = host.strip_suffix('.').unwrap_or(&host).to_string();
    (!host.is_empty()).then_some((host, port))
}

fn ip_of(host: &str) -> Option<IpAddr> {
    let h = host
        .strip_prefix('[')
        .and_then(|h| h.strip_suffix(']'))
        .unwrap_or(host);
    h.parse().ok()
}

/// The media type of a `Content-Type` header, lower case, parameters dropped.
fn media_type(headers: &HeaderMap) -> Option<String> {
    headers.get(header::CONTENT_TYPE).map(|v| {
        String::from_utf8_lossy(v.as_bytes())
            .split(';')
            .next()
            .unwrap_or("")
            .trim()
            .to_ascii_lowercase()
    })
}

impl Guard {
    /// The policy of a service listening on `bind` (the address actually bound, port included)
    /// that also answers to `allowed_hosts` (`name` or `name:port`).
    pub fn new(bind: SocketAddr, allowed_hosts: &[String]) -> Guard {
        Guard {
            bind,
            names: allowed_hosts
                .iter()
                .map(|h| h.trim().to_ascii_lowercase())
                .collect(),
        }
    }

    /// The port a host without one means: the bound port when the scheme's default is not
    /// given (80 for http).
    fn port_ok(&self, port: Option<u16>, default: u16) -> bool {
        port.unwrap_or(default) == self.bind.port()
    }

    /// Whether `authority` (`host[:port]`) names this service; `default` is the scheme's port.
    fn host_ok(&self, authority: &str, default: u16) -> bool {
        let Some((host, port)) = split_host(authority) else {
            return false;
        };
        // A configured name matches with its own port, or on the bound port.
        let named = self.names.iter().any(|n| match split_host(n) {
            Some((h, Some(p))) => h == host && port.unwrap_or(default) == p,
            Some((h, None)) => h == host && self.port_ok(port, default),
            None => false,
        });
        if named {
            return true;
        }
        if !self.port_ok(port, default) {
            return false;
        }
        let bound = self.bind.ip();
        if host == "localhost" {
            return bound.is_loopback() || bound.is_unspecified();
        }
        // IP literals cannot be rebound to another machine by DNS.
        match ip_of(&host) {
            Some(_) if bound.is_unspecified() => true,
            Some(ip) if bound.is_loopback() => ip.is_loopback(),
            Some(ip) => ip == bound,
            None => false,
        }
    }

    /// Whether `origin` (`scheme://authority`) is the service's own.
    fn origin_ok(&self, origin: &str) -> bool {
        let (authority, default) = if let Some(a) = origin.strip_prefix("http://") {
            (a, 80)
        } else if let Some(a) = origin.strip_prefix("https://") {
            (a, 443)
        } else {
            return false;
        };
        self.host_ok(authority, default)
    }

    /// Who is asking: Host, Origin and (for state changes) fetch metadata. Runs before
    /// authentication: a rebound name or another page learns nothing, not even whether a token
    /// is needed.
    pub fn check_source(&self, method: &Method, headers: &HeaderMap) -> Result<(), ApiError> {
        let text = |name: header::HeaderName| {
            headers
                .get(name)
                .map(|v| String::from_utf8_lossy(v.as_bytes()).into_owned())
        };
        if let Some(host) = text(header::HOST) {
            if !self.host_ok(&host, 80) {
                return Err(ApiError::new(
                    StatusCode::MISDIRECTED_REQUEST,
                    "Host: not a name of this service (add it to [server] allowed_hosts)",
                ));
            }
        }
        let origin = text(header::ORIGIN);
        if let Some(o) = &origin {
            if !self.origin_ok(o.trim()) {
                return Err(ApiError::new(
                    StatusCode::FORBIDDEN,
                    "Origin: requests from other web pages are refused",
                ));
            }
        }
        let reads = method == Method::GET || method == Method::HEAD;
        if reads {
            return Ok(());
        }
        let site = text(header::HeaderName::from_static("sec-fetch-site"));
        if site
            .as_deref()
            .is_some_and(|s| !matches!(s.trim(), "same-origin" | "none"))
        {
            return Err(ApiError::new(
                StatusCode::FORBIDDEN,
                "Sec-Fetch-Site: only the service's own page may change anything",
            ));
        }
        let mode = text(header::HeaderName::from_static("sec-fetch-mode"));
        if mode
            .as_deref()
            .is_some_and(|m| matches!(m.trim(), "no-cors" | "navigate" | "nested-navigate"))
        {
            return Err(ApiError::new(
                StatusCode::FORBIDDEN,
                "Sec-Fetch-Mode: forms and no-cors requests may not change anything",
            ));
        }
        Ok(())
    }

    /// What a state change carries: only its route's content types (after authentication).
    pub fn check_body(
        method: &Method,
        headers: &HeaderMap,
        body: Option<BodyKind>,
        body_len: Option<u64>,
    ) -> Result<(), ApiError> {
        if method == Method::GET || method == Method::HEAD {
            return Ok(());
        }
        let text = |name: header::HeaderName| {
            headers
                .get(name)
                .map(|v| String::from_utf8_lossy(v.as_bytes()).into_owned())
        };
        let origin = text(header::ORIGIN);
        let site = text(header::HeaderName::from_static("sec-fetch-site"));
        let ctype = media_type(headers);
        let unsupported = |want: &str| {
            ApiError::new(
                StatusCode::UNSUPPORTED_MEDIA_TYPE,
                format!(
                    "Content-Type {}: send {want}",
                    ctype.as_deref().unwrap_or("(none)")
                ),
            )
        };
        match body.unwrap_or(BodyKind::None) {
            BodyKind::Campaign => {
                if !ctype
                    .as_deref()
                    .is_some_and(|c| CAMPAIGN_TYPES.contains(&c))
                {
                    return Err(unsupported("application/toml or application/json"));
                }
            }
            BodyKind::Json => {
                if ctype.as_deref() != Some("application/json") {
                    return Err(unsupported("application/json"));
                }
            }
            BodyKind::None => match ctype.as_deref() {
                Some("application/json") => {}
                // No content type: a client that is not a browser (browsers send Origin on
                // every POST), with nothing in the body.
                None if origin.is_none() && site.is_none() => {
                    if body_len.is_some_and(|n| n > 0) {
                        return Err(unsupported("no body, or application/json"));
                    }
                }
                _ => return Err(unsupported("no body, or application/json")),
            },
        }
        Ok(())
    }
}

/// Compares a bearer token in constant time, its length included: the time depends on the
/// configured token's length only, not on how much of a guess was right or how long it was.
pub fn token_matches(given: &[u8], token: &[u8]) -> bool {
    use subtle::ConstantTimeEq;
    let mut padded = vec![0u8; token.len()];
    let n = given.len().min(token.len());
    padded[..n].copy_from_slice(&given[..n]);
    let same_len = (given.len() as u64).ct_eq(&(token.len() as u64));
    bool::from(padded.as_slice().ct_eq(token) & same_len)
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::http::HeaderValue;

    impl Guard {
        /// Both checks, in the order the router runs them.
        fn check(
            &self,
            method: &Method,
            headers: &HeaderMap,
            body: Option<BodyKind>,
            body_len: Option<u64>,
        ) -> Result<(), ApiError> {
            self.check_source(method, headers)?;
            Self::check_body(method, headers, body, body_len)
        }
    }

    fn guard(bind: &str) -> Guard {
        Guard::new(bind.parse().unwrap(), &["lab-pc.example".into()])
    }

    fn headers(pairs: &[(&'static str, &str)]) -> HeaderMap {
        let mut h = HeaderMap::new();
        for (k, v) in pairs {
            h.insert(*k, HeaderValue::from_str(v).unwrap());
        }
        h
    }

    #[test]
    fn hosts_are_the_bound_address_localhost_or_configured_names() {
        let g = guard("127.0.0.1:8463");
        for ok in [
            "127.0.0.1:8463",
            "localhost:8463",
            "LOCALHOST.:8463",
            "[::1]:8463",
            "lab-pc.example:8463",
        ] {
            assert!(g.host_ok(ok, 80), "{ok}");
        }
        for bad in [
            "evil.example:8463",
            "127.0.0.1:8464",
            "127.0.0.1",
            "10.0.0.1:8463",
            "",
            "a@127.0.0.1:8463",
            "127.0.0.1:x",
        ] {
            assert!(!g.host_ok(bad, 80), "{bad}");
        }
        let all = guard("0.0.0.0:8463");
        assert!(all.host_ok("192.0.2.7:8463", 80));
        assert!(!all.host_ok("rebound.example:8463", 80));
        let one = guard("192.0.2.7:80");
        assert!(one.host_ok("192.0.2.7", 80));
        assert!(!one.host_ok("localhost", 80));
    }

    #[test]
    fn foreign_origins_and_null_are_refused_reads_included() {
        let g = guard("127.0.0.1:8463");
        let get = |o: &str| g.check(&Method::GET, &headers(&[("origin", o)]), None, None);
        assert!(get("http://127.0.0.1:8463").is_ok());
        assert!(get("http://localhost:8463").is_ok());
        for bad in [
            "http://evil.example",
            "null",
            "http://127.0.0.1:9999",
            "file://",
        ] {
            assert_eq!(get(bad).unwrap_err().status, StatusCode::FORBIDDEN, "{bad}");
        }
        let e = g
            .check(
                &Method::GET,
                &headers(&[("host", "evil.example:8463")]),
                None,
                None,
            )
            .unwrap_err();
        assert_eq!(e.status, StatusCode::MISDIRECTED_REQUEST);
    }

    #[test]
    fn state_changes_take_only_their_content_types() {
        let g = guard("127.0.0.1:8463");
        let post = |h: &[(&'static str, &str)], b: BodyKind, n: u64| {
            g.check(&Method::POST, &headers(h), Some(b), Some(n))
                .map_err(|e| e.status.as_u16())
        };
        for simple in [
            "text/plain",
            "application/x-www-form-urlencoded",
            "multipart/form-data; boundary=x",
        ] {
            assert_eq!(
                post(&[("content-type", simple)], BodyKind::Campaign, 10),
                Err(415)
            );
            assert_eq!(
                post(&[("content-type", simple)], BodyKind::Json, 10),
                Err(415)
            );
            assert_eq!(
                post(&[("content-type", simple)], BodyKind::None, 0),
                Err(415)
            );
        }
        assert_eq!(post(&[], BodyKind::Campaign, 10), Err(415));
        assert_eq!(post(&[], BodyKind::Json, 10), Err(415));
        assert!(post(
            &[("content-type", "application/toml; charset=utf-8")],
            BodyKind::Campaign,
            10
        )
        .is_ok());
        assert!(post(&[("content-type", "application/json")], BodyKind::Json, 10).is_ok());
        // Control routes: curl's bare POST, or the page's JSON.
        assert!(post(&[], BodyKind::None, 0).is_ok());
        assert_eq!(post(&[], BodyKind::None, 3), Err(415));
        // A browser's body-less POST carries Origin: it must say JSON.
        assert_eq!(
            post(&[("origin", "http://127.0.0.1:8463")], BodyKind::None, 0),
            Err(415)
        );
        assert!(post(
            &[
                ("origin", "http://127.0.0.1:8463"),
                ("content-type", "application/json")
            ],
            BodyKind::None,
            2
        )
        .is_ok());
        // Fetch metadata of a cross-site, form or no-cors request.
        for (k, v) in [
            ("sec-fetch-site", "cross-site"),
            ("sec-fetch-site", "same-site"),
            ("sec-fetch-mode", "no-cors"),
            ("sec-fetch-mode", "navigate"),
        ] {
            assert_eq!(
                post(
                    &[(k, v), ("content-type", "application/json")],
                    BodyKind::Json,
                    2
                ),
                Err(403),
                "{k}: {v}"
            );
        }
    }

    #[test]
    fn tokens_compare_whole_and_by_length() {
        assert!(token_matches(b"0123456789abcdef", b"0123456789abcdef"));
        assert!(!token_matches(b"0123456789abcde", b"0123456789abcdef"));
        assert!(!token_matches(b"0123456789abcdef0", b"0123456789abcdef"));
        assert!(!token_matches(b"", b"0123456789abcdef"));
        assert!(!token_matches(b"0123456789abcdeF", b"0123456789abcdef"));
    }
}
