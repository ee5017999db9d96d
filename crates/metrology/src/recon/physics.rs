//! A physics-aware reconstruction for leadscrew stages (beyond the paper).
//!
//! Error curve = slow trend (low DCT frequencies: scale, bow, long waves)
//!             + cyclic errors (harmonics of each period found in the samples or given as the
//!               thread pitch, each with a slowly varying envelope and phase: harmonic × Legendre
//!               polynomials of the position)
//!             + correlated roughness and local defects (an Ornstein–Uhlenbeck process, i.e. the
//!               continuous AR(1), or a smooth Matérn 3/2 one), seen through white sensor noise.
//! The parametric part is a ridge least-squares fit; the residual is kriged with its prior by
//! a Kalman (RTS) smoother along the grid, which is O(n) instead of an m x m solve.
use nalgebra::{DMatrix, DVector, Matrix2, Vector2};
use serde::Serialize;

/// Legendre polynomial P_k(s) by the three-term recurrence (the envelope's basis on [-1, 1]).
pub fn legendre(k: usize, s: f64) -> f64 {
    let (mut p0, mut p1) = (1.0, s);
    if k == 0 {
        return p0;
    }
    for j in 1..k {
        let jf = j as f64;
        let p2 = ((2.0 * jf + 1.0) * s * p1 - jf * p0) / (jf + 1.0);
        p0 = p1;
        p1 = p2;
    }
    p1
}

/// The prior of the physics model's residual (the part its terms do not hold).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Kernel {
    /// Ornstein–Uhlenbeck (Matérn 1/2): a rough residual, kriged piecewise-exponentially.
    #[default]
    Ou,
    /// Matérn 3/2: a smooth residual (a chirp, smooth roughness), whose samples the prior
    /// joins with a continuous slope and whose noise it averages over the correlation length.
    Matern32,
}

impl Kernel {
    fn is_ou(&self) -> bool {
        *self == Kernel::Ou
    }

    /// The residual's posterior mean at the ascending grid indices `at` ([`ou_smooth_at`],
    /// [`m32_smooth_at`]), or at all `n` when `at` is None ([`ou_smooth`], [`m32_smooth`]).
    #[allow(clippy::too_many_arguments)]
    fn smooth(
        self,
        n: usize,
        at: Option<&[usize]>,
        step: f64,
        obs_idx: &[usize],
        obs: &[f64],
        sigma2: f64,
        ell: f64,
        noise2: f64,
    ) -> Vec<f64> {
        match (self, at) {
            (Kernel::Ou, Some(at)) => ou_smooth_at(step, obs_idx, obs, at, sigma2, ell, noise2),
            (Kernel::Ou, None) => ou_smooth(n, step, obs_idx, obs, sigma2, ell, noise2),
            (Kernel::Matern32, Some(at)) => {
                m32_smooth_at(step, obs_idx, obs, at, sigma2, ell, noise2)
            }
            (Kernel::Matern32, None) => m32_smooth(n, step, obs_idx, obs, sigma2, ell, noise2),
        }
    }

    /// The smoother's Σ_j K_xj² at every grid point ([`ou_weight_norms`], [`m32_weight_norms`]).
    fn weight_norms(
        self,
        n: usize,
        step: f64,
        obs_idx: &[usize],
        sigma2: f64,
        ell: f64,
        noise2: f64,
    ) -> Vec<f64> {
        match self {
            Kernel::Ou => ou_weight_norms(n, step, obs_idx, sigma2, ell, noise2),
            Kernel::Matern32 => m32_weight_norms(n, step, obs_idx, sigma2, ell, noise2),
        }
    }
}

/// Model structure and hyper-parameters.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PhysicsParams {
    /// DCT trend frequencies 0..=trend_k.
    pub trend_k: usize,
    /// Harmonics 1..=harmonics of every period in `periods_um`.
    pub harmonics: usize,
    /// Envelope/phase modulation: Legendre degrees 0..=envelope_deg.
    pub envelope_deg: usize,
    /// The first of `periods_um` (0 when the model has no periodic term).
    pub pitch_um: f64,
    /// Periods of the cyclic terms, µm.
    pub periods_um: Vec<f64>,
    /// Quadratic phase rate of each period about the travel's centre, rad/µm² (a period that
    /// drifts along the travel); missing entries are 0.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub chirps: Vec<f64>,
    /// Correlation length of the residual's prior, µm.
    pub corr_um: f64,
    /// The residual's prior: OU (rough) or Matérn 3/2 (once differentiable).
    #[serde(skip_serializing_if = "Kernel::is_ou")]
    pub kernel: Kernel,
    /// Ridge weight (relative to the sample count) on all but the constant column.
    pub ridge: f64,
}

impl PhysicsParams {
    pub fn default_for(pitch_um: f64) -> Self {
        Self::with_periods(vec![pitch_um])
    }

    /// Default structure on the given periods (fewer harmonics when there are several).
    pub fn with_periods(periods_um: Vec<f64>) -> Self {
        Self {
            trend_k: 16,
            harmonics: if periods_um.len() > 1 { 2 } else { 4 },
            envelope_deg: 2,
            pitch_um: periods_um.first().copied().unwrap_or(0.0),
            periods_um,
            chirps: Vec::new(),
            corr_um: 12.0,
            kernel: Kernel::Ou,
            ridge: 1e-4,
        }
    }

