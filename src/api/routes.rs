//! The endpoints. JSON in and out; errors are `{"error": "..."}` with 400 (bad input), 401 (no
//! or wrong token), 403/415/421 (the browser screen, below), 404 (no such campaign or result), 409
//! (not possible in the campaign's state), 507 (the store is over its quota).
//!
//! | route | |
//! |---|---|
//! | `GET /` | the operator's web page ([`super::page`]; its assets under `/ui/`) |
//! | `GET /health` | service up; running and queued campaign ids |
//! | `GET /campaigns` | every campaign with its state and progress, newest first |
//! | `POST /campaigns` | body: campaign TOML (`application/toml`) or JSON `{"toml": "...", "name": "file.toml"}`; 201 with its status |
//! | `GET /campaigns/{id}` | state, planned, stored, percent, message, queue position |
//! | `GET /campaigns/{id}/events[?after=ID]` | server-sent events: the stored log, then live events (`sample` ones too); ends after `finished` |
//! | `POST /campaigns/{id}/pause`, `/resume`, `/abort` | control; answers the status |
//! | `GET /campaigns/{id}/samples[?after=N&limit=L]` | committed samples in commit order: `{"id", "samples": [{"n", "sample"}], "next"}`; `next` is the `after` of the following page (live `sample` events a client missed are all here) |
//! | `GET /campaigns/{id}/results` | `{"id": .., "results": [names]}` |
//! | `GET /campaigns/{id}/results/{*name}` | the bytes, with their stored content type |
//! | `GET /campaigns/{id}/verification` | the verdict of a verification (`csmetro verify ID --json`'s object) of characterisation `id` or by verification campaign `id`; 404 when none |
//! | `POST /stages/{name}/move` | body `{"x_um", "y_um"?, "direction"?, "approach_um"?, "compensation_from"?, "hardware_from"?, "measure"?}`: a (compensated) move; 409 while a campaign runs or waits on that stage |
//! | `GET /stages/{name}/events[?after=ID&limit=L]` | the stage's log outside campaigns: each move (`move`, then `moved` or `move_failed`) with who asked |
//!
//! With a token configured every route, `/health` included, needs `Authorization: Bearer TOKEN`;
//! only the page and its assets (the same for everyone, no data) load without it.
//!
//! Before any of that, [`super::guard`] checks `Host`, `Origin`, fetch metadata and content
//! types: 421 for a Host that is not the service's, 403 for another page's request, 415 for a
//! state change in a type a browser may send without asking (`text/plain`, forms). `POST
//! /campaigns` takes `application/toml` or `application/json`, `POST /stages/{name}/move`
//! `application/json`, pause/resume/abort no body (or `application/json`). No CORS is answered.
//! Result files are served with `Content-Security-Policy: sandbox` and `nosniff`.
//!
//! Submit, pause, resume and abort are logged with their origin: the client's address and,
//! when the request carries an `X-Operator: NAME` header (UTF-8, at most 64 bytes, no control
//! characters, else 400), the operator's name (`"by"` and `"origin"` in the events).
//!
//! A submitted campaign is untrusted: its stage model is a relative `.toml` path inside
//! `[campaigns] base_dir` or `models_dir`, its `[outputs] dir` a relative directory below
//! `results_dir`; anything else is a 400 that names the key and line but shows no server path
//! and no file content.
use std::convert::Infallible;
use std::sync::Arc;

