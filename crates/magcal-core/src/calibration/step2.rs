//! Step 2: nonlinear least squares on the 9 parameters (6 of `P`, 3 of `O`) with residual
//! `|P (b_i - O)| - R`, by Levenberg-Marquardt, started from step 1 (\[P1\] IV.C, after
//! Gebre-Egziabher et al. 2006).
//!
//! Written here rather than taken from a crate: the Levenberg-Marquardt crates on crates.io are
//! built on nalgebra (a second linear-algebra family, which the project excludes), and argmin's
//! Gauss-Newton needs an argmin-math backend that faer is not. The problem has exactly 9
//! parameters (4 and 6 for the reduced models of [`crate::log_fit`], which share the loop), so the
//! damped normal equations are a fixed small system solved by
//! [`crate::small::cholesky_in_place`] without allocation.
// Index loops mirror the matrix algebra they implement.
#![allow(clippy::needless_range_loop)]
#![allow(non_snake_case)]

use super::errors::CalibrationError;
use super::{Estimate, TwoStep};
use crate::chunked;
use crate::small::{
    Mat3, Vec3, add, cholesky_in_place, cholesky_solve, dot, mat_t_vec, mat_vec, norm, scale, sub,
    upper_triangular_inverse,
};

/// Number of parameters of step 2: `P11, P12, P13, P22, P23, P33, O1, O2, O3`.
pub const PARAMETERS: usize = 9;

/// The residual step 2 minimises the squares of, over the same nine unknowns `x = (P, o)`,
/// `o = O / R`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub enum Residual {
    /// `|P (u - o)| - 1` (\[P1\] IV.C, Gebre-Egziabher et al. 2006): the paper's estimator. Its
    /// residual is measured after the correction `P`.
    #[default]
    Paper,
    /// `(|P (u - o)| - 1) / |P^T w|`, `w = P (u - o) / |P (u - o)|`: the
    /// distance of the reading from the fitted ellipsoid to first order, in the readings' own units
    /// (Sampson's approximation). Noise on the readings of variance `sigma^2` per component gives
    /// every such residual the variance `(sigma / R)^2`, so the least-squares fit is the
    /// maximum-likelihood one to first order and `J^T J / (sigma / R)^2` is the information of
    /// the Cramer-Rao floor ([`crate::identifiability`]). The paper's residual is measured after the
    /// correction `P`: where the readings cover only a cap of the ellipsoid, a fit that inflates
    /// the ellipsoid shrinks those residuals, and the least-squares minimum runs off to scale
    /// factors of 10 and more.
    Readings,
}

impl Residual {
    /// A stable snake_case name: `paper`, `readings`.
    pub fn as_str(&self) -> &'static str {
        match self {
            Self::Paper => "paper",
            Self::Readings => "readings",
        }
    }
}

/// Why step 2 stopped (the `TerminationReason` of the fit).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub enum Termination {
    /// The gradient `J^T r` fell below the gradient tolerance (converged).
    Gradient,
    /// The step fell below the step tolerance relative to the parameters (converged).
    StepSize,
    /// An accepted step reduced the cost by less than the cost tolerance, relatively (converged).
    CostReduction,
    /// The iteration limit was reached before any convergence test passed.
    MaxIterations,
    /// The iterate moves along a direction the readings do not determine: its local standard
    /// deviation exceeds a physical scale (a scale factor's half, 10 degrees, |B|). Checked every
    /// [`FLAT_CHECK_EVERY`] iterations from the [`FLAT_CHECK_FROM`]-th: a fit that needs that many
    /// iterations is typically running along such a valley, where the least-squares minimum of
    /// noisy readings can lie at infinity (the ship of `scenarios/ship.toml`).
    FlatDirection,
    /// The settings' [`crate::stop::Stop`] was requested (a deadline passed, a signal came):
    /// asked before every iteration.
    Stopped,
}

impl Termination {
    /// `true` for the three convergence tests, `false` for the iteration limit, a flat direction
    /// and a stop.
    pub fn converged(&self) -> bool {
        !matches!(self, Self::MaxIterations | Self::FlatDirection | Self::Stopped)
    }

    /// A stable snake_case name: `gradient`, `step_size`, `cost_reduction`, `max_iterations`,
    /// `flat_direction`, `stopped`.
    pub fn as_str(&self) -> &'static str {
        match self {
            Self::Gradient => "gradient",
            Self::StepSize => "step_size",
            Self::CostReduction => "cost_reduction",
            Self::MaxIterations => "max_iterations",
            Self::FlatDirection => "flat_direction",
            Self::Stopped => "stopped",
        }
    }
}

