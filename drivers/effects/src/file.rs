//! Model files: `[stage]` and `[[effect]]` tables read and written through serde.
//!
//! Reading goes in two steps so every error can name its line: the document into spanned raw
//! effect tables (generic checks: kind, axis, travel, finite numbers, sizes), then each table
//! into `EffectKind` by its `kind` tag, then the checks serde cannot express (periods > 0, ...).
use std::collections::BTreeMap;
use std::io::Read;
use std::path::Path;

use serde::Deserialize;
use toml::{Spanned, Table, Value};

use super::{AxisId, Effect, EffectKind, ModelError, StageModel, LIBRARY_KINDS, SIM_ONLY_KINDS};

/// At most this many effects in a model: real stages need a few dozen at most (the paper-like
/// generator writes ~20); every effect costs design columns in `gap`.
pub const MAX_EFFECTS: usize = 64;
/// At most this many values in one array (harmonics, Legendre terms): real periodic errors need a
/// handful of harmonics; 1,000 `cos_um` terms made `gap` run for over a minute.
pub const MAX_TERMS: usize = 64;
/// Travel ends at most this far from zero, µm (1 m: any micropositioning stage; a roughness
/// effect tabulates its profile on a 1 µm grid over the travel).
pub const MAX_TRAVEL_UM: f64 = 1e6;

/// At most this many keys in one `[[effect]]` (the largest kind has 11): bounds the search for
/// the key at fault when serde refuses a value.
const MAX_KEYS: usize = 32;
/// At most this many bytes in a model file (the shipped ones are a few kB).
const MAX_FILE_BYTES: u64 = 1 << 20;

