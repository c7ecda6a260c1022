//! `magcal live` guiding a quad in closed loop over MAVLink: a test vehicle whose calibration in
//! force `live` must ask for flies the attitudes the page tells it, within a quad's box, until
//! live says DONE and sends the calibration. The plan must hold still between the moments it is
//! flown or superseded, and what the vehicle then holds must meet the heading budget against the
//! sensor's truth.

use std::net::UdpSocket;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use magcal_core::budget::{BudgetGrid, PAPER_TO_FRD, Tilts, quantile};
use magcal_core::small::Mat3;
use magcal_core::wmm::{Model, Site, field_ned};
use mavlink::dialects::ardupilotmega::{ATTITUDE_DATA, MavMessage, RAW_IMU_DATA};
use rand_distr::{Distribution, Normal};
use serde_json::Value;
use tempfile::TempDir;

use crate::live::{OFS, finish_live, frame, json_of, page_status, start_live_lines, udp_address};
use crate::live_send::{autopilot, heartbeat, in_force};

/// The quad's sensor, forward, right, down, mGauss: `r = K b + BIAS` (the readings before the
/// calibration in force, [`OFS`], is applied).
const K: Mat3 = [[1.04, 0.02, -0.01], [0.02, 0.97, 0.03], [-0.01, 0.03, 1.02]];
const BIAS: [f64; 3] = [120.0, -80.0, 60.0];
/// The sensor's noise, mGauss (1 mGauss: 100 nT).
const NOISE: f64 = 1.0;
/// The quad's box: roll and pitch within 30 degrees, any heading.
const TILT: f64 = 30.0;
const BUDGET: f64 = 1.0;
/// Ticks a second (an `ATTITUDE` and a `RAW_IMU` each), and the quad's turn rate, deg/s.
const RATE: f64 = 50.0;
const TURN: f64 = 60.0;

/// Where it flies: Delft, at the end of 2026.
const SITE: Site = Site {
    lat_deg: 52.0,
    lon_deg: 4.37,
    alt_m: 0.0,
    year: 2026.9,
};

/// The body field (forward, right, down) at roll, pitch and yaw (degrees) of the NED field `n`:
/// `C^T n`, `C = Rz(yaw) Ry(pitch) Rx(roll)` turning the body into NED.
fn body_field(n: [f64; 3], roll: f64, pitch: f64, yaw: f64) -> [f64; 3] {
    let (sr, cr) = roll.to_radians().sin_cos();
    let (sp, cp) = pitch.to_radians().sin_cos();
    let (sy, cy) = yaw.to_radians().sin_cos();
    // Rz^T n, then Ry^T, then Rx^T.
    let a = [cy * n[0] + sy * n[1], -sy * n[0] + cy * n[1], n[2]];
    let b = [cp * a[0] - sp * a[2], a[1], sp * a[0] + cp * a[2]];
    [b[0], cr * b[1] + sr * b[2], -sr * b[1] + cr * b[2]]
}

/// `from` moved towards `to` by at most `step` degrees (the short way round for a heading).
fn towards(from: f64, to: f64, step: f64, wraps: bool) -> f64 {
    let mut d = to - from;
    if wraps {
        d = (d + 540.0).rem_euclid(360.0) - 180.0;
    }
    from + d.clamp(-step, step)
}

/// The 95th percentile of the heading error over the quad's box that a calibration `b = p (r -
/// bias)` of the sensor leaves (the attitudes of docs/conventions.md "Heading budget").
fn true_heading_p95(p: &Mat3, bias: [f64; 3], magnitude: f64, inclination: f64) -> f64 {
    let grid = BudgetGrid::new(inclination, Tilts::of_box([-TILT, TILT], [-TILT, TILT]), &PAPER_TO_FRD);
    let mut errors = Vec::new();
    grid.errors_into((&K, BIAS), magnitude, (p, bias), &mut errors);
    quantile(&mut errors, 0.95)
}

/// The correction the vehicle applies with the parameters it holds, as `b = p (r - bias)`:
/// `m = D (r + OFS)` (docs/conventions.md "Reading ArduPilot logs"; a common scale leaves the
/// heading as it is).
fn held_correction(params: &[(String, f32)]) -> (Mat3, [f64; 3]) {
    let get = |name: &str| {
        f64::from(
            params
                .iter()
                .rev()
                .find(|(n, _)| n == name)
                .unwrap_or_else(|| panic!("{name} not held: {params:?}"))
                .1,
        )
    };
    let (dx, dy, dz) = (get("COMPASS_DIA_X"), get("COMPASS_DIA_Y"), get("COMPASS_DIA_Z"));
    let (ox, oy, oz) = (get("COMPASS_ODI_X"), get("COMPASS_ODI_Y"), get("COMPASS_ODI_Z"));
    let d = [[dx, ox, oy], [ox, dy, oz], [oy, oz, dz]];
    let ofs = ["X", "Y", "Z"].map(|a| get(&format!("COMPASS_OFS_{a}")));
    (d, ofs.map(|o| -o))
}

