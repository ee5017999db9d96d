//! `csmetro bench`: accuracy and speed figures as JSON (recorded in BENCHMARKS.md).
use std::process::ExitCode;

use clap::Subcommand;
use csmetro_sim::ReferenceCurveParams;
use serde::Serialize;
use serde_json::json;

mod families;
mod gap;
mod kernels;
mod speed;
mod uncertainty;

use super::{CliError, CliResult};
use crate::grid::Grid;
use crate::recon::{self, Method, ReconSettings};
use crate::sampling::{Design, DesignKind};
use crate::synth;
use kernels::{chol, dct_pairs};
use speed::speed;

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    what: What,
}

#[derive(Subcommand)]
enum What {
    /// Recovery error (mean/max/std of g - f) per method and m, over seeds, next to the paper's Table II.
    Accuracy {
        #[arg(long, default_value_t = 20)]
        seeds: u64,
        /// Comma-separated m values.
        #[arg(long, default_value = "100,300,600,900")]
        m: String,
        /// Comma-separated methods.
        #[arg(long, default_value = "bp,pchip,linear,physics,auto")]
        methods: String,
    },
    /// `auto` (no pitch) on curves the simulator did not make (the generator the tests share,
    /// eight families; leadscrew and rough on 4,303 points at 2.5 µm with m scaled to the same
    /// sampling fraction): against `physics` told the true period, `bp` and `pchip`; period
    /// detections; cv_error_um against the true error. `real`: the band on the measured curves
    /// of tests/data/real when run from the repository.
    Families {
        #[arg(long, default_value_t = 20)]
        seeds: u64,
        /// Comma-separated m values.
        #[arg(long, default_value = "100,300,600,900")]
        m: String,
        /// Comma-separated families (single, two, limit, chirp, noise, steps, leadscrew, rough).
        #[arg(
            long,
            default_value = "single,two,limit,chirp,noise,steps,leadscrew,rough"
        )]
        families: String,
    },
    /// Solve times (median, p90; first_ms: the first solve, which plans the transforms;
    /// median_best_of_3_ms: per curve the best of three solves, n = 1901 only; core_clock_ghz,
    /// fma_gflops, fma512_gflops, median_mcycles: no longer measured (they came from inline
    /// assembly probes), always null) single-threaded: fast BP at n = 1901, auto with its CV,
    /// scale runs.
    Speed {
        #[arg(long, default_value_t = 11)]
        repeat: usize,
        /// Also time Clarabel on the same BP problem at this m (slow: tens of seconds at m = 600).
        #[arg(long)]
        clarabel_m: Option<usize>,
        /// Add a row of fast BP at n = 1901, m = 600 solved without pause for this many seconds
        /// (the `repeat` curves in turn): median and percentiles over every solve, and the median
        /// of each tenth of the span (`window_medians_ms`).
        #[arg(long, value_name = "SECONDS")]
        sustain_s: Option<f64>,
    },
    /// The BP exact finish's dense Cholesky (a random SPD m x m matrix) through faer, ms; then
    /// the solve G⁻¹X of a block of right-hand sides (the simplex's first block) through faer's
    /// two triangular solves. Best and median of `repeat`.
    Chol {
        #[arg(long, default_value_t = 101)]
        repeat: usize,
        /// Comma-separated sizes.
        #[arg(long, default_value = "300,600,900")]
        m: String,
        /// Right-hand sides of the block solve (a multiple of 8, as the lab scripts use).
        #[arg(long, default_value_t = 32)]
        rhs: usize,
    },
    /// The gap diagnosis: the real MUTS X ISO 230-2 table (backlash value ± SE, drift), and
    /// the independent generator tests/common/othergen.rs (every library kind alone on its four
    /// designs, pairs, nulls, effects outside the library): rates named, runtime.
    Gap {
        /// Seeds per design (each: 15 singles, 6 pairs, 2 nulls, 1 outside the library).
        #[arg(long, default_value_t = 3)]
        seeds: u64,
    },
    /// ISO 230-2 figures with U (k = 2) against the simulator's truth over simulated
    /// characterisations: the CS path (random design, `auto` and its band) and ISO 230-2 cycles
    /// (11 targets, 5 approaches per direction): coverage of E, A, B, M by their U.
    Uncertainty {
        #[arg(long, default_value_t = 50)]
        seeds: u64,
        /// CS measurements per direction (of 1,901 grid points).
        #[arg(long, default_value_t = 300)]
        m: usize,
        /// Measurement noise σ, µm.
        #[arg(long, default_value_t = 0.05)]
        noise_um: f64,
        /// Only one path: `cs` or `cycles` (cycles alone needs no reconstruction: seconds).
        #[arg(long)]
        only: Option<String>,
    },
    /// One orthonormal DCT pair (inverse + forward), µs: the real-FFT (Makhoul) path against
    /// rustdct, and the real-FFT path in f32, at the sizes the solvers meet.
    Dct {
        #[arg(long, default_value_t = 11)]
        repeat: usize,
    },
}

