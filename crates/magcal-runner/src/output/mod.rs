//! The output layer: each CSV file's rows made from a run (their types, and the readers that
//! `check`, `plot` and `report` share, are `magcal_report::rows`, re-exported here); the
//! manifests ([`manifest`]); the result set that is written into a staging directory and swapped
//! in whole ([`staging`]); and the screen table ([`mod@print`]).

pub mod capture;
pub mod file;
pub mod manifest;
pub mod print;
pub mod progress;
pub mod staging;
pub mod stderr;

use magcal_core::design::tour;

use crate::pipeline::{Check, RunOutput};
pub use magcal_report::rows::*;
pub use magcal_report::rows::{cells, log_rows, replay_rows};

/// A statistic as a cell: empty where undefined (NaN).
fn defined(x: f64) -> Option<Real> {
    (!x.is_nan()).then_some(Real(x))
}

/// Degrees rounded to 1e-9 (a nano-degree, 2e-11 rad): angles given in degrees come back as written
/// rather than as the last bits of a round trip through radians.
fn degrees(x: f64) -> Real {
    Real((x * 1e9).round() / 1e9)
}

/// The rows of `summary.csv`.
pub fn summary_rows(out: &RunOutput) -> impl Iterator<Item = SummaryRow> + '_ {
    out.cells.iter().flat_map(move |cell| {
        let design = &out.designs[cell.design].name;
        let o = cell.outcomes();
        cell.summaries().into_iter().map(move |m| {
            let s = m.summary;
            SummaryRow {
                design: design.clone(),
                sigma_nt: Real(cell.sigma_nt),
                attitude_sigma_deg: Real(cell.attitude_sigma_deg),
                trials: cell.trials.len(),
                ok: o.ok,
                not_converged: o.not_converged,
                not_identifiable: o.not_identifiable,
                failed: o.failed,
                metric: m.metric,
                mean: defined(s.mean),
                std: defined(s.std),
                median: defined(s.median),
                p05: defined(s.p05),
                p95: defined(s.p95),
                se_mean: defined(s.se_mean),
                rms: m.rms.and_then(defined),
                crb_rms: m.metric.predicted_rms(&cell.bound).and_then(defined),
            }
        })
    })
}

/// The rows of `crb.csv`.
pub fn crb_rows<'a>(out: &'a RunOutput, truth: &'a magcal_core::ErrorModel) -> impl Iterator<Item = CrbRow> + 'a {
    use magcal_core::identifiability::{PARAMETERS, UNITS};
    // One bound per design and noise level: the cells of the first execution-error level.
    let first = out.cells.first().map_or(0.0, |c| c.attitude_sigma_deg);
    out.cells
        .iter()
        .filter(move |c| c.attitude_sigma_deg == first)
        .flat_map(move |cell| {
            let design = &out.designs[cell.design].name;
            let rms = cell.estimate_rms(truth);
            (0..9).map(move |i| {
                let std = cell.bound.std.and_then(|s| defined(s[i]));
                let mc = rms.map(|r| r[i]);
                CrbRow {
                    design: design.clone(),
                    sigma_nt: Real(cell.sigma_nt),
                    parameter: PARAMETERS[i].to_string(),
                    std,
                    unit: UNITS[i].to_string(),
                    mc_rms: mc.and_then(defined),
                    mc_over_crb: mc.zip(std).and_then(|(m, s)| defined(m / s.0)),
                }
            })
        })
}