    /// Shrinks the structure (envelope degree, then harmonics, then trend frequencies) until
    /// its columns leave room in a cross-validation training set of m samples' (four fifths of
    /// them, two spare); false when even the smallest periodic model does not fit.
    pub fn shrink_to(&mut self, m: usize) -> bool {
        let fits = |p: &Self| p.columns() + 2 <= m * 4 / 5;
        while !fits(self) {
            if self.envelope_deg > 0 {
                self.envelope_deg -= 1;
            } else if self.harmonics > 1 {
                self.harmonics = if self.harmonics > 2 { 2 } else { 1 };
            } else if self.trend_k > 4 {
                self.trend_k = (self.trend_k / 2).max(4);
            } else {
                return false;
            }
        }
        true
    }

    pub fn columns(&self) -> usize {
        self.trend_k + 1 + 2 * self.harmonics * (self.envelope_deg + 1) * self.periods_um.len()
    }
}

/// Design matrix rows for grid indices `rows` (positions start + i·step over n points).
pub fn design(
    p: &PhysicsParams,
    n: usize,
    start_um: f64,
    step_um: f64,
    rows: &[usize],
) -> DMatrix<f64> {
    let cols = p.columns();
    let span = step_um * (n - 1) as f64;
    let mut a = DMatrix::zeros(rows.len(), cols);
    let nf = n as f64;
    let mut legendres = vec![0.0; p.envelope_deg + 1];
    for (r, &i) in rows.iter().enumerate() {
        let x = start_um + i as f64 * step_um;
        let s = if span > 0.0 {
            2.0 * (x - start_um) / span - 1.0
        } else {
            0.0
        };
        let mut c = 0;
        // cos(kθ) by the Chebyshev recurrence and the harmonics' (cos hw, sin hw) by angle
        // addition: one cosine and one sin_cos per row and period instead of one per column (at
        // n = 65,536 the trigonometry was a fifth of the physics fit's time). Within ~1e-14 of
        // the direct values for these orders.
        let theta = std::f64::consts::PI * (i as f64 + 0.5) / nf;
        let (c1, mut prev, mut cur) = (theta.cos(), theta.cos(), 1.0);
        for k in 0..=p.trend_k {
            a[(r, c)] = cur;
            c += 1;
            if k == 0 {
                (prev, cur) = (1.0, c1);
            } else {
                (prev, cur) = (cur, 2.0 * c1 * cur - prev);
            }
        }
        for (d, l) in legendres.iter_mut().enumerate() {
            *l = legendre(d, s);
        }
        let u = x - start_um - span / 2.0;
        for (k, &period) in p.periods_um.iter().enumerate() {
            let chirp = p.chirps.get(k).copied().unwrap_or(0.0);
            let w = 2.0 * std::f64::consts::PI * x / period + chirp * u * u;
            let (s1, c1) = w.sin_cos();
            let (mut sn, mut cs) = (s1, c1);
            for _ in 1..=p.harmonics {
                for &l in &legendres {
                    a[(r, c)] = cs * l;
                    a[(r, c + 1)] = sn * l;
                    c += 2;
                }
                (sn, cs) = (sn * c1 + cs * s1, cs * c1 - sn * s1);
            }
        }
    }
    a
}

/// Posterior mean of an OU process (variance sigma2, correlation length ell) on a uniform grid of
/// n points (spacing step) given noisy observations at ascending indices: Kalman filter + RTS.
pub fn ou_smooth(
    n: usize,
    step: f64,
    obs_idx: &[usize],
    obs: &[f64],
    sigma2: f64,
    ell: f64,
    noise2: f64,
) -> Vec<f64> {
    let phi = (-step / ell).exp();
    let q = sigma2 * (1.0 - phi * phi);
    let mut mf = vec![0.0; n];
    let mut pf = vec![0.0; n];
    let (mut m, mut p) = (0.0, sigma2);
    let mut k = 0;
    for i in 0..n {
        if i > 0 {
            m *= phi;
            p = phi * phi * p + q;
        }
        while k < obs_idx.len() && obs_idx[k] == i {
            let g = p / (p + noise2);
            m += g * (obs[k] - m);
            p *= 1.0 - g;
            k += 1;
        }
        mf[i] = m;
        pf[i] = p;
    }
    let mut ms = mf.clone();
    for i in (0..n.saturating_sub(1)).rev() {
        let pp = phi * phi * pf[i] + q;
        let g = pf[i] * phi / pp;
        ms[i] = mf[i] + g * (ms[i + 1] - phi * mf[i]);
    }
    ms
}