/// Paper Table II (DCT basis pursuit on real data, X forward): m, mean abs, max abs, std (µm).
pub const PAPER_TABLE_II: [(usize, f64, f64, f64); 4] = [
    (100, 0.512, 3.088, 0.655),
    (300, 0.198, 1.186, 0.270),
    (600, 0.092, 0.650, 0.141),
    (900, 0.047, 0.560, 0.085),
];

#[derive(Debug, Clone, Serialize)]
pub struct AccuracyRow {
    pub method: String,
    pub m: usize,
    pub seeds: u64,
    pub mean_abs_um: f64,
    pub max_abs_um: f64,
    pub std_um: f64,
    pub worst_max_abs_um: f64,
    pub median_solve_ms: f64,
    /// For auto: mean of its cross-validated error estimate and how often it picked each method.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mean_cv_error_um: Option<f64>,
}

fn parse_list<T: std::str::FromStr>(s: &str, what: &str) -> Result<Vec<T>, CliError> {
    s.split(',')
        .map(|t| {
            t.trim()
                .parse::<T>()
                .map_err(|_| CliError::input(format!("--{what}: cannot parse {t:?}")))
        })
        .collect()
}

/// Runs every method on the paper-like curve for seeds 0..seeds and each m (random design).
pub fn accuracy(seeds: u64, ms: &[usize], methods: &[Method]) -> anyhow::Result<Vec<AccuracyRow>> {
    let grid: Grid = "0:5:9500".parse().map_err(anyhow::Error::msg)?;
    let params = ReferenceCurveParams::default();
    let mut rows = Vec::new();
    for &m in ms {
        let problems: Vec<_> = (0..seeds)
            .map(|seed| {
                synth::problem(
                    &grid,
                    seed,
                    &params,
                    &Design::new(DesignKind::Random, m, 1000 + seed),
                    0.01,
                )
            })
            .collect::<Result<_, _>>()
            .map_err(anyhow::Error::msg)?;
        for &method in methods {
            let mut acc = (0.0, 0.0, 0.0, 0.0f64, 0.0);
            let mut times = Vec::new();
            for p in &problems {
                let s = ReconSettings {
                    method,
                    ..Default::default()
                };
                let r = recon::reconstruct(&grid, &p.samples, &s)?;
                let (mean, max, std) = synth::error_stats(&r.values, &p.truth);
                acc.0 += mean;
                acc.1 += max;
                acc.2 += std;
                acc.3 = acc.3.max(max);
                acc.4 += r.cv_error_um.unwrap_or(0.0);
                times.push(r.solve_ms);
            }
            let k = seeds as f64;
            rows.push(AccuracyRow {
                method: method.as_str().into(),
                m,
                seeds,
                mean_abs_um: acc.0 / k,
                max_abs_um: acc.1 / k,
                std_um: acc.2 / k,
                worst_max_abs_um: acc.3,
                median_solve_ms: median(&mut times),
                mean_cv_error_um: matches!(method, Method::Auto | Method::Physics)
                    .then_some(acc.4 / k),
            });
        }
    }
    Ok(rows)
}

