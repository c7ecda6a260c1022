//! The flight plans of a `design` or `run` set: each design's attitudes as small vehicle glyphs
//! (nose, right wing, up) on the sphere of nose directions, joined in the visiting order of
//! `designs.csv`, one design at a time behind a dropdown; the attitudes as tables a pilot follows;
//! and each design's certified D-efficiency with the certificate it rests on.
//!
//! Everything is drawn from the set's files alone: the attitude of a row is its quaternion
//! `(qw, qx, qy, qz)` of `C_b^n` (body nose, up, right into North, Up, East, yaw offset
//! included), so the figure's headings are true headings, as the table's.

use std::path::Path;

use anyhow::{Result, bail};
use plotly::common::{Line, Marker, Mode, Title, Visible};
use plotly::layout::update_menu::{Button, ButtonMethod, UpdateMenu};
use plotly::layout::{AspectMode, Axis, Camera, Eye, LayoutScene, Margin};
use plotly::{Layout, Mesh3D, Plot, Scatter3D};
use serde_json::json;

use super::{Cell, Page, Table, drawn, significant};
use crate::rows::{CertificateRow, DesignMetricsRow, DesignPointRow};

/// Length of the nose's stroke on the unit sphere of directions.
const NOSE: f64 = 0.22;
/// Length of the right wing's and the up axis's strokes.
const WING: f64 = 0.12;
/// Largest angle between two points of a drawn arc of the visiting order, degrees.
const ARC_STEP_DEG: f64 = 4.0;

/// One design's attitudes, in visiting order, as `designs.csv` holds them.
#[derive(Debug, Clone)]
pub struct Plan {
    pub design: String,
    pub rows: Vec<DesignPointRow>,
}

/// The designs of `designs.csv` (read from `path`), each with its rows in visiting order.
///
/// # Errors
/// Rows of one design that are not together, a visit number out of order, or an attitude that is
/// not finite or whose quaternion is not a unit quaternion, named by the file's line.
pub fn plans(rows: Vec<DesignPointRow>, path: &Path) -> Result<Vec<Plan>> {
    let mut plans: Vec<Plan> = Vec::new();
    for (i, row) in rows.into_iter().enumerate() {
        let line = i + 2;
        let angles = [row.roll_deg.0, row.yaw_deg.0, row.pitch_deg.0, row.true_heading_deg.0];
        if !angles.iter().all(|v| v.is_finite()) {
            bail!("{}: line {line}: an attitude angle is not finite", path.display());
        }
        let named = !row.design.is_empty()
            && row.design.len() <= 64
            && row
                .design
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'));
        if !named {
            bail!(
                "{}: line {line}: design {:?} is not a scenario's design name (letters, digits, _ - .)",
                path.display(),
                short(&row.design)
            );
        }
        let q = [row.qw.0, row.qx.0, row.qy.0, row.qz.0];
        let norm = q.iter().map(|c| c * c).sum::<f64>().sqrt();
        if !norm.is_finite() || (norm - 1.0).abs() > 1e-9 {
            bail!(
                "{}: line {line}: the quaternion (qw, qx, qy, qz) has norm {}, not 1",
                path.display(),
                significant(norm, 6)
            );
        }
        match plans.last_mut() {
            Some(p) if p.design == row.design => p.rows.push(row),
            _ => {
                if plans.iter().any(|p| p.design == row.design) {
                    bail!(
                        "{}: line {line}: design {:?} again after other designs",
                        path.display(),
                        short(&row.design)
                    );
                }
                plans.push(Plan {
                    design: row.design.clone(),
                    rows: vec![row],
                });
            }
        }
        let p = plans.last().map_or(0, |p| p.rows.len());
        let visit = plans.last().and_then(|p| p.rows.last()).map_or(0, |r| r.visit);
        if visit != p {
            bail!(
                "{}: line {line}: visit {visit}, but it is attitude {p} of its design in the file",
                path.display()
            );
        }
    }
    Ok(plans)
}

/// At most 40 characters of a name from a file, for a message.
fn short(text: &str) -> String {
    text.chars().take(40).collect()
}

