//! A campaign as one NeXus file (HDF5, through the HDF5 library's bindings `hdf5-metno`).
//!
//! ```text
//! /                      NXroot   default=entry, creator, file_time
//! /entry                 NXentry  default=<first curve>; title, campaign_id, stage, state,
//!                                 start_time, end_time, program_name
//!   instrument           NXinstrument  name (stage), rig, <axis>/controller_idn, <axis>/stage
//!   samples              NXdata   every column of samples.csv (+ position_um, error_um: the
//!                                 moving axis's target and measured − target); signal error_um
//!   ef_xx, eb_xx, ...    NXdata   each <component>.csv: position_um axis, cs_um signal,
//!                                 full_scan_um / truth_um (and any u_um) beside it
//!   compensation_x|y     NXdata   the correction table
//!   curves/<run-comp>    NXdata   each reconstruction as it was stored
//!   map_*                NXdata   a map campaign's tables
//!   iso230, summary      NXcollection  iso230.json and summary.json, key by key
//!   notes/campaign       NXnote   the campaign file (text/x-toml)
//!   notes/summary        NXnote   summary.json as text
//! ```
//! Every number is the CSV's or the JSON's own value; a column or key named `*_um` carries
//! `units="um"` (likewise `_s`, `_ms`, `_mrad`, `_urad`).
use std::path::Path;

use h5::types::VarLenUnicode;
use hdf5_metno as h5;
use serde_json::Value;

use super::{link_name, table, unit_of, Column, Export, ExportError};

type H5Result<T> = Result<T, h5::Error>;

fn vlu(s: &str) -> VarLenUnicode {
    // A NUL cannot be stored in a C string: dropped (no campaign text has one).
    s.replace('\0', "").parse().unwrap_or_default()
}

fn attr(loc: &h5::Location, name: &str, value: &str) -> H5Result<()> {
    loc.new_attr::<VarLenUnicode>()
        .create(name)?
        .write_scalar(&vlu(value))
}

fn group(parent: &h5::Group, name: &str, class: &str) -> H5Result<h5::Group> {
    let g = parent.create_group(name)?;
    attr(&g, "NX_class", class)?;
    Ok(g)
}

fn text(parent: &h5::Group, name: &str, value: &str) -> H5Result<h5::Dataset> {
    let d = parent.new_dataset::<VarLenUnicode>().create(name)?;
    d.write_scalar(&vlu(value))?;
    Ok(d)
}

fn number(parent: &h5::Group, name: &str, value: f64) -> H5Result<()> {
    let d = parent.new_dataset::<f64>().create(name)?;
    d.write_scalar(&value)?;
    if let Some(u) = unit_of(name) {
        attr(&d, "units", u)?;
    }
    Ok(())
}

fn numbers(parent: &h5::Group, name: &str, values: &[f64]) -> H5Result<()> {
    let d = parent
        .new_dataset_builder()
        .with_data(values)
        .create(name)?;
    if let Some(u) = unit_of(name) {
        attr(&d, "units", u)?;
    }
    Ok(())
}

fn texts(parent: &h5::Group, name: &str, values: &[String]) -> H5Result<()> {
    let v: Vec<VarLenUnicode> = values.iter().map(|s| vlu(s)).collect();
    parent
        .new_dataset_builder()
        .with_data(v.as_slice())
        .create(name)?;
    Ok(())
}

/// ISO 8601 UTC time of a Unix time.
fn iso8601(unix_s: f64) -> String {
    let [y, m, d, hh, mm, ss] = crate::types::utc_parts(unix_s);
    format!("{y:04}-{m:02}-{d:02}T{hh:02}:{mm:02}:{ss:02}Z")
}

/// An NXdata group of a result table; `signal`/`axes`: the column names plotted by default.
fn nxdata(parent: &h5::Group, name: &str, t: &[(String, Column)]) -> H5Result<h5::Group> {
    let g = group(parent, name, "NXdata")?;
    for (col, c) in t {
        let n = link_name(col);
        match c {
            Column::Numbers(v) => numbers(&g, &n, v)?,
            Column::Text(v) => texts(&g, &n, v)?,
        }
    }
    let numeric: Vec<&str> = t
        .iter()
        .filter(|(_, c)| matches!(c, Column::Numbers(_)))
        .map(|(n, _)| n.as_str())
        .collect();
    let axis = ["position_um", "x_um"]
        .into_iter()
        .find(|a| numeric.contains(a))
        .or(numeric.first().copied());
    let signal = ["cs_um", "error_um", "corr_forward_um", "e_x_um"]
        .into_iter()
        .find(|s| numeric.contains(s))
        .or(numeric.iter().copied().find(|n| Some(*n) != axis));
    if let Some(s) = signal {
        attr(&g, "signal", &link_name(s))?;
    }
    if let Some(a) = axis {
        attr(&g, "axes", &link_name(a))?;
    }
    Ok(g)
}