/// Σ_j K_xj² at every grid point x, K the linear map of [`ou_smooth`] (same arguments, without
/// the observations' values): the variance its output gets from unit white noise on the
/// observations. O(n), one pass each way: the filter's weight row at i is a·(its row at i − 1)
/// plus new observations' weights, orthogonal to it (a = φ·Π(1 − g) over the observations at i),
/// so ‖F_i‖² = a²‖F_{i−1}‖² + Σ g²·(…); the smoother's row is S_i = (1 − Gφ)F_i + G S_{i+1}, and
/// ⟨F_i, S_{i+1}⟩ = ‖F_i‖²·T_{i+1} with T_i = a_i((1 − G_iφ) + G_i T_{i+1}).
pub fn ou_weight_norms(
    n: usize,
    step: f64,
    obs_idx: &[usize],
    sigma2: f64,
    ell: f64,
    noise2: f64,
) -> Vec<f64> {
    let phi = (-step / ell).exp();
    let q = sigma2 * (1.0 - phi * phi);
    let (mut f2, mut pf, mut a) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
    let (mut w2, mut p) = (0.0, sigma2);
    let mut k = 0;
    for i in 0..n {
        let mut ai = phi;
        if i > 0 {
            w2 *= phi * phi;
            p = phi * phi * p + q;
        }
        while k < obs_idx.len() && obs_idx[k] == i {
            let g = p / (p + noise2);
            w2 = (1.0 - g) * (1.0 - g) * w2 + g * g;
            ai *= 1.0 - g;
            p *= 1.0 - g;
            k += 1;
        }
        f2[i] = w2;
        pf[i] = p;
        a[i] = ai;
    }
    let mut s2 = f2.clone();
    // T_{i+1}, from T_{n−1} = a_{n−1} (the last smoothed row is the filtered one).
    let mut t_next = a.last().copied().unwrap_or(0.0);
    for i in (0..n.saturating_sub(1)).rev() {
        let pp = phi * phi * pf[i] + q;
        let g = pf[i] * phi / pp;
        let c = 1.0 - g * phi;
        s2[i] = c * c * f2[i] + 2.0 * c * g * f2[i] * t_next + g * g * s2[i + 1];
        t_next = a[i] * (c + g * t_next);
    }
    s2
}

/// The union of the ascending `obs_idx` and `at`, ascending: one merge, O(m + |at|) (the
/// cross-validation asks for it once per fold and candidate).
fn union_sorted(obs_idx: &[usize], at: &[usize]) -> Vec<usize> {
    let mut pts: Vec<usize> = Vec::with_capacity(obs_idx.len() + at.len());
    let (mut a, mut b) = (0, 0);
    while a < obs_idx.len() || b < at.len() {
        let next = match (obs_idx.get(a), at.get(b)) {
            (Some(&o), Some(&q)) => o.min(q),
            (Some(&o), None) => o,
            (None, Some(&q)) => q,
            (None, None) => break,
        };
        while obs_idx.get(a) == Some(&next) {
            a += 1;
        }
        while at.get(b) == Some(&next) {
            b += 1;
        }
        pts.push(next);
    }
    pts
}

/// `values` (one per ascending `pts`) at the ascending `at`, each one of `pts`.
fn at_points(pts: &[usize], values: &[f64], at: &[usize]) -> Vec<f64> {
    let mut out = Vec::with_capacity(at.len());
    let mut j = 0;
    for &q in at {
        while pts[j] < q {
            j += 1;
        }
        out.push(values[j]);
    }
    out
}

/// [`ou_smooth`] at the grid indices `at` only (ascending): the OU process is Markov, so the
/// filter steps from one index of interest (observed or asked) to the next with that gap's
/// transition, O(m + |at|) instead of O(n). Cross-validation asks for the held-out points alone.
pub fn ou_smooth_at(
    step: f64,
    obs_idx: &[usize],
    obs: &[f64],
    at: &[usize],
    sigma2: f64,
    ell: f64,
    noise2: f64,
) -> Vec<f64> {
    let pts = union_sorted(obs_idx, at);
    let np = pts.len();
    let (mut mf, mut pf, mut phis) = (vec![0.0; np], vec![0.0; np], vec![0.0; np]);
    let (mut m, mut p) = (0.0, sigma2);
    let mut k = 0;
    for j in 0..np {
        if j > 0 {
            let phi = (-((pts[j] - pts[j - 1]) as f64) * step / ell).exp();
            phis[j] = phi;
            m *= phi;
            p = phi * phi * p + sigma2 * (1.0 - phi * phi);
        }
        while k < obs_idx.len() && obs_idx[k] == pts[j] {
            let g = p / (p + noise2);
            m += g * (obs[k] - m);
            p *= 1.0 - g;
            k += 1;
        }
        mf[j] = m;
        pf[j] = p;
    }
    let mut ms = mf.clone();
    for j in (0..np.saturating_sub(1)).rev() {
        let phi = phis[j + 1];
        let pp = phi * phi * pf[j] + sigma2 * (1.0 - phi * phi);
        let g = pf[j] * phi / pp;
        ms[j] = mf[j] + g * (ms[j + 1] - phi * mf[j]);
    }
    at_points(&pts, &ms, at)
}

/// The Matérn 3/2 state (value, slope): transition over `dt` µm and its process noise, for
/// prior variance `sigma2` and correlation length `ell` (Hartikainen and Särkkä, 2010).
fn m32_step(dt: f64, sigma2: f64, ell: f64) -> (Matrix2<f64>, Matrix2<f64>) {
    let l = 3f64.sqrt() / ell;
    let e = (-l * dt).exp();
    let a = Matrix2::new(1.0 + l * dt, dt, -l * l * dt, 1.0 - l * dt) * e;
    let p_inf = Matrix2::new(sigma2, 0.0, 0.0, l * l * sigma2);
    (a, p_inf - a * p_inf * a.transpose())
}

/// The Matérn 3/2 Kalman filter over `pts` (ascending grid indices, step µm): per point the
/// transition into it, the predicted and the filtered covariance, the filtered mean (of `obs`
/// at `obs_idx`; zeros without), and U, the product of (I − k h) over its observations.
struct M32Filter {
    a: Vec<Matrix2<f64>>,
    p_pred: Vec<Matrix2<f64>>,
    p_filt: Vec<Matrix2<f64>>,
    m_filt: Vec<Vector2<f64>>,
    /// Per point, its observations' gains k (in order).
    gains: Vec<Vec<Vector2<f64>>>,
}