/// The body axes of an attitude in East, North, Up: nose, right wing, up.
pub fn body_axes(row: &DesignPointRow) -> [[f64; 3]; 3] {
    let [w, x, y, z] = [row.qw.0, row.qx.0, row.qy.0, row.qz.0];
    // Columns of the rotation matrix of the unit quaternion: the body axes in North, Up, East.
    let column = |k: usize| -> [f64; 3] {
        match k {
            0 => [
                1.0 - 2.0 * (y * y + z * z),
                2.0 * (x * y + w * z),
                2.0 * (x * z - w * y),
            ],
            1 => [
                2.0 * (x * y - w * z),
                1.0 - 2.0 * (x * x + z * z),
                2.0 * (y * z + w * x),
            ],
            _ => [
                2.0 * (x * z + w * y),
                2.0 * (y * z - w * x),
                1.0 - 2.0 * (x * x + y * y),
            ],
        }
    };
    // Body x is the nose, y up, z the right wing; North, Up, East reordered to East, North, Up.
    let enu = |v: [f64; 3]| [v[2], v[0], v[1]];
    [enu(column(0)), enu(column(2)), enu(column(1))]
}

/// Adds the plans: the figure, the designs' efficiencies and certificate, each design's table.
pub fn section(page: &mut Page, plans: &[Plan], metrics: &[DesignMetricsRow], certificate: Option<&CertificateRow>) {
    page.heading("Flight plans");
    let shown = metrics
        .iter()
        .position(|m| m.recommended)
        .filter(|&i| i < plans.len())
        .unwrap_or(0);
    page.plot("plan", plan_plot(plans, shown), 680, format!(
        "Each attitude of the chosen design (the dropdown; first shown: {}) drawn where its nose points on the unit sphere of directions (East, North, Up; the compass letters mark the horizon), as a glyph of three strokes from that point: the nose (red, outwards), the right wing (green) and the vehicle's up (blue). A roll turns the green and blue strokes about the nose; pitch lifts the point above the horizon. The grey line joins the attitudes in the visiting order of designs.csv along great circles, from the larger first marker. Hover a marker for its visit, roll, pitch, true heading and readings.",
        plans.get(shown).map_or("-", |p| p.design.as_str())
    ));
    page.note("The visiting order is the one designs.csv holds (its visit column): a tour that keeps the total rotation short, chosen when the set was made; turn_deg is the rotation from the previous attitude.");
    designs_table(page, plans, metrics);
    certificate_table(page, certificate);
    for (i, plan) in plans.iter().enumerate() {
        attitude_table(page, i + 1, plan);
    }
    page.data(
        "plans",
        json!(
            plans
                .iter()
                .map(|p| json!({"design": p.design, "attitudes": p.rows.len()}))
                .collect::<Vec<_>>()
        ),
    );
}

/// Per design: size, information, efficiency against the run's best, the certified bound, and
/// its verdicts, as `design_metrics.csv` holds them.
fn designs_table(page: &mut Page, plans: &[Plan], metrics: &[DesignMetricsRow]) {
    let yes = |b: bool| Cell::text(if b { "yes" } else { "no" });
    let rows = metrics
        .iter()
        .map(|m| {
            let plan = plans.iter().find(|p| p.design == m.design);
            let turn: f64 = plan.map_or(0.0, |p| p.rows.iter().filter_map(|r| r.turn_deg.map(|t| t.0)).sum());
            vec![
                Cell::text(&m.design),
                Cell::text(m.kind.as_str()),
                Cell::count(plan.map_or(0, |p| p.rows.len())),
                Cell::count(m.m),
                Cell::number(m.ln_det_mf.0, 8),
                Cell::maybe(m.d_efficiency.map(|r| r.0), 4),
                Cell::maybe(m.d_efficiency_bound.map(|r| r.0), 4),
                Cell::number(turn, 4),
                yes(m.identifiable),
                Cell::text(format!(
                    "{} ({} of {} trials ok)",
                    if m.works { "yes" } else { "no" },
                    m.check_ok,
                    m.check_trials
                )),
                yes(m.recommended),
            ]
        })
        .collect();
    page.heading("Designs and their certified D-efficiency");
    page.table(Table {
        id: "designs".into(),
        caption: "Each design as design_metrics.csv holds it: ln det M_F ([P1] eq. (12), H in nT), the D-efficiency against the best design of the set, and the certified lower bound of its D-efficiency against every design of as many readings in the attitude box (docs/conventions.md, Certified D-efficiency); the total turn is the sum of designs.csv's turn_deg".into(),
        header: [
            "design",
            "kind",
            "attitudes",
            "readings m",
            "ln det M_F",
            "D-efficiency in the set",
            "certified D-efficiency (at least)",
            "total turn (degrees)",
            "identifiable",
            "works",
            "recommended",
        ]
        .map(String::from)
        .to_vec(),
        rows,
    });
}

