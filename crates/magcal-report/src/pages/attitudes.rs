//! The vehicle's attitudes a log visited, against its box: roll against pitch and compass heading
//! against pitch, each reading a point (green inside the box, grey outside), the box drawn as its
//! outline, and the counts of `calibration.json`'s `coverage.flown` in a table.

use plotly::common::{Line, Marker, Mode, Title};
use plotly::layout::Axis;
use plotly::{Layout, Plot, Scatter};

use super::{Cell, Page, Table, drawn, significant};
use crate::rows::log_rows::ResidualRow;
use magcal_logs::flown::{Flown, SECTOR_DEG};

/// Colour of a reading inside the box, and outside it.
const INSIDE: &str = "#2ca02c";
const OUTSIDE: &str = "#8c8c8c";

/// A reading's roll, pitch and heading, where the log gave its attitude.
fn angles(r: &ResidualRow) -> Option<[f64; 3]> {
    Some([r.roll_deg?.0, r.pitch_deg?.0, r.heading_deg?.0])
}

/// Adds the section to `page`, its figures of the readings `drawn`; nothing when the log had no
/// attitudes.
pub fn section(page: &mut Page, drawn: &[ResidualRow], flown: Option<&Flown>, box_from: Option<&str>) {
    let Some(flown) = flown else { return };
    page.heading("Attitudes against the vehicle's box");
    let with: Vec<(usize, [f64; 3])> = drawn.iter().filter_map(|r| angles(r).map(|a| (r.line, a))).collect();
    let inside = |a: [f64; 3]| flown.box_deg.is_none_or(|b| b.contains(a));
    let box_words = match (flown.box_deg, box_from) {
        (Some(_), Some(from)) => format!("the box of {from}, outlined"),
        (Some(_), None) => "the vehicle's box, outlined".to_string(),
        _ => "no box given (--scenario or the box flags draw one)".to_string(),
    };
    page.plot(
        "roll-pitch",
        scatter(&with, &inside, 0, flown.box_deg.map(|b| vec![(b.roll_deg, b.pitch_deg)])),
        460,
        format!(
            "Roll (right side down) against pitch (nose up), degrees, of the readings with an attitude; {box_words}; green inside the box in all three angles, grey outside."
        ),
    );
    let heading_boxes = flown.box_deg.map(|b| {
        let [h0, h1] = b.heading_deg;
        if h1 <= 360.0 {
            vec![([h0, h1], b.pitch_deg)]
        } else {
            vec![([h0, 360.0], b.pitch_deg), ([0.0, h1 - 360.0], b.pitch_deg)]
        }
    });
    page.plot(
        "heading-pitch",
        scatter(&with, &inside, 2, heading_boxes),
        460,
        "Compass heading (clockwise from north) against pitch, degrees, the same readings and box.",
    );
    page.table(flown_table(flown));
    page.table(sectors_table(flown));
}

