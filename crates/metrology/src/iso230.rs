//! ISO 230-2 evaluation of a linear axis from bidirectional repeated approaches.
//!
//! Deviation x_ij = measured - target (µm) at target P_i, approach j, direction ↑ (forward) or
//! ↓ (backward). Figures: mean unidirectional deviations x̄↑ x̄↓, reversal B_i = x̄↑ - x̄↓ (B, B̄),
//! mean bidirectional deviation x̄ and its range M, estimator s, repeatability R↑ = 4s↑,
//! R_i = max(2s↑ + 2s↓ + |B_i|, R↑_i, R↓_i), systematic deviation E, accuracy
//! A = max(x̄ + 2s) - min(x̄ - 2s) over both directions.
use std::collections::BTreeMap;

use serde::Serialize;

/// One approach: target position, direction (+1 forward / -1 backward) and deviation, µm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Approach {
    pub target_um: f64,
    pub forward: bool,
    pub deviation_um: f64,
}

/// Figures at one target.
#[derive(Debug, Clone, Serialize)]
pub struct TargetRow {
    pub target_um: f64,
    pub n_up: usize,
    pub n_down: usize,
    pub mean_up_um: f64,
    pub mean_down_um: f64,
    pub s_up_um: f64,
    pub s_down_um: f64,
    /// B_i = x̄↑ - x̄↓
    pub reversal_um: f64,
    /// x̄_i = (x̄↑ + x̄↓) / 2
    pub mean_bidir_um: f64,
    pub r_up_um: f64,
    pub r_down_um: f64,
    pub r_bidir_um: f64,
}

/// ISO 230-2 figures of an axis, µm: the one figures type (the reports', the
/// objects of `iso230.json` and of `summary.json`'s `iso230`). Unidirectional figures are
/// `None` when that direction is absent, bidirectional ones (B, B̄, M) unless both are present,
/// R unless every target has at least two approaches per direction (s is 0 with one).
#[derive(Debug, Clone, Serialize)]
pub struct Iso230Summary {
    pub targets: usize,
    /// Fewest approaches at any target and direction.
    pub min_approaches: usize,
    /// Accuracy A = max(x̄ + 2s) - min(x̄ - 2s), both directions; A↑, A↓.
    pub a_um: f64,
    pub a_up_um: Option<f64>,
    pub a_down_um: Option<f64>,
    /// Reversal value B = max|B_i|, mean reversal B̄ (signed, B_i = x̄↑ - x̄↓).
    pub b_um: Option<f64>,
    pub b_mean_um: Option<f64>,
    /// Systematic positioning error E (range of x̄↑ and x̄↓), E↑, E↓.
    pub e_um: f64,
    pub e_up_um: Option<f64>,
    pub e_down_um: Option<f64>,
    /// Range of the mean bidirectional deviation M.
    pub m_um: Option<f64>,
    /// Repeatability R (bidirectional), R↑, R↓.
    pub r_um: Option<f64>,
    pub r_up_um: Option<f64>,
    pub r_down_um: Option<f64>,
    /// Per-target figures (empty: not reported).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub rows: Vec<TargetRow>,
}

fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let s = if v.len() > 1 {
        (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
    } else {
        0.0
    };
    (mean, s)
}

fn range(v: impl Iterator<Item = f64> + Clone) -> f64 {
    let max = v.clone().fold(f64::NEG_INFINITY, f64::max);
    let min = v.fold(f64::INFINITY, f64::min);
    max - min
}

