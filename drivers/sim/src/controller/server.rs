//! Serving the simulated controller over TCP (127.0.0.1) and over a pty, with the port able to
//! vanish and come back at the same address or path.
use std::io;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use bytes::BytesMut;
use csmetro_effects::AxisId;
use csmetro_gcs::ServerCodec;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::{TcpListener, TcpSocket};
use tokio::sync::{mpsc, watch};
use tokio::task::JoinSet;
use tokio_util::codec::Decoder;
use tracing::{debug, info, warn};

use super::pty::Pty;
use super::{Controller, ControllerConfig, Fault};
use crate::stage::SimStage;

/// Where a simulated controller listens.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Endpoint {
    /// A TCP listener at this address.
    Tcp(SocketAddr),
    /// A stable path (symlink) to the current pty slave; open it like a serial device.
    Pty(PathBuf),
}

impl std::fmt::Display for Endpoint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Endpoint::Tcp(a) => write!(f, "{a}"),
            Endpoint::Pty(p) => write!(f, "{}", p.display()),
        }
    }
}

/// A running simulated C-863. Dropping it stops the server.
pub struct SimController {
    endpoint: Endpoint,
    ctl: Arc<Controller>,
    shutdown: watch::Sender<bool>,
    task: Option<tokio::task::JoinHandle<()>>,
}

enum Ended {
    Closed,
    Vanish(Duration),
}

/// Serves one byte stream until it closes or a vanish fault strikes.
async fn serve_stream<S: AsyncRead + AsyncWrite + Unpin>(
    ctl: &Controller,
    mut s: S,
) -> io::Result<Ended> {
    let mut codec = ServerCodec::default();
    let mut buf = BytesMut::with_capacity(4096);
    loop {
        while let Some(req) = codec.decode(&mut buf)? {
            let out = ctl.handle(&req);
            if !out.delay.is_zero() {
                tokio::time::sleep(out.delay).await;
            }
            if !out.bytes.is_empty() {
                s.write_all(&out.bytes).await?;
                s.flush().await?;
            }
            if let Some(d) = out.vanish {
                return Ok(Ended::Vanish(d));
            }
        }
        if s.read_buf(&mut buf).await? == 0 {
            return Ok(Ended::Closed);
        }
    }
}

fn bind(addr: SocketAddr) -> io::Result<TcpListener> {
    let s = if addr.is_ipv4() {
        TcpSocket::new_v4()?
    } else {
        TcpSocket::new_v6()?
    };
    // Needed to come back on the same port after a vanish fault.
    s.set_reuseaddr(true)?;
    s.bind(addr)?;
    s.listen(16)
}

static PTY_COUNTER: AtomicU64 = AtomicU64::new(0);

/// Default pty links are `<temp dir>/csmetro-c863-<pid>-<n>`: the pid of the serving process
/// tells a stale link (process gone, e.g. after kill -9) from a live one.
const LINK_PREFIX: &str = "csmetro-c863-";

/// The pid encoded in a default link name (or its `.new` temporary).
fn link_owner(name: &str) -> Option<i32> {
    let rest = name.strip_prefix(LINK_PREFIX)?;
    let rest = rest.strip_suffix(".new").unwrap_or(rest);
    let (pid, n) = rest.split_once('-')?;
    if pid.is_empty() || !pid.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    n.parse::<u64>().ok()?;
    pid.parse::<i32>().ok().filter(|&p| p > 0)
}

fn pid_alive(pid: i32) -> bool {
    // Signal 0 only checks: ESRCH means gone; EPERM means alive under another user.
    !matches!(
        nix::sys::signal::kill(nix::unistd::Pid::from_raw(pid), None),
        Err(nix::errno::Errno::ESRCH)
    )
}

/// Removes the default pty links in `dir` whose serving process is gone (a killed simulator
/// cannot remove its own). Only symlinks with the default name are touched; returns how many
/// were removed. Called by [`SimController::start_pty`] for the temp dir.
pub fn remove_stale_links(dir: &Path) -> usize {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    let mut removed = 0;
    for e in entries.flatten() {
        let name = e.file_name();
        let Some(pid) = name.to_str().and_then(link_owner) else {
            continue;
        };
        let is_link = e.file_type().map(|t| t.is_symlink()).unwrap_or(false);
        if is_link && !pid_alive(pid) && std::fs::remove_file(e.path()).is_ok() {
            debug!(link = %e.path().display(), pid, "removed a stale pty link");
            removed += 1;
        }
    }
    removed
}

/// Removes the pty link when the server ends, however it ends.
struct LinkGuard(PathBuf);
impl Drop for LinkGuard {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

fn relink(link: &Path, target: &Path) -> io::Result<()> {
    let tmp = link.with_extension("new");
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(target, &tmp)?;
    std::fs::rename(&tmp, link)
}

impl SimController {
    fn new_ctl(stage: SimStage, axis: AxisId, cfg: ControllerConfig) -> Arc<Controller> {
        Arc::new(Controller::new(stage, axis, cfg))
    }