use axum::body::Bytes;
use axum::extract::{Path, Query, Request, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::middleware::{self, Next};
use axum::response::sse::{Event as SseEvent, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use futures_util::Stream;
use serde::Deserialize;
use serde_json::json;
use tokio::sync::{broadcast, mpsc};

use super::guard::{token_matches, BodyKind, Guard};
use super::manager::ManagerError;
use super::{ApiError, CampaignStatus, Manager};
use crate::campaign::preflight::Class;
use crate::campaign::session::Event;
use crate::campaign::spec::{Campaign, SubmitPolicy};
use crate::types::{check_operator, CampaignState, Origin};

/// Who sent a request, for the event log: the client's address (when the server knows it)
/// and the operator's name from the `X-Operator` header (optional; UTF-8, at most 64 bytes,
/// no control characters, else 400).
struct ApiOrigin(Origin);

impl<S: Send + Sync> axum::extract::FromRequestParts<S> for ApiOrigin {
    type Rejection = ApiError;

    async fn from_request_parts(
        parts: &mut axum::http::request::Parts,
        _: &S,
    ) -> Result<Self, ApiError> {
        let client = parts
            .extensions
            .get::<axum::extract::ConnectInfo<std::net::SocketAddr>>()
            .map(|c| c.0.to_string());
        let operator = match parts.headers.get("x-operator") {
            None => None,
            Some(v) => {
                let s = std::str::from_utf8(v.as_bytes())
                    .map_err(|_| ApiError::bad_request("X-Operator: not UTF-8"))?;
                check_operator(s).map_err(|e| ApiError::bad_request(format!("X-Operator: {e}")))?
            }
        };
        Ok(ApiOrigin(Origin::api(client, operator)))
    }
}

#[derive(Clone)]
struct App {
    manager: Arc<Manager>,
    token: Option<Arc<str>>,
    /// What submitted campaigns may read and write.
    policy: Arc<SubmitPolicy>,
    /// Host, Origin and content-type policy.
    guard: Arc<Guard>,
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let message = crate::types::shorten_numbers(&self.message).into_owned();
        (self.status, Json(json!({"error": message}))).into_response()
    }
}

type ApiResult<T> = Result<T, ApiError>;

/// The manager's errors at the HTTP edge: the status code by kind, the message as it reads.
impl From<ManagerError> for ApiError {
    fn from(e: ManagerError) -> Self {
        let status = match &e {
            ManagerError::NoCampaign(_) | ManagerError::NoResult { .. } => StatusCode::NOT_FOUND,
            ManagerError::Refused { .. }
            | ManagerError::ShuttingDown
            | ManagerError::QueueFull { .. } => StatusCode::CONFLICT,
            ManagerError::OverQuota { .. } => StatusCode::INSUFFICIENT_STORAGE,
            ManagerError::Invalid(_) => StatusCode::BAD_REQUEST,
            ManagerError::Preflight { class, .. } => match class {
                Class::Config => StatusCode::CONFLICT,
                Class::Device | Class::View => StatusCode::SERVICE_UNAVAILABLE,
            },
            ManagerError::NotRecorded | ManagerError::Store => StatusCode::INTERNAL_SERVER_ERROR,
        };
        ApiError::new(status, e.to_string())
    }
}

/// The service's routes; `token`: the bearer token every request must carry, if any;
/// `policy`: what a submitted campaign may read and write; `guard`: which hosts, origins and
/// content types it answers.
pub fn router(
    manager: Arc<Manager>,
    token: Option<String>,
    policy: SubmitPolicy,
    guard: Guard,
) -> Router {
    let app = App {
        manager,
        token: token.map(Arc::from),
        policy: Arc::new(policy),
        guard: Arc::new(guard),
    };
    Router::new()
        .route("/", get(super::page::index))
        .route("/ui/{file}", get(super::page::asset))
        .route("/health", get(health))
        .route("/campaigns", get(list).post(submit))
        .route("/campaigns/{id}", get(status))
        .route("/campaigns/{id}/events", get(events))
        .route("/campaigns/{id}/pause", post(pause))
        .route("/campaigns/{id}/resume", post(resume))
        .route("/campaigns/{id}/abort", post(abort))
        .route("/campaigns/{id}/samples", get(samples))
        .route("/campaigns/{id}/results", get(results))
        .route("/campaigns/{id}/results/{*name}", get(result))
        .route("/campaigns/{id}/verification", get(verification))
        .route("/stages/{name}/move", post(move_stage))
        .route("/stages/{name}/events", get(stage_events))
        .fallback(|| async { ApiError::not_found("no such route") })
        .layer(middleware::from_fn(content_types))
        .layer(middleware::from_fn_with_state(app.clone(), auth))
        .layer(middleware::from_fn_with_state(app.clone(), screen))
        .with_state(app)
}

/// The body a state-changing route takes, by method and path (None for reads).
fn body_kind(method: &axum::http::Method, path: &str) -> Option<BodyKind> {
    if method == axum::http::Method::GET || method == axum::http::Method::HEAD {
        return None;
    }
    let parts: Vec<&str> = path.trim_matches('/').split('/').collect();
    Some(match parts.as_slice() {
        ["campaigns"] => BodyKind::Campaign,
        ["stages", _, "move"] => BodyKind::Json,
        _ => BodyKind::None,
    })
}

fn refused(req: &Request, e: ApiError) -> Response {
    tracing::warn!(method = %req.method(), path = %req.uri().path(), status = e.status.as_u16(), reason = %e.message, "request refused by the browser policy");
    e.into_response()
}

/// Outermost layer: who is asking (Host, Origin, fetch metadata; [`super::guard`]) before
/// authentication, and `nosniff` on every answer.
async fn screen(State(app): State<App>, req: Request, next: Next) -> Response {
    let mut r = match app.guard.check_source(req.method(), req.headers()) {
        Ok(()) => next.run(req).await,
        Err(e) => refused(&req, e),
    };
    r.headers_mut().insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    r
}

/// After authentication: a state change carries only its route's content types.
async fn content_types(req: Request, next: Next) -> Response {
    let len = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().parse::<u64>().ok())
        // A chunked body has a length nobody declared: count it as one.
        .or_else(|| {
            req.headers()
                .contains_key(header::TRANSFER_ENCODING)
                .then_some(1)
        });
    let kind = body_kind(req.method(), req.uri().path());
    match Guard::check_body(req.method(), req.headers(), kind, len) {
        Ok(()) => next.run(req).await,
        Err(e) => refused(&req, e),
    }
}

