//! One process drives a stage at a time: an advisory lock file per stage in a directory every
//! csmetro process on the machine shares, plus one next to the store.
//!
//! The store records which campaign is `running`, but not whether the process that runs it is
//! alive: a service starting beside a foreground `csmetro run` on the same store would take
//! that campaign for an interrupted one and drive the same stage a second time. The kernel
//! releases a `flock` when its holder exits, even on kill -9, so a held lock means "alive"
//! and a free one means "resumable".
//!
//! Two stores (a service and an operator's `csmetro run --db other.db`) could drive the same
//! stage at once with per-store locks only, so the stage is also locked machine-wide: in
//! `CSMETRO_LOCK_DIR` if set, else `/run/lock` (shared by every user), else the system temp
//! directory when `/run/lock` cannot be written (a sandboxed service: give it
//! `ReadWritePaths=/run/lock` so it shares the lock with local users; the per-store lock still
//! guards its own store).
//!
//! A simulated stage ([`Scope::Store`]) drives no hardware: two users' simulated demos named
//! `sim-xy` share nothing but the name, so it is locked in its store only. Real ports
//! ([`Scope::Machine`], and whenever the kind is unknown) keep the machine-wide lock.
use std::fs::{File, OpenOptions, TryLockError};
use std::io::{ErrorKind, Read, Seek, SeekFrom, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};

/// Held for as long as a campaign drives the stage; dropping it releases the stage.
#[derive(Debug)]
pub struct StageLock {
    _machine: Option<File>,
    _store: File,
}

/// Where a stage is locked: see the module's documentation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scope {
    /// The store's lock only (simulated stages).
    Store,
    /// Machine-wide and the store's (real hardware).
    Machine,
}

impl Scope {
    pub fn of(kind: crate::campaign::spec::HardwareKind) -> Self {
        match kind {
            crate::campaign::spec::HardwareKind::Sim => Self::Store,
            crate::campaign::spec::HardwareKind::Real => Self::Machine,
        }
    }

    /// The scope of a stored campaign's TOML (`[hardware] kind`); machine-wide when it cannot
    /// be read, since a real stage locked per store could be driven twice.
    pub fn of_spec_toml(text: &str) -> Self {
        let sim = text.parse::<toml::Table>().ok().is_some_and(|t| {
            t.get("hardware")
                .and_then(|h| h.get("kind"))
                .and_then(toml::Value::as_str)
                == Some("sim")
        });
        if sim {
            Self::Store
        } else {
            Self::Machine
        }
    }
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

/// Longest encoded stage name kept as is in a lock file name; longer ones are cut and hashed
/// so the file name always fits a path component (255 bytes).
const MAX_ENCODED: usize = 96;

/// The stage name reduced to `[A-Za-z0-9.-]` (other bytes as `_` followed by their hex value,
/// so distinct names keep distinct files); a long one is cut and gets the hash of the whole.
fn encode(stage: &str) -> String {
    let mut name = String::new();
    for b in stage.bytes() {
        if b.is_ascii_alphanumeric() || b == b'.' || b == b'-' {
            name.push(b as char);
        } else {
            name.push_str(&format!("_{b:02x}"));
        }
    }
    if name.len() > MAX_ENCODED {
        // FNV-1a: stable across processes and builds (std's hasher is not promised to be).
        let h = stage.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
            (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
        });
        name.truncate(MAX_ENCODED);
        name.push_str(&format!("~{h:016x}"));
    }
    name
}

/// `<store>.stage-<name>.lock`, the name encoded as in the machine-wide lock.
pub fn lock_path(store: &Path, stage: &str) -> PathBuf {
    let mut p = store.as_os_str().to_owned();
    p.push(format!(".stage-{}.lock", encode(stage)));
    PathBuf::from(p)
}

/// The machine-wide lock file of `stage` in `dir`.
pub fn machine_lock_path(dir: &Path, stage: &str) -> PathBuf {
    dir.join(format!("csmetro-stage-{}.lock", encode(stage)))
}

/// Candidate machine-wide lock directories, in order.
fn machine_dirs() -> Vec<PathBuf> {
    match std::env::var_os("CSMETRO_LOCK_DIR") {
        Some(d) if !d.is_empty() => vec![PathBuf::from(d)],
        _ => vec![PathBuf::from("/run/lock"), std::env::temp_dir()],
    }
}

