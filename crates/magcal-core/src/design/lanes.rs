//! `ln det M_F` of several designs at once, laid out so that the compiler vectorises across designs.
//!
//! The paper's PSO evaluates 900,000 designs of 27 angles. Evaluated one at a time, a design costs
//! about 9,000 instructions, a third of them in libm's `sincos` (a scalar routine with branches),
//! too many for the full PSO's target of 0.3 s on two cores (docs/research/benchmarks.md). Here
//! [`LANES`] designs are evaluated together with every loop over the lanes innermost: the
//! branch-free `sin_cos` polynomial below, the moments and the Cholesky factorisation then run as
//! SIMD instructions on baseline x86-64 (SSE2) without any `unsafe` or hand-written intrinsics.
//!
//! Twelve lanes: the 300 particles of Table I are 25 chunks, which two threads share 13 to 12; one
//! chunk's loops are three AVX2 vectors of independent work. Two runs of Table I on one thread took
//! 0.68-0.69 s with eight lanes, 0.50-0.73 s (median 0.545) with twelve and 0.56-0.78 s with
//! sixteen; one run on two threads 0.195-0.223 s with eight, 0.139-0.169 s with twelve (best of
//! five, interleaved, on the same 2-core machine). Fewer than eight do not fill the vector units.
//!
//! The kernel is compiled a second time for AVX2 and chosen at run time when the CPU has it (the
//! `multiversion` crate; baseline x86-64 elsewhere): 4 lanes per instruction instead of SSE2's 2.
//! No AVX-512 clone is built: wider vectors do not make this kernel faster (`benches/design.rs`,
//! `fitness/d_m9_lanes_x8`), and every clone is one more code path to keep bit-identical.
//!
//! Each lane's arithmetic is the same sequence of operations whatever the other lanes hold, so a
//! design's value does not depend on the lane or the batch it is evaluated in (the PSO stays
//! reproducible), and it agrees with the scalar [`DesignProblem::ln_det`] to rounding (tests below).
// Index loops over lanes are what the vectoriser wants.
#![allow(clippy::needless_range_loop)]
// fdlibm constants are written with the digits it publishes them with; they round to the same f64.
#![allow(clippy::excessive_precision)]

use std::f64::consts::FRAC_2_PI;

use super::DesignProblem;
use crate::linear_model::{MOMENTS, Moments, UNKNOWNS};

/// Designs evaluated together (see the measurements above).
pub const LANES: usize = 12;

/// One value per lane.
pub type Lanes = [f64; LANES];

// pi/2 in three parts of 33 bits (fdlibm's pio2_1, pio2_2, pio2_3): k * part is exact for |k| < 2^20.
const PIO2_1: f64 = 1.570_796_326_734_125_614_17e0;
const PIO2_2: f64 = 6.077_100_506_303_965_976_6e-11;
const PIO2_3: f64 = 2.022_266_248_711_166_455_8e-21;
// fdlibm __kernel_sin and __kernel_cos coefficients on [-pi/4, pi/4].
const S: [f64; 6] = [
    -1.666_666_666_666_663_243_48e-1,
    8.333_333_333_322_489_461_24e-3,
    -1.984_126_982_985_794_931_34e-4,
    2.755_731_370_707_006_767_89e-6,
    -2.505_076_025_340_686_341_95e-8,
    1.589_690_995_211_550_102_21e-10,
];
const C: [f64; 6] = [
    4.166_666_666_666_660_190_37e-2,
    -1.388_888_888_887_410_957_49e-3,
    2.480_158_728_947_672_941_78e-5,
    -2.755_731_435_139_066_330_35e-7,
    2.087_572_321_298_174_827_90e-9,
    -1.135_964_755_778_819_482_65e-11,
];
/// Largest argument of the fast path; beyond it, and for non-finite input, `f64::sin_cos`.
const FAST_LIMIT: f64 = 1e5;