async fn auth(State(app): State<App>, req: Request, next: Next) -> Response {
    if let Some(token) = app
        .token
        .as_ref()
        .filter(|_| !super::page::is_public(req.method(), req.uri().path()))
    {
        let given = req
            .headers()
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "))
            .unwrap_or("");
        // Constant time, length included: the comparison does not tell how much of a guess was
        // right.
        if !token_matches(given.as_bytes(), token.as_bytes()) {
            let mut r = ApiError::new(
                StatusCode::UNAUTHORIZED,
                "missing or wrong token (send `Authorization: Bearer <token>`)",
            )
            .into_response();
            r.headers_mut()
                .insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer"));
            return r;
        }
    }
    next.run(req).await
}

async fn health(State(app): State<App>) -> Json<serde_json::Value> {
    let (running, queued) = app.manager.overview();
    Json(json!({
        "status": if app.manager.shutting_down() { "stopping" } else { "ok" },
        "version": env!("CARGO_PKG_VERSION"),
        "running": running,
        "queued": queued,
    }))
}

async fn list(State(app): State<App>) -> ApiResult<Json<Vec<CampaignStatus>>> {
    let m = app.manager.clone();
    blocking(move || m.list()).await.map(Json)
}

/// Store calls take the store's mutex and touch the disk: keep them off the async workers. The
/// call runs inside the runtime: submitting, resuming and aborting schedule tasks on it.
async fn blocking<T: Send + 'static, E: Into<ApiError> + Send + 'static>(
    f: impl FnOnce() -> Result<T, E> + Send + 'static,
) -> ApiResult<T> {
    let rt = tokio::runtime::Handle::current();
    tokio::task::spawn_blocking(move || {
        let _g = rt.enter();
        f().map_err(Into::into)
    })
    .await
    .map_err(|e| ApiError::internal(e.to_string()))?
}

#[derive(Deserialize)]
struct SubmitJson {
    toml: String,
    #[serde(default)]
    name: Option<String>,
}

