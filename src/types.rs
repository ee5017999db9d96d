//! The records a campaign produces, shared by the engine, the store, the reconstruction worker,
//! the reports and the API. Positions in µm, times in s.
use serde::{Deserialize, Serialize};

pub use csmetro_hal::Direction;
pub use csmetro_sim::AxisId;

/// Which design a run belongs to: the compressive-sensing sample or the full reference scan.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Phase {
    /// The random (or jittered) sample that compressive sensing reconstructs from.
    Cs,
    /// Every grid point, the conventional scan the paper compares against.
    Full,
    /// Random points of the XY plane, both axes moving (a `[map]` campaign; the run's axis is
    /// x by convention, its direction the approach side on both axes).
    Map,
}

impl Phase {
    pub fn as_str(self) -> &'static str {
        match self {
            Phase::Cs => "cs",
            Phase::Full => "full",
            Phase::Map => "map",
        }
    }
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "cs" => Some(Phase::Cs),
            "full" => Some(Phase::Full),
            "map" => Some(Phase::Map),
            _ => None,
        }
    }
}

/// One run = one monotonic sweep of one axis in one direction: the unit a curve is made of.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct RunKey {
    pub phase: Phase,
    pub axis: AxisId,
    pub direction: Direction,
    pub cycle: u32,
}

impl RunKey {
    /// e.g. `cs-x-forward-0`.
    pub fn label(&self) -> String {
        format!(
            "{}-{}-{}-{}",
            self.phase.as_str(),
            self.axis.as_str(),
            self.direction.as_str(),
            self.cycle
        )
    }
    /// The two error components this run measures: (driving, coupling), e.g. (ef_xx, ef_xy).
    pub fn components(&self) -> [Component; 2] {
        [
            Component {
                moving: self.axis,
                direction: self.direction,
                measured: self.axis,
            },
            Component {
                moving: self.axis,
                direction: self.direction,
                measured: self.axis.other(),
            },
        ]
    }
}

/// One of the paper's eight error components: e{f|b}_{moving}{measured}, e.g. `eb_xy` = error
/// along y while x moves backward. Error = measured - target (ISO 230-2 sign: P - Pt).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct Component {
    pub moving: AxisId,
    pub direction: Direction,
    pub measured: AxisId,
}

impl Component {
    /// `ef_xx`, `eb_xy`, ...
    pub fn name(&self) -> String {
        let d = match self.direction {
            Direction::Forward => 'f',
            Direction::Backward => 'b',
        };
        format!("e{d}_{}{}", self.moving.as_str(), self.measured.as_str())
    }

    /// The eight components in the paper's order.
    pub fn all() -> Vec<Component> {
        let mut v = Vec::with_capacity(8);
        for moving in [AxisId::X, AxisId::Y] {
            for direction in [Direction::Forward, Direction::Backward] {
                for measured in [moving, moving.other()] {
                    v.push(Component {
                        moving,
                        direction,
                        measured,
                    });
                }
            }
        }
        v
    }

    pub fn parse(s: &str) -> Option<Component> {
        Component::all().into_iter().find(|c| c.name() == s)
    }
}

/// A planned measurement. `seq` is its place in the campaign plan, unique within a campaign:
/// the store keys samples by it, so a resumed campaign never measures a target twice.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Target {
    pub seq: u64,
    pub run: RunKey,
    /// Index on the axis grid.
    pub grid_index: usize,
    pub target_x_um: f64,
    pub target_y_um: f64,
}

impl Target {
    /// Commanded position of the moving axis, µm.
    pub fn target_um(&self) -> f64 {
        match self.run.axis {
            AxisId::X => self.target_x_um,
            AxisId::Y => self.target_y_um,
        }
    }
}