/// The rows of `trials.csv`.
pub fn trial_rows(out: &RunOutput) -> impl Iterator<Item = TrialRow> + '_ {
    out.cells.iter().flat_map(move |cell| {
        let design = &out.designs[cell.design].name;
        cell.trials.iter().enumerate().map(move |(t, trial)| {
            let eta = |f: fn(&magcal_core::RelativeErrors) -> Option<f64>| trial.eta.as_ref().and_then(f).map(Real);
            let est =
                |f: fn(&magcal_core::ErrorModel) -> [f64; 3], i: usize| trial.estimate.as_ref().map(|m| Real(f(m)[i]));
            TrialRow {
                design: design.clone(),
                sigma_nt: Real(cell.sigma_nt),
                attitude_sigma_deg: Real(cell.attitude_sigma_deg),
                trial: t,
                status: Status(trial.status),
                eta_psi: eta(|e| e.psi),
                eta_s: eta(|e| e.scale),
                eta_o: eta(|e| e.bias),
                psi1_deg: est(|m| m.psi_deg(), 0),
                psi2_deg: est(|m| m.psi_deg(), 1),
                psi3_deg: est(|m| m.psi_deg(), 2),
                s1: est(|m| m.scale(), 0),
                s2: est(|m| m.scale(), 1),
                s3: est(|m| m.scale(), 2),
                o1_nt: est(|m| m.bias_nt(), 0),
                o2_nt: est(|m| m.bias_nt(), 1),
                o3_nt: est(|m| m.bias_nt(), 2),
                step2_iterations: trial.iterations,
                rms_residual_nt: trial.rms_residual_nt.map(Real),
                abs_psi_deg: trial.abs.map(|a| Real(a.psi_deg)),
                abs_s: trial.abs.map(|a| Real(a.scale)),
                abs_o_nt: trial.abs.map(|a| Real(a.bias_nt)),
                heading_rms_deg: trial.heading.map(|h| Real(h.rms_deg)),
                heading_max_deg: trial.heading.map(|h| Real(h.max_deg)),
            }
        })
    })
}

/// What turns a yaw into the headings a pilot reads: the field's yaw offset and declination.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Headings {
    /// Degrees added to every yaw (docs/conventions.md "Reference field").
    pub yaw_offset_deg: f64,
    /// Degrees east of true north; `None` for a field without a horizontal component (or where
    /// the headings are not wanted), which leaves the magnetic heading empty.
    pub declination_deg: Option<f64>,
}

impl Headings {
    /// The headings in `field`.
    pub fn of(field: &magcal_core::ReferenceField) -> Self {
        Self {
            yaw_offset_deg: field.yaw_offset_deg(),
            declination_deg: field.declination_deg(),
        }
    }

    /// The true heading of `a`, degrees, as written (to 1e-9 degree, in [0, 360)).
    pub fn true_heading(&self, a: &magcal_core::Attitude) -> Real {
        heading(a.true_heading_deg(self.yaw_offset_deg))
    }

    /// The magnetic heading of `a`, degrees, as written; `None` without a declination.
    pub fn magnetic_heading(&self, a: &magcal_core::Attitude) -> Option<Real> {
        self.declination_deg
            .map(|d| heading(a.magnetic_heading_deg(self.yaw_offset_deg, d)))
    }
}

/// A heading in [0, 360) to 1e-9 degree: one that rounds up to 360 is 0.
fn heading(x: f64) -> Real {
    let r = degrees(x);
    if r.0 >= 360.0 { Real(0.0) } else { r }
}

/// The rows of `designs.csv`, design by design in visiting order.
pub fn design_rows(out: &RunOutput, headings: Headings) -> impl Iterator<Item = DesignPointRow> + '_ {
    let yaw_offset_deg = headings.yaw_offset_deg;
    out.designs.iter().flat_map(move |d| {
        d.order.iter().enumerate().map(move |(v, &i)| {
            let a = &d.attitudes[i];
            let [r, y, p] = a.to_degrees();
            let [qw, qx, qy, qz] = a.body_to_nav_quaternion(yaw_offset_deg);
            let turn = (v > 0).then(|| tour::rotation_angle(&d.attitudes[d.order[v - 1]], a).to_degrees());
            DesignPointRow {
                design: d.name.clone(),
                visit: v + 1,
                point: i + 1,
                roll_deg: degrees(r),
                yaw_deg: degrees(y),
                pitch_deg: degrees(p),
                true_heading_deg: headings.true_heading(a),
                magnetic_heading_deg: headings.magnetic_heading(a),
                qw: Real(qw),
                qx: Real(qx),
                qy: Real(qy),
                qz: Real(qz),
                readings: d.readings[i],
                turn_deg: turn.map(degrees),
            }
        })
    })
}

