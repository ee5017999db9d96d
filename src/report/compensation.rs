//! Compensation lookup tables: the table compressive sensing replaces, at grid resolution.
//!
//! For moving axis x the columns are `position_um`, the available components among `ef_xx_um`,
//! `eb_xx_um`, `ef_xy_um`, `eb_xy_um` (this order; y analogous), then `corr_forward_um` and
//! `corr_backward_um`. corr = -(driving-direction error) for that direction: error = measured -
//! target, so commanding `P + corr(P)` reaches P (to first order). A correction whose driving
//! component is absent is left empty, as is any non-finite value. When the curves carry a
//! pointwise uncertainty, `u_forward_um,u_backward_um` follow (k = 1, µm).
use std::fmt::Write;

use super::{ComponentCurve, ReportError};
use crate::types::{AxisId, Component, Direction};

/// Errors and corrections are written with this many decimals (µm): 1 pm resolution.
const DECIMALS: usize = 6;

/// The components a compensation table of `axis` may hold, in column order: driving forward,
/// driving backward, coupling forward, coupling backward.
pub fn compensation_columns(axis: AxisId) -> [Component; 4] {
    let c = |direction, measured| Component {
        moving: axis,
        direction,
        measured,
    };
    [
        c(Direction::Forward, axis),
        c(Direction::Backward, axis),
        c(Direction::Forward, axis.other()),
        c(Direction::Backward, axis.other()),
    ]
}

/// Position without trailing zeros (`4750`, `12.5`), at most 6 decimals.
fn fmt_position(p: f64) -> String {
    let s = format!("{p:.6}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".into()
    } else {
        s.into()
    }
}

fn fmt_value(v: Option<f64>) -> String {
    match v {
        Some(v) if v.is_finite() => format!("{v:.DECIMALS$}"),
        _ => String::new(),
    }
}

/// The compensation table of moving axis `axis` as CSV, from the reconstructed curves of its
/// components in `curves` (others are ignored). `Ok(None)` when `curves` has no component of
/// that axis; an error when its curves are invalid or not on one grid (within 1e-6 µm). When a
/// component appears twice, the first one is used.
pub fn compensation_csv(
    axis: AxisId,
    curves: &[ComponentCurve],
) -> Result<Option<String>, ReportError> {
    let cols: Vec<(Component, &ComponentCurve)> = compensation_columns(axis)
        .into_iter()
        .filter_map(|comp| {
            curves
                .iter()
                .find(|c| c.parsed() == Some(comp))
                .map(|c| (comp, c))
        })
        .collect();
    let Some(&(_, first)) = cols.first() else {
        return Ok(None);
    };
    for (_, c) in &cols {
        c.validate()?;
        let same = c.grid_um.len() == first.grid_um.len()
            && c.grid_um
                .iter()
                .zip(&first.grid_um)
                .all(|(a, b)| (a - b).abs() <= crate::grid::ON_GRID_TOL_UM);
        if !same {
            return Err(ReportError::InvalidCurve {
                component: c.component.clone(),
                reason: format!(
                    "grid differs from {}'s: a compensation table needs one grid per axis",
                    first.component
                ),
            });
        }
    }
    let driving = |d: Direction| {
        cols.iter()
            .find(|(comp, _)| comp.measured == axis && comp.direction == d)
            .map(|(_, c)| c)
    };
    let (fwd, bwd) = (driving(Direction::Forward), driving(Direction::Backward));

    let mut out = String::from("position_um");
    for (comp, _) in &cols {
        let _ = write!(out, ",{}_um", comp.name());
    }
    out.push_str(",corr_forward_um,corr_backward_um");
    // The corrections' standard uncertainty (k = 1), when the curves carry one: last, so the
    // table's older columns keep their places.
    let u_of = |c: Option<&&ComponentCurve>| {
        c.filter(|c| c.u_um.len() == c.grid_um.len())
            .map(|c| c.u_um.clone())
    };
    let u = [u_of(fwd), u_of(bwd)];
    let with_u = u.iter().any(Option::is_some);
    if with_u {
        out.push_str(",u_forward_um,u_backward_um");
    }
    out.push('\n');
    for (i, &p) in first.grid_um.iter().enumerate() {
        out.push_str(&fmt_position(p));
        for (_, c) in &cols {
            out.push(',');
            out.push_str(&fmt_value(Some(c.reconstructed_um[i])));
        }
        for d in [fwd, bwd] {
            out.push(',');
            out.push_str(&fmt_value(d.map(|c| -c.reconstructed_um[i])));
        }
        if with_u {
            for col in &u {
                out.push(',');
                out.push_str(&fmt_value(col.as_ref().map(|v| v[i])));
            }
        }
        out.push('\n');
    }
    Ok(Some(out))
}

