//! Results in the forms a facility uses: `csmetro export ID --format nexus` writes one NeXus
//! (HDF5) file per campaign through the HDF5 library's own bindings (`--features nexus`);
//! `--format linuxcnc|twincat-lsec|csv --axis x|y` one axis's compensation as a table a motion
//! controller loads ([`controller`]).
//!
//! [`Export`] gathers what a campaign holds in the store (its file, rig identity, every result
//! artifact) without knowing the format; [`table`] reads the result CSVs into columns, so the
//! file holds exactly the values of the CSV results.
use crate::store::{Store, StoreError};

pub mod controller;
#[cfg(feature = "nexus")]
pub mod nexus;

/// Everything about one stored campaign an export writes.
#[derive(Debug, Clone)]
pub struct Export {
    pub id: i64,
    pub name: String,
    pub stage: String,
    pub state: String,
    pub created_unix_s: f64,
    pub updated_unix_s: f64,
    /// The campaign file as submitted.
    pub spec_toml: String,
    /// The simulator's rig description (`rig` event), when it ran on one.
    pub rig: Option<String>,
    /// (axis, controller `*IDN?`, stage) per referenced axis.
    pub axes: Vec<(String, String, String)>,
    /// (name, content type, bytes) of every stored result.
    pub results: Vec<(String, String, Vec<u8>)>,
}

/// Why an export failed.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error("no campaign {0} in the store")]
    NoCampaign(i64),
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("result {name}: {message}")]
    Result { name: String, message: String },
    #[error("writing {path}: {message}")]
    Write { path: String, message: String },
}

impl Export {
    /// Reads campaign `id` from the store.
    pub fn gather(store: &Store, id: i64) -> Result<Export, ExportError> {
        let row = store.campaign(id)?.ok_or(ExportError::NoCampaign(id))?;
        let mut rig = None;
        let mut axes = Vec::new();
        for e in store.events_after(id, 0)? {
            match e.kind.as_str() {
                "rig" => rig = e.data["describe"].as_str().map(str::to_string),
                "axis" => {
                    let s = |k: &str| e.data[k].as_str().unwrap_or("").to_string();
                    let a = (s("axis"), s("idn"), s("stage"));
                    // A resumed campaign references again: one entry per axis.
                    axes.retain(|x: &(String, String, String)| x.0 != a.0);
                    axes.push(a);
                }
                _ => {}
            }
        }
        let mut results = Vec::new();
        for name in store.result_names(id)? {
            if let Some((ctype, bytes)) = store.result(id, &name)? {
                results.push((name, ctype, bytes));
            }
        }
        Ok(Export {
            id,
            name: row.name,
            stage: row.stage,
            state: row.state.as_str().to_string(),
            created_unix_s: row.created_unix_s,
            updated_unix_s: row.updated_unix_s,
            spec_toml: row.spec_toml,
            rig,
            axes,
            results,
        })
    }
}

/// One column of a result CSV: numbers (empty cells NaN) or text.
#[derive(Debug, Clone, PartialEq)]
pub enum Column {
    Numbers(Vec<f64>),
    Text(Vec<String>),
}

/// A result CSV as named columns, in file order.
pub type Table = Vec<(String, Column)>;

/// Largest result table read (the demo's are ~10 k rows).
const MAX_ROWS: usize = 2_000_000;

/// Reads a result CSV: a header, then rows of the same length. A column is numeric when every
/// non-empty cell parses as a number.
pub fn table(name: &str, bytes: &[u8]) -> Result<Table, ExportError> {
    let bad = |message: String| ExportError::Result {
        name: name.to_string(),
        message,
    };
    let mut r = csv::ReaderBuilder::new()
        .has_headers(true)
        .from_reader(bytes);
    let header: Vec<String> = r
        .headers()
        .map_err(|e| bad(e.to_string()))?
        .iter()
        .map(|h| h.trim().to_string())
        .collect();
    let mut cells: Vec<Vec<String>> = vec![Vec::new(); header.len()];
    for (i, rec) in r.records().enumerate() {
        if i >= MAX_ROWS {
            return Err(bad(format!("more than {MAX_ROWS} rows")));
        }
        let rec = rec.map_err(|e| bad(e.to_string()))?;
        for (c, v) in cells.iter_mut().zip(rec.iter()) {
            c.push(v.trim().to_string());
        }
    }
    Ok(header
        .into_iter()
        .zip(cells)
        .map(|(h, col)| {
            let nums: Option<Vec<f64>> = col
                .iter()
                .map(|v| {
                    if v.is_empty() {
                        Some(f64::NAN)
                    } else {
                        v.parse::<f64>().ok()
                    }
                })
                .collect();
            let col = match nums {
                Some(n) if !col.is_empty() => Column::Numbers(n),
                _ => Column::Text(col),
            };
            (h, col)
        })
        .collect())
}

/// The unit a column or JSON key names by its suffix (`position_um` → `um`), NeXus spelling.
pub fn unit_of(name: &str) -> Option<&'static str> {
    const UNITS: [(&str, &str); 8] = [
        ("_um", "um"),
        ("_mm", "mm"),
        ("_s", "s"),
        ("_ms", "ms"),
        ("_mrad", "mrad"),
        ("_urad", "urad"),
        ("_pct", "%"),
        ("_um_per_h", "um/h"),
    ];
    UNITS
        .iter()
        .filter(|(s, _)| name.ends_with(s))
        // The longest suffix wins (`_um_per_h` over `_h`, `_ms` over `_s`).
        .max_by_key(|(s, _)| s.len())
        .map(|(_, u)| *u)
}

/// A name usable as an HDF5 link: `/` and `.` replaced, at most 255 bytes.
pub fn link_name(name: &str) -> String {
    let mut s = crate::report::file_stem(name);
    s.truncate(255);
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_columns_are_numbers_or_text_with_units() {
        let t = table(
            "s.csv",
            b"seq,phase,meas_x_um,theta_mrad\n0,cs,97.43,\n1,full,224.25,0.001\n",
        )
        .unwrap();
        assert_eq!(t[0], ("seq".into(), Column::Numbers(vec![0.0, 1.0])));
        assert_eq!(
            t[1],
            (
                "phase".into(),
                Column::Text(vec!["cs".into(), "full".into()])
            )
        );
        match &t[3].1 {
            Column::Numbers(v) => assert!(v[0].is_nan() && v[1] == 0.001),
            c => panic!("{c:?}"),
        }
        assert_eq!(unit_of("meas_x_um"), Some("um"));
        assert_eq!(unit_of("solve_ms"), Some("ms"));
        assert_eq!(unit_of("rate_um_per_h"), Some("um/h"));
        assert_eq!(unit_of("seq"), None);
        assert_eq!(
            link_name("curves/cs-x-forward-0-ef_xx.csv"),
            "curves_cs-x-forward-0-ef_xx_csv"
        );
        assert!(table("bad.csv", b"a,b\n1,2,3\n").is_err());
    }
}