    /// Serves over TCP at `addr` (port 0 picks a free port; see [`endpoint`](Self::endpoint)).
    pub async fn start_tcp(
        stage: SimStage,
        axis: AxisId,
        cfg: ControllerConfig,
        addr: SocketAddr,
    ) -> io::Result<Self> {
        let ctl = Self::new_ctl(stage, axis, cfg);
        let listener = bind(addr)?;
        let local = listener.local_addr()?;
        let (shutdown, mut stop) = watch::channel(false);
        let c = ctl.clone();
        let task = tokio::spawn(async move {
            let mut listener = Some(listener);
            loop {
                let l = match listener.take() {
                    Some(l) => l,
                    None => match bind(local) {
                        Ok(l) => l,
                        Err(e) => {
                            warn!(%local, error = %e, "rebinding the simulated C-863 failed; retrying");
                            tokio::time::sleep(Duration::from_millis(20)).await;
                            continue;
                        }
                    },
                };
                let (vtx, mut vrx) = mpsc::channel::<Duration>(4);
                let mut conns = JoinSet::new();
                let vanish = loop {
                    tokio::select! {
                        acc = l.accept() => match acc {
                            Ok((s, peer)) => {
                                debug!(%peer, "simulated C-863: client connected");
                                let _ = s.set_nodelay(true);
                                let (c, vtx) = (c.clone(), vtx.clone());
                                conns.spawn(async move {
                                    if let Ok(Ended::Vanish(d)) = serve_stream(&c, s).await {
                                        let _ = vtx.send(d).await;
                                    }
                                });
                            }
                            Err(e) => warn!(error = %e, "accept failed"),
                        },
                        Some(d) = vrx.recv() => break Some(d),
                        _ = stop.changed() => break None,
                        Some(_) = conns.join_next(), if !conns.is_empty() => {}
                    }
                };
                drop(l);
                conns.abort_all();
                match vanish {
                    Some(d) => {
                        info!(ms = d.as_millis() as u64, "simulated C-863 port vanishes");
                        tokio::select! {
                            _ = tokio::time::sleep(d) => {}
                            _ = stop.changed() => return,
                        }
                    }
                    None => return,
                }
            }
        });
        Ok(Self {
            endpoint: Endpoint::Tcp(local),
            ctl,
            shutdown,
            task: Some(task),
        })
    }

    /// Serves over a pseudo-terminal; the endpoint is a symlink `link` (default: a fresh path
    /// in the temp dir) to the current slave, re-pointed when the port comes back.
    pub async fn start_pty(
        stage: SimStage,
        axis: AxisId,
        cfg: ControllerConfig,
        link: Option<PathBuf>,
    ) -> io::Result<Self> {
        let ctl = Self::new_ctl(stage, axis, cfg);
        let link = link.unwrap_or_else(|| {
            let dir = std::env::temp_dir();
            remove_stale_links(&dir);
            let n = PTY_COUNTER.fetch_add(1, Ordering::Relaxed);
            dir.join(format!("{LINK_PREFIX}{}-{n}", std::process::id()))
        });
        let first = Pty::open()?;
        relink(&link, &first.slave_path)?;
        debug!(slave = %first.slave_path.display(), link = %link.display(), "simulated C-863 pty");
        let (shutdown, mut stop) = watch::channel(false);
        let c = ctl.clone();
        let l2 = link.clone();
        let task = tokio::spawn(async move {
            let _guard = LinkGuard(l2.clone());
            let mut pty = Some(first);
            loop {
                let p = match pty.take() {
                    Some(p) => p,
                    None => match Pty::open().and_then(|p| relink(&l2, &p.slave_path).map(|_| p)) {
                        Ok(p) => p,
                        Err(e) => {
                            warn!(error = %e, "reopening the simulated pty failed; retrying");
                            tokio::time::sleep(Duration::from_millis(20)).await;
                            continue;
                        }
                    },
                };
                let Pty {
                    master,
                    slave_path,
                    slave,
                } = p;
                let ended = tokio::select! {
                    r = serve_stream(&c, master) => r,
                    _ = stop.changed() => return,
                };
                drop(slave);
                match ended {
                    Ok(Ended::Vanish(d)) => {
                        info!(slave = %slave_path.display(), ms = d.as_millis() as u64, "simulated pty vanishes");
                        let _ = std::fs::remove_file(&l2);
                        tokio::select! {
                            _ = tokio::time::sleep(d) => {}
                            _ = stop.changed() => return,
                        }
                    }
                    Ok(Ended::Closed) => {}
                    Err(e) => warn!(error = %e, "simulated pty failed; reopening"),
                }
            }
        });
        Ok(Self {
            endpoint: Endpoint::Pty(link),
            ctl,
            shutdown,
            task: Some(task),
        })
    }

    /// Where the server listens.
    pub fn endpoint(&self) -> &Endpoint {
        &self.endpoint
    }

    /// The state machine (command log, fault injection, stage).
    pub fn controller(&self) -> &Arc<Controller> {
        &self.ctl
    }

    /// The simulated stage behind the controller.
    pub fn stage(&self) -> &SimStage {
        self.ctl.stage()
    }

    /// Injects a fault now (see [`Controller::inject`]).
    pub fn inject(&self, fault: Fault) {
        self.ctl.inject(fault)
    }

    /// Number of commands received so far (every line and control byte).
    pub fn command_count(&self) -> u64 {
        self.ctl.command_count()
    }

    /// Stops serving and waits for the server task (the pty link is removed).
    pub async fn shutdown(mut self) {
        let _ = self.shutdown.send(true);
        if let Some(t) = self.task.take() {
            let _ = t.await;
        }
    }
}

impl Drop for SimController {
    fn drop(&mut self) {
        let _ = self.shutdown.send(true);
        if let Some(t) = self.task.take() {
            t.abort();
        }
    }
}