/// `(sin x, cos x)` per lane: Cody-Waite reduction by pi/2 and fdlibm's kernel polynomials,
/// branch-free (quadrants chosen by selects), within 2 ulp of `f64::sin_cos` for |x| <= 1e5.
#[inline(always)]
pub fn sin_cos(x: &Lanes) -> (Lanes, Lanes) {
    if !x.iter().all(|v| v.abs() <= FAST_LIMIT) {
        let mut s = [0.0; LANES];
        let mut c = [0.0; LANES];
        for l in 0..LANES {
            (s[l], c[l]) = x[l].sin_cos();
        }
        return (s, c);
    }
    if x.iter().all(|v| v.abs() <= NO_REDUCTION) {
        // Quadrant 0 in every lane: the reduction below would give `r = x` exactly and the selects
        // would pick `(sin r, cos r)`, so this is the same result without them.
        let mut s = [0.0; LANES];
        let mut c = [0.0; LANES];
        for l in 0..LANES {
            (s[l], c[l]) = kernel_sin_cos(x[l]);
        }
        return (s, c);
    }
    // Round to nearest by adding and subtracting 1.5 * 2^52 (no libm call, no branch).
    const ROUND: f64 = 6_755_399_441_055_744.0;
    let mut s = [0.0; LANES];
    let mut c = [0.0; LANES];
    for l in 0..LANES {
        let k = (x[l] * FRAC_2_PI + ROUND) - ROUND;
        let r = ((x[l] - k * PIO2_1) - k * PIO2_2) - k * PIO2_3;
        let (sin_r, cos_r) = kernel_sin_cos(r);
        // Quadrant q: (s, c), (c, -s), (-s, -c), (-c, s) for q = 0, 1, 2, 3 (mod 4).
        let q = k as i32;
        let (sb, cb) = if q & 1 != 0 { (cos_r, sin_r) } else { (sin_r, cos_r) };
        s[l] = if q & 2 != 0 { -sb } else { sb };
        c[l] = if (q + 1) & 2 != 0 { -cb } else { cb };
    }
    (s, c)
}

/// Largest `|x|` whose quadrant is 0: `x * 2/pi` is then at most 0.4966 and rounds to 0 (pi/4 is
/// 0.7854). Roll and pitch of a vehicle's box are within it.
const NO_REDUCTION: f64 = 0.78;
const _: () = assert!(NO_REDUCTION * FRAC_2_PI < 0.5);

/// fdlibm's `__kernel_sin` and `__kernel_cos` of a reduced argument `r`, |r| <= pi/4.
#[inline(always)]
fn kernel_sin_cos(r: f64) -> (f64, f64) {
    let z = r * r;
    let sin_r = r + r * z * (S[0] + z * (S[1] + z * (S[2] + z * (S[3] + z * (S[4] + z * S[5])))));
    let hz = 0.5 * z;
    let w = 1.0 - hz;
    let cos_r = w + (((1.0 - w) - hz) + z * z * (C[0] + z * (C[1] + z * (C[2] + z * (C[3] + z * (C[4] + z * C[5]))))));
    (sin_r, cos_r)
}

impl DesignProblem {
    /// `ln det M_F` (nT) of [`LANES`] designs at once; `-inf` for a singular design.
    /// Allocation-free.
    ///
    /// # Panics
    /// If a design vector is not of length `3m`.
    #[track_caller]
    pub fn ln_det_lanes(&self, xs: [&[f64]; LANES]) -> Lanes {
        let dim = self.dimension();
        for x in &xs {
            assert_eq!(x.len(), dim, "design vector length must be 3m");
        }
        ln_det_lanes_kernel(self, xs)
    }
}

/// [`ln_det_lanes_body`] compiled for AVX2 and for baseline x86-64, the one the CPU can run chosen
/// at run time (the `multiversion` crate).
///
/// The clones give bit-identical results, so a PSO run is the same design on any x86-64 machine:
/// Rust never fuses a multiply and an add on its own, the body has no `mul_add`, and
/// `+ - * / sqrt` are correctly rounded at any vector width (the test
/// `every_target_gives_the_same_bits` checks the run-time clone against the baseline one).
#[multiversion::multiversion(targets("x86_64+avx2+avx"))]
fn ln_det_lanes_kernel(problem: &DesignProblem, xs: [&[f64]; LANES]) -> Lanes {
    ln_det_lanes_body(problem, xs)
}

/// The kernel for the baseline target only (the reference of the bit-identity test).
#[cfg(test)]
fn ln_det_lanes_baseline(problem: &DesignProblem, xs: [&[f64]; LANES]) -> Lanes {
    ln_det_lanes_body(problem, xs)
}