/// Parameters `x` from `P` (upper triangle, row by row) and the scaled bias `o = O / R`.
pub(crate) fn pack(P: &Mat3, o: Vec3) -> [f64; PARAMETERS] {
    [P[0][0], P[0][1], P[0][2], P[1][1], P[1][2], P[2][2], o[0], o[1], o[2]]
}

/// `P` and `o` from the parameters.
pub(crate) fn unpack(x: &[f64; PARAMETERS]) -> (Mat3, Vec3) {
    (
        [[x[0], x[1], x[2]], [0.0, x[3], x[4]], [0.0, 0.0, x[5]]],
        [x[6], x[7], x[8]],
    )
}

/// Residual `|P (u - o)| - 1` of one reading `u = b / R` and its gradient with respect to `x`:
/// `d/dP_jk = v_j d_k / |v|`, `d/do = -P^T v / |v|`, with `d = u - o`, `v = P d`.
#[inline]
pub(crate) fn residual_and_gradient(x: &[f64; PARAMETERS], u: Vec3) -> (f64, [f64; PARAMETERS]) {
    let (P, o) = unpack(x);
    let d = sub(u, o);
    let v = mat_vec(&P, d);
    let n = norm(v);
    let w = scale(1.0 / n, v);
    let go = scale(-1.0, mat_t_vec(&P, w));
    (
        n - 1.0,
        [
            w[0] * d[0],
            w[0] * d[1],
            w[0] * d[2],
            w[1] * d[1],
            w[1] * d[2],
            w[2] * d[2],
            go[0],
            go[1],
            go[2],
        ],
    )
}

/// The readings as step 2 sees them, `u = b / R`, about the mean `m` where centred: computed
/// from the readings at each use rather than copied (the same bits; two copies of a long log were
/// most of a fit's memory).
#[derive(Clone, Copy)]
struct Scaled<'a> {
    readings: &'a [Vec3],
    inv_r: f64,
    m: Vec3,
}

impl<'a> Scaled<'a> {
    /// The readings `b` in units of `R`, not centred.
    fn new(readings: &'a [Vec3], R: f64) -> Self {
        Self {
            readings,
            inv_r: 1.0 / R,
            m: [0.0; 3],
        }
    }

    /// The same readings about their mean.
    fn centred(self) -> Self {
        let n = self.readings.len() as f64;
        let m = scale(
            1.0 / n,
            self.readings.iter().fold([0.0; 3], |acc, &b| add(acc, self.u(b))),
        );
        Self { m, ..self }
    }

    /// `u = b / R`.
    #[inline(always)]
    fn u(&self, b: Vec3) -> Vec3 {
        scale(self.inv_r, b)
    }

    /// `u - m`.
    #[inline(always)]
    fn d(&self, b: Vec3) -> Vec3 {
        sub(self.u(b), self.m)
    }

    fn len(&self) -> usize {
        self.readings.len()
    }
}

/// Half the sum of squared scaled residuals, `0.5 sum (|P(u_i - o)| - 1)^2`.
fn cost(x: &[f64; PARAMETERS], s: &Scaled) -> f64 {
    let (P, o) = unpack(x);
    0.5 * chunked::sum(s.readings, |&b| (norm(mat_vec(&P, sub(s.u(b), o))) - 1.0).powi(2))
}

/// `J^T J` (lower triangle filled) and `J^T r` at `x`.
fn normal_equations(x: &[f64; PARAMETERS], s: &Scaled) -> ([[f64; PARAMETERS]; PARAMETERS], [f64; PARAMETERS]) {
    chunked::normal_equations(s.readings, |&b| residual_and_gradient(x, s.u(b)))
}

/// First iteration at which step 2 checks for a flat direction; healthy fits have converged by
/// then (12 to 20 iterations on the \[P1\] AUV and the ship, measured).
pub const FLAT_CHECK_FROM: usize = 20;
/// Iterations between two checks for a flat direction.
pub const FLAT_CHECK_EVERY: usize = 10;

/// Physical scales of the local check, as [`crate::PhysicalScales`]'s defaults: a scale factor's
/// std at most half of it (the diagonal of `P`), a non-orthogonality's at most 10 degrees (an
/// off-diagonal entry of `P` against its row's diagonal: `tan 10 deg`), a bias's at most `|B|`
/// (the scaled bias `o = O / R`: 1).
const LOCAL_SCALES: [f64; 3] = [0.5, 0.176_326_980_708_464_97, 1.0];