/// The rows of `design_metrics.csv`.
pub fn design_metrics_rows(out: &RunOutput) -> impl Iterator<Item = DesignMetricsRow> + '_ {
    let reference = out.reference();
    let recommended = out.recommended();
    out.designs.iter().enumerate().map(move |(i, d)| {
        let ratios = reference.map(|u| {
            (
                (u.ln_det_mf - d.ln_det_mf).exp(),
                d.conditioning.cond_h / u.conditioning.cond_h,
                d.conditioning.cond_mf / u.conditioning.cond_mf,
            )
        });
        DesignMetricsRow {
            design: d.name.clone(),
            m: d.m(),
            ln_det_mf: Real(d.ln_det_mf),
            d_efficiency: defined(out.d_efficiency(i)),
            cond_h: defined(d.conditioning.cond_h),
            cond_mf: defined(d.conditioning.cond_mf),
            det_inv_ratio_vs_uniform: ratios.and_then(|r| defined(r.0)),
            cond_h_ratio_vs_uniform: ratios.and_then(|r| defined(r.1)),
            cond_mf_ratio_vs_uniform: ratios.and_then(|r| defined(r.2)),
            kind: d.kind,
            a_criterion: defined(d.a_criterion),
            e_criterion: defined(d.e_criterion),
            best_in_run: out.is_best(i),
            identifiable: d.verdict.identifiable,
            weakest: d.verdict.weakest.clone(),
            d_efficiency_bound: out.d_efficiency_bound(i).and_then(defined),
            criterion: d.criterion.map(|c| c.as_str().to_string()),
            check_sigma_nt: Real(d.check.sigma_nt),
            check_trials: d.check.trials,
            check_ok: d.check.outcomes.ok,
            works: d.check.works(),
            check_heading_median_deg: d.check.heading_median_deg.map(Real),
            check_heading_p95_deg: d.check.heading_p95_deg.map(Real),
            recommended: recommended == Some(i),
            heading_budget_deg: Some(Real(d.check.budget_deg)),
            check_budget_p95_deg: d.check.budget_p95_deg.map(Real),
            check_logs: d.check.logs_usable.map(|_| Check::LOGS),
            check_logs_usable: d.check.logs_usable,
        }
    })
}

/// The rows of `advice.csv`; a search that found nothing writes no row for it.
pub fn advice_rows<'a>(
    out: &'a RunOutput,
    advice: &'a crate::pipeline::advice::Advice,
    bounds: &magcal_core::AttitudeBox,
) -> impl Iterator<Item = AdviceRow> + 'a {
    let base = &out.designs[advice.base];
    let [roll, _, pitch] = bounds.ranges();
    let box_of = |r: &magcal_core::AngleRange| [r.min().to_degrees(), r.max().to_degrees()];
    let row = move |option: &str,
                    model: &str,
                    roll: [f64; 2],
                    pitch: [f64; 2],
                    attitudes: usize,
                    readings: usize,
                    c: &crate::pipeline::Check| AdviceRow {
        option: option.into(),
        model: model.into(),
        design: base.name.clone(),
        sigma_nt: Real(c.sigma_nt),
        roll_min_deg: Real(roll[0]),
        roll_max_deg: Real(roll[1]),
        pitch_min_deg: Real(pitch[0]),
        pitch_max_deg: Real(pitch[1]),
        attitudes,
        readings,
        check_trials: c.trials,
        check_ok: c.outcomes.ok,
        works: c.works(),
        check_heading_median_deg: c.heading_median_deg.map(Real),
        check_heading_p95_deg: c.heading_p95_deg.map(Real),
        heading_budget_deg: Some(Real(c.budget_deg)),
        check_budget_p95_deg: c.budget_p95_deg.map(Real),
        check_logs: c.logs_usable.map(|_| Check::LOGS),
        check_logs_usable: c.logs_usable,
    };
    let (r, p) = (box_of(&roll), box_of(&pitch));
    let (k, m) = (base.attitudes.len(), base.m() * advice.passes);
    let reduced = advice
        .reduced
        .iter()
        .map(move |(model, c)| row("reduced", &model.name(), r, p, k, m, c));
    let quieter = advice
        .quieter
        .iter()
        .map(move |c| row("quieter", "full", r, p, k, m, c));
    let wider = advice.wider.iter().map(move |v| {
        row(
            "wider",
            "full",
            v.roll_deg,
            v.pitch_deg,
            v.attitudes.len(),
            v.attitudes.len() * v.readings_per_attitude,
            &v.check,
        )
    });
    reduced.chain(quieter).chain(wider)
}