/// Opens a lock file: read-write (created, for everyone to share), or read-only when another
/// user created it (`flock` works on either).
fn open_lock(path: &Path) -> std::io::Result<(File, bool)> {
    match OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .mode(0o666)
        .open(path)
    {
        Ok(f) => Ok((f, true)),
        Err(e) if e.kind() == ErrorKind::PermissionDenied && path.exists() => {
            OpenOptions::new().read(true).open(path).map(|f| (f, false))
        }
        Err(e) => Err(e),
    }
}

fn take(path: PathBuf, file: (File, bool), stage: &str) -> Result<File, StageLockError> {
    let (mut file, writable) = file;
    let io = |source| StageLockError::Io {
        path: path.clone(),
        source,
    };
    match file.try_lock() {
        Ok(()) => {}
        Err(TryLockError::WouldBlock) => {
            let mut s = String::new();
            let _ = (&file).take(32).read_to_string(&mut s);
            return Err(StageLockError::Busy {
                stage: stage.to_string(),
                pid: s.trim().parse().ok(),
                path,
            });
        }
        Err(TryLockError::Error(e)) => return Err(io(e)),
    }
    if writable {
        // The holder's pid, for the message another process prints.
        file.set_len(0).map_err(io)?;
        file.seek(SeekFrom::Start(0)).map_err(io)?;
        writeln!(file, "{}", std::process::id()).map_err(io)?;
    }
    Ok(file)
}

/// Takes the stage machine-wide in the first of `dirs` that can hold the lock file (no `dirs`:
/// store only), then in the store; [`StageLockError::Busy`] names the holder's pid.
fn try_lock_in(dirs: &[PathBuf], store: &Path, stage: &str) -> Result<StageLock, StageLockError> {
    let mut last = None;
    let mut machine = None;
    if dirs.is_empty() {
        return Ok(StageLock {
            _machine: None,
            _store: lock_store(store, stage)?,
        });
    }
    for d in dirs {
        let path = machine_lock_path(d, stage);
        match open_lock(&path) {
            Ok(f) => {
                machine = Some(take(path, f, stage)?);
                break;
            }
            Err(source) => last = Some(StageLockError::Io { path, source }),
        }
    }
    let Some(machine) = machine else {
        return Err(last.unwrap_or_else(|| StageLockError::Io {
            path: PathBuf::new(),
            source: std::io::Error::other("no lock directory"),
        }));
    };
    Ok(StageLock {
        _machine: Some(machine),
        _store: lock_store(store, stage)?,
    })
}

fn lock_store(store: &Path, stage: &str) -> Result<File, StageLockError> {
    let path = lock_path(store, stage);
    let file = open_lock(&path).map_err(|source| StageLockError::Io {
        path: path.clone(),
        source,
    })?;
    take(path, file, stage)
}

/// Takes a real stage without waiting; [`StageLockError::Busy`] names the holder's pid.
pub fn try_lock(store: &Path, stage: &str) -> Result<StageLock, StageLockError> {
    try_lock_scoped(store, stage, Scope::Machine)
}

/// Takes the stage in `scope` without waiting.
pub fn try_lock_scoped(
    store: &Path,
    stage: &str,
    scope: Scope,
) -> Result<StageLock, StageLockError> {
    match scope {
        Scope::Machine => try_lock_in(&machine_dirs(), store, stage),
        Scope::Store => try_lock_in(&[], store, stage),
    }
}

/// Whether another process holds the stage (the lock is taken and released at once).
pub fn held_elsewhere(store: &Path, stage: &str) -> Option<StageLockError> {
    try_lock(store, stage).err()
}

