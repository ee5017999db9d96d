//! A pseudo-terminal as the simulated serial line: the driver opens the slave path exactly like
//! a device; the controller reads and writes the master through tokio's reactor.
use std::io;
use std::os::fd::{AsFd, OwnedFd};
use std::path::PathBuf;
use std::pin::Pin;
use std::task::{ready, Context, Poll};

use nix::fcntl::{fcntl, FcntlArg, OFlag};
use nix::sys::termios::{cfmakeraw, tcgetattr, tcsetattr, SetArg};
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

/// An open pty pair in raw mode. The slave stays open here so that the master never sees
/// EIO between two clients.
pub(super) struct Pty {
    pub master: PtyMaster,
    pub slave_path: PathBuf,
    pub slave: OwnedFd,
}

impl Pty {
    pub(super) fn open() -> io::Result<Self> {
        let p = nix::pty::openpty(None, None)?;
        // Raw: no echo, no CR/LF translation, no signals on 0x03 etc.
        let mut t = tcgetattr(&p.slave)?;
        cfmakeraw(&mut t);
        tcsetattr(&p.slave, SetArg::TCSANOW, &t)?;
        let slave_path = nix::unistd::ttyname(p.slave.as_fd())?;
        fcntl(&p.master, FcntlArg::F_SETFL(OFlag::O_NONBLOCK))?;
        // SAFETY: `p.master` is an open OwnedFd moved into the AsyncFd, which owns it (and so
        // keeps that same descriptor open) until the AsyncFd is dropped.
        let master = unsafe { AsyncFd::register(p.master) }.map_err(|e| e.into_parts().1)?;
        Ok(Self {
            master: PtyMaster(master),
            slave_path,
            slave: p.slave,
        })
    }
}

pub(super) struct PtyMaster(AsyncFd<OwnedFd>);

impl AsyncRead for PtyMaster {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        loop {
            let mut guard = ready!(self.0.poll_read_ready(cx))?;
            let unfilled = buf.initialize_unfilled();
            match guard
                .try_io(|fd| nix::unistd::read(fd.get_ref(), unfilled).map_err(io::Error::from))
            {
                Ok(Ok(n)) => {
                    buf.advance(n);
                    return Poll::Ready(Ok(()));
                }
                Ok(Err(e)) => return Poll::Ready(Err(e)),
                Err(_would_block) => continue,
            }
        }
    }
}

impl AsyncWrite for PtyMaster {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        loop {
            let mut guard = ready!(self.0.poll_write_ready(cx))?;
            match guard.try_io(|fd| nix::unistd::write(fd.get_ref(), buf).map_err(io::Error::from))
            {
                Ok(r) => return Poll::Ready(r),
                Err(_would_block) => continue,
            }
        }
    }
    fn poll_flush(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }
    fn poll_shutdown(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }
}