impl M32Filter {
    #[allow(clippy::too_many_arguments)]
    fn run(
        step: f64,
        pts: &[usize],
        obs_idx: &[usize],
        obs: Option<&[f64]>,
        sigma2: f64,
        ell: f64,
        noise2: f64,
    ) -> Self {
        let np = pts.len();
        let l = 3f64.sqrt() / ell;
        let p_inf = Matrix2::new(sigma2, 0.0, 0.0, l * l * sigma2);
        let mut f = M32Filter {
            a: Vec::with_capacity(np),
            p_pred: Vec::with_capacity(np),
            p_filt: Vec::with_capacity(np),
            m_filt: Vec::with_capacity(np),
            gains: Vec::with_capacity(np),
        };
        let (mut m, mut p) = (Vector2::zeros(), p_inf);
        let mut k = 0;
        for j in 0..np {
            let a = if j > 0 {
                let (a, q) = m32_step((pts[j] - pts[j - 1]) as f64 * step, sigma2, ell);
                m = a * m;
                p = a * p * a.transpose() + q;
                a
            } else {
                Matrix2::identity()
            };
            f.a.push(a);
            f.p_pred.push(p);
            let mut gains = Vec::new();
            while k < obs_idx.len() && obs_idx[k] == pts[j] {
                let s = p[(0, 0)] + noise2;
                let g = p.column(0) / s;
                if let Some(y) = obs {
                    m += g * (y[k] - m[0]);
                }
                p -= g * g.transpose() * s;
                // Symmetric against rounding.
                p = (p + p.transpose()) * 0.5;
                gains.push(g);
                k += 1;
            }
            f.gains.push(gains);
            f.p_filt.push(p);
            f.m_filt.push(m);
        }
        f
    }

    /// The RTS smoother's gain at point j < last: P_f,j A_{j+1}ᵀ P_pred,j+1⁻¹.
    fn smoother_gain(&self, j: usize) -> Matrix2<f64> {
        let inv = self.p_pred[j + 1]
            .try_inverse()
            .unwrap_or_else(Matrix2::zeros);
        self.p_filt[j] * self.a[j + 1].transpose() * inv
    }
}

/// Posterior mean of a Matérn 3/2 process (variance `sigma2`, correlation length `ell`) at the
/// ascending grid indices `at` (grid spacing `step`), from noisy observations `obs` at the
/// ascending `obs_idx`: a Kalman filter and RTS smoother over the union of both, O(m + |at|).
pub fn m32_smooth_at(
    step: f64,
    obs_idx: &[usize],
    obs: &[f64],
    at: &[usize],
    sigma2: f64,
    ell: f64,
    noise2: f64,
) -> Vec<f64> {
    let pts = union_sorted(obs_idx, at);
    let values = m32_posterior(step, &pts, obs_idx, obs, sigma2, ell, noise2);
    at_points(&pts, &values, at)
}

/// [`m32_smooth_at`] at every index of an n-point grid.
pub fn m32_smooth(
    n: usize,
    step: f64,
    obs_idx: &[usize],
    obs: &[f64],
    sigma2: f64,
    ell: f64,
    noise2: f64,
) -> Vec<f64> {
    let all: Vec<usize> = (0..n).collect();
    m32_posterior(step, &all, obs_idx, obs, sigma2, ell, noise2)
}

/// The Matérn 3/2 posterior mean at every one of `pts` (ascending, holding every `obs_idx`).
fn m32_posterior(
    step: f64,
    pts: &[usize],
    obs_idx: &[usize],
    obs: &[f64],
    sigma2: f64,
    ell: f64,
    noise2: f64,
) -> Vec<f64> {
    if pts.is_empty() {
        return Vec::new();
    }
    let f = M32Filter::run(step, pts, obs_idx, Some(obs), sigma2, ell, noise2);
    let mut ms = f.m_filt.clone();
    for j in (0..pts.len() - 1).rev() {
        let g = f.smoother_gain(j);
        ms[j] = f.m_filt[j] + g * (ms[j + 1] - f.a[j + 1] * f.m_filt[j]);
    }
    ms.iter().map(|m| m[0]).collect()
}