/// The certificate of `certificate.csv`, or a note that the set has none.
fn certificate_table(page: &mut Page, certificate: Option<&CertificateRow>) {
    let Some(c) = certificate else {
        page.note("certificate.csv holds no certificate: no design in the box identifies the model, so no efficiency is certified.");
        return;
    };
    let rows = vec![
        vec![
            Cell::text("ln det M(xi) per reading of the approximate design"),
            Cell::number(c.ln_det_per_reading.0, 10),
        ],
        vec![
            Cell::text("largest variance d_max over the box (9 at the optimum)"),
            Cell::number(c.d_max.0, 8),
        ],
        vec![Cell::text("where: roll (degrees)"), Cell::number(c.d_max_roll_deg.0, 6)],
        vec![Cell::text("where: yaw (degrees)"), Cell::number(c.d_max_yaw_deg.0, 6)],
        vec![
            Cell::text("where: pitch (degrees)"),
            Cell::number(c.d_max_pitch_deg.0, 6),
        ],
        vec![
            Cell::text("bound on ln det M* per reading"),
            Cell::number(c.ln_det_bound_per_reading.0, 10),
        ],
        vec![Cell::text("tolerance"), Cell::number(c.tolerance.0, 4)],
        vec![
            Cell::text("converged"),
            Cell::text(if c.converged { "yes" } else { "no" }),
        ],
        vec![Cell::text("rounds"), Cell::count(c.rounds)],
        vec![Cell::text("candidate attitudes"), Cell::count(c.candidates)],
        vec![Cell::text("support points"), Cell::count(c.support_points)],
    ];
    page.table(Table {
        id: "certificate".into(),
        caption: "The certificate (certificate.csv): an approximate design xi of the box and Atwood's bound ln det M* <= ln det M(xi) + 9 ln(d_max / 9), which every design's certified efficiency above rests on".into(),
        header: ["figure", "value"].map(String::from).to_vec(),
        rows,
    });
}

/// Design `index`'s attitudes in visiting order, as `designs.csv` holds them.
fn attitude_table(page: &mut Page, index: usize, plan: &Plan) {
    let angle = |v: f64| Cell {
        text: format!("{v:.1}"),
        value: Some(v),
    };
    let heading = |v: f64| Cell {
        text: crate::rows::compass_text(v, 1),
        value: Some(v),
    };
    let rows = plan
        .rows
        .iter()
        .map(|r| {
            vec![
                Cell::count(r.visit),
                angle(r.roll_deg.0),
                angle(r.pitch_deg.0),
                angle(r.yaw_deg.0),
                heading(r.true_heading_deg.0),
                r.magnetic_heading_deg.map_or_else(|| Cell::text("-"), |h| heading(h.0)),
                Cell::count(r.readings),
                r.turn_deg.map_or_else(|| Cell::text("-"), |t| angle(t.0)),
            ]
        })
        .collect();
    page.table(Table {
        id: format!("attitudes-{index}"),
        caption: format!(
            "Design {}: its {} attitudes in visiting order (designs.csv). Roll > 0 lowers the right side, pitch > 0 raises the nose, [P1]'s yaw > 0 turns the nose west; the headings are the nose's, clockwise from true and from magnetic north",
            plan.design,
            plan.rows.len()
        ),
        header: [
            "visit",
            "roll (degrees)",
            "pitch (degrees)",
            "yaw (degrees)",
            "true heading (degrees)",
            "magnetic heading (degrees)",
            "readings",
            "turn from the previous (degrees)",
        ]
        .map(String::from)
        .to_vec(),
        rows,
    });
}

