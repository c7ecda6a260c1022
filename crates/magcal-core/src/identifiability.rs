//! The Cramer-Rao floor of a calibration design and its identifiability verdict
//! (docs/conventions.md "Identifiability and the Cramer-Rao floor").
//!
//! The calibration is attitude-independent: each reading has an unknown body direction, and only
//! `r_i = |P (b_i - O)| - R` carries information. With the noise `n ~ N(0, sigma^2 I3)` of
//! \[P1\] eq. (5), `r_i` has variance `sigma^2 |grad_b r_i|^2` to first order, so the Fisher
//! information of the nine parameters `theta = (psi1, psi2, psi3, S1, S2, S3, O1, O2, O3)` is
//!
//! `F = sum_i J_i J_i^T / (sigma^2 |g_i|^2)`, `J_i = d r_i / d theta`, `g_i = grad_b r_i = P^T w_i`,
//!
//! with `w_i = P (b_i - O) / |P (b_i - O)|`. At the noise-free readings of the truth,
//! `P (b_i - O) = B_i`, the body field, and the chain rule through `K = diag(S) N(psi)` and
//! `dP = -P dK P` gives `d r_i / d psi_a = -g_i^T (dK / d psi_a) B_i`, the same for `S_a`, and
//! `d r_i / d O = -g_i`: the information is formed directly in the physical units (degrees, -, nT)
//! and no Jacobian of the inverse map (docs/conventions.md) is needed. Treating the body directions as
//! nuisance parameters of the full readings gives the same bound (docs/conventions.md).
//!
//! # The verdict
//! A design is **identifiable** at a noise level when its information is regular to working
//! precision and every parameter's predicted standard deviation is below its physical scale
//! ([`PhysicalScales`]: 10 degrees for a non-orthogonality angle, half the true scale factor, the
//! field magnitude `|B|` for a bias). Beyond those, the estimate of that parameter says nothing.
//! The weakest combination is the eigenvector of the smallest eigenvalue of the information in
//! units of those scales; [`Verdict::weakest`] names its largest components in words.

#![allow(non_snake_case)]

use faer::{Mat, Side};

use crate::sensor::ErrorModel;
use crate::small::{Mat3, Vec3, dot, mat_t_vec, mat_vec, norm};

/// The nine physical parameters, in the order of [`CramerRao::covariance`].
pub const PARAMETERS: [&str; 9] = [
    "psi1_deg", "psi2_deg", "psi3_deg", "s1", "s2", "s3", "o1_nt", "o2_nt", "o3_nt",
];

/// The unit of each of [`PARAMETERS`].
pub const UNITS: [&str; 9] = ["deg", "deg", "deg", "-", "-", "-", "nT", "nT", "nT"];

/// How a verdict names the three sensor axes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub enum AxisNames {
    /// \[P1\]'s body frame, for designs (the sensor's axes are the body's, to first order): "1
    /// (nose)", "2 (up)", "3 (right)" (\[P1\] II.A).
    #[default]
    Body,
    /// A log's own columns, whose mounting is unknown: "x", "y", "z".
    Sensor,
}

impl AxisNames {
    /// The three names.
    pub fn names(self) -> [&'static str; 3] {
        match self {
            Self::Body => ["1 (nose)", "2 (up)", "3 (right)"],
            Self::Sensor => ["x", "y", "z"],
        }
    }
}

/// Scales beyond which a parameter is not determined.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PhysicalScales {
    /// Non-orthogonality angle, degrees. Default 10.
    pub psi_deg: f64,
    /// Scale factor, as a fraction of the true one. Default 0.5.
    pub scale_fraction: f64,
    /// Bias, as a multiple of the field magnitude `|B|`. Default 1.
    pub bias_fraction_of_field: f64,
}

impl Default for PhysicalScales {
    fn default() -> Self {
        Self {
            psi_deg: 10.0,
            scale_fraction: 0.5,
            bias_fraction_of_field: 1.0,
        }
    }
}