/// Kinds that act on every sample (or on none) and so need no `axis`.
const AXIS_FREE: &[&str] = &["camera_rotation", "camera_scale", "thermal_drift", "noise"];

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileToml {
    stage: Option<StageToml>,
    #[serde(default)]
    effect: Vec<Spanned<BTreeMap<Spanned<String>, Value>>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct StageToml {
    travel_x_um: Option<Spanned<Vec<f64>>>,
    travel_y_um: Option<Spanned<Vec<f64>>>,
}

/// 1-based line of a byte offset.
fn line_at(text: &str, offset: usize) -> usize {
    let end = offset.min(text.len());
    text.as_bytes()[..end]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

fn at(line: usize, message: impl Into<String>) -> ModelError {
    ModelError::Line {
        line,
        message: message.into(),
    }
}

/// serde's wording in the file's terms, on one line.
fn humane(message: &str) -> String {
    message
        .trim()
        .replace("unknown field", "unknown parameter")
        .replace("missing field", "missing parameter")
        .replace('\n', "; ")
}

fn toml_error(text: &str, e: &toml::de::Error) -> ModelError {
    let line = e.span().map(|s| line_at(text, s.start)).unwrap_or(1);
    at(line, humane(e.message()))
}

/// A `[lo, hi]` travel in µm: finite, lo < hi, within ±`MAX_TRAVEL_UM`.
fn travel(key: &str, v: &[f64]) -> Result<[f64; 2], String> {
    match *v {
        [lo, hi] if lo.is_finite() && hi.is_finite() && lo < hi => {
            if lo.abs() > MAX_TRAVEL_UM || hi.abs() > MAX_TRAVEL_UM {
                Err(format!(
                    "`{key}` = [{lo}, {hi}] µm reaches beyond ±{MAX_TRAVEL_UM} µm"
                ))
            } else {
                Ok([lo, hi])
            }
        }
        _ => Err(format!(
            "`{key}` must be [lo, hi] in µm, finite, with lo < hi"
        )),
    }
}

impl StageModel {
    /// Reads a model TOML file; errors are one line, `FILE:LINE: what`.
    pub fn load(path: &Path) -> Result<Self, ModelError> {
        let shown = path.display().to_string();
        // Checked before opening: the file is untrusted and could be anything (a fifo blocks
        // the open, /dev/zero never ends, /proc files report a size of 0).
        let refuse = |message: String| ModelError::File {
            path: shown.clone(),
            message,
        };
        let meta = std::fs::metadata(path).map_err(|e| refuse(e.to_string()))?;
        if !meta.is_file() || path.starts_with("/proc") || path.starts_with("/sys") {
            return Err(refuse("not a regular file".into()));
        }
        if meta.len() > MAX_FILE_BYTES {
            return Err(refuse(format!(
                "{} bytes; a model file is at most {MAX_FILE_BYTES}",
                meta.len()
            )));
        }
        let mut text = String::new();
        std::fs::File::open(path)
            .and_then(|f| f.take(MAX_FILE_BYTES + 1).read_to_string(&mut text))
            .map_err(|e| refuse(e.to_string()))?;
        if text.len() as u64 > MAX_FILE_BYTES {
            return Err(refuse(format!(
                "more than {MAX_FILE_BYTES} bytes; a model file is at most that"
            )));
        }
        Self::from_toml_str(&text).map_err(|e| match e {
            ModelError::Line { line, message } => ModelError::File {
                path: format!("{shown}:{line}"),
                message,
            },
            other => ModelError::File {
                path: shown,
                message: other.to_string(),
            },
        })
    }

    /// Reads a model from TOML text; errors name the line.
    pub fn from_toml_str(text: &str) -> Result<Self, ModelError> {
        let file: FileToml = toml::from_str(text).map_err(|e| toml_error(text, &e))?;
        let mut model = StageModel::default();
        if let Some(stage) = file.stage {
            for (key, v, slot) in [
                ("travel_x_um", stage.travel_x_um, &mut model.travel_x_um),
                ("travel_y_um", stage.travel_y_um, &mut model.travel_y_um),
            ] {
                if let Some(v) = v {
                    *slot = travel(key, v.get_ref())
                        .map_err(|m| at(line_at(text, v.span().start), m))?;
                }
            }
        }
        if let Some(extra) = file.effect.get(MAX_EFFECTS) {
            return Err(at(
                line_at(text, extra.span().start),
                format!(
                    "{} effects; a model has at most {MAX_EFFECTS}",
                    file.effect.len()
                ),
            ));
        }
        for raw in file.effect {
            let effect = read_effect(text, raw)?;
            model.push(effect);
        }
        Ok(model)
    }

    /// Reads a model from a parsed TOML table (errors name lines of the table written out).
    pub fn from_table(table: &Table) -> Result<Self, ModelError> {
        let text = toml::to_string(table).map_err(|e| ModelError::Invalid(e.to_string()))?;
        Self::from_toml_str(&text)
    }

    /// The model as TOML, in the same format `load` reads.
    pub fn to_toml_string(&self) -> String {
        let mut root = Table::new();
        let mut stage = Table::new();
        stage.insert("travel_x_um".into(), pair(self.travel_x_um));
        stage.insert("travel_y_um".into(), pair(self.travel_y_um));
        root.insert("stage".into(), Value::Table(stage));
        let effects: Vec<Value> = self
            .effects
            .iter()
            .map(|e| Value::Table(e.to_table()))
            .collect();
        root.insert("effect".into(), Value::Array(effects));
        toml::to_string(&root).expect("a TOML table always serializes")
    }
}

fn pair(v: [f64; 2]) -> Value {
    Value::Array(vec![Value::Float(v[0]), Value::Float(v[1])])
}

/// Every number finite and every array at most `MAX_TERMS` long (before serde sees the table).
fn check_values(key: &str, v: &Value) -> Result<(), String> {
    match v {
        Value::Float(x) if !x.is_finite() => Err(format!("`{key}` must be finite, not {x}")),
        Value::Array(a) if a.len() > MAX_TERMS => Err(format!(
            "`{key}` has {} values; at most {MAX_TERMS} per effect",
            a.len()
        )),
        Value::Array(a) => a.iter().try_for_each(|x| check_values(key, x)),
        _ => Ok(()),
    }
}

fn read_effect(
    text: &str,
    raw: Spanned<BTreeMap<Spanned<String>, Value>>,
) -> Result<Effect, ModelError> {
    let start = line_at(text, raw.span().start);
    let mut lines = BTreeMap::new();
    let mut table = Table::new();
    for (k, v) in raw.into_inner() {
        lines.insert(k.get_ref().clone(), line_at(text, k.span().start));
        table.insert(k.into_inner(), v);
    }
    let line_of = |key: &str| lines.get(key).copied().unwrap_or(start);
    let kind = match table.remove("kind") {
        Some(Value::String(s)) => s,
        _ => {
            return Err(at(
                line_of("kind"),
                format!(
                    "effect without a `kind` (one of {})",
                    LIBRARY_KINDS.join(", ")
                ),
            ))
        }
    };
    if !LIBRARY_KINDS.contains(&kind.as_str()) && !SIM_ONLY_KINDS.contains(&kind.as_str()) {
        return Err(at(
            line_of("kind"),
            format!(
                "unknown kind `{kind}` (library: {}; simulator-only: {})",
                LIBRARY_KINDS.join(", "),
                SIM_ONLY_KINDS.join(", ")
            ),
        ));
    }
    let fail = |key: &str, m: String| at(line_of(key), format!("{kind} effect: {m}"));
    if table.len() > MAX_KEYS {
        return Err(fail(
            "",
            format!(
                "{} parameters; an effect has at most {MAX_KEYS}",
                table.len()
            ),
        ));
    }
    for (k, v) in &table {
        check_values(k, v).map_err(|m| fail(k, m))?;
    }
    let axis = match table.remove("axis") {
        Some(Value::String(s)) => AxisId::parse(&s)
            .ok_or_else(|| fail("axis", format!("`axis` must be x or y, not {s:?}")))?,
        Some(_) => return Err(fail("axis", "`axis` must be x or y".into())),
        // Global kinds belong to no axis; others must name theirs.
        None if AXIS_FREE.contains(&kind.as_str()) => AxisId::X,
        None => return Err(fail("axis", "missing `axis` (x or y)".into())),
    };
    let travel_um = match table.remove("travel_um") {
        None => None,
        Some(v) => {
            let v: Vec<f64> = v
                .try_into()
                .map_err(|_| fail("travel_um", "`travel_um` must be [lo, hi] in µm".into()))?;
            Some(travel("travel_um", &v).map_err(|m| fail("travel_um", m))?)
        }
    };
    if kind == "thermal_drift" {
        // A drift moves its own axis unless told otherwise; any case, as `axis`.
        let component = match table.get("component") {
            None => axis,
            Some(Value::String(s)) => AxisId::parse(s).ok_or_else(|| {
                fail(
                    "component",
                    format!("`component` must be x or y, not {s:?}"),
                )
            })?,
            Some(_) => return Err(fail("component", "`component` must be x or y".into())),
        };
        table.insert("component".into(), Value::String(component.as_str().into()));
    }
    table.insert("kind".into(), Value::String(kind.clone()));
    let parsed = EffectKind::deserialize(Value::Table(table.clone())).map_err(|e| {
        let m = humane(e.message());
        // serde names an unknown key; a wrong value it does not name (the kind tag buffers
        // the table), so find the key whose removal cures or changes the error.
        let key = match m.strip_prefix("unknown parameter `") {
            Some(r) => r.split('`').next().map(str::to_string),
            None if m.starts_with("missing parameter") => None,
            None => table.keys().find(|k| value_at_fault(&table, k)).cloned(),
        };
        match key {
            Some(k) if !m.contains(&format!("`{k}`")) => fail(&k, format!("`{k}`: {m}")),
            Some(k) => fail(&k, m),
            None => fail("", m),
        }
    })?;
    check_kind(&parsed).map_err(|(key, m)| fail(key, m))?;
    let mut e = Effect::new(axis, parsed);
    e.travel_um = travel_um;
    Ok(e)
}

/// Whether `key` holds the value serde refused: without it the table reads, or only misses it.
fn value_at_fault(table: &Table, key: &str) -> bool {
    if key == "kind" {
        return false;
    }
    let mut t = table.clone();
    t.remove(key);
    match EffectKind::deserialize(Value::Table(t)) {
        Ok(_) => true,
        Err(e) => e.message().starts_with(&format!("missing field `{key}`")),
    }
}

/// What serde cannot say: strictly positive periods and widths, non-empty profiles.
fn check_kind(kind: &EffectKind) -> Result<(), (&'static str, String)> {
    let positive = |key: &'static str, v: f64| {
        if v > 0.0 {
            Ok(())
        } else {
            Err((key, format!("`{key}` must be > 0")))
        }
    };
    match kind {
        EffectKind::LeadscrewCyclic {
            period_um,
            cos_um,
            sin_um,
        }
        | EffectKind::MotorCyclic {
            period_um,
            cos_um,
            sin_um,
        } => {
            positive("period_um", *period_um)?;
            if cos_um.is_empty() && sin_um.is_empty() {
                return Err((
                    "cos_um",
                    "needs `cos_um` and/or `sin_um` (one value per harmonic)".into(),
                ));
            }
            Ok(())
        }
        EffectKind::Straightness { legendre_um } if legendre_um.is_empty() => {
            Err(("legendre_um", "needs `legendre_um` = [c2, c3, ..]".into()))
        }
        EffectKind::Noise { sigma_um } if *sigma_um < 0.0 => {
            Err(("sigma_um", "`sigma_um` must be >= 0".into()))
        }
        EffectKind::LeadscrewModulated {
            period_um,
            env_wave_period_um,
            ..
        } => {
            positive("period_um", *period_um)?;
            positive("env_wave_period_um", *env_wave_period_um)
        }
        EffectKind::Harmonic { period_um, .. } => positive("period_um", *period_um),
        EffectKind::Defect { sigma_um, .. } => positive("sigma_um", *sigma_um),
        EffectKind::Roughness { corr_um, .. } => positive("corr_um", *corr_um),
        _ => Ok(()),
    }
}

impl Effect {
    /// This effect's parameters as an ordered map (for reports and JSON).
    pub fn params(&self) -> BTreeMap<String, Value> {
        let mut t = self.to_table();
        t.remove("kind");
        t.remove("axis");
        t.into_iter().collect()
    }

    /// The `[[effect]]` table: kind, axis, travel, then the parameters in declaration order.
    pub fn to_table(&self) -> Table {
        let mut t = Table::new();
        t.insert("kind".into(), Value::String(self.kind.name().into()));
        t.insert("axis".into(), Value::String(self.axis.as_str().into()));
        if let Some(tr) = self.travel_um {
            t.insert("travel_um".into(), pair(tr));
        }
        match Value::try_from(&self.kind) {
            Ok(Value::Table(params)) => {
                t.extend(params.into_iter().filter(|(k, _)| k != "kind"));
            }
            other => unreachable!("an effect kind serializes to a table, not {other:?}"),
        }
        t
    }
}

#[cfg(test)]
mod tests;