/// Whether the readings determine every parameter near `x`: the local covariance
/// `var_r (J^T J)^-1` (scaled problem, `var_r` the variance of one scaled residual) has every
/// standard deviation within its physical scale ([`LOCAL_SCALES`]). `false` when `J^T J` is
/// singular.
pub(crate) fn locally_identifiable(jtj: &[[f64; PARAMETERS]; PARAMETERS], x: &[f64; PARAMETERS], var_r: f64) -> bool {
    let mut l = *jtj;
    for i in 0..PARAMETERS {
        for j in i + 1..PARAMETERS {
            l[i][j] = l[j][i];
        }
    }
    if !cholesky_in_place(&mut l) {
        return false;
    }
    // Diagonal of the inverse: (J^T J)^-1 = L^-T L^-1, so its i-th diagonal entry is the squared
    // norm of column i of M = L^-1 (lower triangular, by forward substitution).
    let mut m = [[0.0; PARAMETERS]; PARAMETERS];
    for i in 0..PARAMETERS {
        m[i][i] = 1.0 / l[i][i];
        for j in 0..i {
            let s: f64 = (j..i).map(|k| l[i][k] * m[k][j]).sum();
            m[i][j] = -s / l[i][i];
        }
    }
    let std = |j: usize| (var_r * (j..PARAMETERS).map(|i| m[i][j] * m[i][j]).sum::<f64>()).sqrt();
    // x = (P11, P12, P13, P22, P23, P33, o1, o2, o3).
    let (diagonal, off) = ([0, 3, 5], [(1, 0), (2, 0), (4, 3)]);
    diagonal.iter().all(|&i| std(i) <= LOCAL_SCALES[0] * x[i].abs())
        && off.iter().all(|&(i, row)| std(i) <= LOCAL_SCALES[1] * x[row].abs())
        && (6..9).all(|i| std(i) <= LOCAL_SCALES[2])
}

/// The variance of one scaled residual: from the known noise (`sigma / R` times the mean of
/// `|grad_b r|^2`, docs/conventions.md), else from the residuals (`2 f / (m - 9)`), else (9 readings
/// and no known noise: an exact fit) none.
fn residual_variance(settings: &TwoStep, x: &[f64; PARAMETERS], u: &Scaled, f: f64, r: f64) -> Option<f64> {
    match settings.noise_nt {
        Some(sigma) => {
            let (P, o) = unpack(x);
            let mean_g2 = chunked::sum(u.readings, |&b| {
                let v = mat_vec(&P, sub(u.u(b), o));
                let g = mat_t_vec(&P, scale(1.0 / norm(v), v));
                g.iter().map(|c| c * c).sum::<f64>()
            }) / u.len() as f64;
            Some((sigma / r).powi(2) * mean_g2)
        }
        None if u.len() > PARAMETERS => Some(2.0 * f / (u.len() - PARAMETERS) as f64),
        None => None,
    }
}

/// The variance of one [`Residual::Readings`] residual: `(sigma / R)^2` from the known noise, else
/// `2 f / (m - 9)` from the cost `f` of `m` readings, else (9 readings, no known noise) none.
fn reading_variance(settings: &TwoStep, m: usize, f: f64, r: f64) -> Option<f64> {
    match settings.noise_nt {
        Some(sigma) => Some((sigma / r).powi(2)),
        None if m > PARAMETERS => Some(2.0 * f / (m - PARAMETERS) as f64),
        None => None,
    }
}

/// The outcome of step 2.
pub(crate) struct Refined {
    pub estimate: Estimate,
    pub iterations: usize,
    pub termination: Termination,
    /// Whether the readings determine every parameter at the estimate (`None`: not known, an
    /// exact fit of 9 readings without a known noise).
    pub identifiable: Option<bool>,
}

/// Residual `e = (|v| - 1) / |g|` of [`Residual::Readings`] for one reading `d` (scaled, about the
/// mean reading `m`) at `y = (P, c)`, `c = P (m - o)`: `v = P d + c = P (u - o)`, `w = v / |v|`,
/// `g = P^T w` (the gradient of `|v|` with respect to the reading); and its gradient with respect
/// to `y`: `de = dr / |g| - e (g . dg) / |g|^2` with
/// `dr / dP_jk = w_j d_k`, `dr / dc = w`,
/// `g . dg / dP_jk = w_j g_k + d_k (g . P_j - |g|^2 w_j) / |v|` (`P_j` the j-th row of `P`),
/// `g . dg / dc = (q - (q . w) w) / |v|`, `q = P g`.
/// With `m = 0` and `c = -P o` it is the residual at `(P, o)`.
#[inline]
pub(crate) fn reading_residual_and_gradient(y: &[f64; PARAMETERS], d: Vec3) -> (f64, [f64; PARAMETERS]) {
    let (P, c) = unpack(y);
    let v = add(mat_vec(&P, d), c);
    let nv = norm(v);
    let inv_nv = 1.0 / nv;
    let w = scale(inv_nv, v);
    let g = mat_t_vec(&P, w);
    let g2 = dot(g, g);
    let inv_g2 = 1.0 / g2;
    let inv_ng = inv_g2.sqrt();
    let e = (nv - 1.0) * inv_ng;
    // q = P g, so that g . P_j = q_j.
    let q = mat_vec(&P, g);
    let qw = dot(q, w);
    let e_g2 = e * inv_g2;
    let t: Vec3 = std::array::from_fn(|j| (q[j] - g2 * w[j]) * inv_nv);
    let mut grad = [0.0; PARAMETERS];
    let entries = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)];
    for (i, &(j, k)) in entries.iter().enumerate() {
        grad[i] = w[j] * d[k] * inv_ng - e_g2 * (w[j] * g[k] + d[k] * t[j]);
    }
    for a in 0..3 {
        grad[6 + a] = w[a] * inv_ng - e_g2 * (q[a] - qw * w[a]) * inv_nv;
    }
    (e, grad)
}