/// A JSON value as groups (objects, arrays of objects) and datasets (numbers, strings, arrays
/// of numbers or strings); nulls are left out.
fn json_into(parent: &h5::Group, name: &str, v: &Value) -> H5Result<()> {
    let name = link_name(name);
    match v {
        Value::Null => Ok(()),
        Value::Bool(b) => number(parent, &name, if *b { 1.0 } else { 0.0 }),
        Value::Number(n) => number(parent, &name, n.as_f64().unwrap_or(f64::NAN)),
        Value::String(s) => text(parent, &name, s).map(|_| ()),
        Value::Array(a) if !a.is_empty() && a.iter().all(Value::is_number) => {
            let v: Vec<f64> = a.iter().filter_map(Value::as_f64).collect();
            numbers(parent, &name, &v)
        }
        Value::Array(a) if !a.is_empty() && a.iter().all(Value::is_string) => {
            let v: Vec<String> = a
                .iter()
                .filter_map(|s| s.as_str().map(str::to_string))
                .collect();
            texts(parent, &name, &v)
        }
        Value::Array(a) => {
            let g = group(parent, &name, "NXcollection")?;
            for (i, x) in a.iter().enumerate() {
                json_into(&g, &i.to_string(), x)?;
            }
            Ok(())
        }
        Value::Object(o) => {
            let g = group(parent, &name, "NXcollection")?;
            for (k, x) in o {
                json_into(&g, k, x)?;
            }
            Ok(())
        }
    }
}

/// `samples.csv` plus the moving axis's target (`position_um`) and error (`error_um`), which
/// the samples layout (`crate::samples::LAYOUT`) has had since it became one for every file.
fn with_errors(mut t: Vec<(String, Column)>) -> Vec<(String, Column)> {
    let col =
        |t: &[(String, Column)], n: &str| t.iter().find(|(c, _)| c == n).map(|(_, c)| c.clone());
    if col(&t, "position_um").is_some() || col(&t, "error_um").is_some() {
        return t;
    }
    let (Some(Column::Text(axis)), Some(Column::Numbers(tx)), Some(Column::Numbers(ty))) = (
        col(&t, "axis"),
        col(&t, "target_x_um"),
        col(&t, "target_y_um"),
    ) else {
        return t;
    };
    let (Some(Column::Numbers(mx)), Some(Column::Numbers(my))) =
        (col(&t, "meas_x_um"), col(&t, "meas_y_um"))
    else {
        return t;
    };
    let mut pos = Vec::with_capacity(axis.len());
    let mut err = Vec::with_capacity(axis.len());
    for i in 0..axis.len() {
        let (p, m) = if axis[i] == "y" {
            (ty[i], my[i])
        } else {
            (tx[i], mx[i])
        };
        pos.push(p);
        err.push(m - p);
    }
    t.push(("position_um".into(), Column::Numbers(pos)));
    t.push(("error_um".into(), Column::Numbers(err)));
    t
}