/// Points of the great-circle arc from unit vector `a` to `b`, `b` included, `a` not.
fn arc(a: [f64; 3], b: [f64; 3]) -> Vec<[f64; 3]> {
    let cos = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]).clamp(-1.0, 1.0);
    let angle = cos.acos();
    let sin = angle.sin();
    if sin < 1e-9 {
        // The same direction, or opposite ones, which no single great circle joins: a chord.
        return vec![b];
    }
    let steps = (angle.to_degrees() / ARC_STEP_DEG).ceil().max(1.0) as usize;
    (1..=steps)
        .map(|k| {
            let t = k as f64 / steps as f64;
            let (u, v) = (((1.0 - t) * angle).sin() / sin, (t * angle).sin() / sin);
            std::array::from_fn(|i| u * a[i] + v * b[i])
        })
        .collect()
}

/// Columns x, y, z of polylines separated by gaps, rounded for drawing.
type Columns = [Vec<Option<f64>>; 3];

fn push(columns: &mut Columns, p: Option<[f64; 3]>) {
    for (i, c) in columns.iter_mut().enumerate() {
        c.push(p.map(|p| drawn(p[i])));
    }
}

fn lines(
    columns: Columns,
    name: &str,
    colour: &'static str,
    width: f64,
    group: usize,
) -> Box<Scatter3D<Option<f64>, Option<f64>, Option<f64>>> {
    let [x, y, z] = columns;
    Scatter3D::new(x, y, z)
        .mode(Mode::Lines)
        .name(name)
        .legend_group(format!("design-{group}"))
        .line(Line::new().color(colour).width(width))
        .hover_info(plotly::common::HoverInfo::Skip)
}

/// The traces of one design: the visiting order, the three strokes of every glyph, the markers.
fn design_traces(plot: &mut Plot, plan: &Plan, group: usize, shown: bool) -> usize {
    let visible = if shown { Visible::True } else { Visible::False };
    let axes: Vec<[[f64; 3]; 3]> = plan.rows.iter().map(body_axes).collect();
    let mut path: Columns = Default::default();
    for (k, a) in axes.iter().enumerate() {
        if k == 0 {
            push(&mut path, Some(a[0]));
        } else {
            for p in arc(axes[k - 1][0], a[0]) {
                push(&mut path, Some(p));
            }
        }
    }
    plot.add_trace(lines(path, "visiting order", "#777777", 3.0, group).visible(visible.clone()));
    for (axis, name, colour, length) in [
        (0, "nose", "#d62728", NOSE),
        (1, "right wing", "#2ca02c", WING),
        (2, "up", "#1f77b4", WING),
    ] {
        let mut strokes: Columns = Default::default();
        for a in &axes {
            let start = a[0];
            push(&mut strokes, Some(start));
            push(
                &mut strokes,
                Some(std::array::from_fn(|i| start[i] + length * a[axis][i])),
            );
            push(&mut strokes, None);
        }
        plot.add_trace(lines(strokes, name, colour, 5.0, group).visible(visible.clone()));
    }
    let text: Vec<String> = plan
        .rows
        .iter()
        .map(|r| {
            format!(
                "{}: visit {} of {}: roll {:.1}, pitch {:.1}, true heading {:.1} degrees, {} readings",
                plan.design,
                r.visit,
                plan.rows.len(),
                r.roll_deg.0,
                r.pitch_deg.0,
                r.true_heading_deg.0,
                r.readings
            )
        })
        .collect();
    let col = |i: usize| axes.iter().map(|a| drawn(a[0][i])).collect::<Vec<f64>>();
    let sizes: Vec<usize> = (0..axes.len()).map(|k| if k == 0 { 9 } else { 5 }).collect();
    plot.add_trace(
        Scatter3D::new(col(0), col(1), col(2))
            .mode(Mode::Markers)
            .name(format!("{} attitudes", plan.design))
            .legend_group(format!("design-{group}"))
            .text_array(text)
            .hover_info(plotly::common::HoverInfo::Text)
            .marker(Marker::new().size_array(sizes).color("#222222"))
            .visible(visible),
    );
    5
}