/// The Cramer-Rao bound of a design at one noise level.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct CramerRao {
    /// Covariance of `(psi_deg, S, O_nt)`, row-major 9x9, or `None` when the information is
    /// singular to working precision.
    pub covariance: Option<[[f64; 9]; 9]>,
    /// Predicted standard deviation of each of [`PARAMETERS`] (NaN-free: `None` when singular).
    pub std: Option<[f64; 9]>,
    /// The verdict.
    pub verdict: Verdict,
    /// The truth the bound is about.
    truth: ErrorModel,
}

/// Whether a design determines every parameter, and its weakest combination.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct Verdict {
    /// Every parameter's predicted std below its physical scale, and the information regular.
    pub identifiable: bool,
    /// The weakest combination in words: "scale and bias of sensor axis 2 (up) are confounded".
    pub weakest: String,
    /// The weakest combination: unit eigenvector in units of the physical scales.
    pub direction: [f64; 9],
    /// Its predicted standard deviation in units of the physical scales (`inf` when singular).
    pub std_in_scales: f64,
}

impl CramerRao {
    /// The bound for readings of `truth` at the body fields `body_fields` (nT; the design's
    /// attitudes through \[P1\] eq. (1)-(2)), noise `sigma_nt` per component.
    ///
    /// # Panics
    /// If `sigma_nt` is negative or not finite (a caller bug: scenarios are validated).
    #[track_caller]
    pub fn new(truth: &ErrorModel, body_fields: &[Vec3], sigma_nt: f64, scales: &PhysicalScales) -> Self {
        Self::named(truth, body_fields, sigma_nt, scales, AxisNames::Body)
    }

    /// [`Self::new`] with the verdict naming the axes by `names`.
    ///
    /// # Panics
    /// As [`Self::new`].
    #[track_caller]
    pub fn named(
        truth: &ErrorModel,
        body_fields: &[Vec3],
        sigma_nt: f64,
        scales: &PhysicalScales,
        names: AxisNames,
    ) -> Self {
        let info = information_per_unit_variance(truth, body_fields);
        let field = body_fields.first().map_or(1.0, |&b| norm(b));
        Self::from_information(truth, &info, field, sigma_nt, scales, names)
    }

    /// [`Self::named`] from the information per unit variance
    /// ([`information_per_unit_variance`]) of the body fields, for a caller that summed it
    /// already; `field` (nT) is the magnitude the bias's physical scale is relative to
    /// ([`Self::named`] takes the first field's).
    ///
    /// # Panics
    /// As [`Self::new`].
    #[track_caller]
    pub fn from_information(
        truth: &ErrorModel,
        info: &[[f64; 9]; 9],
        field: f64,
        sigma_nt: f64,
        scales: &PhysicalScales,
        names: AxisNames,
    ) -> Self {
        assert!(
            sigma_nt.is_finite() && sigma_nt >= 0.0,
            "sigma_nt must be finite and >= 0"
        );
        let d = scale_vector(truth, field, scales);
        // F in units of the physical scales: F_s = D F D.
        let Fs = Mat::from_fn(9, 9, |i, j| d[i] * info[i][j] * d[j]);
        let (direction, std_in_scales, covariance) = match Fs.self_adjoint_eigen(Side::Lower) {
            Ok(evd) => {
                let s: Vec<f64> = (0..9).map(|i| evd.S()[i]).collect();
                let max = s.iter().copied().fold(0.0_f64, f64::max);
                let (k, min) = s
                    .iter()
                    .copied()
                    .enumerate()
                    .min_by(|a, b| a.1.total_cmp(&b.1))
                    .expect("nine eigenvalues");
                let direction: [f64; 9] = std::array::from_fn(|i| evd.U()[(i, k)]);
                // Regular to working precision: the smallest eigenvalue above the rounding of
                // the largest (the entries are sums of m products, each good to a few ulps).
                let regular = max > 0.0 && min > 1e3 * 9.0 * f64::EPSILON * max;
                if regular {
                    // Cov_s = V diag(1/lambda) V^T per unit variance; Cov = sigma^2 D Cov_s D.
                    let cov: [[f64; 9]; 9] = std::array::from_fn(|i| {
                        std::array::from_fn(|j| {
                            let c: f64 = (0..9).map(|l| evd.U()[(i, l)] * evd.U()[(j, l)] / s[l]).sum();
                            sigma_nt * sigma_nt * d[i] * c * d[j]
                        })
                    });
                    (direction, sigma_nt / min.sqrt(), Some(cov))
                } else {
                    (direction, f64::INFINITY, None)
                }
            }
            Err(_) => ([0.0; 9], f64::INFINITY, None),
        };
        let std = covariance.map(|c| std::array::from_fn(|i| c[i][i].max(0.0).sqrt()));
        let within = std.is_some_and(|s: [f64; 9]| (0..9).all(|i| s[i] <= d[i]));
        let verdict = Verdict {
            identifiable: within,
            weakest: match &covariance {
                Some(c) => describe_by_correlation(c, &d, sigma_nt, within, names),
                None => describe_singular(&direction, names),
            },
            direction,
            std_in_scales,
        };
        Self {
            covariance,
            std,
            verdict,
            truth: *truth,
        }
    }