/// `ln det M_F` of [`LANES`] designs of `m` attitudes, with the loops over the lanes innermost.
#[inline(always)]
fn ln_det_lanes_body(problem: &DesignProblem, xs: [&[f64]; LANES]) -> Lanes {
    let [n, u, e] = problem.field().b_n();
    let yaw_offset = problem.field().yaw_offset_deg().to_radians();
    let k = problem.k_scaled();
    let o = problem.o_scaled();
    let mut moments = [[0.0; LANES]; MOMENTS];
    for a in 0..problem.m() {
        let mut roll = [0.0; LANES];
        let mut yaw = [0.0; LANES];
        let mut pitch = [0.0; LANES];
        for l in 0..LANES {
            roll[l] = xs[l][3 * a];
            yaw[l] = xs[l][3 * a + 1] + yaw_offset;
            pitch[l] = xs[l][3 * a + 2];
        }
        let (sr, cr) = sin_cos(&roll);
        let (sy, cy) = sin_cos(&yaw);
        let (sp, cp) = sin_cos(&pitch);
        let mut reading = [[0.0; LANES]; 3];
        for l in 0..LANES {
            // [P1] eq. (2) as three plane rotations (see ReferenceField::body_field).
            let v1 = [cy[l] * n - sy[l] * e, u, sy[l] * n + cy[l] * e];
            let v2 = [cp[l] * v1[0] + sp[l] * v1[1], -sp[l] * v1[0] + cp[l] * v1[1], v1[2]];
            let b = [v2[0], cr[l] * v2[1] + sr[l] * v2[2], -sr[l] * v2[1] + cr[l] * v2[2]];
            for i in 0..3 {
                reading[i][l] = k[i][0] * b[0] + k[i][1] * b[1] + k[i][2] * b[2] + o[i];
            }
        }
        for l in 0..LANES {
            let terms = crate::linear_model::monomials([reading[0][l], reading[1][l], reading[2][l]]);
            for (m, t) in moments.iter_mut().zip(terms) {
                m[l] += t;
            }
        }
    }
    // M_F per lane, lower triangle, then Cholesky with the lanes innermost.
    let mut a = [[[0.0; LANES]; UNKNOWNS]; UNKNOWNS];
    for i in 0..UNKNOWNS {
        for j in 0..=i {
            a[i][j] = moments[Moments::index_of(i, j)];
        }
    }
    let mut ok = [true; LANES];
    let mut product = [1.0; LANES];
    for j in 0..UNKNOWNS {
        let mut d = a[j][j];
        for kk in 0..j {
            for l in 0..LANES {
                d[l] -= a[j][kk][l] * a[j][kk][l];
            }
        }
        for l in 0..LANES {
            // A failed lane carries on with a harmless pivot; its result is -inf below.
            ok[l] &= d[l] > 0.0 && d[l].is_finite();
            d[l] = if ok[l] { d[l] } else { 1.0 };
            product[l] *= d[l];
            d[l] = d[l].sqrt();
        }
        a[j][j] = d;
        for i in (j + 1)..UNKNOWNS {
            let mut s = a[i][j];
            for kk in 0..j {
                for l in 0..LANES {
                    s[l] -= a[i][kk][l] * a[j][kk][l];
                }
            }
            for l in 0..LANES {
                a[i][j][l] = s[l] / d[l];
            }
        }
    }
    let shift = problem.ln_det_shift();
    let mut out = [0.0; LANES];
    for l in 0..LANES {
        out[l] = if !ok[l] {
            f64::NEG_INFINITY
        } else if product[l].is_normal() {
            product[l].ln() + shift
        } else {
            (0..UNKNOWNS).map(|j| 2.0 * a[j][j][l].ln()).sum::<f64>() + shift
        };
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::attitude::{Attitude, AttitudeBox};
    use crate::design::sources;
    use crate::design::to_vector;
    use crate::paper;
    use crate::rng::stream_rng;
    use rand::RngExt;

    #[test]
    fn sin_cos_agrees_with_std_to_two_ulp() {
        let mut rng = stream_rng(1, 0);
        let mut worst: f64 = 0.0;
        let mut check = |x: Lanes| {
            let (s, c) = sin_cos(&x);
            for l in 0..LANES {
                let (s0, c0) = x[l].sin_cos();
                worst = worst.max((s[l] - s0).abs().max((c[l] - c0).abs()) / f64::EPSILON);
            }
        };
        for _ in 0..250_000 {
            check(std::array::from_fn(|_| rng.random_range(-10.0..10.0)));
        }
        for _ in 0..25_000 {
            check(std::array::from_fn(|_| rng.random_range(-1e5..1e5)));
        }
        for k in -40..=40 {
            let b = k as f64 * std::f64::consts::FRAC_PI_4;
            let near = [b, b.next_up(), b.next_down(), -b];
            check(std::array::from_fn(|l| near[l % 4]));
        }
        assert!(worst <= 2.0, "worst error {worst} eps");
        // Outside the fast range, and NaN, it is f64::sin_cos itself.
        let odd = [1e9, 0.5, f64::NAN, 2.0];
        let (s, c) = sin_cos(&std::array::from_fn(|l| odd[l % 4]));
        assert!(s[0].to_bits() == 1e9f64.sin().to_bits() && c[1].to_bits() == 0.5f64.cos().to_bits());
        assert!(s[2].is_nan());
    }

    #[test]
    fn small_angles_skip_the_reduction_with_the_same_bits() {
        // All lanes within NO_REDUCTION take the path without reduction; one lane beyond it sends
        // the others through the reduction and the selects. Each lane's bits must agree.
        let mut rng = stream_rng(4, 0);
        let edges = [
            NO_REDUCTION,
            -NO_REDUCTION,
            NO_REDUCTION.next_down(),
            0.0,
            -0.0,
            1e-300,
            -5e-324,
        ];
        for i in 0..100_000 {
            let small: Lanes = std::array::from_fn(|l| {
                if i < edges.len() && l == 0 {
                    edges[i]
                } else {
                    rng.random_range(-NO_REDUCTION..=NO_REDUCTION)
                }
            });
            let mut mixed = small;
            mixed[LANES - 1] = 2.0;
            let (s1, c1) = sin_cos(&small);
            let (s2, c2) = sin_cos(&mixed);
            for l in 0..LANES - 1 {
                assert_eq!(s1[l].to_bits(), s2[l].to_bits(), "sin {}", small[l]);
                assert_eq!(c1[l].to_bits(), c2[l].to_bits(), "cos {}", small[l]);
            }
        }
    }

    #[test]
    fn lanes_agree_with_the_scalar_ln_det() {
        let field = paper::changsha_field().with_yaw_offset_deg(37.0).unwrap();
        for (bounds, m) in [(paper::auv_box(), 9), (AttitudeBox::full(), 14)] {
            let p = DesignProblem::new(field, paper::true_error_model(), bounds, m).unwrap();
            let mut rng = stream_rng(2, m as u64);
            for _ in 0..200 {
                let designs: Vec<Vec<f64>> = (0..LANES)
                    .map(|_| to_vector(&sources::random(&bounds, m, &mut rng)))
                    .collect();
                let got = p.ln_det_lanes(std::array::from_fn(|l| designs[l].as_slice()));
                for l in 0..LANES {
                    let want = p.ln_det(&designs[l]);
                    // Same operations up to 2-ulp trigonometry and the order of sums: a relative
                    // perturbation dM of M_F moves ln det by trace(M^-1 dM) <= 9 cond(M) |dM|/|M|.
                    let m_f = crate::linear_model::InformationMatrix::from_readings(
                        &p.model()
                            .measure_all(&p.field().body_fields(&crate::design::from_vector(&designs[l]))),
                        p.field().magnitude(),
                    );
                    let cond = crate::linear_model::cond_2(m_f.to_faer().as_ref());
                    let tol = 9.0 * cond * 16.0 * f64::EPSILON;
                    assert!((got[l] - want).abs() <= tol, "{} vs {want}, tol {tol:e}", got[l]);
                }
            }
        }
    }

    #[test]
    fn every_target_gives_the_same_bits() {
        // The run-time clone (AVX2 where the CPU has it) against the baseline clone,
        // on the AUV box and the full attitude space, yaw offset included.
        let field = paper::changsha_field().with_yaw_offset_deg(90.0).unwrap();
        for (bounds, m) in [(paper::auv_box(), 9), (AttitudeBox::full(), 12)] {
            let p = DesignProblem::new(field, paper::true_error_model(), bounds, m).unwrap();
            let mut rng = stream_rng(3, m as u64);
            for _ in 0..500 {
                let designs: Vec<Vec<f64>> = (0..LANES)
                    .map(|_| to_vector(&sources::random(&bounds, m, &mut rng)))
                    .collect();
                let xs = std::array::from_fn(|l| designs[l].as_slice());
                let fast = ln_det_lanes_kernel(&p, xs);
                let base = ln_det_lanes_baseline(&p, xs);
                assert_eq!(fast.map(f64::to_bits), base.map(f64::to_bits));
            }
        }
    }

    #[test]
    fn a_lane_does_not_depend_on_its_neighbours() {
        let p = crate::design::tests::paper_problem();
        let good = to_vector(&paper::uniformity_design());
        let other = to_vector(&paper::table2_d_optimal());
        let singular = to_vector(&[Attitude::from_degrees(1.0, 2.0, 3.0); 9]);
        let first = [&good, &other, &singular, &good];
        let second = [&singular, &singular, &good, &other];
        let a = p.ln_det_lanes(std::array::from_fn(|l| first[l % 4].as_slice()));
        let b = p.ln_det_lanes(std::array::from_fn(|l| second[l % 4].as_slice()));
        assert_eq!(a[0].to_bits(), b[2].to_bits());
        assert_eq!(a[0].to_bits(), a[3].to_bits());
        assert_eq!(a[1].to_bits(), b[3].to_bits());
        assert!(a[2] == f64::NEG_INFINITY && b[0] == f64::NEG_INFINITY);
        assert!((a[0] - 303.4800).abs() < 5e-5);
    }
}