/// Half the sum of squared [`Residual::Readings`] residuals of the readings `d` about `m` at
/// `y = (P, c)`: the residual of [`reading_residual_and_gradient`] without its gradient, which
/// the loop evaluates at every trial step.
fn reading_cost(y: &[f64; PARAMETERS], s: &Scaled) -> f64 {
    let (P, c) = unpack(y);
    // |g|^2 = |P^T v|^2 / |v|^2.
    0.5 * chunked::sum(s.readings, |&b| {
        let v = add(mat_vec(&P, s.d(b)), c);
        let nv2 = dot(v, v);
        let pv = mat_t_vec(&P, v);
        let e = nv2.sqrt() - 1.0;
        e * e * nv2 / dot(pv, pv)
    })
}

/// `J^T J` (lower triangle filled) and `J^T r` of [`Residual::Readings`] at `y = (P, c)`.
fn reading_normal_equations(y: &[f64; PARAMETERS], s: &Scaled) -> (Normal, [f64; PARAMETERS]) {
    chunked::normal_equations(s.readings, |&b| reading_residual_and_gradient(y, s.d(b)))
}

/// The residual of [`Residual::Readings`] of the reading `u` at `x = (P, o)` and its gradient
/// with respect to `x`, by the chain rule through `c = -P o` (`m = 0`): `de/do = -P^T de/dc`,
/// `de/dP_jk |o = de/dP_jk |c - o_k de/dc_j`.
pub(crate) fn reading_residual_at(x: &[f64; PARAMETERS], u: Vec3) -> (f64, [f64; PARAMETERS]) {
    const ENTRIES: [(usize, usize); 6] = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)];
    let (P, o) = unpack(x);
    let y = pack(&P, scale(-1.0, mat_vec(&P, o)));
    let (e, mut g) = reading_residual_and_gradient(&y, u);
    let dc = [g[6], g[7], g[8]];
    for (i, &(j, k)) in ENTRIES.iter().enumerate() {
        g[i] -= o[k] * dc[j];
    }
    let go = mat_t_vec(&P, dc);
    for a in 0..3 {
        g[6 + a] = -go[a];
    }
    (e, g)
}

/// `J^T J` (lower triangle filled) of [`Residual::Readings`] with respect to `x = (P, o)`
/// ([`reading_residual_at`]).
#[cfg(test)]
fn reading_information(x: &[f64; PARAMETERS], s: &Scaled) -> Normal {
    chunked::normal_equations(s.readings, |&b| reading_residual_at(x, s.u(b))).0
}

/// `J^T J` of [`Residual::Readings`] in `x = (P, o)` (full) from `jtj`, its lower triangle in the
/// centred unknowns `y = (P, c)` about `m` at the same point: `J_x = J_y M` with `M = dy/dx`
/// (`dc_j / dP_jk = (m - o)_k`, `dc / do = -P`), so `J_x^T J_x = M^T (J_y^T J_y) M`, the
/// information [`reading_residual_at`]'s gradients sum to, to rounding, without a pass over the
/// readings.
fn uncentred_information(jtj: &Normal, x: &[f64; PARAMETERS], m: Vec3) -> Normal {
    const ENTRIES: [(usize, usize); 6] = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)];
    let (P, o) = unpack(x);
    let mo = sub(m, o);
    let mut M = [[0.0; PARAMETERS]; PARAMETERS];
    for (a, &(j, k)) in ENTRIES.iter().enumerate() {
        M[a][a] = 1.0;
        M[6 + j][a] = mo[k];
    }
    for j in 0..3 {
        for k in 0..3 {
            M[6 + j][6 + k] = -P[j][k];
        }
    }
    let S = |i: usize, j: usize| if i >= j { jtj[i][j] } else { jtj[j][i] };
    let SM: Normal = std::array::from_fn(|b| std::array::from_fn(|a| (0..PARAMETERS).map(|c| S(b, c) * M[c][a]).sum()));
    std::array::from_fn(|a| std::array::from_fn(|a2| (0..PARAMETERS).map(|b| M[b][a] * SM[b][a2]).sum()))
}