fn write_entry(f: &h5::File, e: &Export) -> Result<(), ExportError> {
    let h = |r: H5Result<()>| r;
    let fail = |name: &str, err: h5::Error| ExportError::Result {
        name: name.to_string(),
        message: err.to_string(),
    };
    let root: &h5::Group = f;
    (|| -> H5Result<()> {
        attr(root, "NX_class", "NXroot")?;
        attr(root, "default", "entry")?;
        attr(
            root,
            "creator",
            &format!("csmetro {}", env!("CARGO_PKG_VERSION")),
        )?;
        attr(root, "file_time", &iso8601(crate::store::now_unix_s()))?;
        Ok(())
    })()
    .map_err(|x| fail("/", x))?;
    let entry = group(root, "entry", "NXentry").map_err(|x| fail("entry", x))?;
    h((|| {
        text(&entry, "title", &e.name)?;
        let d = entry.new_dataset::<i64>().create("campaign_id")?;
        d.write_scalar(&e.id)?;
        text(&entry, "stage", &e.stage)?;
        text(&entry, "state", &e.state)?;
        text(&entry, "start_time", &iso8601(e.created_unix_s))?;
        text(&entry, "end_time", &iso8601(e.updated_unix_s))?;
        let p = text(&entry, "program_name", "csmetro")?;
        attr(&p, "version", env!("CARGO_PKG_VERSION"))?;
        let inst = group(&entry, "instrument", "NXinstrument")?;
        text(&inst, "name", &e.stage)?;
        if let Some(r) = &e.rig {
            text(&inst, "rig", r)?;
        }
        for (axis, idn, stage) in &e.axes {
            let a = group(&inst, &link_name(axis), "NXpositioner")?;
            text(&a, "controller_idn", idn)?;
            text(&a, "stage", stage)?;
        }
        let notes = group(&entry, "notes", "NXcollection")?;
        let n = group(&notes, "campaign", "NXnote")?;
        text(&n, "type", "text/x-toml")?;
        text(&n, "data", &e.spec_toml)?;
        Ok(())
    })())
    .map_err(|x| fail("entry", x))?;

    let mut default: Option<String> = None;
    let mut curves: Option<h5::Group> = None;
    for (name, ctype, bytes) in &e.results {
        let is_csv = ctype.starts_with("text/csv") || name.ends_with(".csv");
        if is_csv {
            let t = table(name, bytes)?;
            let (parent, link) = match name.strip_prefix("curves/") {
                Some(rest) => {
                    if curves.is_none() {
                        curves = Some(
                            group(&entry, "curves", "NXcollection").map_err(|x| fail(name, x))?,
                        );
                    }
                    (
                        curves.clone().expect("just made"),
                        link_name(rest.trim_end_matches(".csv")),
                    )
                }
                None => (entry.clone(), link_name(name.trim_end_matches(".csv"))),
            };
            if parent.link_exists(&link) {
                continue;
            }
            let t = if name == "samples.csv" {
                with_errors(t)
            } else {
                t
            };
            nxdata(&parent, &link, &t).map_err(|x| fail(name, x))?;
            // The first component curve is the plot a reader opens by default.
            let component = !name.contains('/')
                && name.len() == "ef_xx.csv".len()
                && (name.starts_with("ef_") || name.starts_with("eb_"));
            if default.is_none() && component {
                default = Some(link);
            }
        } else if name.ends_with(".json") && ctype.contains("json") {
            let v: Value = serde_json::from_slice(bytes).map_err(|x| ExportError::Result {
                name: name.clone(),
                message: x.to_string(),
            })?;
            let base = link_name(name.trim_end_matches(".json"));
            if entry.link_exists(&base) {
                continue;
            }
            json_into(&entry, &base, &v).map_err(|x| fail(name, x))?;
            if name == "summary.json" {
                (|| -> H5Result<()> {
                    let notes = entry.group("notes")?;
                    let n = group(&notes, "summary", "NXnote")?;
                    text(&n, "type", "application/json")?;
                    text(&n, "data", &String::from_utf8_lossy(bytes))?;
                    Ok(())
                })()
                .map_err(|x| fail(name, x))?;
            }
        }
    }
    let default = default.unwrap_or_else(|| "samples".into());
    if entry.link_exists(&default) {
        attr(&entry, "default", &default).map_err(|x| fail("entry", x))?;
    }
    Ok(())
}

/// Writes campaign `e` as a NeXus file at `path` (written beside, then renamed: a reader never
/// sees half a file).
pub fn write(e: &Export, path: &Path) -> Result<(), ExportError> {
    let shown = path.display().to_string();
    let w = |message: String| ExportError::Write {
        path: shown.clone(),
        message,
    };
    let tmp = path.with_extension("nxs.part");
    let f = h5::File::create(&tmp).map_err(|x| w(x.to_string()))?;
    let r = write_entry(&f, e);
    let closed = f.close().map_err(|x| w(x.to_string()));
    if let Err(x) = r.and(closed) {
        let _ = std::fs::remove_file(&tmp);
        return Err(x);
    }
    std::fs::rename(&tmp, path).map_err(|x| w(x.to_string()))
}

#[cfg(test)]
mod tests {
    use super::iso8601;

    #[test]
    fn times_are_iso_8601_utc() {
        assert_eq!(iso8601(0.0), "1970-01-01T00:00:00Z");
        assert_eq!(iso8601(1_764_633_600.5), "2025-12-02T00:00:00Z");
        assert_eq!(iso8601(951_782_400.0), "2000-02-29T00:00:00Z");
    }
}