#[cfg(test)]
mod tests {
    use super::super::testdata::curve;
    use super::*;

    fn parse(csv: &str) -> (Vec<String>, Vec<Vec<String>>) {
        let mut lines = csv.lines();
        let header = lines.next().unwrap().split(',').map(String::from).collect();
        let rows = lines
            .map(|l| l.split(',').map(String::from).collect())
            .collect();
        (header, rows)
    }

    #[test]
    fn x_table_has_the_components_in_order_and_negated_corrections() {
        // Given out of order, with a y component that must not appear.
        let curves = vec![
            curve("eb_xy", 0.3),
            curve("ef_yy", 9.0),
            curve("eb_xx", -1.0),
            curve("ef_xx", 1.0),
            curve("ef_xy", 0.2),
        ];
        let csv = compensation_csv(AxisId::X, &curves).unwrap().unwrap();
        let (header, rows) = parse(&csv);
        assert_eq!(
            header,
            [
                "position_um",
                "ef_xx_um",
                "eb_xx_um",
                "ef_xy_um",
                "eb_xy_um",
                "corr_forward_um",
                "corr_backward_um"
            ]
        );
        assert_eq!(rows.len(), curves[0].grid_um.len());
        let ef = &curves[3];
        let eb = &curves[2];
        for (i, r) in rows.iter().enumerate() {
            assert_eq!(r.len(), 7);
            let v: Vec<f64> = r.iter().map(|s| s.parse().unwrap()).collect();
            assert!((v[0] - ef.grid_um[i]).abs() < 1e-9);
            assert!((v[1] - ef.reconstructed_um[i]).abs() <= 1e-6);
            assert!((v[2] - eb.reconstructed_um[i]).abs() <= 1e-6);
            // To reach P, command P + corr: corr = -error of that driving direction.
            assert!(
                (v[5] + ef.reconstructed_um[i]).abs() <= 1e-6,
                "row {i}: {r:?}"
            );
            assert!(
                (v[6] + eb.reconstructed_um[i]).abs() <= 1e-6,
                "row {i}: {r:?}"
            );
        }
        // Offsets +1 / -1 µm dominate at the start: forward correction negative there.
        assert!(rows[0][5].starts_with('-') && !rows[0][6].starts_with('-'));
        assert_eq!(rows[2][0], "10");
    }

    #[test]
    fn y_table_with_one_direction_leaves_the_other_correction_empty() {
        let curves = vec![
            curve("ef_yy", 0.5),
            curve("ef_xx", 0.0),
            curve("eb_yx", 0.1),
        ];
        let csv = compensation_csv(AxisId::Y, &curves).unwrap().unwrap();
        let (header, rows) = parse(&csv);
        assert_eq!(
            header,
            [
                "position_um",
                "ef_yy_um",
                "eb_yx_um",
                "corr_forward_um",
                "corr_backward_um"
            ]
        );
        assert_eq!(rows[0].len(), 5);
        assert_eq!(rows[0][4], "");
        assert_eq!(rows[0][3], format!("{:.6}", -curves[0].reconstructed_um[0]));
        assert!(compensation_csv(AxisId::X, &[curve("ef_yy", 0.0)])
            .unwrap()
            .is_none());
    }

    #[test]
    fn different_grids_on_one_axis_are_refused() {
        let mut b = curve("eb_xx", 0.0);
        b.grid_um[5] += 1.0;
        assert!(compensation_csv(AxisId::X, &[curve("ef_xx", 0.0), b]).is_err());
    }

    #[test]
    fn positions_print_without_trailing_zeros() {
        assert_eq!(fmt_position(4750.0), "4750");
        assert_eq!(fmt_position(12.5), "12.5");
        assert_eq!(fmt_position(0.1 + 0.2), "0.3");
        assert_eq!(fmt_position(-0.0), "0");
        assert_eq!(fmt_value(Some(1.0 / 3.0)), "0.333333");
        assert_eq!(fmt_value(Some(f64::NAN)), "");
    }
}