/// The sphere, the horizon and the compass points, shown with every design.
fn backdrop(plot: &mut Plot) -> usize {
    let (lat, lon) = (12usize, 24usize);
    let mut points = Vec::new();
    for a in 0..=lat {
        let theta = std::f64::consts::PI * a as f64 / lat as f64;
        for b in 0..lon {
            let phi = std::f64::consts::TAU * b as f64 / lon as f64;
            points.push([theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos()]);
        }
    }
    let mut tri = [Vec::new(), Vec::new(), Vec::new()];
    for a in 0..lat {
        for b in 0..lon {
            let (p, q) = (a * lon + b, a * lon + (b + 1) % lon);
            for t in [[p, q, p + lon], [q, q + lon, p + lon]] {
                for i in 0..3 {
                    tri[i].push(t[i]);
                }
            }
        }
    }
    let col = |i: usize| points.iter().map(|p| drawn(p[i])).collect::<Vec<f64>>();
    let [i, j, k] = tri;
    plot.add_trace(
        Mesh3D::new(col(0), col(1), col(2), Some(i), Some(j), Some(k))
            .name("unit sphere of nose directions")
            .opacity(0.35)
            .color("#6baed6")
            .hover_info(plotly::common::HoverInfo::Skip),
    );
    let mut horizon: Columns = Default::default();
    for s in 0..=72 {
        let phi = std::f64::consts::TAU * s as f64 / 72.0;
        push(&mut horizon, Some([phi.sin(), phi.cos(), 0.0]));
    }
    let [x, y, z] = horizon;
    plot.add_trace(
        Scatter3D::new(x, y, z)
            .mode(Mode::Lines)
            .name("horizon")
            .line(Line::new().color("#999999").width(1.5))
            .hover_info(plotly::common::HoverInfo::Skip),
    );
    let r = 1.25;
    plot.add_trace(
        Scatter3D::new(
            vec![0.0, r, 0.0, -r, 0.0],
            vec![r, 0.0, -r, 0.0, 0.0],
            vec![0.0, 0.0, 0.0, 0.0, r],
        )
        .mode(Mode::Text)
        .name("compass")
        .text_array(["N", "E", "S", "W", "up"].map(String::from).to_vec())
        .show_legend(false)
        .hover_info(plotly::common::HoverInfo::Skip),
    );
    3
}

