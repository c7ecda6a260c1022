//! The sphere of field directions as the pages draw it: MotionCal's 100 regions of equal area
//! coloured by the readings in each ([`coverage_plot`]), on which other figures mark directions.

use magcal_core::Vec3;
use magcal_core::log_fit::motioncal_region;
use plotly::layout::{AspectMode, LayoutScene};
use plotly::{Layout, Mesh3D, Plot};

use super::drawn;

/// The columns of `points` and of `triangles`, as plotly's mesh takes them.
pub fn mesh(points: &[[f64; 3]], triangles: &[[usize; 3]]) -> Box<Mesh3D<f64, f64, f64>> {
    let col = |i: usize| points.iter().map(|p| drawn(p[i])).collect::<Vec<f64>>();
    let tri = |i: usize| Some(triangles.iter().map(|t| t[i]).collect::<Vec<usize>>());
    Mesh3D::new(col(0), col(1), col(2), tri(0), tri(1), tri(2))
}

/// The colour of a region holding `count` readings: red none, orange one, yellow two, green
/// three or more (the steps of MotionCal's gap error: 1, 0.2, 0.01 and 0).
pub fn region_colour(count: usize) -> &'static str {
    match count {
        0 => "#d62728",
        1 => "#ff7f0e",
        2 => "#f2c94c",
        _ => "#2ca02c",
    }
}

/// The unit sphere cut into MotionCal's 100 regions, each coloured by its count of readings, in
/// a scene with equal scales and no legend: one mesh (one WebGL draw, not a hundred), each region
/// a patch of 3 x 4 cells of its own vertices, every triangle coloured by the region's count and
/// every vertex hovering its region.
pub fn coverage_plot(counts: &[usize; 100]) -> Plot {
    let (lats, lons) = (3usize, 4usize);
    let mut points = Vec::new();
    let mut triangles = Vec::new();
    let mut colours = Vec::new();
    let (mut regions, mut readings) = (Vec::new(), Vec::new());
    for (index, &count) in counts.iter().enumerate() {
        let region = motioncal_region(index);
        let first = points.len();
        for a in 0..=lats {
            let s = region.sin_latitude[0] + (region.sin_latitude[1] - region.sin_latitude[0]) * a as f64 / lats as f64;
            let c = (1.0 - s * s).max(0.0).sqrt();
            for b in 0..=lons {
                let t = region.turn[0] + (region.turn[1] - region.turn[0]) * b as f64 / lons as f64;
                let phi = std::f64::consts::TAU * t;
                points.push([c * phi.cos(), c * phi.sin(), s]);
                regions.push(index);
                readings.push(count);
            }
        }
        for a in 0..lats {
            for b in 0..lons {
                let p = first + a * (lons + 1) + b;
                triangles.push([p, p + 1, p + lons + 1]);
                triangles.push([p + 1, p + lons + 2, p + lons + 1]);
                colours.extend([region_colour(count); 2]);
            }
        }
    }
    let patches = mesh(&points, &triangles)
        .face_color(colours)
        // Per vertex its region and count as numbers, the words once.
        .custom_data(regions)
        .text_array(readings.iter().map(ToString::to_string).collect())
        .hover_template("region %{customdata}: %{text} readings<extra></extra>")
        .name("regions")
        .flat_shading(true);
    let mut plot = Plot::new();
    plot.add_trace(patches);
    plot.set_layout(
        Layout::new()
            .show_legend(false)
            .scene(LayoutScene::new().aspect_mode(AspectMode::Data))
            .margin(plotly::layout::Margin::new().left(0).right(0).top(30).bottom(0)),
    );
    plot
}

/// The direction of `v` (a unit vector), or `None` for a vector of no length or not finite.
pub fn direction(v: Vec3) -> Option<Vec3> {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    (n > 0.0 && n.is_finite()).then(|| v.map(|c| c / n))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_direction_is_a_unit_vector_and_a_zero_or_infinite_vector_has_none() {
        let d = direction([3.0, 0.0, -4.0]).unwrap();
        assert_eq!(d, [0.6, 0.0, -0.8]);
        assert_eq!(direction([0.0; 3]), None);
        assert_eq!(direction([f64::INFINITY, 0.0, 0.0]), None);
        assert_eq!(direction([f64::NAN, 1.0, 0.0]), None);
    }

    #[test]
    fn the_coverage_sphere_is_one_mesh_with_a_patch_per_region_coloured_by_its_count() {
        let mut counts = [3usize; 100];
        counts[0] = 0;
        counts[99] = 1;
        let json = coverage_plot(&counts).to_json();
        assert_eq!(json.matches("\"type\":\"mesh3d\"").count(), 1);
        // 20 vertices and 24 triangles a region; each vertex hovers its region and count.
        let plot: serde_json::Value = serde_json::from_str(&json).unwrap();
        let trace = &plot["data"][0];
        let regions = trace["customdata"].as_array().unwrap();
        let readings = trace["text"].as_array().unwrap();
        assert_eq!((regions.len(), readings.len()), (100 * 20, 100 * 20));
        assert!((0..20).all(|v| regions[v] == 0 && readings[v] == "0"));
        assert!((0..20).all(|v| regions[99 * 20 + v] == 99 && readings[99 * 20 + v] == "1"));
        assert_eq!(
            trace["hovertemplate"],
            "region %{customdata}: %{text} readings<extra></extra>"
        );
        assert_eq!(json.matches(region_colour(0)).count(), 24);
        assert_eq!(json.matches(region_colour(1)).count(), 24);
        assert_eq!(json.matches(region_colour(3)).count(), 98 * 24);
    }
}