    /// Predicted rms of the relative errors `eta_psi, eta_S, eta_O` of \[P1\] eq. (21)-(23),
    /// percent: `100 sqrt(trace Cov(v)) / |v|`; `None` where the truth is zero or the bound
    /// does not exist.
    pub fn rms_eta(&self) -> [Option<f64>; 3] {
        let truth = [self.truth.psi_deg(), self.truth.scale(), self.truth.bias_nt()];
        let abs = self.rms_abs();
        std::array::from_fn(|g| {
            let n = norm(truth[g]);
            abs[g].filter(|_| n > 0.0).map(|a| 100.0 * a / n)
        })
    }

    /// Predicted rms of the absolute errors `|psi_hat - psi|` (deg), `|S_hat - S|`,
    /// `|O_hat - O|` (nT): `sqrt(trace Cov(v))`.
    pub fn rms_abs(&self) -> [Option<f64>; 3] {
        std::array::from_fn(|g| {
            self.covariance
                .map(|c| (0..3).map(|i| c[3 * g + i][3 * g + i].max(0.0)).sum::<f64>().sqrt())
        })
    }
}

/// Physical scales per parameter: psi degrees, scale factors, biases (nT).
fn scale_vector(truth: &ErrorModel, field_nt: f64, s: &PhysicalScales) -> [f64; 9] {
    let S = truth.scale();
    [
        s.psi_deg,
        s.psi_deg,
        s.psi_deg,
        s.scale_fraction * S[0],
        s.scale_fraction * S[1],
        s.scale_fraction * S[2],
        s.bias_fraction_of_field * field_nt,
        s.bias_fraction_of_field * field_nt,
        s.bias_fraction_of_field * field_nt,
    ]
}

/// `dK / d theta_a` for the six parameters of `K = diag(S) N(psi)` (psi per degree).
fn dK(truth: &ErrorModel) -> [Mat3; 6] {
    let [p1, p2, p3] = truth.psi_deg().map(f64::to_radians);
    let S = truth.scale();
    let N = truth.N();
    let deg = std::f64::consts::PI / 180.0;
    let (s1, c1) = p1.sin_cos();
    let (s2, c2) = p2.sin_cos();
    let (s3, c3) = p3.sin_cos();
    let z = [0.0; 3];
    [
        [z, [0.0, -s1 * S[1] * deg, c1 * S[1] * deg], z],
        [[-s2 * c3 * S[0] * deg, -s2 * s3 * S[0] * deg, c2 * S[0] * deg], z, z],
        [[-c2 * s3 * S[0] * deg, c2 * c3 * S[0] * deg, 0.0], z, z],
        [N[0], z, z],
        [z, N[1], z],
        [z, z, N[2]],
    ]
}