async fn submit(
    State(app): State<App>,
    ApiOrigin(who): ApiOrigin,
    headers: HeaderMap,
    body: Bytes,
) -> ApiResult<(StatusCode, Json<CampaignStatus>)> {
    let ctype = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("")
        .to_ascii_lowercase();
    let (text, name) = if ctype.starts_with("application/json") {
        let j: SubmitJson = serde_json::from_slice(&body).map_err(|e| {
            ApiError::bad_request(format!(
                "body: expected {{\"toml\": \"...\", \"name\": \"file.toml\"}}: {e}"
            ))
        })?;
        (j.toml, j.name.unwrap_or_default())
    } else {
        let text = String::from_utf8(body.to_vec())
            .map_err(|_| ApiError::bad_request("body: the campaign file is not UTF-8"))?;
        (text, String::new())
    };
    if name.len() > MAX_NAME_BYTES {
        return Err(ApiError::bad_request(format!(
            "name: at most {MAX_NAME_BYTES} bytes"
        )));
    }
    let m = app.manager.clone();
    let policy = app.policy.clone();
    let st = blocking(move || {
        // The client's file is untrusted: it may name files only where the service allows and
        // write only below the results directory. Errors name the client's file name only.
        let origin = submitted_origin(&name);
        Campaign::parse_submitted(&text, &origin, &policy)
            .map_err(|e| ApiError::bad_request(e.to_string()))?;
        Ok::<_, ApiError>(m.submit_by(&text, &name, &who)?)
    })
    .await?;
    Ok((StatusCode::CREATED, Json(st)))
}

/// Longest file name a client may give its campaign.
const MAX_NAME_BYTES: usize = 255;

/// The name errors show for a submitted file: the base name the client gave.
fn submitted_origin(name: &str) -> String {
    std::path::Path::new(name)
        .file_name()
        .map(|f| f.to_string_lossy().into_owned())
        .filter(|f| !f.is_empty())
        .unwrap_or_else(|| "submitted.toml".into())
}

async fn status(State(app): State<App>, Path(id): Path<i64>) -> ApiResult<Json<CampaignStatus>> {
    let m = app.manager.clone();
    blocking(move || m.status(id)).await.map(Json)
}

async fn pause(
    State(app): State<App>,
    ApiOrigin(who): ApiOrigin,
    Path(id): Path<i64>,
) -> ApiResult<Json<CampaignStatus>> {
    let m = app.manager.clone();
    blocking(move || m.pause_by(id, &who)).await.map(Json)
}

async fn resume(
    State(app): State<App>,
    ApiOrigin(who): ApiOrigin,
    Path(id): Path<i64>,
) -> ApiResult<Json<CampaignStatus>> {
    let m = app.manager.clone();
    blocking(move || m.resume_by(id, &who)).await.map(Json)
}

async fn abort(
    State(app): State<App>,
    ApiOrigin(who): ApiOrigin,
    Path(id): Path<i64>,
) -> ApiResult<Json<CampaignStatus>> {
    let m = app.manager.clone();
    blocking(move || m.abort_by(id, &who)).await.map(Json)
}

#[derive(Deserialize)]
struct SamplesQuery {
    after: Option<i64>,
    limit: Option<usize>,
}

/// Largest page of samples (a full demo campaign is ~6400).
const MAX_SAMPLES_PAGE: usize = 10_000;

async fn samples(
    State(app): State<App>,
    Path(id): Path<i64>,
    Query(q): Query<SamplesQuery>,
) -> ApiResult<Json<serde_json::Value>> {
    let after = q.after.unwrap_or(0);
    let limit = q.limit.unwrap_or(MAX_SAMPLES_PAGE);
    if after < 0 || limit == 0 || limit > MAX_SAMPLES_PAGE {
        return Err(ApiError::bad_request(format!(
            "after must be ≥ 0 and limit in 1..={MAX_SAMPLES_PAGE}"
        )));
    }
    let m = app.manager.clone();
    let rows = blocking(move || m.samples_after(id, after, limit)).await?;
    let next = rows.last().map_or(after, |(n, _)| *n);
    let samples: Vec<_> = rows
        .into_iter()
        .map(|(n, s)| json!({"n": n, "sample": s}))
        .collect();
    Ok(Json(json!({"id": id, "samples": samples, "next": next})))
}