/// One stored measurement: a decoded, accepted frame (or the mean of several) at a target.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SampleRecord {
    pub target: Target,
    /// Decoded stage position, µm (pattern frame, mean over the averaged frames).
    pub meas_x_um: f64,
    pub meas_y_um: f64,
    pub theta_mrad: f64,
    /// Position the controller reported (encoder), µm.
    pub encoder_um: f64,
    /// Physical time since the campaign started, s (the time axis of drift effects).
    pub time_s: f64,
    /// Wall-clock time the sample was taken, s since the Unix epoch.
    pub unix_s: f64,
    /// Decode quality: fraction of code bits agreeing with the window, worst frame.
    pub quality: f64,
    /// Frames averaged and frames rejected (retried) for this sample.
    pub frames: u32,
    pub rejected: u32,
    /// Physical time this point took (move, settle, dwell, frames), s.
    pub point_s: f64,
    /// Scatter of the averaged frames (x, y): the sample standard deviation of single frames
    /// about their mean, µm; `None` with one frame. The camera's repeatability at a standing
    /// stage, from which the reconstruction's noise floor is measured (`crate::noise`).
    #[serde(default)]
    pub frame_sd_um: Option<[f64; 2]>,
}

impl SampleRecord {
    /// Error = measured - target along `measured`, µm.
    pub fn error_um(&self, measured: AxisId) -> f64 {
        match measured {
            AxisId::X => self.meas_x_um - self.target.target_x_um,
            AxisId::Y => self.meas_y_um - self.target.target_y_um,
        }
    }

    /// Tests' sample: `target` measured exactly there (the encoder on the moving axis), one
    /// frame, every time 0; a test sets the fields it is about.
    #[cfg(test)]
    pub(crate) fn at(target: Target) -> Self {
        SampleRecord {
            target,
            meas_x_um: target.target_x_um,
            meas_y_um: target.target_y_um,
            theta_mrad: 0.0,
            encoder_um: target.target_um(),
            time_s: 0.0,
            unix_s: 0.0,
            quality: 1.0,
            frames: 1,
            rejected: 0,
            point_s: 0.0,
            frame_sd_um: None,
        }
    }
}

/// Campaign lifecycle as stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CampaignState {
    Queued,
    Running,
    Paused,
    /// Stopped by a crash or a lost device; `resume` continues from the last stored sample.
    Interrupted,
    Aborted,
    Failed,
    Done,
}

impl CampaignState {
    pub fn as_str(self) -> &'static str {
        match self {
            CampaignState::Queued => "queued",
            CampaignState::Running => "running",
            CampaignState::Paused => "paused",
            CampaignState::Interrupted => "interrupted",
            CampaignState::Aborted => "aborted",
            CampaignState::Failed => "failed",
            CampaignState::Done => "done",
        }
    }
    pub fn parse(s: &str) -> Option<Self> {
        [
            CampaignState::Queued,
            CampaignState::Running,
            CampaignState::Paused,
            CampaignState::Interrupted,
            CampaignState::Aborted,
            CampaignState::Failed,
            CampaignState::Done,
        ]
        .into_iter()
        .find(|c| c.as_str() == s)
    }
    /// In the hands of a process (the service or a foreground run): running, or paused between
    /// two points. Left so by a process that died, nobody finishes it.
    pub fn is_in_progress(self) -> bool {
        matches!(self, CampaignState::Running | CampaignState::Paused)
    }

    /// Finished for good (no resume).
    pub fn is_final(self) -> bool {
        matches!(
            self,
            CampaignState::Aborted | CampaignState::Failed | CampaignState::Done
        )
    }
}

/// Who asked for a state change: the event log names it (`"origin"`, and `"by"` in words).
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Origin {
    /// `cli` (a foreground `csmetro run`/`resume`), `api` (an HTTP client), `service` (the
    /// service on its own: start, shutdown, the orphan check).
    pub via: String,
    /// The HTTP client's address, `ip:port`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub client: Option<String>,
    /// The operator's name, when given (`--operator`, the `X-Operator` header).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub operator: Option<String>,
}

/// Longest operator name kept, bytes.
pub const MAX_OPERATOR_BYTES: usize = 64;

