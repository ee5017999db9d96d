//! The embedded SQLite store: campaigns, their samples, their event log and their results.
//!
//! One file per service, opened in WAL mode with `synchronous=NORMAL`: every call that writes
//! is one transaction, and a committed transaction survives the process being killed (`kill -9`,
//! a panic, a lost device taking the service down). Only a power loss or an OS crash can lose
//! the last few transactions, never corrupt the file. A resumed campaign reads back
//! [`Store::done_seqs`] and measures only the targets not stored yet: a target is never stored
//! twice (`UNIQUE(campaign_id, seq)`).
//!
//! Every field of a [`SampleRecord`] has a real column, so the lab can query the file with the
//! `sqlite3` shell, e.g.
//!
//! ```sql
//! SELECT seq, axis, direction, target_x_um, meas_x_um - target_x_um AS err_x_um
//!   FROM samples WHERE campaign_id = 3 AND phase = 'cs' ORDER BY seq;
//! ```
//!
//! Enumerations are stored as their lowercase names (`cs`/`full`, `x`/`y`,
//! `forward`/`backward`, `queued`/`running`/...), timestamps as REAL seconds since the Unix
//! epoch. REAL columns hold IEEE doubles exactly, with two exceptions SQLite cannot represent:
//! NaN is stored as NULL and -0.0 as 0.0. For those rare values the exact bits are kept in the
//! sample's `raw_bits` column (NULL otherwise), so reading back reproduces every record bit for
//! bit.
//!
//! The schema version is `PRAGMA user_version`; [`Store::open`] creates or migrates the schema and
//! refuses a file written by a newer csmetro.
use std::collections::BTreeSet;
use std::fmt;
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use rusqlite::{params, Connection, ErrorCode, OptionalExtension, TransactionBehavior};
use serde::Serialize;

use crate::types::{CampaignState, SampleRecord};

mod rows;
mod schema;
use rows::{
    campaign_from_row, i64_from, raw_bits, reals, sample_from_row, sample_from_row_at, u64_from,
    CAMPAIGN_COLS, SAMPLE_COLS,
};
use schema::MIGRATIONS;

/// The schema this build writes. Bump it and append to `schema::MIGRATIONS` to change the schema.
pub const SCHEMA_VERSION: i32 = 5;

/// `PRAGMA application_id` of a csmetro store ("CSMT"), so `file(1)`-like tools and
/// [`Store::open`] can tell a csmetro database from another SQLite file.
pub const APPLICATION_ID: i32 = 0x4353_4D54;

/// How long a writer waits for another connection's lock before giving up.
pub const BUSY_TIMEOUT: Duration = Duration::from_secs(5);

/// What went wrong, naming the database (`:memory:` for an in-memory store) and the operation.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("store {path}: cannot create directory {dir}: {source}")]
    CreateDir {
        path: String,
        dir: String,
        #[source]
        source: std::io::Error,
    },
    #[error("store {path}: {op}: {source}")]
    Sqlite {
        path: String,
        op: String,
        #[source]
        source: rusqlite::Error,
    },
    #[error("store {path}: schema version {found} is newer than this build supports ({supported}); upgrade csmetro")]
    SchemaTooNew {
        path: String,
        found: i32,
        supported: i32,
    },
    #[error("store {path}: not a csmetro store (application_id {found:#x})")]
    NotAStore { path: String, found: i32 },
    #[error("store {path}: {op}: no campaign {id}")]
    UnknownCampaign { path: String, op: String, id: i64 },
    #[error("store {path}: {op}: stage {stage:?} already runs campaign {running}")]
    StageBusy {
        path: String,
        op: String,
        stage: String,
        running: i64,
    },
    #[error("store {path}: {op}: {what}")]
    OutOfRange {
        path: String,
        op: String,
        what: RowError,
    },
    #[error("store {path}: {op}: corrupt row: {what}")]
    Corrupt {
        path: String,
        op: String,
        what: RowError,
    },
}

