"""The session store's tables: one SQLite schema, created (IF NOT EXISTS) by every `Store`.

Tables added later are migrated by `Store._migrate`. Every session's option set (the names of
its buzzers, box j is `names[j]`; the paper's is red, blue) is in `option_sets`, and its trials,
for any number of options, in `trials`, whose option, human and robot are names of that set
(checked by `Store.write_trial`: SQL cannot check against another table's JSON). `fits`
(`FITS_SCHEMA`), `withdrawals` with `withdrawn_aggregates`, and `provenance` (one row per
conductor run of a session: `services.core.provenance`) are read and written by `fits.py`,
`withdrawals.py` and `provenance.py`; their schemas are here, so every store, an older one too,
has them once opened (the columns added to `withdrawals` later by `Store._migrate`).
"""

SCHEMA = """
CREATE TABLE IF NOT EXISTS sessions (
    session     TEXT PRIMARY KEY,
    participant TEXT NOT NULL,
    rig         TEXT NOT NULL,
    seed        INTEGER,
    started_ns  INTEGER NOT NULL,
    finished_ns INTEGER,
    status      TEXT NOT NULL CHECK (status IN ('running', 'complete', 'aborted')),
    config      TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS trials (
    session     TEXT NOT NULL REFERENCES sessions(session),
    trial       INTEGER NOT NULL,
    mode        TEXT NOT NULL CHECK (mode IN ('dissensus', 'consensus')),
    option      TEXT CHECK (option <> ''),
    gaze_level  TEXT NOT NULL,
    yaw         REAL NOT NULL,
    pitch       REAL NOT NULL,
    t_go_ns     INTEGER,
    t_end_ns    INTEGER,
    human       TEXT CHECK (human <> ''),
    robot       TEXT CHECK (robot <> ''),
    outcome     TEXT CHECK (outcome IN ('C', 'CH', 'D', 'DH')),
    switches    INTEGER NOT NULL,
    violations  INTEGER NOT NULL,
    clicks      INTEGER,
    score       INTEGER NOT NULL,
    end_reason  TEXT NOT NULL,
    interrupted INTEGER NOT NULL DEFAULT 0,
    attempts    INTEGER NOT NULL DEFAULT 1,
    PRIMARY KEY (session, trial)
);
CREATE TABLE IF NOT EXISTS option_sets (
    session   TEXT PRIMARY KEY REFERENCES sessions(session),
    n_options INTEGER NOT NULL CHECK (n_options >= 2),
    names     TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS safety_events (
    session TEXT NOT NULL,
    trial   INTEGER NOT NULL,
    attempt INTEGER NOT NULL,
    t_ns    INTEGER NOT NULL,
    device  TEXT NOT NULL,
    event   TEXT NOT NULL CHECK (event IN ('safe_stop', 'clear', 'estop', 'release')),
    reason  TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS safety_events_by_trial ON safety_events (session, trial, t_ns);
CREATE TABLE IF NOT EXISTS rig_events (
    session TEXT NOT NULL,
    trial   INTEGER NOT NULL,
    attempt INTEGER NOT NULL,
    t_ns    INTEGER NOT NULL,
    host    TEXT NOT NULL,
    service TEXT NOT NULL,
    kind    TEXT NOT NULL,
    code    INTEGER,
    text    TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS rig_events_by_trial ON rig_events (session, trial, t_ns);
CREATE TABLE IF NOT EXISTS interruptions (
    session    TEXT NOT NULL,
    trial      INTEGER NOT NULL,
    attempt    INTEGER NOT NULL,
    t_start_ns INTEGER NOT NULL,
    t_ns       INTEGER NOT NULL,
    reason     TEXT NOT NULL,
    PRIMARY KEY (session, trial, attempt)
);
CREATE TABLE IF NOT EXISTS cues (
    session    TEXT NOT NULL,
    trial      INTEGER NOT NULL,
    attempt    INTEGER NOT NULL,
    cue        TEXT NOT NULL,
    planned_ns INTEGER NOT NULL,
    played_ns  INTEGER NOT NULL
);
CREATE INDEX IF NOT EXISTS cues_by_trial ON cues (session, trial, planned_ns);
CREATE TABLE IF NOT EXISTS open_attempts (
    session    TEXT PRIMARY KEY REFERENCES sessions(session),
    trial      INTEGER NOT NULL,
    attempt    INTEGER NOT NULL,
    t_start_ns INTEGER NOT NULL
);
CREATE TABLE IF NOT EXISTS samples (
    session  TEXT NOT NULL,
    trial    INTEGER NOT NULL,
    t_ns     INTEGER NOT NULL,
    detected INTEGER NOT NULL,
    hand_x   REAL,
    hand_y   REAL,
    z_h      REAL,
    z_r      REAL,
    b_r      REAL,
    ee_x     REAL,
    ee_y     REAL,
    theta    REAL,
    distance REAL,
    landmarks BLOB
);
CREATE INDEX IF NOT EXISTS samples_by_trial ON samples (session, trial, t_ns);
CREATE TABLE IF NOT EXISTS questionnaires (
    participant TEXT PRIMARY KEY,
    q1          INTEGER NOT NULL CHECK (q1 BETWEEN 1 AND 10),
    q2          INTEGER NOT NULL CHECK (q2 BETWEEN 1 AND 10),
    q3          TEXT NOT NULL CHECK (q3 IN ('Yes', 'No', 'Maybe')),
    q4          INTEGER NOT NULL CHECK (q4 BETWEEN 1 AND 10),
    q5          INTEGER NOT NULL CHECK (q5 BETWEEN 1 AND 10),
    entered_ns  INTEGER NOT NULL,
    source      TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS recordings (
    session    TEXT NOT NULL REFERENCES sessions(session),
    path       TEXT NOT NULL,
    started_ns INTEGER NOT NULL,
    PRIMARY KEY (session, path)
);
CREATE TABLE IF NOT EXISTS participants (
    participant  TEXT PRIMARY KEY,
    consent      INTEGER NOT NULL CHECK (consent IN (0, 1)),
    consented_ns INTEGER NOT NULL,
    demographics TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS session_orders (
    session     TEXT PRIMARY KEY,
    participant TEXT NOT NULL,
    options     TEXT NOT NULL,
    again       TEXT,
    recorded_ns INTEGER NOT NULL
);
CREATE TABLE IF NOT EXISTS withdrawals (
    participant  TEXT PRIMARY KEY,
    withdrawn_ns INTEGER NOT NULL,
    reason       TEXT NOT NULL DEFAULT '',
    deleted      INTEGER NOT NULL DEFAULT 0 CHECK (deleted IN (0, 1)),
    deleted_ns   INTEGER,
    counts       TEXT NOT NULL DEFAULT '{}',
    withdrawn_by TEXT NOT NULL DEFAULT '',
    aggregated   INTEGER NOT NULL DEFAULT 0 CHECK (aggregated IN (0, 1))
);
CREATE TABLE IF NOT EXISTS withdrawn_aggregates (
    options TEXT NOT NULL,
    trial   INTEGER NOT NULL,
    mode    TEXT NOT NULL,
    outcome TEXT NOT NULL,
    n       INTEGER NOT NULL,
    PRIMARY KEY (options, trial, mode, outcome)
);
CREATE TABLE IF NOT EXISTS provenance (
    session          TEXT NOT NULL,
    started_ns       INTEGER NOT NULL,
    version          TEXT NOT NULL,
    sources_sha256   TEXT NOT NULL,
    params_hash      TEXT NOT NULL,
    params_file      TEXT,
    params_sha256    TEXT,
    rig_file         TEXT,
    rig_sha256       TEXT,
    policy_file      TEXT,
    policy_sha256    TEXT,
    study_file       TEXT,
    study_sha256     TEXT,
    study_name       TEXT,
    consent_version  TEXT,
    allocation_seed  INTEGER,
    preregistration  TEXT,
    hosts            TEXT NOT NULL DEFAULT '{}',
    recording_file   TEXT,
    recording_sha256 TEXT,
    finished_ns      INTEGER,
    PRIMARY KEY (session, started_ns)
);
"""