/// [`held_elsewhere`] in `scope`.
pub fn held_elsewhere_scoped(store: &Path, stage: &str, scope: Scope) -> Option<StageLockError> {
    try_lock_scoped(store, stage, scope).err()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `try_lock` with a private machine-wide directory (tests run in parallel).
    fn try_lock(store: &Path, stage: &str) -> Result<StageLock, StageLockError> {
        try_lock_in(&[store.parent().unwrap().join("locks")], store, stage)
    }

    fn held_elsewhere(store: &Path, stage: &str) -> Option<StageLockError> {
        try_lock(store, stage).err()
    }

    #[test]
    fn a_held_stage_is_refused_until_released() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("locks")).unwrap();
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

    #[test]
    fn two_stores_cannot_drive_the_same_stage() {
        let dir = tempfile::tempdir().unwrap();
        let machine = [dir.path().join("machine")];
        std::fs::create_dir(&machine[0]).unwrap();
        let a = try_lock_in(&machine, &dir.path().join("a.db"), "sim-xy").expect("free");
        match try_lock_in(&machine, &dir.path().join("b.db"), "sim-xy") {
            Err(StageLockError::Busy { pid, .. }) => assert_eq!(pid, Some(std::process::id())),
            other => panic!("another store took a held stage: {other:?}"),
        }
        let _other = try_lock_in(&machine, &dir.path().join("b.db"), "sim-z").expect("free");
        drop(a);
        let _b = try_lock_in(&machine, &dir.path().join("b.db"), "sim-xy").expect("released");
    }

    #[test]
    fn a_long_stage_name_gets_a_lock_not_a_wait() {
        let dir = tempfile::tempdir().unwrap();
        let machine = [dir.path().to_path_buf()];
        let long = "s".repeat(300);
        let l = try_lock_in(&machine, &dir.path().join("c.db"), &long).expect("lockable");
        assert!(matches!(
            try_lock_in(&machine, &dir.path().join("c.db"), &long),
            Err(StageLockError::Busy { .. })
        ));
        drop(l);
        let p = machine_lock_path(dir.path(), &long);
        assert!(p.file_name().unwrap().len() < 255);
        assert_ne!(p, machine_lock_path(dir.path(), &"s".repeat(299)));
    }

    #[test]
    fn simulated_stages_of_two_stores_run_at_once_real_ones_do_not() {
        let dir = tempfile::tempdir().unwrap();
        let (a_db, b_db) = (dir.path().join("a.db"), dir.path().join("b.db"));
        let a = try_lock_in(&[], &a_db, "sim-xy").expect("free");
        let b = try_lock_in(&[], &b_db, "sim-xy").expect("another store's sim-xy is not ours");
        // The same store still refuses a second holder, simulated or real.
        assert!(matches!(
            try_lock_in(&[], &a_db, "sim-xy"),
            Err(StageLockError::Busy { .. })
        ));
        let machine = [dir.path().join("machine")];
        std::fs::create_dir(&machine[0]).unwrap();
        assert!(matches!(
            try_lock_in(&machine, &a_db, "sim-xy"),
            Err(StageLockError::Busy { .. })
        ));
        drop((a, b));
        // A real port stays machine-wide: a second store is refused.
        let r = try_lock_in(&machine, &a_db, "bench").expect("free");
        assert!(matches!(
            try_lock_in(&machine, &b_db, "bench"),
            Err(StageLockError::Busy { .. })
        ));
        drop(r);
        // What `csmetro run|move|verify` of a simulated stage take.
        let (c_db, d_db) = (dir.path().join("c.db"), dir.path().join("d.db"));
        let _c = try_lock_scoped(&c_db, "sim-xy", Scope::Store).expect("free");
        let _d = try_lock_scoped(&d_db, "sim-xy", Scope::Store).expect("another store");
        assert!(held_elsewhere_scoped(&c_db, "sim-xy", Scope::Store).is_some());
    }

    #[test]
    fn the_scope_follows_the_hardware_kind() {
        use crate::campaign::spec::HardwareKind;
        assert_eq!(Scope::of(HardwareKind::Sim), Scope::Store);
        assert_eq!(Scope::of(HardwareKind::Real), Scope::Machine);
        let sim = "[campaign]\nname = \"a\"\n[hardware]\nkind = \"sim\"\n";
        assert_eq!(Scope::of_spec_toml(sim), Scope::Store);
        assert_eq!(
            Scope::of_spec_toml(&sim.replace("sim\"", "real\"")),
            Scope::Machine
        );
        // Unreadable: machine-wide, the safe side.
        assert_eq!(Scope::of_spec_toml("not toml ["), Scope::Machine);
        assert_eq!(Scope::of_spec_toml("[hardware]\nkind = 3"), Scope::Machine);
    }

    #[test]
    fn an_unwritable_first_directory_falls_back_to_the_next() {
        let dir = tempfile::tempdir().unwrap();
        let dirs = [dir.path().join("missing"), dir.path().to_path_buf()];
        let _l = try_lock_in(&dirs, &dir.path().join("d.db"), "x").expect("second directory");
        assert!(machine_lock_path(dir.path(), "x").exists());
    }
}
