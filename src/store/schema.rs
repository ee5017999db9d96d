//! The store's schema as the migrations that build it: frozen history, appended to, never edited.

/// `MIGRATIONS[i]` takes the schema from version `i` to `i + 1`.
pub(super) const MIGRATIONS: &[&str] = &[
    // 0 -> 1: the initial schema.
    r#"
CREATE TABLE campaigns (
    id             INTEGER PRIMARY KEY AUTOINCREMENT,
    name           TEXT    NOT NULL,
    spec_toml      TEXT    NOT NULL,
    spec_path      TEXT    NOT NULL,
    -- The stage (instrument) the campaign runs on: at most one running campaign per stage.
    stage          TEXT    NOT NULL,
    state          TEXT    NOT NULL CHECK (state IN
                       ('queued', 'running', 'paused', 'interrupted', 'aborted', 'failed', 'done')),
    planned        INTEGER NOT NULL CHECK (planned >= 0),
    created_unix_s REAL    NOT NULL,
    updated_unix_s REAL    NOT NULL,
    message        TEXT
);
CREATE INDEX campaigns_by_state ON campaigns (state);
CREATE UNIQUE INDEX one_running_campaign_per_stage ON campaigns (stage) WHERE state = 'running';

-- One row per stored measurement. Positions in um, times in s, angles in mrad.
-- A NULL in a REAL column is a NaN; raw_bits keeps the exact bits of NaN and -0.0 values.
CREATE TABLE samples (
    id          INTEGER PRIMARY KEY,
    campaign_id INTEGER NOT NULL REFERENCES campaigns (id) ON DELETE CASCADE,
    seq         INTEGER NOT NULL CHECK (seq >= 0),
    phase       TEXT    NOT NULL CHECK (phase IN ('cs', 'full')),
    axis        TEXT    NOT NULL CHECK (axis IN ('x', 'y')),
    direction   TEXT    NOT NULL CHECK (direction IN ('forward', 'backward')),
    cycle       INTEGER NOT NULL CHECK (cycle >= 0),
    grid_index  INTEGER NOT NULL CHECK (grid_index >= 0),
    target_x_um REAL,
    target_y_um REAL,
    meas_x_um   REAL,
    meas_y_um   REAL,
    theta_mrad  REAL,
    encoder_um  REAL,
    time_s      REAL,
    unix_s      REAL,
    quality     REAL,
    frames      INTEGER NOT NULL CHECK (frames >= 0),
    rejected    INTEGER NOT NULL CHECK (rejected >= 0),
    point_s     REAL,
    raw_bits    TEXT,
    UNIQUE (campaign_id, seq)
);

-- The campaign's log, streamed to clients; ids only grow (AUTOINCREMENT never reuses one).
CREATE TABLE events (
    id          INTEGER PRIMARY KEY AUTOINCREMENT,
    campaign_id INTEGER NOT NULL REFERENCES campaigns (id) ON DELETE CASCADE,
    unix_s      REAL    NOT NULL,
    kind        TEXT    NOT NULL,
    data        TEXT    NOT NULL
);
CREATE INDEX events_by_campaign ON events (campaign_id, id);

-- Artifacts: curve CSVs, summary JSON, plots, compensation tables. Put again = replaced.
CREATE TABLE results (
    campaign_id    INTEGER NOT NULL REFERENCES campaigns (id) ON DELETE CASCADE,
    name           TEXT    NOT NULL,
    content_type   TEXT    NOT NULL,
    bytes          BLOB    NOT NULL,
    updated_unix_s REAL    NOT NULL,
    PRIMARY KEY (campaign_id, name)
);
"#,
    // 1 -> 2: the store's identity (results folders are marked with it, so a folder is never
    // taken over by a campaign of another store with the same id), and a campaign's
    // updated_unix_s moves with every committed sample.
    r#"
CREATE TABLE store_info (
    key   TEXT PRIMARY KEY,
    value TEXT NOT NULL
);
INSERT INTO store_info (key, value) VALUES ('id', lower(hex(randomblob(8))));
CREATE TRIGGER samples_touch_campaign AFTER INSERT ON samples BEGIN
    UPDATE campaigns
       SET updated_unix_s = max(updated_unix_s, (julianday('now') - 2440587.5) * 86400.0)
     WHERE id = NEW.campaign_id;
END;
"#,
    // 2 -> 3: samples of `[map]` runs (phase 'map'). SQLite cannot alter a CHECK: the table is
    // rebuilt with every row, and its trigger recreated.
    r#"
CREATE TABLE samples_v3 (
    id          INTEGER PRIMARY KEY,
    campaign_id INTEGER NOT NULL REFERENCES campaigns (id) ON DELETE CASCADE,
    seq         INTEGER NOT NULL CHECK (seq >= 0),
    phase       TEXT    NOT NULL CHECK (phase IN ('cs', 'full', 'map')),
    axis        TEXT    NOT NULL CHECK (axis IN ('x', 'y')),
    direction   TEXT    NOT NULL CHECK (direction IN ('forward', 'backward')),
    cycle       INTEGER NOT NULL CHECK (cycle >= 0),
    grid_index  INTEGER NOT NULL CHECK (grid_index >= 0),
    target_x_um REAL,
    target_y_um REAL,
    meas_x_um   REAL,
    meas_y_um   REAL,
    theta_mrad  REAL,
    encoder_um  REAL,
    time_s      REAL,
    unix_s      REAL,
    quality     REAL,
    frames      INTEGER NOT NULL CHECK (frames >= 0),
    rejected    INTEGER NOT NULL CHECK (rejected >= 0),
    point_s     REAL,
    raw_bits    TEXT,
    UNIQUE (campaign_id, seq)
);
INSERT INTO samples_v3 SELECT * FROM samples;
DROP TABLE samples;
ALTER TABLE samples_v3 RENAME TO samples;
CREATE TRIGGER samples_touch_campaign AFTER INSERT ON samples BEGIN
    UPDATE campaigns
       SET updated_unix_s = max(updated_unix_s, (julianday('now') - 2440587.5) * 86400.0)
     WHERE id = NEW.campaign_id;
END;
"#,
    // 3 -> 4: the log of what was done to a stage outside campaigns (moves over the API, with
    // who asked), so every motion a client causes leaves a trace; a campaign's stage model
    // snapshot.
    r#"
CREATE TABLE stage_events (
    id     INTEGER PRIMARY KEY AUTOINCREMENT,
    stage  TEXT    NOT NULL,
    unix_s REAL    NOT NULL,
    kind   TEXT    NOT NULL,
    data   TEXT    NOT NULL
);
CREATE INDEX stage_events_by_stage ON stage_events (stage, id);
-- The stage model a campaign was validated with (its TOML): resumes run the same truth and
-- never read a file that may have been swapped since.
ALTER TABLE campaigns ADD COLUMN model_toml TEXT;
"#,
    // 4 -> 5: the frames' scatter at each point (x, y; NULL with one frame): the camera's
    // repeatability, from which the reconstruction's noise floor is measured.
    r#"
ALTER TABLE samples ADD COLUMN frame_sd_x_um REAL;
ALTER TABLE samples ADD COLUMN frame_sd_y_um REAL;
"#,
];