/// `(P, c)` with `c = P (m - o)` from `(P, o)`: the unknowns of [`Residual::Readings`] about the
/// mean reading `m`, in which the valley of a weakly turned axis is straight (`c` is the centre of
/// the readings after correction, which they determine even where `P` and `o` trade along a
/// hyperbola).
fn to_centred(x: &[f64; PARAMETERS], m: Vec3) -> [f64; PARAMETERS] {
    let (P, o) = unpack(x);
    pack(&P, mat_vec(&P, sub(m, o)))
}

/// `(P, o)` from `(P, c)`: `o = m - P^-1 c`; `None` when `P` is singular.
fn from_centred(y: &[f64; PARAMETERS], m: Vec3) -> Option<[f64; PARAMETERS]> {
    let (P, c) = unpack(y);
    let k = upper_triangular_inverse(&P)?;
    Some(pack(&P, sub(m, mat_vec(&k, c))))
}

/// Levenberg-Marquardt from `start` (step 1) in the unknowns of `settings.residual`, with
/// Marquardt's diagonal scaling and Nielsen's damping update (Madsen, Nielsen, Tingleff, *Methods
/// for non-linear least squares problems*, 2004, Algorithm 3.16). The local identifiability
/// check uses the covariance of the residual minimised.
pub(crate) fn refine(
    settings: &TwoStep,
    start: &Estimate,
    readings: &[Vec3],
    field_magnitude_nt: f64,
) -> Result<Refined, CalibrationError> {
    refine_holding(settings, start, readings, field_magnitude_nt, [true; PARAMETERS])
}

/// Makes the normal equations leave the unknowns `x_i` with `!free[i]` where they are: their row
/// and column of `J^T J` become those of the identity and their gradient 0, so every step has
/// `h_i = 0` and their local variance is the residual's own, far below any physical scale.
fn hold(jtj: &mut Normal, g: &mut [f64; PARAMETERS], free: [bool; PARAMETERS]) {
    for i in (0..PARAMETERS).filter(|&i| !free[i]) {
        g[i] = 0.0;
        for j in 0..PARAMETERS {
            jtj[i][j] = 0.0;
            jtj[j][i] = 0.0;
        }
        jtj[i][i] = 1.0;
    }
}

/// [`refine`] with the entries `P11, P12, P13, P22, P23, P33` of `P` that are not `free` held at
/// the start's values; the bias is always free (`free[6..]` true: the readings' residual is
/// iterated in the centred unknowns `(P, c)`, where holding `c` would not hold `o`). Holding
/// applies to [`Residual::Readings`] only: the paper's residual is refined with all nine free.
///
/// # Panics
/// In debug builds, if part of the bias is not `free` (a caller bug).
pub(crate) fn refine_holding(
    settings: &TwoStep,
    start: &Estimate,
    readings: &[Vec3],
    field_magnitude_nt: f64,
    free: [bool; PARAMETERS],
) -> Result<Refined, CalibrationError> {
    debug_assert!(free[6..].iter().all(|&f| f), "refine_holding: the bias is always free");
    let R = field_magnitude_nt;
    let u = Scaled::new(readings, R);
    let x0 = pack(&start.p, scale(1.0 / R, start.bias_nt));
    let paper_ok = |jtj: &Normal, x: &[f64; PARAMETERS], f: f64| {
        residual_variance(settings, x, &u, f, R).map(|var_r| locally_identifiable(jtj, x, var_r))
    };
    let fit = match settings.residual {
        Residual::Paper => levenberg_marquardt(
            settings,
            x0,
            |x| cost(x, &u),
            |x| normal_equations(x, &u),
            paper_ok,
            true,
        ),
        Residual::Readings => {
            // Iterated on about the mean reading, judged in (P, o) as the paper's form is.
            let d = u.centred();
            let m = d.m;
            let readings_ok = |jtj_y: &Normal, y: &[f64; PARAMETERS], f: f64| {
                let x = from_centred(y, m)?;
                // A held unknown's row and column of `jtj_y` are the hold's, not the readings'; the
                // free ones' information in `x` needs the free unknowns' and `c`'s alone.
                let mut jtj = uncentred_information(jtj_y, &x, m);
                hold(&mut jtj, &mut [0.0; PARAMETERS], free);
                reading_variance(settings, u.len(), f, R).map(|var| locally_identifiable(&jtj, &x, var))
            };
            let fit = levenberg_marquardt(
                settings,
                to_centred(&x0, m),
                |y| reading_cost(y, &d),
                |y| {
                    let (mut jtj, mut g) = reading_normal_equations(y, &d);
                    hold(&mut jtj, &mut g, free);
                    (jtj, g)
                },
                readings_ok,
                false,
            );
            Fit {
                x: from_centred(&fit.x, m).ok_or(CalibrationError::NotPositiveDefinite {
                    reason: "estimated P is singular",
                })?,
                ..fit
            }
        }
    };
    let (x, iterations, termination, identifiable) = (fit.x, fit.iterations, fit.termination, fit.identifiable);
    // |P d| is unchanged when a row of P changes sign; keep the positive-diagonal representative.
    let (mut P, o) = unpack(&x);
    for row in P.iter_mut() {
        let diag_sign = row.iter().find(|v| **v != 0.0).copied().unwrap_or(1.0).signum();
        *row = row.map(|v| v * diag_sign);
    }
    let estimate = Estimate::checked(P, scale(R, o), readings, R)?;
    Ok(Refined {
        estimate,
        iterations,
        termination,
        identifiable,
    })
}