/// A value that does not fit its column, or a stored row that does not decode.
#[derive(Debug, thiserror::Error)]
pub enum RowError {
    #[error("{what} = {value} is negative")]
    Negative { what: &'static str, value: i64 },
    #[error("{what} = {value} does not fit in u32")]
    NotU32 { what: &'static str, value: i64 },
    #[error("{what} = {value} exceeds {max}", max = i64::MAX)]
    NotI64 { what: &'static str, value: u64 },
    #[error("grid_index = {0}")]
    GridIndexRange(usize),
    #[error("raw_bits entry {0:?} is not name:hex")]
    RawBitsEntry(String),
    #[error("raw_bits names unknown column {0:?}")]
    RawBitsColumn(String),
    #[error("raw_bits entry {part:?}: {source}")]
    RawBitsHex {
        part: String,
        source: std::num::ParseIntError,
    },
    /// An enumeration column (`phase`, `axis`, `direction`) with an unknown name.
    #[error("seq {seq}: unknown {what} {value:?}")]
    Unknown {
        seq: u64,
        what: &'static str,
        value: String,
    },
    #[error("seq {seq}: grid_index = {value} is negative")]
    NegativeGridIndex { seq: u64, value: i64 },
    #[error("campaign {id}: unknown state {value:?}")]
    State { id: i64, value: String },
    #[error("event {id}: data is not JSON: {source}")]
    EventJson { id: i64, source: serde_json::Error },
    #[error("stage event {id}: data is not JSON: {source}")]
    StageEventJson { id: i64, source: serde_json::Error },
}

/// One campaign as stored.
#[derive(Debug, Clone, Serialize)]
pub struct CampaignRow {
    pub id: i64,
    pub name: String,
    pub spec_toml: String,
    pub spec_path: String,
    /// Which stage it runs on; one running campaign per stage at a time.
    pub stage: String,
    pub state: CampaignState,
    /// Number of targets in the plan.
    pub planned: u64,
    pub created_unix_s: f64,
    pub updated_unix_s: f64,
    /// Why it is in its state (error text, who paused it...), if anyone said.
    pub message: Option<String>,
}

/// One entry of a campaign's event log.
#[derive(Debug, Clone, Serialize)]
pub struct EventRow {
    /// Grows with every event of every campaign: clients resume a stream with `after_id`.
    pub id: i64,
    pub campaign: i64,
    pub unix_s: f64,
    pub kind: String,
    pub data: serde_json::Value,
}

/// One entry of a stage's log (moves over the API, with their origin).
#[derive(Debug, Clone, Serialize)]
pub struct StageEventRow {
    pub id: i64,
    pub stage: String,
    pub unix_s: f64,
    pub kind: String,
    pub data: serde_json::Value,
}

/// The store: one SQLite connection. `Send`, not `Sync`: share it behind a mutex or give it to
/// one thread; other processes (the `sqlite3` shell, a second reader) may open the file at the
/// same time.
pub struct Store {
    conn: Connection,
    path: Option<PathBuf>,
}

impl fmt::Debug for Store {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Store").field("path", &self.path).finish()
    }
}

/// Seconds since the Unix epoch, now.
pub fn now_unix_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0)
}

