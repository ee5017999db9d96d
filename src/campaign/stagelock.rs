//! One process drives a stage at a time: an advisory lock file per stage next to the store.
//!
//! The store records which campaign is `running`, but not whether the process that runs it is
//! alive: a service starting beside a foreground `csmetro run` on the same store would take
//! that campaign for an interrupted one and drive the same stage a second time. The kernel
//! releases a `flock` when its holder exits, even on kill -9, so a held lock means "alive"
//! and a free one means "resumable".
use std::fs::{File, OpenOptions, TryLockError};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

/// Held for as long as a campaign drives the stage; dropping it releases the stage.
#[derive(Debug)]
pub struct StageLock {
    _file: File,
}

#[derive(Debug, thiserror::Error)]
pub enum StageLockError {
    #[error("stage `{stage}` is driven by another csmetro process{}; nothing was moved (lock {})",
        .pid.map(|p| format!(" (pid {p})")).unwrap_or_default(), .path.display())]
    Busy {
        stage: String,
        pid: Option<u32>,
        path: PathBuf,
    },
    #[error("stage lock {}: {source}", .path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// `<store>.stage-<name>.lock`, the name reduced to `[A-Za-z0-9._-]` (other bytes as `_`
/// followed by their hex value, so distinct names keep distinct files).
pub fn lock_path(store: &Path, stage: &str) -> PathBuf {
    let mut name = String::new();
    for b in stage.bytes() {
        if b.is_ascii_alphanumeric() || b == b'.' || b == b'-' {
            name.push(b as char);
        } else {
            name.push_str(&format!("_{b:02x}"));
        }
    }
    let mut p = store.as_os_str().to_owned();
    p.push(format!(".stage-{name}.lock"));
    PathBuf::from(p)
}

/// Takes the stage without waiting; [`StageLockError::Busy`] names the holder's pid.
pub fn try_lock(store: &Path, stage: &str) -> Result<StageLock, StageLockError> {
    let path = lock_path(store, stage);
    let io = |source| StageLockError::Io {
        path: path.clone(),
        source,
    };
    let mut file = OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path)
        .map_err(io)?;
    match file.try_lock() {
        Ok(()) => {}
        Err(TryLockError::WouldBlock) => {
            let mut s = String::new();
            let _ = file.read_to_string(&mut s);
            return Err(StageLockError::Busy {
                stage: stage.to_string(),
                pid: s.trim().parse().ok(),
                path,
            });
        }
        Err(TryLockError::Error(e)) => return Err(io(e)),
    }
    // The holder's pid, for the message another process prints.
    file.set_len(0).map_err(io)?;
    file.seek(SeekFrom::Start(0)).map_err(io)?;
    writeln!(file, "{}", std::process::id()).map_err(io)?;
    Ok(StageLock { _file: file })
}

/// Whether another process holds the stage (the lock is taken and released at once).
pub fn held_elsewhere(store: &Path, stage: &str) -> Option<StageLockError> {
    try_lock(store, stage).err()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_held_stage_is_refused_until_released() {
        let dir = tempfile::tempdir().unwrap();
        let db = dir.path().join("csmetro.db");
        let a = try_lock(&db, "sim-xy").expect("free");
        match try_lock(&db, "sim-xy") {
            Err(StageLockError::Busy { pid, stage, .. }) => {
                assert_eq!(pid, Some(std::process::id()));
                assert_eq!(stage, "sim-xy");
            }
            other => panic!("expected busy, got {other:?}"),
        }
        assert!(held_elsewhere(&db, "sim-xy").is_some());
        // Other stages are independent.
        let _b = try_lock(&db, "bench 2/x").expect("another stage is free");
        drop(a);
        assert!(held_elsewhere(&db, "sim-xy").is_none());
        let _c = try_lock(&db, "sim-xy").expect("free again after release");
    }

    #[test]
    fn lock_names_stay_distinct_and_on_one_path_component() {
        let db = Path::new("/var/lib/csmetro/csmetro.db");
        let p = lock_path(db, "a/b");
        assert_eq!(p, Path::new("/var/lib/csmetro/csmetro.db.stage-a_2fb.lock"));
        assert_ne!(lock_path(db, "a_b"), lock_path(db, "a/b"));
    }
}