/// Per body field, the gradient `J_i = d r_i / d theta` of the residual `r_i = |P (b_i - O)| - R`
/// in `theta = (psi_deg, S, O_nt)` and `|g_i|^2`, `g_i = grad_b r_i = P^T w_i` (the module
/// documentation): the residual's variance is `sigma^2 |g_i|^2`. The Fisher information is
/// `sum J_i J_i^T / |g_i|^2` ([`information_per_unit_variance`]); an unweighted least-squares fit
/// of the residuals has the covariance `sigma^2 A^-1 B A^-1` with `A = sum J_i J_i^T` and
/// `B = sum |g_i|^2 J_i J_i^T`.
pub fn residual_jacobian<'a>(
    truth: &ErrorModel,
    body_fields: &'a [Vec3],
) -> impl Iterator<Item = ([f64; 9], f64)> + 'a {
    let P = truth.P();
    let dk = dK(truth);
    body_fields.iter().map(move |&B| {
        // A field of zero length (a reading at the bias) has no direction; any one serves.
        let R = norm(B);
        let w = if R > 0.0 { B.map(|v| v / R) } else { [1.0, 0.0, 0.0] };
        let g = mat_t_vec(&P, w);
        let mut J = [0.0; 9];
        for (a, dka) in dk.iter().enumerate() {
            J[a] = -dot(g, mat_vec(dka, B));
        }
        for i in 0..3 {
            J[6 + i] = -g[i];
        }
        (J, dot(g, g))
    })
}

/// The Fisher information of `(psi_deg, S, O_nt)` for unit noise variance (nT^2).
pub fn information_per_unit_variance(truth: &ErrorModel, body_fields: &[Vec3]) -> [[f64; 9]; 9] {
    let P = truth.P();
    let dk = dK(truth);
    let mut F = [[0.0; 9]; 9];
    for &B in body_fields {
        let R = norm(B);
        // w = P (b - O) / |P (b - O)| = B / |B| at the truth; g = grad_b r = P^T w.
        let w = B.map(|v| v / R);
        let g = mat_t_vec(&P, w);
        let weight = 1.0 / dot(g, g);
        let mut J = [0.0; 9];
        for (a, dka) in dk.iter().enumerate() {
            J[a] = -dot(g, mat_vec(dka, B));
        }
        for i in 0..3 {
            J[6 + i] = -g[i];
        }
        for i in 0..9 {
            for j in 0..9 {
                F[i][j] += weight * J[i] * J[j];
            }
        }
    }
    F
}

/// The name of parameter `i` in words.
fn parameter_words(i: usize, names: AxisNames) -> String {
    let psi = match names {
        AxisNames::Body => ["psi1 (axes 2-3)", "psi2 (axes 1-3)", "psi3 (axes 1-2)"],
        AxisNames::Sensor => ["psi1 (axes y-z)", "psi2 (axes x-z)", "psi3 (axes x-y)"],
    };
    let axes = names.names();
    match i {
        0..=2 => format!("non-orthogonality {}", psi[i]),
        3..=5 => format!("scale of axis {}", axes[i - 3]),
        _ => format!("bias of axis {}", axes[i - 6]),
    }
}

/// The weakest parameter in words (the largest std in units of its physical scale), with the
/// parameter most correlated with it when the correlation exceeds 0.9 in magnitude: "scale and
/// bias of sensor axis 2 (up) are confounded (correlation -0.9993); largest predicted std: ...".
fn describe_by_correlation(
    cov: &[[f64; 9]; 9],
    scales: &[f64; 9],
    sigma_nt: f64,
    identifiable: bool,
    axes: AxisNames,
) -> String {
    let std: [f64; 9] = std::array::from_fn(|i| cov[i][i].max(0.0).sqrt());
    let worst = (0..9)
        .max_by(|&a, &b| (std[a] / scales[a]).total_cmp(&(std[b] / scales[b])))
        .expect("nine");
    let corr = |j: usize| cov[worst][j] / (std[worst] * std[j]);
    let partner = (0..9)
        .filter(|&j| j != worst && std[j] > 0.0)
        .max_by(|&a, &b| corr(a).abs().total_cmp(&corr(b).abs()))
        .filter(|&j| corr(j).abs() >= 0.9);
    let (names, _) = name_parameters(&[Some(worst), partner].into_iter().flatten().collect::<Vec<_>>(), axes);
    let correlation = partner.map_or(String::new(), |j| format!(" (correlation {:.4})", corr(j)));
    let what = match (identifiable, partner) {
        (true, _) => format!("weakest: {names}{correlation}"),
        (false, Some(_)) => format!("{names} are confounded{correlation}"),
        (false, None) => format!("{names} is not determined"),
    };
    format!(
        "{what}; largest predicted std: {} {:.4} {} at {sigma_nt} nT",
        PARAMETERS[worst], std[worst], UNITS[worst]
    )
}