async fn results(
    State(app): State<App>,
    Path(id): Path<i64>,
) -> ApiResult<Json<serde_json::Value>> {
    let m = app.manager.clone();
    let names = blocking(move || m.result_names(id)).await?;
    Ok(Json(json!({"id": id, "results": names})))
}

async fn result(
    State(app): State<App>,
    Path((id, name)): Path<(i64, String)>,
) -> ApiResult<Response> {
    let m = app.manager.clone();
    let (ctype, bytes) = blocking(move || m.result(id, &name)).await?;
    let ctype = HeaderValue::from_str(&ctype)
        .unwrap_or_else(|_| HeaderValue::from_static("application/octet-stream"));
    // Stored HTML and SVG open on the service's own origin: sandboxed, they run no script and
    // reach nothing of it.
    Ok((
        [
            (header::CONTENT_TYPE, ctype),
            (
                header::CONTENT_SECURITY_POLICY,
                HeaderValue::from_static(
                    "sandbox; default-src 'none'; img-src data:; style-src 'unsafe-inline'",
                ),
            ),
        ],
        bytes,
    )
        .into_response())
}

#[derive(Deserialize)]
struct EventsQuery {
    after: Option<i64>,
}

fn sse_of(e: &Event) -> SseEvent {
    let ev = SseEvent::default()
        .event(&e.kind)
        .data(serde_json::to_string(e).unwrap_or_default());
    // Samples are not in the stored log (id 0): no id, so Last-Event-ID stays a log position.
    if e.id > 0 {
        ev.id(e.id.to_string())
    } else {
        ev
    }
}

fn event_of(r: crate::store::EventRow) -> Event {
    Event {
        id: r.id,
        campaign: r.campaign,
        unix_s: r.unix_s,
        kind: r.kind,
        data: r.data,
    }
}

/// A campaign that will still produce events on its own.
fn live(state: CampaignState) -> bool {
    matches!(
        state,
        CampaignState::Queued | CampaignState::Running | CampaignState::Paused
    )
}

/// Server-sent events: the stored log after `after` (query or `Last-Event-ID`), then live
/// events until the campaign's `finished` event; a campaign that is over (or interrupted,
/// waiting for an operator) ends the stream after the log.
async fn events(
    State(app): State<App>,
    Path(id): Path<i64>,
    Query(q): Query<EventsQuery>,
    headers: HeaderMap,
) -> ApiResult<Sse<impl Stream<Item = Result<SseEvent, Infallible>>>> {
    let after = q
        .after
        .or_else(|| {
            headers
                .get("last-event-id")
                .and_then(|v| v.to_str().ok())
                .and_then(|v| v.trim().parse().ok())
        })
        .unwrap_or(0);
    let m = app.manager.clone();
    // Subscribe before reading the log so nothing falls between the two.
    let sub = m.subscribe();
    let m2 = m.clone();
    // Log first, then state: a campaign that ended meanwhile shows a final state, and its
    // `finished` event is read again below.
    let (state, log) = blocking(move || {
        let mut log = m2.events_after(id, after)?;
        let st = m2.status(id)?.state;
        if !live(st) {
            let last = log.last().map_or(after, |e| e.id);
            log.extend(m2.events_after(id, last)?);
        }
        Ok::<_, ManagerError>((st, log))
    })
    .await?;
    let (tx, rx) = mpsc::channel::<SseEvent>(256);
    tokio::spawn(follow(m, id, state, log, sub, tx));
    let stream =
        futures_util::stream::unfold(
            rx,
            |mut rx| async move { rx.recv().await.map(|e| (Ok(e), rx)) },
        );
    Ok(Sse::new(stream).keep_alive(KeepAlive::default()))
}