#[test]
fn a_quad_flying_the_plan_with_its_calibration_unknown_reaches_done_and_holds_what_meets_the_budget() {
    let tmp = TempDir::new().unwrap();
    let out = tmp.path().join("out");
    let ned_nt = field_ned(Model::Wmm2025, &SITE).unwrap();
    let ned = ned_nt.map(|v| v / 100.0);
    let magnitude = ned.iter().map(|v| v * v).sum::<f64>().sqrt();
    let inclination = magcal_core::field::inclination_deg(ned);
    let tilt = format!("-{TILT},{TILT}");
    let (mut child, first, stderr) = start_live_lines(
        &[
            "udpin:127.0.0.1:0",
            "--site",
            &format!("{},{},{}", SITE.lat_deg, SITE.lon_deg, SITE.alt_m),
            "--date",
            &SITE.year.to_string(),
            &format!("--roll={tilt}"),
            &format!("--pitch={tilt}"),
            "--heading-budget",
            &BUDGET.to_string(),
            "--every",
            "0.5",
            "--page",
            "0",
            "--send",
            "--json",
            "--out",
            out.to_str().unwrap(),
        ],
        2,
    );
    let addr = udp_address(&first[0]);
    let page = first[1]
        .strip_prefix("live: page at http://")
        .unwrap_or_else(|| panic!("{first:?}"))
        .trim_end_matches('/')
        .to_string();
    // The vehicle pushes nothing of its calibration: live has to ask for it.
    let stop = Arc::new(AtomicBool::new(false));
    let vehicle = UdpSocket::bind("127.0.0.1:0").unwrap();
    let pilot = autopilot(
        vehicle.try_clone().unwrap(),
        in_force(1800.0),
        true,
        false,
        Arc::clone(&stop),
    );
    let mut rng = magcal_core::rng::stream_rng(57, 0);
    let (noise, wobble) = (Normal::new(0.0, NOISE).unwrap(), Normal::new(0.0, 1.0).unwrap());
    let (mut roll, mut pitch, mut yaw) = (0.0f64, 0.0f64, 0.0f64);
    let (mut target, mut heads, mut last) = (None::<[f64; 3]>, Vec::new(), Value::Null);
    let (started, mut last_poll) = (Instant::now(), Instant::now());
    let mut tick = 0u32;
    let step = TURN / RATE;
    let ended = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        assert!(
            started.elapsed() < Duration::from_secs(120),
            "not done in 120 s: {last}"
        );
        let t = f64::from(tick) / RATE;
        if t < 8.0 {
            // Lift-off: level, one turn round at 45 deg/s.
            yaw = (45.0 * t + 180.0).rem_euclid(360.0) - 180.0;
        } else if let Some([r, p, h]) = target {
            let near = |a: f64, b: f64| ((a - b + 540.0).rem_euclid(360.0) - 180.0).abs() <= 3.0 * step;
            if near(roll, r) && near(pitch, p) && near(yaw, h) {
                // Holding the attitude asked, as a quad holds it in gusts.
                roll = r + wobble.sample(&mut rng);
                pitch = p + wobble.sample(&mut rng);
                yaw = h + 2.0 * wobble.sample(&mut rng);
            } else {
                roll = towards(roll, r, step, false);
                pitch = towards(pitch, p, step, false);
                yaw = towards(yaw, h, step, true);
            }
        }
        let b = body_field(ned, roll, pitch, yaw);
        // ArduPilot's int16 cast truncates towards zero.
        let mag: [i16; 3] = std::array::from_fn(|a| {
            let r: f64 = (0..3).map(|c| K[a][c] * b[c]).sum::<f64>() + BIAS[a] + noise.sample(&mut rng);
            (r + f64::from(OFS[a])) as i16
        });
        let t_ms = 1000 + 20 * tick;
        let mut datagram = Vec::new();
        if tick.is_multiple_of(50) {
            datagram.extend(heartbeat(1));
        }
        datagram.extend(frame(&MavMessage::ATTITUDE(ATTITUDE_DATA {
            time_boot_ms: t_ms,
            roll: roll.to_radians() as f32,
            pitch: pitch.to_radians() as f32,
            yaw: yaw.to_radians() as f32,
            ..ATTITUDE_DATA::default()
        })));
        datagram.extend(frame(&MavMessage::RAW_IMU(RAW_IMU_DATA {
            time_usec: u64::from(t_ms) * 1000,
            xmag: mag[0],
            ymag: mag[1],
            zmag: mag[2],
            ..RAW_IMU_DATA::default()
        })));
        vehicle.send_to(&datagram, &addr).unwrap();
        tick += 1;
        std::thread::sleep(Duration::from_secs_f64(1.0 / RATE));
        if last_poll.elapsed() >= Duration::from_millis(300) {
            last_poll = Instant::now();
            // Live ends at DONE with --send: its page may be gone between two looks.
            let Some(body) = page_status(&page) else {
                continue;
            };
            last = serde_json::from_slice(&body).unwrap();
            let head = &last["plan"][0];
            if let (Some(r), Some(p), Some(h)) = (
                head["roll_deg"].as_f64(),
                head["pitch_deg"].as_f64(),
                head["true_heading_deg"].as_f64(),
            ) {
                // The direction the page draws is the field the compass reads there, in its own
                // axes (forward, right, down), not [P1]'s.
                let u: [f64; 3] = serde_json::from_value(head["field_direction"].clone()).unwrap();
                let b = body_field(ned, r, p, h);
                let n = b.iter().map(|v| v * v).sum::<f64>().sqrt();
                for i in 0..3 {
                    assert!((u[i] - b[i] / n).abs() < 1e-6, "{head}: {b:?}");
                }
                if target != Some([r, p, h]) {
                    heads.push((
                        tick,
                        [r, p, h],
                        last["targets_flown"].clone(),
                        last["plans_superseded"].clone(),
                    ));
                    target = Some([r, p, h]);
                }
            }
        }
    };
    let (live, lines, code) = finish_live(child, &stderr);
    stop.store(true, Ordering::Relaxed);
    let heard = pilot.join().unwrap();
    assert_eq!((code, ended.code()), (0, Some(0)), "{lines:#?}");
    // Asked for its calibration, and sent the new one, every value held as sent.
    assert!(heard.reads.iter().any(|r| r == "COMPASS_OFS_X"), "{heard:?}");
    let sent = live["sent"]["parameters"].as_array().unwrap().len();
    assert!(
        sent >= 9 && live["sent"]["equal"].as_array().unwrap().len() == sent,
        "{}",
        live["sent"]
    );
    // The plan moved only when flown or superseded: every change the vehicle saw is counted,
    // and superseded at most once per target flown, plus one.
    let (flown, superseded) = (
        live["targets_flown"].as_u64().unwrap(),
        live["plans_superseded"].as_u64().unwrap(),
    );
    let changes = heads.len().saturating_sub(1) as u64;
    assert!(changes <= flown + superseded, "{changes} changes: {heads:?} {live}");
    assert!(
        superseded <= flown + 1,
        "{flown} flown, {superseded} superseded: {heads:?}"
    );
    // Each target asked was within the quad's box.
    for (_, [r, p, _], _, _) in &heads {
        assert!(r.abs() <= TILT + 1e-9 && p.abs() <= TILT + 1e-9, "{heads:?}");
    }
    // DONE is the budget met: in the fit's words, and against the truth with what the vehicle
    // now holds (the symmetric soft iron and offsets `export --to ardupilot` writes).
    let cal = json_of(&out.join("calibration.json"));
    assert_eq!(cal["usable"], true);
    let predicted = cal["heading_budget"]["predicted_deg"].as_f64().unwrap();
    assert!(predicted <= BUDGET, "{predicted}");
    let (d, o) = held_correction(&heard.sets);
    let held = true_heading_p95(&d, o, magnitude, inclination);
    // Before: the calibration in force (offsets only, and wrong) left this much.
    let before = true_heading_p95(
        &magcal_core::budget::IDENTITY,
        OFS.map(|v| -f64::from(v)),
        magnitude,
        inclination,
    );
    // The prediction is a 95/95 tolerance, but DONE is the first fit whose prediction meets the
    // budget, and a first passage picks the fits that happen to predict little: in 12 runs the
    // vehicle held 0.12-1.56 degrees, 2 of them above the budget (the live chapter of the guide).
    // Twice the budget is a miss that stopping rule does not explain.
    assert!(held <= 2.0 * BUDGET, "held {held}, predicted {predicted}");
    assert!(before > 10.0 * BUDGET, "{before}");
    eprintln!(
        "quad: {} s, {} readings, {} heads, {flown} flown, {superseded} superseded, predicted {predicted:.3} deg, held {held:.3}, before {before:.1}",
        tick / 50,
        live["readings"],
        heads.len()
    );
}