/// Σ_j K_xj² at every grid point x for [`m32_smooth`] (K its linear map of the observations),
/// O(n) as [`ou_weight_norms`] with 2 × 2 matrices: the filter's weight rows F_i (2 × m) have
/// the Gram matrix G_i = A G Aᵀ, then (I − kh) G (I − kh)ᵀ + kkᵀ per observation; the smoother's
/// S_i = C F_i + J S_{i+1} (C = I − J A), and S_{i+1}'s part along F_i is T_{i+1} F_i with
/// T_i = (C_i + J_i T_{i+1}) U_i A_i, U_i the product of (I − kh) at i, so
/// S_i S_iᵀ = C G Cᵀ + C G Tᵀ Jᵀ + J T G Cᵀ + J (S_{i+1} S_{i+1}ᵀ) Jᵀ.
pub fn m32_weight_norms(
    n: usize,
    step: f64,
    obs_idx: &[usize],
    sigma2: f64,
    ell: f64,
    noise2: f64,
) -> Vec<f64> {
    if n == 0 {
        return Vec::new();
    }
    let pts: Vec<usize> = (0..n).collect();
    let f = M32Filter::run(step, &pts, obs_idx, None, sigma2, ell, noise2);
    let mut g = Vec::with_capacity(n);
    let mut u = Vec::with_capacity(n);
    let mut gram = Matrix2::zeros();
    for j in 0..n {
        gram = f.a[j] * gram * f.a[j].transpose();
        let mut uj = Matrix2::identity();
        for k in &f.gains[j] {
            // I − k h with h = (1, 0).
            let mk = Matrix2::identity() - Matrix2::from_columns(&[*k, Vector2::zeros()]);
            gram = mk * gram * mk.transpose() + k * k.transpose();
            uj = mk * uj;
        }
        g.push(gram);
        u.push(uj);
    }
    let mut out = vec![0.0; n];
    let mut gs = g[n - 1];
    out[n - 1] = gs[(0, 0)];
    let mut t_next = u[n - 1] * f.a[n - 1];
    for j in (0..n - 1).rev() {
        let jg = f.smoother_gain(j);
        let c = Matrix2::identity() - jg * f.a[j + 1];
        let cross = c * g[j] * t_next.transpose() * jg.transpose();
        gs = c * g[j] * c.transpose() + cross + cross.transpose() + jg * gs * jg.transpose();
        out[j] = gs[(0, 0)].max(0.0);
        t_next = (c + jg * t_next) * u[j] * f.a[j];
    }
    out
}

/// A fitted model: trend coefficients and the kriged residual at the grid indices asked for.
pub struct Fitted {
    beta: DVector<f64>,
    /// Ascending grid indices of `rough` (every index when empty).
    rough_at: Vec<usize>,
    rough: Vec<f64>,
    /// The regularised normal matrix's factor, and the prior and noise variances the
    /// residual's smoother used (µm²): with them the fit is a fixed linear map of the samples
    /// ([`Fitted::noise_variance`]).
    chol: nalgebra::Cholesky<f64, nalgebra::Dyn>,
    sigma2: f64,
    noise2: f64,
}

impl Fitted {
    /// Predictions at grid indices `at`, whose design rows are `rows` (same order); every index
    /// must be one the roughness was kriged at.
    pub fn predict(&self, rows: &DMatrix<f64>, at: &[usize]) -> Vec<f64> {
        let cols = self.beta.len();
        let trend = rows.columns(0, cols) * &self.beta;
        at.iter()
            .enumerate()
            .map(|(r, &i)| {
                let k = if self.rough_at.is_empty() {
                    i
                } else {
                    self.rough_at.binary_search(&i).unwrap_or(0)
                };
                trend[r] + self.rough.get(k).copied().unwrap_or(0.0)
            })
            .collect()
    }
}

/// Fits on samples at grid indices `idx` (ascending) with values `y`; `rows` holds their design
/// rows. Only the sampled rows are needed, so cross-validation never builds the full n-row design.
pub fn fit(
    p: &PhysicsParams,
    rows: &DMatrix<f64>,
    n: usize,
    step_um: f64,
    idx: &[usize],
    y: &[f64],
    noise_um: f64,
) -> Option<Fitted> {
    let m = idx.len();
    let cols = rows.ncols().min(m.saturating_sub(1)).max(1);
    let a = rows.columns(0, cols);
    let yv = DVector::from_column_slice(y);
    let ata = a.transpose() * a;
    let aty = a.transpose() * &yv;
    let fitted = |beta: &DVector<f64>| (a * beta).iter().copied().collect::<Vec<f64>>();
    fit_normal(p, ata, aty, fitted, n, step_um, idx, y, noise_um, None)
}

/// [`fit`] from the normal equations of the samples (AᵀA and Aᵀy over their first `cols`
/// columns, `cols` as [`fit`] chooses it) and a function giving the fitted values A·β at them:
/// cross-validation forms each fold's equations as the whole set's minus the held-out rows'.
/// `at`: the ascending grid indices the model will be asked about (None: all n).
#[allow(clippy::too_many_arguments)]
pub fn fit_normal(
    p: &PhysicsParams,
    mut ata: DMatrix<f64>,
    aty: DVector<f64>,
    fitted: impl Fn(&DVector<f64>) -> Vec<f64>,
    n: usize,
    step_um: f64,
    idx: &[usize],
    y: &[f64],
    noise_um: f64,
    at: Option<&[usize]>,
) -> Option<Fitted> {
    let m = idx.len();
    let cols = ata.ncols();
    let lambda = p.ridge * m as f64;
    for c in 1..cols {
        ata[(c, c)] += lambda;
    }
    ata[(0, 0)] += 1e-12 * m as f64;
    let chol = ata.cholesky()?;
    let beta = chol.solve(&aty);
    let fitted = fitted(&beta);
    let resid: Vec<f64> = (0..m).map(|r| y[r] - fitted[r]).collect();
    let var = resid.iter().map(|v| v * v).sum::<f64>() / m as f64;
    let noise2 = (noise_um * noise_um).max(1e-6 * var).max(1e-18);
    let sigma2 = (var - noise2).max(noise2);
    let rough = p
        .kernel
        .smooth(n, at, step_um, idx, &resid, sigma2, p.corr_um, noise2);
    let rough_at = at.map_or_else(Vec::new, <[usize]>::to_vec);
    Some(Fitted {
        beta,
        rough_at,
        rough,
        chol,
        sigma2,
        noise2,
    })
}