/// The weakest direction (an eigenvector of a singular information) in words: its components
/// that carry at least 4 % of its squared length, at most three.
fn describe_singular(direction: &[f64; 9], axes: AxisNames) -> String {
    let mut order: Vec<usize> = (0..9).collect();
    order.sort_by(|&a, &b| direction[b].abs().total_cmp(&direction[a].abs()));
    let top: Vec<usize> = order
        .iter()
        .copied()
        .take(3)
        .filter(|&i| direction[i].abs() >= 0.2)
        .collect();
    let top = if top.is_empty() { vec![order[0]] } else { top };
    let (names, with) = name_parameters(&top, axes);
    let verb = if top.len() == 1 {
        "is not determined"
    } else {
        "are confounded"
    };
    format!("{names} {verb}{with}: the information is singular")
}

/// Parameters in words: a scale and the bias of the same axis (the classic confusion of an axis
/// that barely turns against the field) as "scale and bias of sensor axis k", the others joined
/// by "and". Returns the names and, when a pair stands with others, `", with <the others>"`.
fn name_parameters(params: &[usize], axes: AxisNames) -> (String, String) {
    let names = axes.names();
    let pair = (0..3).find(|k| params.contains(&(3 + k)) && params.contains(&(6 + k)));
    let others: Vec<String> = params
        .iter()
        .filter(|&&i| pair.is_none_or(|k| i != 3 + k && i != 6 + k))
        .map(|&i| parameter_words(i, axes))
        .collect();
    match pair {
        Some(k) if others.is_empty() => (format!("scale and bias of sensor axis {}", names[k]), String::new()),
        Some(k) => (
            format!("scale and bias of sensor axis {}", names[k]),
            format!(", with {}", others.join(" and ")),
        ),
        None => (others.join(" and "), String::new()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::attitude::Attitude;
    use crate::paper;

    fn bound(yaw_offset: f64, design: &[Attitude]) -> CramerRao {
        let field = paper::changsha_field().with_yaw_offset_deg(yaw_offset).unwrap();
        CramerRao::new(
            &paper::true_error_model(),
            &field.body_fields(design),
            30.0,
            &PhysicalScales::default(),
        )
    }

    /// Agreement to the digits a check value is printed with: half a unit of its last digit.
    fn close(got: f64, want: f64, decimals: i32) -> bool {
        (got - want).abs() <= 0.5 * 10f64.powi(-decimals) + 1e-12
    }

    #[test]
    fn conventions_check_values() {
        // docs/conventions.md "Identifiability and the Cramer-Rao floor", 30 nT, [P1] truth: yaw offset,
        // design, rms eta and its printed decimals, std and its printed decimals per group.
        type Row = (f64, Vec<Attitude>, [f64; 3], [i32; 3], [f64; 9], [i32; 3]);
        let cases: [Row; 3] = [
            (
                90.0,
                paper::uniformity_design(),
                [31.19, 0.836, 8.62],
                [2, 3, 2],
                [0.6271, 0.1676, 0.2247, 0.00728, 0.01241, 0.00676, 173.3, 561.5, 418.1],
                [4, 5, 1],
            ),
            (
                0.0,
                paper::uniformity_design(),
                [106.68, 7.455, 62.43],
                [2, 3, 2],
                [0.8411, 0.3397, 2.1672, 0.06674, 0.10913, 0.06129, 1519.0, 4969.5, 527.3],
                [4, 5, 1],
            ),
            (
                0.0,
                paper::conventions_optimum(),
                [10.69, 0.684, 5.92],
                [2, 3, 2],
                [0.1845, 0.0450, 0.1390, 0.00500, 0.01079, 0.00530, 78.0, 479.1, 99.1],
                [4, 5, 1],
            ),
        ];
        for (offset, design, eta, eta_decimals, std, std_decimals) in cases {
            let b = bound(offset, &design);
            let rms = b.rms_eta().map(Option::unwrap);
            for g in 0..3 {
                assert!(
                    close(rms[g], eta[g], eta_decimals[g]),
                    "offset {offset}: rms eta {rms:?} vs {eta:?}"
                );
            }
            let s = b.std.unwrap();
            for i in 0..9 {
                assert!(
                    close(s[i], std[i], std_decimals[i / 3]),
                    "offset {offset}: std {} = {} vs {}",
                    PARAMETERS[i],
                    s[i],
                    std[i]
                );
            }
            assert!(b.verdict.identifiable, "{}", b.verdict.weakest);
        }
    }

    #[test]
    fn the_bound_scales_with_sigma_and_is_zero_without_noise() {
        let field = paper::changsha_field();
        let body = field.body_fields(&paper::uniformity_design());
        let truth = paper::true_error_model();
        let s = PhysicalScales::default();
        let a = CramerRao::new(&truth, &body, 1.0, &s).std.unwrap();
        let b = CramerRao::new(&truth, &body, 3.0, &s).std.unwrap();
        for i in 0..9 {
            assert!((b[i] - 3.0 * a[i]).abs() <= 1e-12 * b[i], "{i}");
        }
        let zero = CramerRao::new(&truth, &body, 0.0, &s);
        assert!(zero.std.unwrap().iter().all(|v| *v == 0.0) && zero.verdict.identifiable);
    }

    #[test]
    fn a_level_box_confounds_the_up_axis_scale_and_bias() {
        // Ground vehicle: roll and pitch +-1 degree, any yaw. The up axis barely turns against
        // the field, so its scale and bias cannot be told apart.
        let field = paper::changsha_field();
        let design: Vec<Attitude> = (0..12)
            .map(|i| {
                let sign = if i % 2 == 0 { 1.0 } else { -1.0 };
                Attitude::from_degrees(sign, i as f64 * 30.0 - 180.0, -sign * ((i / 2) % 2) as f64)
            })
            .collect();
        let b = CramerRao::new(
            &paper::true_error_model(),
            &field.body_fields(&design),
            30.0,
            &PhysicalScales::default(),
        );
        assert!(!b.verdict.identifiable);
        assert!(
            b.verdict
                .weakest
                .starts_with("scale and bias of sensor axis 2 (up) are confounded"),
            "{}",
            b.verdict.weakest
        );
        // A yaw-only design: the information is singular.
        let flat: Vec<Attitude> = (0..12)
            .map(|i| Attitude::from_degrees(0.0, i as f64 * 30.0, 0.0))
            .collect();
        let b = CramerRao::new(
            &paper::true_error_model(),
            &field.body_fields(&flat),
            30.0,
            &PhysicalScales::default(),
        );
        assert!(!b.verdict.identifiable && b.std.is_none() && b.rms_eta() == [None; 3]);
        assert!(b.verdict.weakest.contains("singular"), "{}", b.verdict.weakest);
    }

    #[test]
    fn a_zero_truth_has_no_relative_bound() {
        let nominal = ErrorModel::new([0.0; 3], [1.0; 3], [0.0; 3]).unwrap();
        let field = paper::changsha_field();
        let b = CramerRao::new(
            &nominal,
            &field.body_fields(&paper::uniformity_design()),
            30.0,
            &PhysicalScales::default(),
        );
        let [psi, s, o] = b.rms_eta();
        assert!(psi.is_none() && s.is_some() && o.is_none());
        assert!(b.rms_abs().iter().all(|v| v.is_some_and(f64::is_finite)));
    }
}