/// Evaluates approaches; targets closer than `tol_um` are the same target. `None` without data.
pub fn evaluate(approaches: &[Approach], tol_um: f64) -> Option<Iso230Summary> {
    if approaches.is_empty() {
        return None;
    }
    let key = |p: f64| (p / tol_um.max(1e-12)).round() as i64;
    let mut groups: BTreeMap<i64, (f64, Vec<f64>, Vec<f64>)> = BTreeMap::new();
    for a in approaches {
        let g = groups
            .entry(key(a.target_um))
            .or_insert((a.target_um, Vec::new(), Vec::new()));
        if a.forward {
            g.1.push(a.deviation_um)
        } else {
            g.2.push(a.deviation_um)
        }
    }
    let rows: Vec<TargetRow> = groups
        .values()
        .map(|(p, up, down)| {
            let (mu, su) = if up.is_empty() {
                (f64::NAN, f64::NAN)
            } else {
                mean_std(up)
            };
            let (md, sd) = if down.is_empty() {
                (f64::NAN, f64::NAN)
            } else {
                mean_std(down)
            };
            let b = mu - md;
            let (r_up, r_down) = (4.0 * su, 4.0 * sd);
            TargetRow {
                target_um: *p,
                n_up: up.len(),
                n_down: down.len(),
                mean_up_um: mu,
                mean_down_um: md,
                s_up_um: su,
                s_down_um: sd,
                reversal_um: b,
                mean_bidir_um: (mu + md) / 2.0,
                r_up_um: r_up,
                r_down_um: r_down,
                r_bidir_um: (2.0 * su + 2.0 * sd + b.abs()).max(r_up).max(r_down),
            }
        })
        .collect();
    let has_up = rows.iter().all(|r| r.n_up > 0);
    let has_down = rows.iter().all(|r| r.n_down > 0);
    let up = || rows.iter().filter(|r| r.n_up > 0);
    let down = || rows.iter().filter(|r| r.n_down > 0);
    let max_of = |it: &mut dyn Iterator<Item = f64>| it.fold(f64::NEG_INFINITY, f64::max);
    let acc = |rs: &mut dyn Iterator<Item = (f64, f64)>| {
        let (mut hi, mut lo) = (f64::NEG_INFINITY, f64::INFINITY);
        for (m, s) in rs {
            hi = hi.max(m + 2.0 * s);
            lo = lo.min(m - 2.0 * s);
        }
        hi - lo
    };
    let a_up = acc(&mut up().map(|r| (r.mean_up_um, r.s_up_um)));
    let a_down = acc(&mut down().map(|r| (r.mean_down_um, r.s_down_um)));
    let a = acc(&mut up()
        .map(|r| (r.mean_up_um, r.s_up_um))
        .chain(down().map(|r| (r.mean_down_um, r.s_down_um))));
    let e_up = range(up().map(|r| r.mean_up_um));
    let e_down = range(down().map(|r| r.mean_down_um));
    let e = range(
        up().map(|r| r.mean_up_um)
            .chain(down().map(|r| r.mean_down_um)),
    );
    let both = has_up && has_down;
    let min_approaches = rows
        .iter()
        .flat_map(|r| [r.n_up, r.n_down])
        .filter(|&n| n > 0)
        .min()
        .unwrap_or(0);
    let repeated = min_approaches >= 2;
    Some(Iso230Summary {
        targets: rows.len(),
        min_approaches,
        a_um: a,
        a_up_um: has_up.then_some(a_up),
        a_down_um: has_down.then_some(a_down),
        b_um: both.then(|| max_of(&mut rows.iter().map(|r| r.reversal_um.abs()))),
        b_mean_um: both
            .then(|| rows.iter().map(|r| r.reversal_um).sum::<f64>() / rows.len() as f64),
        e_um: e,
        e_up_um: has_up.then_some(e_up),
        e_down_um: has_down.then_some(e_down),
        m_um: both.then(|| range(rows.iter().map(|r| r.mean_bidir_um))),
        r_um: repeated.then(|| {
            if both {
                max_of(&mut rows.iter().map(|r| r.r_bidir_um))
            } else {
                max_of(&mut up().map(|r| r.r_up_um).chain(down().map(|r| r.r_down_um)))
            }
        }),
        r_up_um: (has_up && repeated).then(|| max_of(&mut up().map(|r| r.r_up_um))),
        r_down_um: (has_down && repeated).then(|| max_of(&mut down().map(|r| r.r_down_um))),
        rows,
    })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// One approach (test data).
    pub(crate) fn ap(p: f64, fwd: bool, d: f64) -> Approach {
        Approach {
            target_um: p,
            forward: fwd,
            deviation_um: d,
        }
    }

    /// Hand-computed case: two targets, two approaches per direction.
    #[test]
    fn figures_match_a_hand_computation() {
        let data = [
            ap(0.0, true, 1.0),
            ap(0.0, true, 3.0),
            ap(0.0, false, -1.0),
            ap(0.0, false, -1.0),
            ap(100.0, true, 2.0),
            ap(100.0, true, 2.0),
            ap(100.0, false, 0.0),
            ap(100.0, false, 2.0),
        ];
        let r = evaluate(&data, 1e-6).unwrap();
        let s2 = 2f64.sqrt();
        let t0 = &r.rows[0];
        assert_eq!((t0.mean_up_um, t0.mean_down_um), (2.0, -1.0));
        assert!((t0.s_up_um - s2).abs() < 1e-12 && t0.s_down_um == 0.0);
        assert_eq!(t0.reversal_um, 3.0);
        let t1 = &r.rows[1];
        assert_eq!(
            (t1.mean_up_um, t1.mean_down_um, t1.reversal_um),
            (2.0, 1.0, 1.0)
        );
        let s = &r;
        assert_eq!(s.b_um, Some(3.0));
        assert_eq!(s.b_mean_um, Some(2.0));
        assert_eq!(s.m_um, Some(1.0)); // x̄ = 0.5 and 1.5
        assert_eq!(s.e_um, 3.0); // from -1 to 2
                                 // R at target 0: 2·√2 + 0 + 3 vs 4√2.
        assert!((s.r_um.unwrap() - (2.0 * s2 + 3.0)).abs() < 1e-12);
        // A: max(x̄ + 2s) = 2 + 2√2 (target 0 up), min(x̄ - 2s) = -1 (target 0 down), or 1 - 2·√2 (target 1 down).
        let lo = (-1.0f64).min(1.0 - 2.0 * s2);
        assert!((s.a_um - (2.0 + 2.0 * s2 - lo)).abs() < 1e-12);
        assert_eq!(s.min_approaches, 2);
    }

    /// A published worked example, computed by hand from the ISO 230-2:2014 definitions
    /// (independently of this module), 3 targets × 3 approaches per direction, deviations in µm:
    ///
    /// | P_i / µm | x_ij↑ | x_ij↓ | x̄↑ | x̄↓ | s↑ | s↓ | B_i | x̄_i | R_i |
    /// |---|---|---|---|---|---|---|---|---|---|
    /// | 0   | 1, 2, 3 | -1, 0, -2 | 2 | -1 | 1  | 1 | 3 | 0.5  | max(2+2+3, 4, 4) = 7 |
    /// | 100 | 4, 4, 7 | 2, 3, 4   | 5 | 3  | √3 | 1 | 2 | 4    | max(2√3+2+2, 4√3, 4) = 4+2√3 |
    /// | 200 | 0, 2, 1 | -3, -1, -2 | 1 | -2 | 1 | 1 | 3 | -0.5 | 7 |
    ///
    /// B = max|B_i| = 3; B̄ = 8/3; M = 4 - (-0.5) = 4.5; E↑ = 5 - 1 = 4; E↓ = 3 - (-2) = 5;
    /// E = 5 - (-2) = 7; R↑ = 4√3 = 6.9282; R↓ = 4; R = 4 + 2√3 = 7.4641;
    /// A↑ = max(4, 5+2√3, 3) - min(0, 5-2√3, -1) = 6 + 2√3 = 9.4641;
    /// A↓ = max(1, 5, 0) - min(-3, 1, -4) = 9; A = (5 + 2√3) - (-4) = 9 + 2√3 = 12.4641.
    #[test]
    fn figures_match_the_published_hand_computed_example() {
        let up = [
            (0.0, [1.0, 2.0, 3.0]),
            (100.0, [4.0, 4.0, 7.0]),
            (200.0, [0.0, 2.0, 1.0]),
        ];
        let down = [
            (0.0, [-1.0, 0.0, -2.0]),
            (100.0, [2.0, 3.0, 4.0]),
            (200.0, [-3.0, -1.0, -2.0]),
        ];
        // Interleaved as a bidirectional test cycle runs: up the axis, then down, three times.
        let mut data = Vec::new();
        for j in 0..3 {
            data.extend(up.iter().map(|(p, x)| ap(*p, true, x[j])));
            data.extend(down.iter().rev().map(|(p, x)| ap(*p, false, x[j])));
        }
        let r = evaluate(&data, 1e-3).unwrap();
        let s3 = 3f64.sqrt();
        let close = |got: f64, want: f64, what: &str| {
            assert!((got - want).abs() < 1e-9, "{what}: {got} vs {want}")
        };
        assert_eq!((r.targets, r.min_approaches), (3, 3));
        let want_rows = [
            (0.0, 2.0, -1.0, 1.0, 1.0, 3.0, 0.5, 7.0),
            (100.0, 5.0, 3.0, s3, 1.0, 2.0, 4.0, 4.0 + 2.0 * s3),
            (200.0, 1.0, -2.0, 1.0, 1.0, 3.0, -0.5, 7.0),
        ];
        for (row, w) in r.rows.iter().zip(want_rows) {
            close(row.target_um, w.0, "P_i");
            close(row.mean_up_um, w.1, "x̄↑");
            close(row.mean_down_um, w.2, "x̄↓");
            close(row.s_up_um, w.3, "s↑");
            close(row.s_down_um, w.4, "s↓");
            close(row.reversal_um, w.5, "B_i");
            close(row.mean_bidir_um, w.6, "x̄_i");
            close(row.r_bidir_um, w.7, "R_i");
        }
        close(r.b_um.unwrap(), 3.0, "B");
        close(r.b_mean_um.unwrap(), 8.0 / 3.0, "B̄");
        close(r.m_um.unwrap(), 4.5, "M");
        close(r.e_up_um.unwrap(), 4.0, "E↑");
        close(r.e_down_um.unwrap(), 5.0, "E↓");
        close(r.e_um, 7.0, "E");
        close(r.r_up_um.unwrap(), 4.0 * s3, "R↑");
        close(r.r_down_um.unwrap(), 4.0, "R↓");
        close(r.r_um.unwrap(), 4.0 + 2.0 * s3, "R");
        close(r.a_up_um.unwrap(), 6.0 + 2.0 * s3, "A↑");
        close(r.a_down_um.unwrap(), 9.0, "A↓");
        close(r.a_um, 9.0 + 2.0 * s3, "A");
        // The published decimals, as a reader checks them.
        assert_eq!(format!("{:.4}", r.r_um.unwrap()), "7.4641");
        assert_eq!(format!("{:.4}", r.a_um), "12.4641");
    }

    #[test]
    fn one_direction_only_leaves_bidirectional_figures_empty() {
        let r = evaluate(&[ap(0.0, true, 1.0), ap(5.0, true, 2.0)], 1e-6).unwrap();
        assert!(r.b_um.is_none() && r.m_um.is_none() && r.a_down_um.is_none());
        assert_eq!(r.e_um, 1.0);
        assert_eq!(r.min_approaches, 1);
        // One approach per target: s = 0, no repeatability to report.
        assert!(r.r_um.is_none() && r.r_up_um.is_none());
        assert!(evaluate(&[], 1e-6).is_none());
    }
}