/// The rows of `approximate.csv` (none without a certificate).
pub fn approximate_rows(out: &RunOutput, headings: Headings) -> impl Iterator<Item = ApproximatePointRow> + '_ {
    out.approximate.iter().flat_map(move |a| {
        a.support.iter().zip(&a.weights).enumerate().map(move |(i, (at, w))| {
            let [r, y, p] = at.to_degrees();
            ApproximatePointRow {
                point: i + 1,
                roll_deg: degrees(r),
                yaw_deg: degrees(y),
                pitch_deg: degrees(p),
                true_heading_deg: headings.true_heading(at),
                magnetic_heading_deg: headings.magnetic_heading(at),
                weight: Real(*w),
            }
        })
    })
}

/// The row of `certificate.csv` (none without a certificate).
pub fn certificate_rows(out: &RunOutput, tolerance: f64) -> impl Iterator<Item = CertificateRow> + '_ {
    out.approximate.iter().map(move |a| {
        let c = &a.certificate;
        let [r, y, p] = c.at.to_degrees();
        CertificateRow {
            ln_det_per_reading: Real(a.ln_det),
            d_max: Real(c.d_max),
            d_max_roll_deg: degrees(r),
            d_max_yaw_deg: degrees(y),
            d_max_pitch_deg: degrees(p),
            ln_det_bound_per_reading: Real(c.ln_det_bound),
            tolerance: Real(tolerance),
            converged: a.converged,
            rounds: a.rounds,
            candidates: a.candidates,
            support_points: a.support.len(),
        }
    })
}

/// The rows of `pso_runs.csv`.
pub fn pso_run_rows(out: &RunOutput) -> impl Iterator<Item = PsoRunRow> + '_ {
    let m = out.pso_runs_m;
    out.pso_runs.iter().flatten().map(move |r| PsoRunRow {
        run: r.run,
        m,
        final_ln_det: Real(-r.fitness),
        evaluations: r.evaluations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn headings_are_named_wrapped_and_empty_without_a_declination() {
        use magcal_core::Attitude;
        let h = Headings {
            yaw_offset_deg: 90.0,
            declination_deg: Some(-26.5),
        };
        // yaw 0 with offset 90: true heading 270, magnetic 270 + 26.5 - 360.
        let a = Attitude::from_degrees(0.0, 0.0, 0.0);
        assert_eq!(h.true_heading(&a), Real(270.0));
        assert_eq!(h.magnetic_heading(&a), Some(Real(296.5)));
        let b = Attitude::from_degrees(0.0, -63.5, 0.0);
        assert_eq!(h.magnetic_heading(&b), Some(Real(0.0)));
        // Just below 360 rounds to 360 at 1e-9 degree: written as 0.
        let c = Attitude::from_degrees(0.0, -90.0 + 1e-12, 0.0);
        assert_eq!(h.true_heading(&c), Real(0.0));
        let none = Headings {
            declination_deg: None,
            ..h
        };
        assert_eq!(none.magnetic_heading(&a), None);
        assert_eq!(
            header::<DesignPointRow>().unwrap().iter().collect::<Vec<_>>()[5..8],
            ["pitch_deg", "true_heading_deg", "magnetic_heading_deg"]
        );
        // A designs.csv with the one heading column of earlier versions is refused by name.
        let old = b"design,visit,point,roll_deg,yaw_deg,pitch_deg,heading_deg,qw,qx,qy,qz,readings,turn_deg\n\
                    u,1,1,0,0,0,0,1,0,0,0,1,\n";
        let e = parse_csv::<DesignPointRow>(old, "base/designs.csv")
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "base/designs.csv: line 2: missing field `true_heading_deg`: the header has no such column (a file of another magcal version?)"
        );
    }
}