# Per-participant model fits (`nod fit`, services/store/fits.py).
FITS_SCHEMA = """
CREATE TABLE IF NOT EXISTS fits (
    participant TEXT NOT NULL,
    session     TEXT NOT NULL,
    parameter   TEXT NOT NULL,
    estimate    REAL NOT NULL,
    low         REAL NOT NULL,
    high        REAL NOT NULL,
    level       REAL NOT NULL,
    method      TEXT NOT NULL,
    fitted_ns   INTEGER NOT NULL,
    probability REAL,  -- a 0/1 parameter's probability of 1 (its estimate: the likelier value)
    prior_p     REAL,  -- the person's out-of-prior check: p < 0.05 flags them (NULL: unchecked)
    PRIMARY KEY (participant, parameter)
);
"""

# The robot policy of each session and its settings per trial (`services.store.policies`), and
# the participant's estimate after each trial (`services.store.estimates`): in every store, so
# a study's stores read as one (`services.store.study_stores.union_of`) whoever ran a policy.
POLICY_SCHEMA = """
CREATE TABLE IF NOT EXISTS policy_cohorts (
    prefix         TEXT NOT NULL,
    first_seed     INTEGER NOT NULL,
    policy         TEXT NOT NULL,
    policy_sha256  TEXT NOT NULL,
    policy_text    TEXT,  -- the policy file itself: a resume rebuilds the same policy from it
    built_on       TEXT,  -- JSON: the configuration of the people its table was simulated from
    PRIMARY KEY (prefix, first_seed)
);
CREATE TABLE IF NOT EXISTS policy_sessions (
    session        TEXT PRIMARY KEY,
    policy         TEXT NOT NULL,
    policy_sha256  TEXT NOT NULL,
    kind           TEXT
);
CREATE TABLE IF NOT EXISTS policy_trials (
    session     TEXT NOT NULL,
    trial       INTEGER NOT NULL,
    b_star      REAL NOT NULL,
    gaze_level  TEXT NOT NULL,
    u_r         REAL NOT NULL,
    PRIMARY KEY (session, trial)
);
CREATE TABLE IF NOT EXISTS person_estimates (
    session      TEXT NOT NULL,
    trial        INTEGER NOT NULL,
    trials_seen  INTEGER NOT NULL,
    seconds      REAL NOT NULL,
    name         TEXT NOT NULL,
    estimate     REAL NOT NULL,
    low          REAL NOT NULL,
    high         REAL NOT NULL,
    probability  REAL,
    PRIMARY KEY (session, trial, name)
);
"""