pub fn median(v: &mut [f64]) -> f64 {
    percentile(v, 0.5)
}

pub(super) fn percentile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(|a, b| a.partial_cmp(b).unwrap_or(std::cmp::Ordering::Equal));
    v[((v.len() - 1) as f64 * q).round() as usize]
}

pub fn run(a: Args) -> CliResult {
    match a.what {
        What::Accuracy { seeds, m, methods } => {
            let ms: Vec<usize> = parse_list(&m, "m")?;
            let methods: Vec<Method> = parse_list(&methods, "methods")?;
            let rows = accuracy(seeds, &ms, &methods).map_err(CliError::failure)?;
            let paper: Vec<_> = PAPER_TABLE_II
                .iter()
                .map(|&(m, mean, max, std)| json!({"m": m, "mean_abs_um": mean, "max_abs_um": max, "std_um": std}))
                .collect();
            outln!(
                "{}",
                json!({"benchmark": "accuracy", "n": 1901, "noise_um": 0.01, "rows": rows, "paper_table_ii": paper})
            );
        }
        What::Families { seeds, m, families } => {
            let ms: Vec<usize> = parse_list(&m, "m")?;
            let fams: Vec<String> = parse_list(&families, "families")?;
            if seeds == 0 || ms.iter().any(|&m| !(2..=1901).contains(&m)) {
                return Err(CliError::input(
                    "--seeds at least 1 and every --m in 2..=1901 (n = 1901)",
                ));
            }
            if let Some(f) = fams
                .iter()
                .find(|f| !families::FAMILIES.contains(&f.as_str()))
            {
                return Err(CliError::input(format!(
                    "--families: unknown family {f:?} (one of {})",
                    families::FAMILIES.join(", ")
                )));
            }
            let rows = families::run(seeds, &ms, &fams).map_err(CliError::failure)?;
            let real = families::real(seeds, &ms).map_err(CliError::failure)?;
            outln!(
                "{}",
                json!({"benchmark": "families", "n": 1901, "rows": rows, "real": real})
            );
        }
        What::Gap { seeds } => {
            if seeds == 0 {
                return Err(CliError::input("--seeds at least 1"));
            }
            outln!("{}", gap::run(seeds).map_err(CliError::failure)?);
        }
        What::Uncertainty {
            seeds,
            m,
            noise_um,
            only,
        } => {
            let (cs, cycles) = match only.as_deref() {
                None => (true, true),
                Some("cs") => (true, false),
                Some("cycles") => (false, true),
                Some(o) => {
                    return Err(CliError::input(format!("--only {o:?}: cs or cycles")));
                }
            };
            if seeds == 0 || !(2..=1901).contains(&m) || !(noise_um.is_finite() && noise_um > 0.0) {
                return Err(CliError::input(
                    "--seeds at least 1, --m in 2..=1901, --noise-um > 0",
                ));
            }
            let r = uncertainty::run(seeds, m, noise_um, cs, cycles).map_err(CliError::failure)?;
            outln!(
                "{}",
                json!({"benchmark": "uncertainty", "n": 1901, "report": r})
            );
        }
        What::Dct { repeat } => outln!("{}", dct_pairs(repeat.max(1))),
        What::Chol { repeat, m, rhs } => {
            let ms: Vec<usize> = parse_list(&m, "m")?;
            if rhs == 0 || !rhs.is_multiple_of(8) {
                return Err(CliError::input(format!(
                    "--rhs {rhs}: a positive multiple of 8"
                )));
            }
            outln!("{}", chol(&ms, repeat.max(1), rhs));
        }
        What::Speed {
            repeat,
            clarabel_m,
            sustain_s,
        } => {
            if let Some(t) = sustain_s.filter(|t| !(t.is_finite() && *t > 0.0)) {
                return Err(CliError::input(format!(
                    "--sustain-s {t}: a positive number of seconds"
                )));
            }
            let out = speed(repeat, clarabel_m, sustain_s).map_err(CliError::failure)?;
            outln!("{out}");
        }
    }
    Ok(ExitCode::SUCCESS)
}
