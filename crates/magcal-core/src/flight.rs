//! A simulated ordinary flight: level legs joined by coordinated turns, the kind of log a ship,
//! a fixed-wing aircraft or a heavy multirotor records on a mission (docs/conventions.md
//! "Vector calibration along a track"). It is what the vector calibration along a track is
//! tested on: no manoeuvre for the compass, tilts of at most [`FlightPlan::bank_deg`] plus a
//! little turbulence, every heading visited by the turns, a track long enough for the field to
//! change along it.

use rand::RngExt;
use rand_distr::{Distribution, StandardNormal};

use crate::rng::stream_rng;

/// What to fly.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlightPlan {
    /// Start, degrees north.
    pub lat_deg: f64,
    /// Start, degrees east.
    pub lon_deg: f64,
    /// Mean height, metres above the ellipsoid.
    pub alt_m: f64,
    /// Ground speed, m/s.
    pub speed_m_s: f64,
    /// Length of the track, metres.
    pub length_m: f64,
    /// Bank angle of the turns, degrees.
    pub bank_deg: f64,
    /// Seconds of level flight between turns.
    pub leg_s: f64,
    /// Readings per second.
    pub rate_hz: f64,
    /// Standard deviation of the roll and pitch of turbulence, degrees.
    pub turbulence_deg: f64,
}

impl Default for FlightPlan {
    /// 20 km at 20 m/s from 60 N, 10 E at 300 m, 10-degree turns, 120-s legs, 10 Hz, 1.5
    /// degrees of turbulence.
    fn default() -> Self {
        Self {
            lat_deg: 60.0,
            lon_deg: 10.0,
            alt_m: 300.0,
            speed_m_s: 20.0,
            length_m: 20_000.0,
            bank_deg: 10.0,
            leg_s: 120.0,
            rate_hz: 10.0,
            turbulence_deg: 1.5,
        }
    }
}

/// One instant of a flight.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlightSample {
    /// Seconds from the start.
    pub time_s: f64,
    /// Degrees north.
    pub lat_deg: f64,
    /// Degrees east.
    pub lon_deg: f64,
    /// Metres above the ellipsoid.
    pub alt_m: f64,
    /// NED attitude, degrees: roll (right side down).
    pub roll_deg: f64,
    /// Pitch (nose up), degrees.
    pub pitch_deg: f64,
    /// Heading, clockwise from north, degrees in [0, 360).
    pub heading_deg: f64,
    /// Battery current, amperes: more in the turns and climbs, with the motor's ripple.
    pub current_a: f64,
}

/// The flight of `plan`: legs to the north (20 degrees either side, in turn), each followed by
/// a full turn, right and left in turn (the turns visit every heading); turbulence and current
/// drawn from `seed`.
pub fn fly(plan: &FlightPlan, seed: u64) -> Vec<FlightSample> {
    let mut rng = stream_rng(seed, 0xF1);
    let dt = 1.0 / plan.rate_hz;
    let g = 9.80665;
    // Turn rate of a coordinated turn at the bank angle: g tan(bank) / v.
    let turn_rate = (g * plan.bank_deg.to_radians().tan() / plan.speed_m_s).to_degrees();
    let r_earth = 6_371_008.8;
    let (mut lat, mut lon, mut heading) = (plan.lat_deg, plan.lon_deg, 340.0_f64);
    let (mut travelled, mut t) = (0.0, 0.0);
    // Turbulence as a first-order process of 2 s: slow, as an airframe's.
    let tau = 2.0;
    let keep = (-dt / tau).exp();
    let shake = plan.turbulence_deg * (1.0 - keep * keep).sqrt();
    let (mut gust_roll, mut gust_pitch) = (0.0, 0.0);
    let mut out = Vec::new();
    // Alternate: a leg, then a full turn right (and on to the next leg's course, 40 degrees
    // more) or left (40 degrees less).
    let mut phase_left = plan.leg_s;
    let mut turning = 0.0_f64; // degrees still to turn, signed
    let mut right = true;
    while travelled < plan.length_m {
        gust_roll = keep * gust_roll + shake * <StandardNormal as Distribution<f64>>::sample(&StandardNormal, &mut rng);
        gust_pitch =
            keep * gust_pitch + shake * <StandardNormal as Distribution<f64>>::sample(&StandardNormal, &mut rng);
        let bank = if turning > 0.0 {
            plan.bank_deg
        } else if turning < 0.0 {
            -plan.bank_deg
        } else {
            0.0
        };
        let climb = 2.0 * (t / 90.0 * std::f64::consts::TAU).sin();
        out.push(FlightSample {
            time_s: t,
            lat_deg: lat,
            lon_deg: lon,
            alt_m: plan.alt_m + 40.0 * (t / 300.0 * std::f64::consts::TAU).sin(),
            roll_deg: bank + gust_roll,
            pitch_deg: climb + gust_pitch,
            heading_deg: heading.rem_euclid(360.0),
            current_a: 12.0 + 0.6 * bank.abs() + 1.5 * climb + 0.8 * rng.random::<f64>(),
        });
        // Move along the heading.
        let step = plan.speed_m_s * dt;
        lat += (step * heading.to_radians().cos() / r_earth).to_degrees();
        lon += (step * heading.to_radians().sin() / (r_earth * lat.to_radians().cos())).to_degrees();
        travelled += step;
        t += dt;
        if turning != 0.0 {
            let d = (turn_rate * dt).min(turning.abs()) * turning.signum();
            heading += d;
            turning -= d;
            if turning.abs() < 1e-9 {
                turning = 0.0;
                phase_left = plan.leg_s;
            }
        } else {
            phase_left -= dt;
            if phase_left <= 0.0 {
                turning = if right { 400.0 } else { -400.0 };
                right = !right;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_flight_is_20_km_of_small_tilts_and_every_heading() {
        let f = fly(&FlightPlan::default(), 1);
        // 20 km at 20 m/s and 10 Hz.
        assert_eq!(f.len(), 10_000);
        let max_tilt = f
            .iter()
            .map(|s| s.roll_deg.abs().max(s.pitch_deg.abs()))
            .fold(0.0, f64::max);
        assert!(max_tilt < 17.0, "{max_tilt}");
        let mut sectors = [0usize; 12];
        for s in &f {
            sectors[(s.heading_deg / 30.0) as usize % 12] += 1;
        }
        assert!(sectors.iter().all(|&n| n > 50), "{sectors:?}");
        // The track goes somewhere: several km from the start.
        let last = f.last().unwrap();
        let north_km = (last.lat_deg - 60.0) * 111.2;
        let east_km = (last.lon_deg - 10.0) * 111.2 * 0.5;
        assert!(north_km.hypot(east_km) > 5.0, "{north_km} {east_km}");
    }
}