impl Origin {
    pub fn cli(operator: Option<String>) -> Self {
        Self {
            via: "cli".into(),
            client: None,
            operator,
        }
    }
    pub fn api(client: Option<String>, operator: Option<String>) -> Self {
        Self {
            via: "api".into(),
            client,
            operator,
        }
    }
    pub fn service() -> Self {
        Self {
            via: "service".into(),
            client: None,
            operator: None,
        }
    }
    /// In words: `operator "ana" via the API from 127.0.0.1:50123`, `the service`.
    pub fn describe(&self) -> String {
        let who = match &self.operator {
            Some(o) => format!("operator {o:?}"),
            None if self.via == "service" => return "the service".into(),
            None => "an operator".into(),
        };
        match (self.via.as_str(), &self.client) {
            ("api", Some(c)) => format!("{who} via the API from {c}"),
            ("api", None) => format!("{who} via the API"),
            ("cli", _) => format!("{who} on the command line"),
            (v, _) => format!("{who} via {v}"),
        }
    }
    /// The audit fields of an event: `{"by": "...", "origin": {...}}`.
    pub fn fields(&self) -> serde_json::Value {
        serde_json::json!({"by": self.describe(), "origin": self})
    }
}

/// Why an operator name was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum OperatorError {
    #[error("operator name longer than {MAX_OPERATOR_BYTES} bytes")]
    TooLong,
    #[error("operator name with control characters")]
    Control,
}

/// An operator name as given by a user: trimmed, at most [`MAX_OPERATOR_BYTES`], no control
/// characters. `Ok(None)` when empty.
pub fn check_operator(name: &str) -> Result<Option<String>, OperatorError> {
    let n = name.trim();
    if n.is_empty() {
        return Ok(None);
    }
    if n.len() > MAX_OPERATOR_BYTES {
        return Err(OperatorError::TooLong);
    }
    if n.chars().any(char::is_control) {
        return Err(OperatorError::Control);
    }
    Ok(Some(n.to_string()))
}

/// A message with every number written with more than 17 digits shortened to scientific
/// notation (`1e308`, not 309 digits): errors quote values a user gave, and a value like `1e308`
/// would otherwise fill a terminal or an HTTP answer.
pub fn shorten_numbers(msg: &str) -> std::borrow::Cow<'_, str> {
    let b = msg.as_bytes();
    let digits = |r: &[u8]| r.iter().filter(|c| c.is_ascii_digit()).count();
    let mut out = String::new();
    let (mut last, mut i) = (0, 0);
    while i < b.len() {
        if !b[i].is_ascii_digit() {
            i += 1;
            continue;
        }
        let start = i;
        while i < b.len() && (b[i].is_ascii_digit() || b[i] == b'.') {
            i += 1;
        }
        let run = &msg[start..i];
        let run = run.trim_end_matches('.');
        if digits(run.as_bytes()) > 17 {
            if let Ok(v) = run.parse::<f64>() {
                out.push_str(&msg[last..start]);
                out.push_str(&format!("{v:e}"));
                last = start + run.len();
            }
        }
    }
    if last == 0 {
        return std::borrow::Cow::Borrowed(msg);
    }
    out.push_str(&msg[last..]);
    std::borrow::Cow::Owned(out)
}

/// (year, month, day, hour, minute, second) in UTC of a Unix time (H. Hinnant's days-to-civil
/// algorithm); times before 1970 are clamped to it.
pub fn utc_parts(unix_s: f64) -> [i64; 6] {
    let t = unix_s.max(0.0) as i64;
    let (days, secs) = (t.div_euclid(86_400), t.rem_euclid(86_400));
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    [y, m, d, secs / 3600, (secs / 60) % 60, secs % 60]
}

#[cfg(test)]
mod shorten_tests {
    use super::shorten_numbers;

    #[test]
    fn long_numbers_are_written_short_and_the_rest_is_kept() {
        let long = format!("{}", 1e308);
        assert_eq!(
            shorten_numbers(&format!("grid 0:5:{long} has more than 1000000 points")),
            "grid 0:5:1e308 has more than 1000000 points"
        );
        assert_eq!(
            shorten_numbers(&format!("floating point `{long}.0`, expected")),
            "floating point `1e308`, expected"
        );
        assert_eq!(shorten_numbers("9500 µm at 1.25 s"), "9500 µm at 1.25 s");
        assert_eq!(
            shorten_numbers("seed 12345678901234567"),
            "seed 12345678901234567"
        );
    }
}