fn plan_plot(plans: &[Plan], shown: usize) -> Plot {
    let mut plot = Plot::new();
    let shared = backdrop(&mut plot);
    let mut per_design = Vec::new();
    for (g, plan) in plans.iter().enumerate() {
        per_design.push(design_traces(&mut plot, plan, g, g == shown));
    }
    let visible = |chosen: usize| -> Vec<bool> {
        let mut v = vec![true; shared];
        for (g, &n) in per_design.iter().enumerate() {
            v.extend(std::iter::repeat_n(g == chosen, n));
        }
        v
    };
    let buttons: Vec<Button> = plans
        .iter()
        .enumerate()
        .map(|(g, p)| {
            Button::new()
                .label(&p.design)
                .method(ButtonMethod::Restyle)
                .args(json!([{"visible": visible(g)}]))
        })
        .collect();
    let axis = |name: &str| Axis::new().title(Title::with_text(name)).range(vec![-1.3, 1.3]);
    plot.set_layout(
        Layout::new()
            .scene(
                LayoutScene::new()
                    .aspect_mode(AspectMode::Cube)
                    // From south-south-east and above: north into the screen, east to the right.
                    .camera(Camera::new().eye(Eye::from((0.6, -1.3, 0.7))))
                    .x_axis(axis("East"))
                    .y_axis(axis("North"))
                    .z_axis(axis("Up")),
            )
            .update_menus(vec![
                UpdateMenu::new().buttons(buttons).active(shown as i32).x(0.0).y(1.0),
            ])
            .margin(Margin::new().left(0).right(0).top(40).bottom(0)),
    );
    plot
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rows::read_csv;

    fn results(set: &str) -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../results")
            .join(set)
            .join("designs.csv")
    }

    /// The nose drawn from the quaternion points at the row's own true heading and pitch, and the
    /// right wing drops by the row's roll: the figure agrees with the table (docs/conventions.md,
    /// sense of the angles), with and without a yaw offset.
    #[test]
    fn glyphs_agree_with_the_rows_heading_pitch_and_roll() {
        for set in ["wu2014", "wu2014-yaw90", "ship"] {
            let path = results(set);
            let rows: Vec<DesignPointRow> = read_csv(&path).unwrap();
            assert!(!rows.is_empty());
            for r in &rows {
                let [nose, right, up] = body_axes(r);
                let tol = 64.0 * f64::EPSILON;
                for (u, v) in [(nose, right), (nose, up), (right, up)] {
                    assert!((u[0] * v[0] + u[1] * v[1] + u[2] * v[2]).abs() < tol, "{set} {r:?}");
                }
                let heading = nose[0].atan2(nose[1]).to_degrees().rem_euclid(360.0);
                let dh = (heading - r.true_heading_deg.0 + 540.0).rem_euclid(360.0) - 180.0;
                // designs.csv rounds its angles to 1e-9 degree.
                assert!(dh.abs() < 1e-7, "{set}: heading {heading} against {r:?}");
                assert!(
                    (nose[2].asin().to_degrees() - r.pitch_deg.0).abs() < 1e-7,
                    "{set}: {r:?}"
                );
                // Roll > 0 lowers the right side: rolled about the pitched nose, the wing's up
                // component is -sin(roll) cos(pitch).
                let (roll, pitch) = (r.roll_deg.0.to_radians(), r.pitch_deg.0.to_radians());
                assert!((right[2] + roll.sin() * pitch.cos()).abs() < 1e-9, "{set}: {r:?}");
            }
            let plans = plans(rows, &path).unwrap();
            assert!(
                plans
                    .iter()
                    .all(|p| p.rows.iter().enumerate().all(|(k, r)| r.visit == k + 1))
            );
        }
    }

    #[test]
    fn arcs_stay_on_the_sphere_and_end_at_the_next_attitude() {
        let a = [1.0, 0.0, 0.0];
        let b = [0.0, 0.6, 0.8];
        let points = arc(a, b);
        assert_eq!(points.len(), 23, "90 degrees in steps of at most 4");
        for p in &points {
            let n = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            assert!((n - 1.0).abs() < 8.0 * f64::EPSILON, "{n}");
        }
        let last = points[points.len() - 1];
        assert!((0..3).all(|i| (last[i] - b[i]).abs() < 4.0 * f64::EPSILON));
        assert_eq!(arc(a, a), vec![a]);
    }

    #[test]
    fn a_plan_out_of_order_or_split_is_refused_naming_the_line() {
        let path = results("wu2014");
        let rows: Vec<DesignPointRow> = read_csv(&path).unwrap();
        let mut swapped = rows.clone();
        swapped.swap(1, 2);
        let e = plans(swapped, &path).unwrap_err().to_string();
        assert!(e.contains("line 3: visit 3"), "{e}");
        let mut split = rows.clone();
        let last = split.len() - 1;
        split[last].design = rows[0].design.clone();
        let e = plans(split, &path).unwrap_err().to_string();
        assert!(e.contains("again after other designs"), "{e}");
        let mut odd = rows.clone();
        odd[2].design = "</script>".into();
        let e = plans(odd, &path).unwrap_err().to_string();
        assert!(e.contains("line 4: design \"</script>\" is not"), "{e}");
        let mut bad = rows;
        bad[4].qw.0 = 2.0;
        let e = plans(bad, &path).unwrap_err().to_string();
        assert!(e.contains("line 6: the quaternion"), "{e}");
    }
}