/// The readings in units of the field `R` (nT) about their mean `m`, and the coordinates `z`
/// under `T` of `estimate` in the frame centred on `m` (each read at the first nonzero entry of
/// its column of `T`).
fn centred_coordinates<'a, const N: usize>(
    estimate: &Estimate,
    readings: &'a [Vec3],
    R: f64,
    T: &[[f64; N]; PARAMETERS],
) -> (Scaled<'a>, [f64; N]) {
    let d = Scaled::new(readings, R).centred();
    let m = d.m;
    let y0 = to_centred(&pack(&estimate.p, scale(1.0 / R, estimate.bias_nt)), m);
    let z0: [f64; N] = std::array::from_fn(|j| {
        (0..PARAMETERS)
            .find(|&i| T[i][j] != 0.0)
            .map_or(0.0, |i| y0[i] / T[i][j])
    });
    (d, z0)
}

/// Step 2 on [`Residual::Readings`] for a model whose unknowns `z` (`N` of them) give the
/// centred unknowns linearly, `y = (P, c) = T z` (`c = P (m - o)` about the mean reading `m`):
/// the reduced models of [`crate::log_fit`] (diagonal: `P` diagonal, `z = (P11, P22, P33, c)`;
/// offset: `P = p I`, `z = (p, c)`). Started from `start` (which must be of the model: its `P`
/// is read at the first nonzero entry of each column of `T`), through the one
/// [`levenberg_marquardt`] loop; no local check (`identifiable` is `None`: the caller's statistics
/// judge the model).
pub(crate) fn refine_linear<const N: usize>(
    settings: &TwoStep,
    start: &Estimate,
    readings: &[Vec3],
    field_magnitude_nt: f64,
    T: &[[f64; N]; PARAMETERS],
) -> Result<Refined, CalibrationError> {
    let R = field_magnitude_nt;
    let (d, z0) = centred_coordinates(start, readings, R, T);
    let m = d.m;
    let y_of = |z: &[f64; N]| -> [f64; PARAMETERS] { std::array::from_fn(|i| (0..N).map(|j| T[i][j] * z[j]).sum()) };
    let normal = |z: &[f64; N]| {
        let y = y_of(z);
        chunked::normal_equations(d.readings, |&b| {
            let (e, gy) = reading_residual_and_gradient(&y, d.d(b));
            (
                e,
                std::array::from_fn(|j| (0..PARAMETERS).map(|i| T[i][j] * gy[i]).sum()),
            )
        })
    };
    let fit = levenberg_marquardt(
        settings,
        z0,
        |z| reading_cost(&y_of(z), &d),
        normal,
        |_, _, _| None,
        false,
    );
    let x = from_centred(&y_of(&fit.x), m).ok_or(CalibrationError::NotPositiveDefinite {
        reason: "estimated P is singular",
    })?;
    let (mut P, o) = unpack(&x);
    for row in P.iter_mut() {
        let diag_sign = row.iter().find(|v| **v != 0.0).copied().unwrap_or(1.0).signum();
        *row = row.map(|v| v * diag_sign);
    }
    Ok(Refined {
        estimate: Estimate::checked(P, scale(R, o), readings, R)?,
        iterations: fit.iterations,
        termination: fit.termination,
        identifiable: None,
    })
}