impl Store {
    /// Opens (creating it, and its parent directories, if needed) the store at `path`: WAL
    /// journal, `synchronous=NORMAL`, 5 s busy timeout, foreign keys on; creates or migrates the
    /// schema.
    pub fn open(path: &Path) -> Result<Store, StoreError> {
        let shown = path.display().to_string();
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|source| StoreError::CreateDir {
                path: shown.clone(),
                dir: dir.display().to_string(),
                source,
            })?;
        }
        let conn = Connection::open(path).map_err(|source| StoreError::Sqlite {
            path: shown,
            op: "open".into(),
            source,
        })?;
        Self::init(conn, Some(path.to_path_buf()))
    }

    /// A store that lives in memory and vanishes with it (tests, dry runs).
    pub fn open_in_memory() -> Result<Store, StoreError> {
        let conn = Connection::open_in_memory().map_err(|source| StoreError::Sqlite {
            path: ":memory:".into(),
            op: "open".into(),
            source,
        })?;
        Self::init(conn, None)
    }

    /// The database file, None in memory.
    pub fn path(&self) -> Option<&Path> {
        self.path.as_deref()
    }

    /// The store's identity: 16 hex digits drawn when the store was created (or migrated to
    /// schema 2), the same for every process that opens the file, different for another store.
    pub fn store_id(&self) -> Result<String, StoreError> {
        self.conn
            .query_row("SELECT value FROM store_info WHERE key = 'id'", [], |r| {
                r.get(0)
            })
            .map_err(|e| self.err("read store id", e))
    }

    fn init(conn: Connection, path: Option<PathBuf>) -> Result<Store, StoreError> {
        let mut store = Store { conn, path };
        store
            .conn
            .busy_timeout(BUSY_TIMEOUT)
            .map_err(|e| store.err("set busy_timeout", e))?;
        // Entering WAL needs an exclusive lock and SQLite answers busy at once, without its busy
        // handler, while another process opens the same new file (CI saw `csmetro run` fail so
        // against a reader): retried for the busy timeout.
        let t0 = std::time::Instant::now();
        let mode: String = loop {
            match store
                .conn
                .query_row("PRAGMA journal_mode = WAL", [], |r| r.get(0))
            {
                Err(rusqlite::Error::SqliteFailure(e, _))
                    if e.code == rusqlite::ErrorCode::DatabaseBusy
                        && t0.elapsed() < BUSY_TIMEOUT =>
                {
                    std::thread::sleep(std::time::Duration::from_millis(10));
                }
                r => break r.map_err(|e| store.err("set journal_mode=WAL", e))?,
            }
        };
        if store.path.is_some() && !mode.eq_ignore_ascii_case("wal") {
            // E.g. a file system without shared memory: still crash-safe (rollback journal),
            // just slower and without concurrent readers.
            tracing::warn!(
                store = %store.shown(),
                journal_mode = %mode,
                "SQLite refused WAL mode"
            );
        }
        store
            .conn
            .pragma_update(None, "synchronous", "NORMAL")
            .map_err(|e| store.err("set synchronous=NORMAL", e))?;
        store
            .conn
            .pragma_update(None, "foreign_keys", true)
            .map_err(|e| store.err("enable foreign_keys", e))?;
        store.migrate()?;
        Ok(store)
    }

    /// Brings the schema to [`SCHEMA_VERSION`], in one immediate transaction so two processes
    /// opening a new file at once do not both create it.
    fn migrate(&mut self) -> Result<(), StoreError> {
        let shown = self.shown();
        let sq = |op: &str| {
            let shown = shown.clone();
            let op = op.to_string();
            move |source: rusqlite::Error| StoreError::Sqlite {
                path: shown,
                op,
                source,
            }
        };
        let tx = self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .map_err(sq("begin schema migration"))?;
        let app: i32 = tx
            .query_row("PRAGMA application_id", [], |r| r.get(0))
            .map_err(sq("read application_id"))?;
        let version: i32 = tx
            .query_row("PRAGMA user_version", [], |r| r.get(0))
            .map_err(sq("read user_version"))?;
        if app != 0 && app != APPLICATION_ID {
            return Err(StoreError::NotAStore {
                path: shown,
                found: app,
            });
        }
        if version > SCHEMA_VERSION {
            return Err(StoreError::SchemaTooNew {
                path: shown,
                found: version,
                supported: SCHEMA_VERSION,
            });
        }
        if version == 0 {
            // A fresh csmetro file has no tables; refuse to scribble over someone else's db.
            let tables: i64 = tx
                .query_row(
                    "SELECT count(*) FROM sqlite_schema WHERE type = 'table'",
                    [],
                    |r| r.get(0),
                )
                .map_err(sq("inspect schema"))?;
            if tables > 0 && app != APPLICATION_ID {
                return Err(StoreError::NotAStore {
                    path: shown,
                    found: app,
                });
            }
        }
        for (from, sql) in MIGRATIONS.iter().enumerate().skip(version.max(0) as usize) {
            tx.execute_batch(sql)
                .map_err(sq(&format!("migrate schema {from} -> {}", from + 1)))?;
        }
        if version < SCHEMA_VERSION {
            tx.pragma_update(None, "application_id", APPLICATION_ID)
                .map_err(sq("set application_id"))?;
            tx.pragma_update(None, "user_version", SCHEMA_VERSION)
                .map_err(sq("set user_version"))?;
        }
        tx.commit().map_err(sq("commit schema migration"))
    }

    fn shown(&self) -> String {
        match &self.path {
            Some(p) => p.display().to_string(),
            None => ":memory:".into(),
        }
    }

    fn err(&self, op: impl Into<String>, source: rusqlite::Error) -> StoreError {
        StoreError::Sqlite {
            path: self.shown(),
            op: op.into(),
            source,
        }
    }

    fn out_of_range(&self, op: &str, what: RowError) -> StoreError {
        StoreError::OutOfRange {
            path: self.shown(),
            op: op.into(),
            what,
        }
    }

    fn corrupt(&self, op: &str, what: RowError) -> StoreError {
        StoreError::Corrupt {
            path: self.shown(),
            op: op.into(),
            what,
        }
    }

    fn unknown(&self, op: &str, id: i64) -> StoreError {
        StoreError::UnknownCampaign {
            path: self.shown(),
            op: op.into(),
            id,
        }
    }

    /// Maps a foreign-key failure to [`StoreError::UnknownCampaign`], anything else to `Sqlite`.
    fn write_err(&self, op: &str, campaign: i64, e: rusqlite::Error) -> StoreError {
        match &e {
            rusqlite::Error::SqliteFailure(f, _)
                if f.code == ErrorCode::ConstraintViolation
                    && f.extended_code == rusqlite::ffi::SQLITE_CONSTRAINT_FOREIGNKEY =>
            {
                self.unknown(op, campaign)
            }
            _ => self.err(op, e),
        }
    }

    /// Records a new campaign in state `Queued`; returns its id (ids only grow).
    pub fn create_campaign(
        &self,
        name: &str,
        spec_toml: &str,
        spec_path: &str,
        stage: &str,
        planned: u64,
    ) -> Result<i64, StoreError> {
        const OP: &str = "create campaign";
        let planned = i64_from(planned, "planned").map_err(|w| self.out_of_range(OP, w))?;
        let now = now_unix_s();
        self.conn
            .prepare_cached(
                "INSERT INTO campaigns (name, spec_toml, spec_path, stage, state, planned, \
                 created_unix_s, updated_unix_s) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?7)",
            )
            .and_then(|mut st| {
                st.execute(params![
                    name,
                    spec_toml,
                    spec_path,
                    stage,
                    CampaignState::Queued.as_str(),
                    planned,
                    now
                ])
            })
            .map_err(|e| self.err(OP, e))?;
        Ok(self.conn.last_insert_rowid())
    }

    fn query_campaigns(
        &self,
        op: &str,
        sql_tail: &str,
        args: &[&dyn rusqlite::ToSql],
    ) -> Result<Vec<CampaignRow>, StoreError> {
        let sql = format!("SELECT {CAMPAIGN_COLS} FROM campaigns {sql_tail}");
        let mut st = self
            .conn
            .prepare_cached(&sql)
            .map_err(|e| self.err(op, e))?;
        let rows = st
            .query_map(args, campaign_from_row)
            .and_then(|rows| rows.collect::<rusqlite::Result<Vec<_>>>())
            .map_err(|e| self.err(op, e))?;
        rows.into_iter()
            .map(|r| r.map_err(|w| self.corrupt(op, w)))
            .collect()
    }

    /// The campaign `id`, None if there is none.
    pub fn campaign(&self, id: i64) -> Result<Option<CampaignRow>, StoreError> {
        Ok(self
            .query_campaigns("read campaign", "WHERE id = ?1", &[&id])?
            .pop())
    }

    /// Every campaign, newest first.
    pub fn campaigns(&self) -> Result<Vec<CampaignRow>, StoreError> {
        self.query_campaigns("list campaigns", "ORDER BY id DESC", &[])
    }

    /// The campaigns not in a final state (queued, running, paused, interrupted), oldest first:
    /// the service resumes these at start.
    pub fn unfinished(&self) -> Result<Vec<CampaignRow>, StoreError> {
        self.query_campaigns(
            "list unfinished campaigns",
            "WHERE state IN ('queued', 'running', 'paused', 'interrupted') ORDER BY id ASC",
            &[],
        )
    }

    /// Sets a campaign's state and message (None clears the message) and bumps its
    /// `updated_unix_s`. Refuses ([`StoreError::StageBusy`]) to make a campaign `Running` while
    /// another one runs on the same stage.
    pub fn set_state(
        &self,
        id: i64,
        state: CampaignState,
        message: Option<&str>,
    ) -> Result<(), StoreError> {
        let op = format!("set campaign {id} state to {}", state.as_str());
        if self.update_state(&op, id, None, state, message)? == 0 {
            return Err(self.unknown(&op, id));
        }
        Ok(())
    }

    /// [`Store::set_state`] only while the campaign is in `from` (one statement, so a state
    /// another task sets in between is never overwritten): whether it was. The operator's pause
    /// of a campaign whose session had just stored `done` turned it `paused` (the session leaves
    /// the manager's table of running campaigns only after it stored its end).
    pub fn set_state_from(
        &self,
        id: i64,
        from: CampaignState,
        state: CampaignState,
        message: Option<&str>,
    ) -> Result<bool, StoreError> {
        let op = format!(
            "set campaign {id} state from {} to {}",
            from.as_str(),
            state.as_str()
        );
        let n = self.update_state(&op, id, Some(from), state, message)?;
        if n == 0 && self.campaign(id)?.is_none() {
            return Err(self.unknown(&op, id));
        }
        Ok(n == 1)
    }

    /// The UPDATE of [`Store::set_state`] and [`Store::set_state_from`] (`from`: only in that
    /// state): the rows changed.
    fn update_state(
        &self,
        op: &str,
        id: i64,
        from: Option<CampaignState>,
        state: CampaignState,
        message: Option<&str>,
    ) -> Result<usize, StoreError> {
        self.conn
            .prepare_cached(
                "UPDATE campaigns SET state = ?2, message = ?3, updated_unix_s = ?4 \
                 WHERE id = ?1 AND (?5 IS NULL OR state = ?5)",
            )
            .and_then(|mut st| {
                st.execute(params![
                    id,
                    state.as_str(),
                    message,
                    now_unix_s(),
                    from.map(CampaignState::as_str)
                ])
            })
            .map_err(|e| match &e {
                rusqlite::Error::SqliteFailure(f, _)
                    if f.code == ErrorCode::ConstraintViolation
                        && state == CampaignState::Running =>
                {
                    match self.running_on_stage_of(id) {
                        Ok(Some((stage, running))) => StoreError::StageBusy {
                            path: self.shown(),
                            op: op.to_string(),
                            stage,
                            running,
                        },
                        _ => self.err(op, e),
                    }
                }
                _ => self.err(op, e),
            })
    }

    /// (stage, the other campaign running on it) for campaign `id`'s stage.
    fn running_on_stage_of(&self, id: i64) -> rusqlite::Result<Option<(String, i64)>> {
        self.conn
            .query_row(
                "SELECT c.stage, r.id FROM campaigns c JOIN campaigns r ON r.stage = c.stage \
                 WHERE c.id = ?1 AND r.state = 'running' AND r.id != c.id",
                [id],
                |r| Ok((r.get(0)?, r.get(1)?)),
            )
            .optional()
    }

    /// Changes the number of planned targets (e.g. after a plan is extended on resume).
    pub fn set_planned(&self, id: i64, planned: u64) -> Result<(), StoreError> {
        let op = format!("set campaign {id} planned");
        let planned = i64_from(planned, "planned").map_err(|w| self.out_of_range(&op, w))?;
        let n = self
            .conn
            .prepare_cached("UPDATE campaigns SET planned = ?2, updated_unix_s = ?3 WHERE id = ?1")
            .and_then(|mut st| st.execute(params![id, planned, now_unix_s()]))
            .map_err(|e| self.err(&op, e))?;
        if n == 0 {
            return Err(self.unknown(&op, id));
        }
        Ok(())
    }

    /// Commits one sample in its own transaction. Returns Ok(false) and changes nothing when a
    /// sample with the same (campaign, target.seq) exists already: a target is never stored
    /// twice.
    pub fn insert_sample(&self, campaign: i64, s: &SampleRecord) -> Result<bool, StoreError> {
        const OP: &str = "insert sample";
        let t = &s.target;
        let seq = i64_from(t.seq, "seq").map_err(|w| self.out_of_range(OP, w))?;
        let grid_index = i64::try_from(t.grid_index)
            .map_err(|_| self.out_of_range(OP, RowError::GridIndexRange(t.grid_index)))?;
        let v = reals(s);
        let raw = raw_bits(&v);
        // NaN binds as NULL; -0.0 binds as 0.0; raw_bits has their exact bits.
        let n = self
            .conn
            .prepare_cached(
                "INSERT INTO samples (campaign_id, seq, phase, axis, direction, cycle, grid_index, \
                 target_x_um, target_y_um, meas_x_um, meas_y_um, theta_mrad, encoder_um, time_s, \
                 unix_s, quality, frames, rejected, point_s, raw_bits, frame_sd_x_um, \
                 frame_sd_y_um) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, \
                 ?14, ?15, ?16, ?17, ?18, ?19, ?20, ?21, ?22) ON CONFLICT (campaign_id, seq) DO NOTHING",
            )
            .and_then(|mut st| {
                st.execute(params![
                    campaign,
                    seq,
                    t.run.phase.as_str(),
                    t.run.axis.as_str(),
                    t.run.direction.as_str(),
                    t.run.cycle,
                    grid_index,
                    v[0],
                    v[1],
                    v[2],
                    v[3],
                    v[4],
                    v[5],
                    v[6],
                    v[7],
                    v[8],
                    s.frames,
                    s.rejected,
                    v[9],
                    raw,
                    s.frame_sd_um.map(|d| d[0]),
                    s.frame_sd_um.map(|d| d[1]),
                ])
            })
            .map_err(|e| self.write_err(OP, campaign, e))?;
        Ok(n == 1)
    }

    /// Every sample of a campaign, ordered by seq.
    /// Samples in commit order after commit number `after` (0: from the first), at most
    /// `limit`: `(n, sample)` where `n` is the cursor for the next call. A client that missed
    /// live `sample` events (a reconnect, a slow reader) reads them here, each exactly once.
    pub fn samples_after(
        &self,
        campaign: i64,
        after: i64,
        limit: usize,
    ) -> Result<Vec<(i64, SampleRecord)>, StoreError> {
        const OP: &str = "read samples after a commit";
        let sql = format!(
            "SELECT id, {SAMPLE_COLS} FROM samples WHERE campaign_id = ?1 AND id > ?2 \
             ORDER BY id LIMIT ?3"
        );
        let limit = i64::try_from(limit).unwrap_or(i64::MAX);
        let mut st = self
            .conn
            .prepare_cached(&sql)
            .map_err(|e| self.err(OP, e))?;
        let rows = st
            .query_map(params![campaign, after, limit], |row| {
                let n: i64 = row.get(0)?;
                Ok((n, sample_from_row_at(row, 1)?))
            })
            .and_then(|rows| rows.collect::<rusqlite::Result<Vec<_>>>())
            .map_err(|e| self.err(OP, e))?;
        rows.into_iter()
            .map(|(n, r)| r.map(|s| (n, s)).map_err(|w| self.corrupt(OP, w)))
            .collect()
    }

    pub fn samples(&self, campaign: i64) -> Result<Vec<SampleRecord>, StoreError> {
        const OP: &str = "read samples";
        let sql = format!("SELECT {SAMPLE_COLS} FROM samples WHERE campaign_id = ?1 ORDER BY seq");
        let mut st = self
            .conn
            .prepare_cached(&sql)
            .map_err(|e| self.err(OP, e))?;
        let rows = st
            .query_map([campaign], sample_from_row)
            .and_then(|rows| rows.collect::<rusqlite::Result<Vec<_>>>())
            .map_err(|e| self.err(OP, e))?;
        rows.into_iter()
            .map(|r| r.map_err(|w| self.corrupt(OP, w)))
            .collect()
    }

    /// Number of stored samples of a campaign.
    pub fn sample_count(&self, campaign: i64) -> Result<u64, StoreError> {
        const OP: &str = "count samples";
        let n: i64 = self
            .conn
            .prepare_cached("SELECT count(*) FROM samples WHERE campaign_id = ?1")
            .and_then(|mut st| st.query_row([campaign], |r| r.get(0)))
            .map_err(|e| self.err(OP, e))?;
        u64_from(n, "count").map_err(|w| self.corrupt(OP, w))
    }

    /// The seqs of the targets already stored: a resumed campaign skips these.
    pub fn done_seqs(&self, campaign: i64) -> Result<BTreeSet<u64>, StoreError> {
        const OP: &str = "read done seqs";
        let mut st = self
            .conn
            .prepare_cached("SELECT seq FROM samples WHERE campaign_id = ?1")
            .map_err(|e| self.err(OP, e))?;
        let seqs = st
            .query_map([campaign], |r| r.get::<_, i64>(0))
            .and_then(|rows| rows.collect::<rusqlite::Result<Vec<_>>>())
            .map_err(|e| self.err(OP, e))?;
        seqs.into_iter()
            .map(|s| u64_from(s, "seq").map_err(|w| self.corrupt(OP, w)))
            .collect()
    }

    /// Appends an event to a campaign's log; returns its id, greater than every id before it.
    pub fn add_event(
        &self,
        campaign: i64,
        kind: &str,
        data: &serde_json::Value,
    ) -> Result<i64, StoreError> {
        const OP: &str = "add event";
        let text = data.to_string();
        self.conn
            .prepare_cached(
                "INSERT INTO events (campaign_id, unix_s, kind, data) VALUES (?1, ?2, ?3, ?4)",
            )
            .and_then(|mut st| st.execute(params![campaign, now_unix_s(), kind, text]))
            .map_err(|e| self.write_err(OP, campaign, e))?;
        Ok(self.conn.last_insert_rowid())
    }

    /// Keeps the stage model text campaign `id` was validated with.
    pub fn set_model_snapshot(&self, id: i64, model_toml: &str) -> Result<(), StoreError> {
        const OP: &str = "store the stage model";
        let n = self
            .conn
            .prepare_cached("UPDATE campaigns SET model_toml = ?2 WHERE id = ?1")
            .and_then(|mut st| st.execute(params![id, model_toml]))
            .map_err(|e| self.write_err(OP, id, e))?;
        if n == 0 {
            return Err(self.unknown(OP, id));
        }
        Ok(())
    }

    /// The stage model text campaign `id` was validated with (None: it has none, or the store
    /// recorded it before snapshots).
    pub fn model_snapshot(&self, id: i64) -> Result<Option<String>, StoreError> {
        const OP: &str = "read the stage model";
        self.conn
            .query_row(
                "SELECT model_toml FROM campaigns WHERE id = ?1",
                [id],
                |r| r.get::<_, Option<String>>(0),
            )
            .optional()
            .map_err(|e| self.err(OP, e))?
            .ok_or_else(|| self.unknown(OP, id))
    }

    /// Appends an event to a stage's log (what happened to it outside campaigns: moves);
    /// returns its id.
    pub fn add_stage_event(
        &self,
        stage: &str,
        kind: &str,
        data: &serde_json::Value,
    ) -> Result<i64, StoreError> {
        const OP: &str = "add stage event";
        let text = data.to_string();
        self.conn
            .prepare_cached(
                "INSERT INTO stage_events (stage, unix_s, kind, data) VALUES (?1, ?2, ?3, ?4)",
            )
            .and_then(|mut st| st.execute(params![stage, now_unix_s(), kind, text]))
            .map_err(|e| self.err(OP, e))?;
        Ok(self.conn.last_insert_rowid())
    }

    /// A stage's events with id > `after_id`, oldest first, at most `limit`: (id, unix_s,
    /// kind, data).
    pub fn stage_events_after(
        &self,
        stage: &str,
        after_id: i64,
        limit: usize,
    ) -> Result<Vec<StageEventRow>, StoreError> {
        const OP: &str = "read stage events";
        let limit = i64::try_from(limit).unwrap_or(i64::MAX);
        let mut st = self
            .conn
            .prepare_cached(
                "SELECT id, unix_s, kind, data FROM stage_events \
                 WHERE stage = ?1 AND id > ?2 ORDER BY id LIMIT ?3",
            )
            .map_err(|e| self.err(OP, e))?;
        let rows = st
            .query_map(params![stage, after_id, limit], |r| {
                Ok((
                    r.get::<_, i64>(0)?,
                    r.get::<_, f64>(1)?,
                    r.get::<_, String>(2)?,
                    r.get::<_, String>(3)?,
                ))
            })
            .and_then(|rows| rows.collect::<rusqlite::Result<Vec<_>>>())
            .map_err(|e| self.err(OP, e))?;
        rows.into_iter()
            .map(|(id, unix_s, kind, data)| {
                let data = serde_json::from_str(&data)
                    .map_err(|source| self.corrupt(OP, RowError::StageEventJson { id, source }))?;
                Ok(StageEventRow {
                    id,
                    stage: stage.to_string(),
                    unix_s,
                    kind,
                    data,
                })
            })
            .collect()
    }

    /// A campaign's events with id > `after_id`, oldest first (`after_id = 0`: all of them).
    pub fn events_after(&self, campaign: i64, after_id: i64) -> Result<Vec<EventRow>, StoreError> {
        const OP: &str = "read events";
        let mut st = self
            .conn
            .prepare_cached(
                "SELECT id, campaign_id, unix_s, kind, data FROM events \
                 WHERE campaign_id = ?1 AND id > ?2 ORDER BY id",
            )
            .map_err(|e| self.err(OP, e))?;
        let rows = st
            .query_map(params![campaign, after_id], |r| {
                Ok((
                    r.get::<_, i64>(0)?,
                    r.get::<_, i64>(1)?,
                    r.get::<_, f64>(2)?,
                    r.get::<_, String>(3)?,
                    r.get::<_, String>(4)?,
                ))
            })
            .and_then(|rows| rows.collect::<rusqlite::Result<Vec<_>>>())
            .map_err(|e| self.err(OP, e))?;
        rows.into_iter()
            .map(|(id, campaign, unix_s, kind, data)| {
                let data = serde_json::from_str(&data)
                    .map_err(|source| self.corrupt(OP, RowError::EventJson { id, source }))?;
                Ok(EventRow {
                    id,
                    campaign,
                    unix_s,
                    kind,
                    data,
                })
            })
            .collect()
    }

    /// Stores a result/artifact of a campaign (curve CSV, summary JSON, SVG/PNG plot,
    /// compensation table), replacing any earlier one of the same name.
    pub fn put_result(
        &self,
        campaign: i64,
        name: &str,
        content_type: &str,
        bytes: &[u8],
    ) -> Result<(), StoreError> {
        let op = format!("put result {name:?}");
        self.conn
            .prepare_cached(
                "INSERT INTO results (campaign_id, name, content_type, bytes, updated_unix_s) \
                 VALUES (?1, ?2, ?3, ?4, ?5) ON CONFLICT (campaign_id, name) DO UPDATE SET \
                 content_type = excluded.content_type, bytes = excluded.bytes, \
                 updated_unix_s = excluded.updated_unix_s",
            )
            .and_then(|mut st| {
                st.execute(params![campaign, name, content_type, bytes, now_unix_s()])
            })
            .map_err(|e| self.write_err(&op, campaign, e))?;
        Ok(())
    }

    /// A result's (content type, bytes), None if the campaign has none of that name.
    pub fn result(
        &self,
        campaign: i64,
        name: &str,
    ) -> Result<Option<(String, Vec<u8>)>, StoreError> {
        self.conn
            .prepare_cached(
                "SELECT content_type, bytes FROM results WHERE campaign_id = ?1 AND name = ?2",
            )
            .and_then(|mut st| {
                st.query_row(params![campaign, name], |r| Ok((r.get(0)?, r.get(1)?)))
                    .optional()
            })
            .map_err(|e| self.err(format!("read result {name:?}"), e))
    }

    /// The names of a campaign's results, sorted.
    pub fn result_names(&self, campaign: i64) -> Result<Vec<String>, StoreError> {
        const OP: &str = "list results";
        self.conn
            .prepare_cached("SELECT name FROM results WHERE campaign_id = ?1 ORDER BY name")
            .and_then(|mut st| {
                st.query_map([campaign], |r| r.get(0))?
                    .collect::<rusqlite::Result<Vec<String>>>()
            })
            .map_err(|e| self.err(OP, e))
    }
}

#[cfg(test)]
mod tests;