/// The readings `shown` (line, `[roll, pitch, heading]`) as points of (angle `x` of
/// roll/pitch/heading, pitch), or of (roll, pitch) for `x = 0`; `outlines` the box's rectangles in
/// those axes.
fn scatter(
    shown: &[(usize, [f64; 3])],
    inside: &dyn Fn([f64; 3]) -> bool,
    x: usize,
    outlines: Option<Vec<([f64; 2], [f64; 2])>>,
) -> Plot {
    let mut plot = Plot::new();
    for (is_inside, name, colour) in [(true, "inside the box", INSIDE), (false, "outside the box", OUTSIDE)] {
        let points: Vec<(usize, [f64; 3])> = shown.iter().copied().filter(|(_, a)| inside(*a) == is_inside).collect();
        if points.is_empty() {
            continue;
        }
        let xs: Vec<f64> = points.iter().map(|(_, a)| drawn(a[x])).collect();
        let ys: Vec<f64> = points.iter().map(|(_, a)| drawn(a[1])).collect();
        // The hover names the line and the angle the axes do not show, and beside them the
        // trace (inside or outside the box): per point only the numbers, the words once in the
        // template (a third of the page's bytes otherwise).
        let lines: Vec<usize> = points.iter().map(|(line, _)| *line).collect();
        let (other, template) = if x == 0 {
            (2, "line %{customdata}: roll %{x}, pitch %{y}, heading %{text}")
        } else {
            (0, "line %{customdata}: roll %{text}, pitch %{y}, heading %{x}")
        };
        let text: Vec<String> = points.iter().map(|(_, a)| significant(a[other], 4)).collect();
        plot.add_trace(
            Scatter::new(xs, ys)
                .mode(Mode::Markers)
                .name(name)
                .custom_data(lines)
                .text_array(text)
                .hover_template(template)
                .marker(Marker::new().size(3).color(colour).opacity(0.6)),
        );
    }
    for (k, ([x0, x1], [y0, y1])) in outlines.into_iter().flatten().enumerate() {
        plot.add_trace(
            Scatter::new(vec![x0, x1, x1, x0, x0], vec![y0, y0, y1, y1, y0])
                .mode(Mode::Lines)
                .name("the box")
                .show_legend(k == 0)
                .line(Line::new().color("#d62728").width(2.0)),
        );
    }
    let x_title = if x == 0 {
        "roll (degrees)"
    } else {
        "compass heading (degrees)"
    };
    let x_range = if x == 0 { [-180.0, 180.0] } else { [0.0, 360.0] };
    let x_axis = Axis::new()
        .title(Title::with_text(x_title))
        .range(x_range.to_vec())
        .dtick(30.0);
    plot.set_layout(
        Layout::new()
            .x_axis(x_axis)
            .y_axis(
                Axis::new()
                    .title(Title::with_text("pitch (degrees)"))
                    .range(vec![-90.0, 90.0])
                    .dtick(30.0),
            )
            .margin(plotly::layout::Margin::new().left(60).right(20).top(20).bottom(50)),
    );
    plot
}

/// The readings of `coverage.flown` per heading sector, a column each.
fn sectors_table(f: &Flown) -> Table {
    let mut header = vec!["heading (degrees)".to_string()];
    header.extend(
        (0..f.heading_sectors.len())
            .map(|i| format!("{:.0}-{:.0}", i as f64 * SECTOR_DEG, (i + 1) as f64 * SECTOR_DEG)),
    );
    let mut row = vec![Cell::text("readings")];
    row.extend(f.heading_sectors.iter().map(|n| Cell::count(*n)));
    Table {
        id: "flown-sectors".into(),
        caption: "Readings with an attitude per heading sector of the nose, from 0 (north of the log's attitude frame)"
            .into(),
        header,
        rows: vec![row],
    }
}

/// `coverage.flown` of calibration.json as a table.
fn flown_table(f: &Flown) -> Table {
    let spread = |name: &str, v: &[f64; 5]| {
        let mut row = vec![Cell::text(name)];
        row.extend(v.iter().map(|x| Cell::number(*x, 4)));
        row
    };
    let mut rows = vec![spread("roll", &f.roll_deg), spread("pitch", &f.pitch_deg)];
    rows.push(vec![
        Cell::text("readings with an attitude"),
        Cell::count(f.with_attitude),
    ]);
    if let Some(n) = f.in_box {
        rows.push(vec![Cell::text("of them inside the box"), Cell::count(n)]);
    }
    Table {
        id: "flown".into(),
        caption: "Attitudes visited, degrees (all readings with an attitude): minimum, 5th percentile, median, 95th percentile, maximum".into(),
        header: ["", "min", "p5", "median", "p95", "max"].map(String::from).to_vec(),
        rows,
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_box_in_degrees_holds_what_the_box_in_yaw_holds() {
        use magcal_core::AttitudeBox;
        use magcal_logs::flown::Bounds;
        for (yaw, offset) in [
            ([0.0, 90.0], 90.0),
            ([-20.0, 30.0], 0.0),
            ([-180.0, 180.0], 37.0),
            ([100.0, 250.0], -12.5),
        ] {
            let bounds = AttitudeBox::from_degrees([-5.0, 5.0], yaw, [-20.0, 20.0]).unwrap();
            let b = Bounds {
                bounds: &bounds,
                yaw_offset_deg: offset,
            };
            let d = b.degrees();
            for roll in [-5.1, -5.0, 0.0, 4.999_999_999_9, 5.2] {
                for pitch in [-20.5, -20.0, 3.0, 20.0, 21.0] {
                    for h in 0..720 {
                        let a = [roll, pitch, f64::from(h) * 0.5];
                        assert_eq!(d.contains(a), b.contains(a), "{yaw:?} {offset} {a:?}");
                    }
                }
            }
        }
    }
}