/// How far the cost of [`Residual::Readings`] rises along entries of `P` (see
/// [`crate::log_fit::Profile`]): for each entry of `P` among the unknowns `z` of
/// `y = (P, c) = T z` (`scales`: their indices in `z`), the entry moved by 3 of its standard
/// errors `sqrt(C_kk)` (`C = var (J^T J)^-1` at `estimate`, `var` the variance of one scaled
/// residual) each way, the other unknowns re-fitted from the linear profile path
/// `z + t C e_k / C_kk` with it held. Returns the smallest rise of the cost, in units of `var`
/// times 2 (the chi-square's), and the index in `scales` and the side where it is; a straight
/// problem rises by 9. `None` where `J^T J` is singular.
pub(crate) fn profile_rise<const N: usize>(
    settings: &TwoStep,
    estimate: &Estimate,
    readings: &[Vec3],
    field_magnitude_nt: f64,
    T: &[[f64; N]; PARAMETERS],
    scales: &[usize],
    var: f64,
) -> Option<(f64, usize, f64)> {
    let R = field_magnitude_nt;
    let (d, z0) = centred_coordinates(estimate, readings, R, T);
    let y_of = |z: &[f64; N]| -> [f64; PARAMETERS] { std::array::from_fn(|i| (0..N).map(|j| T[i][j] * z[j]).sum()) };
    let normal = |z: &[f64; N], held: Option<usize>| {
        let y = y_of(z);
        let (mut jtj, mut g) = chunked::normal_equations(d.readings, |&b| {
            let (e, gy) = reading_residual_and_gradient(&y, d.d(b));
            (
                e,
                std::array::from_fn(|j| (0..PARAMETERS).map(|i| T[i][j] * gy[i]).sum()),
            )
        });
        if let Some(k) = held {
            g[k] = 0.0;
            for j in 0..N {
                jtj[k][j] = 0.0;
                jtj[j][k] = 0.0;
            }
            jtj[k][k] = 1.0;
        }
        (jtj, g)
    };
    let cost = |z: &[f64; N]| reading_cost(&y_of(z), &d);
    let f0 = cost(&z0);
    let (mut l, _) = normal(&z0, None);
    for i in 0..N {
        for j in i + 1..N {
            l[i][j] = l[j][i];
        }
    }
    if !cholesky_in_place(&mut l) {
        return None;
    }
    let inv = crate::small::cholesky_inverse(&l);
    let mut least: Option<(f64, usize, f64)> = None;
    for (which, &k) in scales.iter().enumerate() {
        let ckk = var * inv[k][k];
        if !(ckk > 0.0 && ckk.is_finite()) {
            return None;
        }
        for side in [-1.0, 1.0] {
            let t = side * 3.0 * ckk.sqrt();
            let start: [f64; N] = std::array::from_fn(|j| z0[j] + t * var * inv[j][k] / ckk);
            let fit = levenberg_marquardt(settings, start, cost, |z| normal(z, Some(k)), |_, _, _| None, false);
            let rise = 2.0 * (cost(&fit.x) - f0) / var;
            if least.is_none_or(|(r, _, _)| rise < r) {
                least = Some((rise, which, side));
            }
        }
    }
    least
}

/// The starting damping of [`levenberg_marquardt`] relative to the diagonal of `J^T J` (Madsen et
/// al.'s `tau` for a start that is not known to be close).
const INITIAL_DAMPING: f64 = 1e-3;

/// `J^T J`, lower triangle filled.
type Normal = [[f64; PARAMETERS]; PARAMETERS];

/// Where [`levenberg_marquardt`] stopped.
pub(crate) struct Fit<const N: usize> {
    pub x: [f64; N],
    pub iterations: usize,
    pub termination: Termination,
    /// The local check at `x` (`None`: no noise to judge by).
    pub identifiable: Option<bool>,
}

