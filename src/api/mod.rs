//! The HTTP/JSON service (`csmetro serve`): submit, list, follow, pause, resume and abort
//! campaigns, fetch their results. See [`routes`] for the endpoints, [`manager`] for queueing
//! and crash recovery, [`config`] for the configuration file.
use std::future::IntoFuture;
use std::time::Duration;

use axum::http::StatusCode;

pub mod config;
pub mod guard;
pub mod manager;
pub mod motion;
pub mod page;
mod progress;
pub mod routes;

pub use config::{ConfigError, ServiceConfig};
pub use manager::{CampaignStatus, Limits, Manager};

/// How long shutdown waits for running campaigns to stop motion and record their state.
pub const SHUTDOWN_GRACE: Duration = Duration::from_secs(10);

/// An error answered as `{"error": "..."}` with its status code.
#[derive(Debug, Clone)]
pub struct ApiError {
    pub status: StatusCode,
    pub message: String,
}

impl ApiError {
    pub fn new(status: StatusCode, message: impl Into<String>) -> Self {
        Self {
            status,
            message: message.into(),
        }
    }
    pub fn bad_request(m: impl Into<String>) -> Self {
        Self::new(StatusCode::BAD_REQUEST, m)
    }
    pub fn not_found(m: impl Into<String>) -> Self {
        Self::new(StatusCode::NOT_FOUND, m)
    }
    pub fn conflict(m: impl Into<String>) -> Self {
        Self::new(StatusCode::CONFLICT, m)
    }
    pub fn internal(m: impl Into<String>) -> Self {
        Self::new(StatusCode::INTERNAL_SERVER_ERROR, m)
    }
}

impl std::fmt::Display for ApiError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} {}", self.status.as_u16(), self.message)
    }
}

fn notify(state: &[sd_notify::NotifyState<'_>]) {
    // Outside systemd NOTIFY_SOCKET is unset and this does nothing.
    if let Err(e) = sd_notify::notify(false, state) {
        tracing::warn!(error = %e, "sd_notify failed");
    }
}

/// Resolves on SIGINT or SIGTERM.
async fn stop_signal() {
    use tokio::signal::unix::{signal, SignalKind};
    let mut term = signal(SignalKind::terminate()).ok();
    tokio::select! {
        _ = tokio::signal::ctrl_c() => {}
        _ = async {
            match term.as_mut() {
                Some(t) => { t.recv().await; }
                None => std::future::pending::<()>().await,
            }
        } => {}
    }
}

/// Why the service could not start or stopped on its own.
#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    #[error(transparent)]
    Store(#[from] crate::store::StoreError),
    #[error("cannot listen on {bind}: {source}")]
    Listen {
        bind: String,
        source: std::io::Error,
    },
    #[error("listening socket: {0}")]
    Socket(std::io::Error),
    #[error("server: {0}")]
    Server(std::io::Error),
}

/// Runs the service until SIGINT/SIGTERM: opens the store, binds, prints the listening URL as
/// the first stdout line, resumes unfinished campaigns, tells systemd READY=1 and pings its
/// watchdog; on a signal tells STOPPING=1, stops the campaigns (motion first, resumable) and
/// waits for them up to [`SHUTDOWN_GRACE`].
pub async fn run(cfg: ServiceConfig) -> Result<(), ServiceError> {
    let store = crate::store::Store::open(&cfg.db)?;
    let store = crate::campaign::events::SharedStore::new(store);
    let manager = Manager::new(
        store.clone(),
        &cfg.results_dir,
        &cfg.campaigns_dir,
        cfg.limits,
    );
    let listener = tokio::net::TcpListener::bind(cfg.bind)
        .await
        .map_err(|source| ServiceError::Listen {
            bind: cfg.bind.to_string(),
            source,
        })?;
    let addr = listener.local_addr().map_err(ServiceError::Socket)?;
    {
        use std::io::Write;
        let mut out = std::io::stdout().lock();
        let _ = writeln!(out, "http://{addr}");
        let _ = out.flush();
    }
    tracing::info!(%addr, db = %cfg.db.display(), auth = cfg.token.is_some(), config = %cfg.path.display(), "listening");
    let resumed = manager.start()?;
    if !resumed.is_empty() {
        tracing::info!(campaigns = ?resumed, "unfinished campaigns queued again");
    }
    notify(&[
        sd_notify::NotifyState::Ready,
        sd_notify::NotifyState::Status(&format!("listening on {addr}")),
    ]);

    let mut usec = 0u64;
    if sd_notify::watchdog_enabled(false, &mut usec) && usec > 0 {
        let period = Duration::from_micros(usec / 2);
        let store = store.clone();
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(period);
            loop {
                tick.tick().await;
                // Ping only while the store answers: a wedged store gets the service restarted.
                let st = store.clone();
                let alive =
                    tokio::task::spawn_blocking(move || st.with(|s| s.sample_count(0).is_ok()))
                        .await
                        .unwrap_or(false);
                if alive {
                    notify(&[sd_notify::NotifyState::Watchdog]);
                } else {
                    tracing::error!("store does not answer: watchdog not pinged");
                }
            }
        });
    }

    // The guard knows the port actually bound (`:0` in tests).
    let guard = guard::Guard::new(addr, &cfg.allowed_hosts);
    let app = routes::router(
        manager.clone(),
        cfg.token.clone(),
        cfg.submit_policy(),
        guard,
    );
    let mut down = manager.shutdown_signal();
    // Connect info: the event log names the client address of every control action.
    let app = app.into_make_service_with_connect_info::<std::net::SocketAddr>();
    let server = axum::serve(listener, app).with_graceful_shutdown(async move {
        let _ = down.wait_for(|d| *d).await;
    });
    let mut server = std::pin::pin!(server.into_future());
    let early = tokio::select! {
        r = &mut server => Some(r),
        _ = stop_signal() => None,
    };
    tracing::info!("stopping: campaigns stop motion and stay resumable");
    notify(&[sd_notify::NotifyState::Stopping]);
    let left = manager.shutdown(SHUTDOWN_GRACE).await;
    if left > 0 {
        tracing::warn!(
            campaigns = left,
            "still running after the grace period; they resume at the next start"
        );
    }
    match early {
        Some(r) => r.map_err(ServiceError::Server)?,
        None => server.await.map_err(ServiceError::Server)?,
    }
    tracing::info!("stopped");
    Ok(())
}