impl Fitted {
    /// The variance the sensor noise alone gives this fit at every grid point (µm²): with its
    /// hyper-parameters held, the fit is linear in the samples, g = S y (ridge least squares,
    /// then the smoother of its residual), so white noise of σ = `noise_um` gives σ² ‖S_x‖² at
    /// grid point x. Whatever the model's bias, the curve's mean square error there is that plus
    /// the bias² (the band's noise part, `band::pointwise_u`). `rows` are the samples' design rows
    /// (those the fit was made on, at grid indices `idx`, `p` its structure), `grid_rows` every
    /// grid point's. S_x = K_x + C_x B with B = (AᵀA + Λ)⁻¹Aᵀ, K the smoother and
    /// C = A_grid − K A: the cross and quadratic terms come from 2·cols smoother runs, ‖K_x‖²
    /// from [`ou_weight_norms`] or [`m32_weight_norms`]. The quadratic form is O(n·cols²): at n = 65,536 it made the
    /// physics fit 1.6 times slower. None when the rows do not match the fit.
    #[allow(clippy::too_many_arguments)]
    pub fn noise_variance(
        &self,
        p: &PhysicsParams,
        rows: &DMatrix<f64>,
        grid_rows: &DMatrix<f64>,
        n: usize,
        step_um: f64,
        idx: &[usize],
        noise_um: f64,
    ) -> Option<Vec<f64>> {
        let cols = self.beta.len();
        let fits = |m: &DMatrix<f64>, r: usize| m.nrows() == r && m.ncols() >= cols;
        if !fits(rows, idx.len()) || !fits(grid_rows, n) {
            return None;
        }
        let (sigma2, noise2) = (self.sigma2, self.noise2);
        let a = rows.columns(0, cols);
        let smooth = |v: Vec<f64>| {
            p.kernel
                .smooth(n, None, step_um, idx, &v, sigma2, p.corr_um, noise2)
        };
        let b = self.chol.solve(&a.transpose().into_owned());
        let mut c = grid_rows.columns(0, cols).into_owned();
        let mut d = DMatrix::zeros(n, cols);
        for k in 0..cols {
            let ka = smooth(a.column(k).iter().copied().collect());
            let kb = smooth(b.row(k).iter().copied().collect());
            for x in 0..n {
                c[(x, k)] -= ka[x];
                d[(x, k)] = kb[x];
            }
        }
        let cg = &c * (&b * b.transpose());
        let kk = p
            .kernel
            .weight_norms(n, step_um, idx, sigma2, p.corr_um, noise2);
        let s2 = noise_um.max(0.0).powi(2);
        // Column by column: the matrices are column-major.
        let mut sum: Vec<f64> = kk;
        for k in 0..cols {
            let (ck, dk, gk) = (c.column(k), d.column(k), cg.column(k));
            for x in 0..n {
                sum[x] += ck[x] * (2.0 * dk[x] + gk[x]);
            }
        }
        Some(sum.into_iter().map(|v| s2 * v.max(0.0)).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn design_rows_match_the_direct_cosines_and_sines() {
        let mut p = PhysicsParams::with_periods(vec![400.0, 37.0]);
        p.chirps = vec![1e-7];
        p.harmonics = 8;
        p.trend_k = 32;
        let (n, start, step) = (20_001, -50.0, 0.5);
        let rows = [0, 1, 777, 10_000, 20_000];
        let a = design(&p, n, start, step, &rows);
        let span = step * (n - 1) as f64;
        for (r, &i) in rows.iter().enumerate() {
            let x = start + i as f64 * step;
            let s = 2.0 * (x - start) / span - 1.0;
            let mut want = Vec::new();
            for k in 0..=p.trend_k {
                want.push((std::f64::consts::PI * k as f64 * (i as f64 + 0.5) / n as f64).cos());
            }
            let u = x - start - span / 2.0;
            for (k, &period) in p.periods_um.iter().enumerate() {
                let chirp = p.chirps.get(k).copied().unwrap_or(0.0);
                let w = std::f64::consts::TAU * x / period + chirp * u * u;
                for h in 1..=p.harmonics {
                    let (sn, cs) = (h as f64 * w).sin_cos();
                    for d in 0..=p.envelope_deg {
                        want.extend([cs * legendre(d, s), sn * legendre(d, s)]);
                    }
                }
            }
            assert_eq!(want.len(), p.columns());
            for (c, w) in want.iter().enumerate() {
                assert!((a[(r, c)] - w).abs() < 1e-12, "row {i} column {c}");
            }
        }
    }

    /// The Matérn 3/2 posterior mean at `at` by a dense GP solve.
    fn m32_dense(
        step: f64,
        idx: &[usize],
        obs: &[f64],
        at: &[usize],
        s2: f64,
        ell: f64,
        n2: f64,
    ) -> Vec<f64> {
        let k = |a: usize, b: usize| {
            let d = 3f64.sqrt() * (a as f64 - b as f64).abs() * step / ell;
            s2 * (1.0 + d) * (-d).exp()
        };
        let m = idx.len();
        let c = DMatrix::from_fn(m, m, |i, j| {
            k(idx[i], idx[j]) + if i == j { n2 } else { 0.0 }
        });
        let w = c
            .cholesky()
            .unwrap()
            .solve(&DVector::from_column_slice(obs));
        at.iter()
            .map(|&x| (0..m).map(|j| k(x, idx[j]) * w[j]).sum())
            .collect()
    }

    #[test]
    fn the_matern_smoother_is_the_gp_posterior_mean() {
        let n = 300;
        let idx: Vec<usize> = (0..n).filter(|i| (i * 7 + 3) % 11 < 3).collect();
        let obs: Vec<f64> = idx
            .iter()
            .map(|&i| (i as f64 / 17.0).sin() + 0.1 * (i % 3) as f64)
            .collect();
        let all: Vec<usize> = (0..n).collect();
        for (s2, ell, n2) in [(1.0, 30.0, 0.01), (0.3, 5.0, 0.2), (2.0, 200.0, 1e-6)] {
            let fast = m32_smooth(n, 2.0, &idx, &obs, s2, ell, n2);
            let dense = m32_dense(2.0, &idx, &obs, &all, s2, ell, n2);
            for (a, b) in fast.iter().zip(&dense) {
                assert!(
                    (a - b).abs() < 1e-6 * (1.0 + b.abs()),
                    "{a} vs {b} ({s2}, {ell}, {n2})"
                );
            }
            let at = [0, 5, 150, 151, 299];
            let sparse = m32_smooth_at(2.0, &idx, &obs, &at, s2, ell, n2);
            for (a, &q) in sparse.iter().zip(&at) {
                assert!((a - fast[q]).abs() < 1e-9 * (1.0 + a.abs()));
            }
        }
    }

    /// Σ_j K_xj² of a linear smoother `smooth` of `m` observations, from its unit responses.
    fn unit_response_norms(n: usize, m: usize, smooth: impl Fn(&[f64]) -> Vec<f64>) -> Vec<f64> {
        let mut brute = vec![0.0; n];
        for j in 0..m {
            let mut unit = vec![0.0; m];
            unit[j] = 1.0;
            for (b, v) in brute.iter_mut().zip(smooth(&unit)) {
                *b += v * v;
            }
        }
        brute
    }

    #[test]
    fn matern_weight_norms_are_the_sum_of_squared_unit_responses() {
        let n = 120;
        // Two observations at 40: a repeated target.
        let idx = vec![3, 10, 11, 40, 40, 41, 42, 80, 119];
        for (s2, ell, n2) in [
            (1.0, 5.0, 1.0),
            (2.0, 40.0, 0.1),
            (0.5, 3.0, 3.0),
            (1.0, 300.0, 1e-4),
        ] {
            let brute = unit_response_norms(n, idx.len(), |unit| {
                m32_smooth(n, 2.0, &idx, unit, s2, ell, n2)
            });
            let fast = m32_weight_norms(n, 2.0, &idx, s2, ell, n2);
            for (x, (a, b)) in fast.iter().zip(&brute).enumerate() {
                assert!(
                    (a - b).abs() < 1e-9 * (1.0 + b),
                    "x = {x}: {a} vs {b} ({s2}, {ell}, {n2})"
                );
            }
        }
    }

    #[test]
    fn legendre_matches_closed_forms() {
        for &s in &[-1.0, -0.3, 0.0, 0.7, 1.0] {
            assert_eq!((legendre(0, s), legendre(1, s)), (1.0, s));
            assert!((legendre(2, s) - 0.5 * (3.0 * s * s - 1.0)).abs() < 1e-14);
            assert!((legendre(3, s) - 0.5 * (5.0 * s * s * s - 3.0 * s)).abs() < 1e-14);
            assert!((legendre(4, s) - (35.0 * s.powi(4) - 30.0 * s * s + 3.0) / 8.0).abs() < 1e-14);
        }
    }

    #[test]
    fn ou_smoother_interpolates_noise_free_data_and_reverts_to_zero_far_away() {
        let n = 201;
        let idx = [50usize, 52, 150];
        let obs = [1.0, 1.2, -0.5];
        let v = ou_smooth(n, 1.0, &idx, &obs, 1.0, 5.0, 1e-12);
        for (i, o) in idx.iter().zip(obs) {
            assert!((v[*i] - o).abs() < 1e-6, "{} vs {o}", v[*i]);
        }
        // Between two close samples: between their values; far from data: back to the mean.
        assert!(v[51] > 1.0 && v[51] < 1.2);
        assert!(v[100].abs() < 1e-3);
        assert!(v[0].abs() < 1e-3);
    }

    /// The smoother's weight norms by their recursion are those of its unit responses.
    #[test]
    fn ou_weight_norms_are_the_sum_of_squared_unit_responses() {
        let n = 300;
        let idx = [0usize, 3, 4, 4, 40, 41, 90, 200, 201, 202, 299];
        for (sigma2, ell, noise2) in [(1.0, 5.0, 1.0), (2.0, 40.0, 0.1), (0.5, 1.0, 3.0)] {
            let brute = unit_response_norms(n, idx.len(), |unit| {
                ou_smooth(n, 2.0, &idx, unit, sigma2, ell, noise2)
            });
            let fast = ou_weight_norms(n, 2.0, &idx, sigma2, ell, noise2);
            for i in 0..n {
                assert!(
                    (fast[i] - brute[i]).abs() < 1e-12 * brute[i].max(1.0),
                    "{i}: {} vs {}",
                    fast[i],
                    brute[i]
                );
            }
        }
    }

    /// The sparse smoother is the dense one at the indices asked (exact: the same recursion).
    #[test]
    fn sparse_ou_smoother_equals_the_dense_one() {
        let n = 500;
        let idx = [3usize, 4, 40, 41, 200, 333, 499];
        let obs = [0.5, 0.7, -1.0, -0.8, 2.0, 0.1, -0.3];
        let dense = ou_smooth(n, 2.5, &idx, &obs, 1.3, 30.0, 0.01);
        let at = [0usize, 4, 20, 41, 100, 333, 400, 499];
        let sparse = ou_smooth_at(2.5, &idx, &obs, &at, 1.3, 30.0, 0.01);
        for (k, &i) in at.iter().enumerate() {
            assert!(
                (sparse[k] - dense[i]).abs() < 1e-12,
                "{i}: {} vs {}",
                sparse[k],
                dense[i]
            );
        }
    }

    #[test]
    fn recovers_a_modulated_leadscrew_curve_from_few_samples() {
        let n = 1901;
        let step = 5.0;
        let truth: Vec<f64> = (0..n)
            .map(|i| {
                let x = i as f64 * step;
                let s = x / 4750.0 - 1.0;
                (1.0 + 0.1 * s) * (2.0 * std::f64::consts::PI * x / 400.0 + 0.3).cos() + 0.5 * s * s
            })
            .collect();
        let idx = crate::sampling::Design::new(crate::sampling::DesignKind::Random, 100, 1)
            .indices(n)
            .unwrap();
        let y: Vec<f64> = idx.iter().map(|&i| truth[i]).collect();
        let p = PhysicsParams::default_for(400.0);
        let all: Vec<usize> = (0..n).collect();
        let rows = design(&p, n, 0.0, step, &idx);
        let values = fit(&p, &rows, n, step, &idx, &y, 0.0)
            .unwrap()
            .predict(&design(&p, n, 0.0, step, &all), &all);
        let mae = values
            .iter()
            .zip(&truth)
            .map(|(a, b)| (a - b).abs())
            .sum::<f64>()
            / n as f64;
        assert!(mae < 0.01, "mean abs error {mae}");
    }

    /// The noise variance is the spread the fit itself shows over draws of the sensor noise
    /// (a curve the model holds, so the OU prior stays at its floor and the fit is linear in the
    /// samples): 400 draws, compared at the samples and off them.
    #[test]
    fn noise_variance_is_the_fits_own_spread_over_noise_draws() {
        let (n, step, sigma) = (401, 5.0, 0.05);
        let truth: Vec<f64> = (0..n)
            .map(|i| {
                let x = i as f64 * step;
                0.8 * (std::f64::consts::TAU * x / 400.0 + 0.4).sin() + 1e-4 * x
            })
            .collect();
        let idx = crate::sampling::Design::new(crate::sampling::DesignKind::Random, 90, 3)
            .indices(n)
            .unwrap();
        // Both residual priors: the map is linear in the samples either way.
        for (kernel, corr) in [(Kernel::Ou, 12.0), (Kernel::Matern32, 60.0)] {
            let mut p = PhysicsParams::default_for(400.0);
            (p.kernel, p.corr_um) = (kernel, corr);
            assert!(p.shrink_to(idx.len()));
            let all: Vec<usize> = (0..n).collect();
            let (rows, grid_rows) = (
                design(&p, n, 0.0, step, &idx),
                design(&p, n, 0.0, step, &all),
            );
            let mut gauss = crate::recon::test_curve::normals(11);
            let draws = 400;
            let (mut sum, mut sum2) = (vec![0.0; n], vec![0.0; n]);
            let mut last = None;
            for _ in 0..draws {
                let y: Vec<f64> = idx.iter().map(|&i| truth[i] + sigma * gauss()).collect();
                let fitted = fit(&p, &rows, n, step, &idx, &y, sigma).unwrap();
                let g = fitted.predict(&grid_rows, &all);
                for i in 0..n {
                    sum[i] += g[i];
                    sum2[i] += g[i] * g[i];
                }
                last = Some(fitted);
            }
            // The map of the last draw (the hyper-parameters stay at their floor for every draw).
            let var = last
                .unwrap()
                .noise_variance(&p, &rows, &grid_rows, n, step, &idx, sigma)
                .unwrap();
            let spread: Vec<f64> = (0..n)
                .map(|i| (sum2[i] - sum[i] * sum[i] / draws as f64) / (draws - 1) as f64)
                .collect();
            let mean_over = |v: &[f64], at: bool| {
                let pick: Vec<f64> = (0..n)
                    .filter(|i| idx.binary_search(i).is_ok() == at)
                    .map(|i| v[i])
                    .collect();
                pick.iter().sum::<f64>() / pick.len() as f64
            };
            for at in [true, false] {
                let (model, seen) = (mean_over(&var, at), mean_over(&spread, at));
                eprintln!("at the samples {at}: {model:.4e} against {seen:.4e}");
                assert!(
                    (model / seen - 1.0).abs() < 0.08,
                    "{kernel:?} at the samples {at}: σ²‖S_x‖² {model:.3e} against the draws' {seen:.3e}"
                );
            }
            // Pointwise too, within the draws' own sampling error (√(2/400) ≈ 7 %, so 4.5 of them).
            for i in 0..n {
                assert!(
                    (var[i] / spread[i] - 1.0).abs() < 0.32,
                    "{kernel:?} grid point {i}: {:.3e} against {:.3e}",
                    var[i],
                    spread[i]
                );
            }
        }
    }
}