/// The damped Gauss-Newton loop on `cost` in `N` unknowns from `start`, whose `J^T J` (the lower
/// triangle is read) and `J^T r` `normal` gives; `locally_identifiable` (`J^T J`, `x`, cost) is the
/// check for a flat direction, made every [`FLAT_CHECK_EVERY`] iterations from the
/// [`FLAT_CHECK_FROM`]-th when `stop_on_flat`, and at the end. Step 2 (9 unknowns) and the
/// reduced models of [`crate::log_fit`] (4 and 6) share it.
pub(crate) fn levenberg_marquardt<const N: usize>(
    settings: &TwoStep,
    start: [f64; N],
    cost: impl Fn(&[f64; N]) -> f64,
    normal: impl Fn(&[f64; N]) -> ([[f64; N]; N], [f64; N]),
    locally_identifiable: impl Fn(&[[f64; N]; N], &[f64; N], f64) -> Option<bool>,
    stop_on_flat: bool,
) -> Fit<N> {
    let mut x = start;
    let mut f = cost(&x);
    let (mut jtj, mut g) = normal(&x);
    // With Marquardt's scaling the damping `mu diag(J^T J)` is relative: Madsen et al.'s
    // starting `tau = 1e-3` is `mu` itself, whatever the number of readings.
    let mut mu = INITIAL_DAMPING;
    let mut nu = 2.0;
    let mut iterations = 0;
    let termination = loop {
        if g.iter().all(|gi| gi.abs() <= settings.gradient_tolerance) {
            break Termination::Gradient;
        }
        if iterations >= settings.max_iterations {
            break Termination::MaxIterations;
        }
        if settings.stop.requested() {
            break Termination::Stopped;
        }
        if stop_on_flat
            && iterations >= FLAT_CHECK_FROM
            && (iterations - FLAT_CHECK_FROM).is_multiple_of(FLAT_CHECK_EVERY)
            && locally_identifiable(&jtj, &x, f) == Some(false)
        {
            break Termination::FlatDirection;
        }
        iterations += 1;
        // (J^T J + mu diag(J^T J)) h = -J^T r
        let mut damped = jtj;
        let mut diag = [0.0; N];
        for i in 0..N {
            diag[i] = jtj[i][i].max(f64::MIN_POSITIVE);
            damped[i][i] += mu * diag[i];
        }
        if !cholesky_in_place(&mut damped) {
            // Only reachable with a degenerate Jacobian: more damping makes the system definite.
            mu *= nu;
            nu *= 2.0;
            continue;
        }
        let h = cholesky_solve(&damped, &g.map(|v| -v));
        let h_norm = h.iter().map(|v| v * v).sum::<f64>().sqrt();
        let x_norm = x.iter().map(|v| v * v).sum::<f64>().sqrt();
        if h_norm <= settings.step_tolerance * (x_norm + settings.step_tolerance) {
            break Termination::StepSize;
        }
        let x_new: [f64; N] = std::array::from_fn(|i| x[i] + h[i]);
        let f_new = cost(&x_new);
        // Predicted reduction L(0) - L(h) = 0.5 h^T (mu D h - g).
        let predicted: f64 = 0.5 * (0..N).map(|i| h[i] * (mu * diag[i] * h[i] - g[i])).sum::<f64>();
        let rho = (f - f_new) / predicted;
        if f_new.is_finite() && rho > 0.0 {
            let reduction = f - f_new;
            x = x_new;
            f = f_new;
            (jtj, g) = normal(&x);
            mu *= (1.0_f64 / 3.0).max(1.0 - (2.0 * rho - 1.0).powi(3));
            nu = 2.0;
            if reduction <= settings.cost_tolerance * f {
                break Termination::CostReduction;
            }
        } else {
            mu *= nu;
            nu *= 2.0;
        }
    };
    Fit {
        x,
        iterations,
        termination,
        identifiable: locally_identifiable(&jtj, &x, f),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::RngExt;

    /// The information in `(P, o)` from the centred one equals the sum over the readings of
    /// [`reading_residual_at`]'s gradients, to rounding: each entry within 1e-12 of the geometric
    /// mean of its two diagonal entries, for sensors far from and near the identity and readings
    /// far from the origin.
    #[test]
    fn the_uncentred_information_is_the_readings_own() {
        let mut rng = crate::rng::stream_rng(35, 2);
        for case in 0..50 {
            let P: Mat3 = std::array::from_fn(|i| {
                std::array::from_fn(|j| match j.cmp(&i) {
                    std::cmp::Ordering::Less => 0.0,
                    std::cmp::Ordering::Equal => rng.random_range(0.5..2.0),
                    std::cmp::Ordering::Greater => rng.random_range(-0.3..0.3),
                })
            });
            let o: Vec3 = std::array::from_fn(|_| rng.random_range(-3.0..3.0) * f64::from(case % 5));
            let readings: Vec<Vec3> = (0..300)
                .map(|_| {
                    let z: f64 = rng.random_range(-1.0..1.0);
                    let a: f64 = rng.random_range(0.0..std::f64::consts::TAU);
                    let b = [(1.0 - z * z).sqrt() * a.cos(), (1.0 - z * z).sqrt() * a.sin(), z];
                    let k = crate::small::upper_triangular_inverse(&P).unwrap();
                    std::array::from_fn(|i| mat_vec(&k, b)[i] + o[i] + rng.random_range(-0.01..0.01))
                })
                .collect();
            let u = Scaled::new(&readings, 1.0);
            let d = Scaled::new(&readings, 1.0).centred();
            let x = pack(&P, o);
            let y = to_centred(&x, d.m);
            let (jtj_y, _) = reading_normal_equations(&y, &d);
            let from_centred_info = uncentred_information(&jtj_y, &x, d.m);
            let direct = reading_information(&x, &u);
            for i in 0..PARAMETERS {
                for j in 0..=i {
                    let scale = (direct[i][i] * direct[j][j]).sqrt();
                    assert!(
                        (from_centred_info[i][j] - direct[i][j]).abs() <= 1e-12 * scale,
                        "case {case} ({i}, {j}): {} against {}",
                        from_centred_info[i][j],
                        direct[i][j]
                    );
                }
            }
        }
    }
}