/// Feeds one SSE client until its campaign finishes, the client leaves or the service stops.
async fn follow(
    m: Arc<Manager>,
    id: i64,
    state: CampaignState,
    log: Vec<crate::store::EventRow>,
    mut sub: broadcast::Receiver<Event>,
    tx: mpsc::Sender<SseEvent>,
) {
    let mut last = log.last().map_or(0, |e| e.id);
    for r in log {
        if tx.send(sse_of(&event_of(r))).await.is_err() {
            return;
        }
    }
    if !live(state) {
        return;
    }
    let mut down = m.shutdown_signal();
    // Ends the stream at a `finished` event, except the one a shutdown produces: that
    // campaign resumes at the next start.
    let ends =
        |e: &Event| e.kind == "finished" && !(m.shutting_down() && e.data["state"] == "aborted");
    loop {
        let e = tokio::select! {
            _ = tx.closed() => return,
            _ = down.wait_for(|d| *d) => return,
            r = sub.recv() => r,
        };
        let batch = match e {
            Ok(e) if e.campaign != id => continue,
            Ok(e) if e.id != 0 && e.id <= last => continue,
            Ok(e) => vec![e],
            Err(broadcast::error::RecvError::Lagged(n)) => {
                // Too slow: the missed samples are gone, the logged events are in the store.
                tracing::debug!(
                    campaign = id,
                    missed = n,
                    "SSE client lagged; catching up from the store"
                );
                let m2 = m.clone();
                match blocking(move || m2.events_after(id, last)).await {
                    Ok(rows) => rows.into_iter().map(event_of).collect(),
                    Err(_) => return,
                }
            }
            Err(broadcast::error::RecvError::Closed) => return,
        };
        for e in batch {
            last = last.max(e.id);
            let end = ends(&e);
            if e.kind == "finished" && !end {
                continue;
            }
            if tx.send(sse_of(&e)).await.is_err() || end {
                return;
            }
        }
    }
}

/// `POST /stages/{name}/move`, see [`crate::campaign::motion`]. Every move that passes its
/// checks is logged on the stage (`GET /stages/{name}/events`) with who asked: `move` before
/// anything moves, then `moved` or `move_failed`.
async fn move_stage(
    State(app): State<App>,
    ApiOrigin(who): ApiOrigin,
    Path(name): Path<String>,
    body: Bytes,
) -> ApiResult<Json<serde_json::Value>> {
    let m = app.manager.clone();
    let stage = name.clone();
    let (c, comp, req, lock) =
        blocking(move || super::motion::api_prepare(&m, &name, &body)).await?;
    let wanted: serde_json::Map<String, serde_json::Value> = req
        .wanted
        .iter()
        .map(|(a, v)| (format!("{}_um", a.as_str()), json!(v)))
        .collect();
    let mut asked = who.fields();
    asked["wanted"] = serde_json::Value::Object(wanted);
    asked["compensated"] = json!(comp.is_some());
    // No trace, no motion: a move whose log entry cannot be written does not happen.
    stage_event(&app, &stage, "move", asked).await?;
    let out = crate::campaign::motion::execute(&c, comp.as_ref(), &req, std::future::pending())
        .await
        .map_err(|e| match e {
            crate::campaign::motion::MoveError::Refused(m) => ApiError::bad_request(m),
            crate::campaign::motion::MoveError::Failed(m) => ApiError::internal(m),
        });
    drop(lock);
    let mut done = who.fields();
    match &out {
        Ok(v) => done["result"] = v.clone(),
        Err(e) => done["error"] = json!(e.message),
    }
    let kind = if out.is_ok() { "moved" } else { "move_failed" };
    if let Err(e) = stage_event(&app, &stage, kind, done).await {
        // The move is done (its `move` entry is logged) and its result goes to the client.
        tracing::error!(stage = %stage, error = %e, "the end of a move was not logged");
    }
    out.map(Json)
}

/// Appends to a stage's log (off the async workers: the store's mutex and disk).
async fn stage_event(
    app: &App,
    stage: &str,
    kind: &'static str,
    data: serde_json::Value,
) -> ApiResult<i64> {
    let m = app.manager.clone();
    let stage = stage.to_string();
    blocking(move || {
        m.store()
            .with(|s| s.add_stage_event(&stage, kind, &data))
            .map_err(|e| {
                tracing::error!(error = %e, "stage event not stored");
                ApiError::internal("the stage's log could not be written")
            })
    })
    .await
}

