//! The operator's web page at `/`: the queue and history of campaigns with progress and ETA, a
//! live plot of each campaign's samples with its reconstructions (a `[map]` campaign: heat maps
//! of e_x and e_y over XY, its samples live, then the reconstructed grid from `map_<dir>.csv`,
//! and the ISO 230-1 figures from `summary.json`), the ISO 230-2 figures, the
//! control buttons, campaign submission and the result files. Plain HTML, CSS and JavaScript
//! embedded in the binary (works offline, no build step); everything it shows comes from the
//! JSON routes, with the token (when the service needs one) in the `Authorization` header.
//!
//! The page and its assets are the only routes served without a token: they are the same for
//! every visitor and hold no data.
use axum::extract::Path;
use axum::http::{header, HeaderValue, Method, StatusCode};
use axum::response::{IntoResponse, Response};

use super::ApiError;

const INDEX_HTML: &str = include_str!("page/index.html");
const APP_JS: &str = include_str!("page/app.js");
const STYLE_CSS: &str = include_str!("page/style.css");

/// The page's assets under `/ui/`: (file name, content type, bytes).
const ASSETS: &[(&str, &str, &str)] = &[
    ("app.js", "text/javascript; charset=utf-8", APP_JS),
    ("style.css", "text/css; charset=utf-8", STYLE_CSS),
];

/// Scripts, styles and connections from this origin only; images also from `blob:` (result
/// plots are fetched with the token, then shown); no framing.
const CSP: &str = "default-src 'none'; script-src 'self'; style-src 'self'; \
                   img-src 'self' blob: data:; connect-src 'self'; base-uri 'none'; \
                   form-action 'none'; frame-ancestors 'none'";

/// Requests served without a token: the page and its assets (GET/HEAD of known paths only).
pub fn is_public(method: &Method, path: &str) -> bool {
    (method == Method::GET || method == Method::HEAD)
        && (path == "/"
            || path
                .strip_prefix("/ui/")
                .is_some_and(|f| ASSETS.iter().any(|(n, _, _)| *n == f)))
}

fn respond(ctype: &'static str, body: &'static str) -> Response {
    let mut r = (StatusCode::OK, body).into_response();
    let h = r.headers_mut();
    h.insert(header::CONTENT_TYPE, HeaderValue::from_static(ctype));
    // Always checked again: a new binary serves its own page.
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    h.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(CSP),
    );
    h.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    h.insert(
        header::REFERRER_POLICY,
        HeaderValue::from_static("no-referrer"),
    );
    r
}

/// `GET /`: the page.
pub async fn index() -> Response {
    respond("text/html; charset=utf-8", INDEX_HTML)
}

/// `GET /ui/{file}`: one of the page's assets.
pub async fn asset(Path(file): Path<String>) -> Response {
    match ASSETS.iter().find(|(n, _, _)| *n == file) {
        Some((_, ctype, body)) => respond(ctype, body),
        None => ApiError::not_found("no such route").into_response(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_the_page_and_its_assets_are_public() {
        assert!(is_public(&Method::GET, "/"));
        assert!(is_public(&Method::GET, "/ui/app.js"));
        assert!(is_public(&Method::HEAD, "/ui/style.css"));
        assert!(!is_public(&Method::POST, "/"));
        assert!(!is_public(&Method::GET, "/ui/"));
        assert!(!is_public(&Method::GET, "/ui/nope.js"));
        assert!(!is_public(&Method::GET, "/ui/../campaigns"));
        assert!(!is_public(&Method::GET, "/campaigns"));
        assert!(!is_public(&Method::GET, "/health"));
    }

    #[test]
    fn the_page_loads_its_assets_from_this_origin_only() {
        // Works offline: no CDN, no external URL anywhere in what the page loads.
        for text in [INDEX_HTML, APP_JS, STYLE_CSS] {
            assert!(!text.contains("http://") && !text.contains("https://"));
        }
        for (name, _, _) in ASSETS {
            assert!(INDEX_HTML.contains(&format!("/ui/{name}")), "{name}");
        }
        // The token travels in a header, never in a URL.
        assert!(APP_JS.contains("'Authorization'"));
        assert!(!APP_JS.contains("token="));
        assert!(!APP_JS.contains("new EventSource"));
    }
}