#[derive(Deserialize)]
struct StageEventsQuery {
    after: Option<i64>,
    limit: Option<usize>,
}

/// Largest page of a stage's log.
const MAX_STAGE_EVENTS_PAGE: usize = 1000;

/// `GET /stages/{name}/events?after=ID&limit=L`: what was done to the stage outside campaigns
/// (moves, with their origin), oldest first: `{"stage", "events": [...], "next"}`.
async fn stage_events(
    State(app): State<App>,
    Path(name): Path<String>,
    Query(q): Query<StageEventsQuery>,
) -> ApiResult<Json<serde_json::Value>> {
    let after = q.after.unwrap_or(0);
    let limit = q.limit.unwrap_or(MAX_STAGE_EVENTS_PAGE);
    if after < 0 || limit == 0 || limit > MAX_STAGE_EVENTS_PAGE {
        return Err(ApiError::bad_request(format!(
            "after must be ≥ 0 and limit in 1..={MAX_STAGE_EVENTS_PAGE}"
        )));
    }
    if name.is_empty() || name.len() > crate::campaign::spec::MAX_NAME_LEN {
        return Err(ApiError::bad_request("stage: a name of 1 to 64 bytes"));
    }
    let m = app.manager.clone();
    let stage = name.clone();
    let rows = blocking(move || {
        m.store()
            .with(|s| s.stage_events_after(&stage, after, limit))
            .map_err(|e| {
                tracing::error!(error = %e, "stage events not read");
                ApiError::internal("the stage's log could not be read")
            })
    })
    .await?;
    let next = rows.last().map_or(after, |r| r.id);
    Ok(Json(json!({"stage": name, "events": rows, "next": next})))
}

/// `GET /campaigns/{id}/verification`: the stored verdict, see [`crate::campaign::verify`].
async fn verification(
    State(app): State<App>,
    Path(id): Path<i64>,
) -> ApiResult<Json<serde_json::Value>> {
    let m = app.manager.clone();
    let (_, bytes) = blocking(move || {
        m.result(id, crate::campaign::verify::VERDICT_FILE)
            .map_err(|e| match &e {
                ManagerError::NoCampaign(_) | ManagerError::NoResult { .. } => {
                    ApiError::not_found(format!("no verification: {e}"))
                }
                _ => ApiError::from(e),
            })
    })
    .await?;
    serde_json::from_slice(&bytes)
        .map(Json)
        .map_err(|_| ApiError::internal("the stored verification is not JSON"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_manager_s_errors_map_to_their_status_by_kind_with_their_text() {
        let cases = [
            (
                ManagerError::NoCampaign(7),
                StatusCode::NOT_FOUND,
                "no campaign 7",
            ),
            (
                ManagerError::Refused {
                    id: 3,
                    state: "done",
                    what: "pause",
                },
                StatusCode::CONFLICT,
                "campaign 3 is done: cannot pause it",
            ),
            (
                ManagerError::ShuttingDown,
                StatusCode::CONFLICT,
                "the service is shutting down",
            ),
            (
                ManagerError::OverQuota {
                    used_mb: 9,
                    max_mb: 8,
                },
                StatusCode::INSUFFICIENT_STORAGE,
                "the store holds 9 MB",
            ),
            (
                ManagerError::Preflight {
                    class: Class::Config,
                    message: "pre-flight check `camera` failed".into(),
                },
                StatusCode::CONFLICT,
                "; the campaign was not queued",
            ),
            (
                ManagerError::Preflight {
                    class: Class::Device,
                    message: "x".into(),
                },
                StatusCode::SERVICE_UNAVAILABLE,
                "x; the campaign was not queued",
            ),
            (
                ManagerError::Store,
                StatusCode::INTERNAL_SERVER_ERROR,
                "the service's store failed (its log has the details)",
            ),
        ];
        for (e, status, text) in cases {
            let a = ApiError::from(e);
            assert_eq!(a.status, status, "{}", a.message);
            assert!(a.message.contains(text), "{}", a.message);
        }
    }
}
