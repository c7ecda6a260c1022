//! The cells of magcal's CSV files and screens: numbers written exactly ([`Real`]) or to seven
//! significant digits ([`Derived`]), a trial's outcome ([`Status`]), a compass heading.

use magcal_core::CalibrationStatus;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// A number in a CSV cell, written with `{}` (shortest round trip, never an exponent: the format
/// of the committed baselines) and read back exactly; `inf`, `-inf` and `NaN` round-trip too.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Real(pub f64);

impl Serialize for Real {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(&self.0)
    }
}

impl<'de> Deserialize<'de> for Real {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        f64::deserialize(d).map(Real)
    }
}

impl From<f64> for Real {
    fn from(x: f64) -> Self {
        Self(x)
    }
}

/// A number derived from a reading (a calibrated field, its norm and residual, an angle) in a CSV
/// cell: 7 significant digits, never an exponent. A reading's relative error is 1e-4 at best (a
/// 16-bit sensor), so the 7th digit is far below it, and a long log's residual file is about
/// half the size it would be at 17 digits. Read back as any number.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Derived(pub f64);

impl Derived {
    /// Significant digits written.
    pub const DIGITS: i32 = 7;
}

impl Serialize for Derived {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let x = self.0;
        if !x.is_finite() || x == 0.0 {
            return s.collect_str(&x);
        }
        // Decimals that leave DIGITS significant ones; the rounding may carry into one more
        // integer digit (9999999.5 -> 10000000), which is still 7 significant digits.
        let decimals = (Self::DIGITS - 1 - x.abs().log10().floor() as i32).clamp(0, 40) as usize;
        let mut buf = [0u8; 48];
        if let Some(text) = fixed_by_integer(x, decimals, &mut buf) {
            return s.serialize_str(text);
        }
        s.serialize_str(&fixed_by_format(x, decimals))
    }
}

/// `x` with `decimals` digits after the point, correctly rounded, then its zeros after the point
/// and a bare point trimmed: the reference, by the standard library's exact formatting.
fn fixed_by_format(x: f64, decimals: usize) -> String {
    let text = format!("{x:.decimals$}");
    if text.contains('.') {
        text.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        text
    }
}

/// [`fixed_by_format`] by integer arithmetic, five times faster (a long log's residual file holds
/// eight such numbers per reading), or `None` where it cannot be sure of the same text. The
/// product `|x| 10^decimals` (`10^decimals` exact up to `10^22`) is rounded once, within half
/// an ulp of the exact one; where its fraction is more than an ulp from one half, the exact
/// product rounds to the same integer, so the digits are those of the correctly rounded text.
/// Near a tie, or out of range, the standard library decides.
fn fixed_by_integer(x: f64, decimals: usize, buf: &mut [u8; 48]) -> Option<&str> {
    const POW10: [f64; 23] = [
        1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19,
        1e20, 1e21, 1e22,
    ];
    let scaled = x.abs() * *POW10.get(decimals)?;
    if scaled >= 4_503_599_627_370_496.0 {
        return None;
    }
    let floor = scaled.floor();
    // Exact: both are multiples of the ulp of `scaled`.
    let fraction = scaled - floor;
    if (fraction - 0.5).abs() <= f64::EPSILON * scaled {
        return None;
    }
    let mut n = floor as u64 + u64::from(fraction > 0.5);
    // Digits from the right: the decimals (their trailing zeros dropped), the point, the
    // integer part (at least "0"), the sign.
    let mut at = buf.len();
    let mut put = |b: u8, at: &mut usize| {
        *at -= 1;
        buf[*at] = b;
    };
    let mut significant = false;
    for _ in 0..decimals {
        let digit = (n % 10) as u8;
        n /= 10;
        significant |= digit != 0;
        if significant {
            put(b'0' + digit, &mut at);
        }
    }
    if significant {
        put(b'.', &mut at);
    }
    loop {
        put(b'0' + (n % 10) as u8, &mut at);
        n /= 10;
        if n == 0 {
            break;
        }
    }
    if x.is_sign_negative() {
        put(b'-', &mut at);
    }
    std::str::from_utf8(&buf[at..]).ok()
}

impl<'de> Deserialize<'de> for Derived {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        f64::deserialize(d).map(Derived)
    }
}

/// A trial's calibration status, by the name [`CalibrationStatus::as_str`] gives it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Status(pub CalibrationStatus);

impl Default for Status {
    fn default() -> Self {
        Self(CalibrationStatus::Ok)
    }
}

impl Serialize for Status {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.0.as_str())
    }
}

impl<'de> Deserialize<'de> for Status {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let text = String::deserialize(d)?;
        CalibrationStatus::from_name(&text)
            .map(Status)
            .ok_or_else(|| serde::de::Error::custom(format!("{text:?} is not a trial status")))
    }
}

/// A compass heading in degrees `[0, 360)` shown with `decimals` digits: a value that rounds up
/// to 360 is shown as 0, as a compass reads it.
pub fn compass_text(degrees: f64, decimals: usize) -> String {
    let text = format!("{degrees:.decimals$}");
    match text.parse::<f64>() {
        Ok(v) if v >= 360.0 => format!("{:.decimals$}", v - 360.0),
        _ => text,
    }
}

/// The line above a table of headings: the declination used and where it comes from, or why
/// there is no magnetic heading.
pub fn declination_line(declination_deg: Option<f64>, source: &str) -> String {
    match declination_deg {
        Some(d) => format!("declination {d:+.2} deg ({source}); magnetic heading = true heading - declination"),
        None => format!(
            "declination undefined: the field ({source}) has no horizontal component, so a compass has no heading; true headings only"
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The integer path writes the standard library's text wherever it answers: on values of
    /// every magnitude, on ties and the floats beside them, and on the carry to one more digit.
    #[test]
    fn derived_numbers_by_integers_are_the_formatted_text() {
        use rand::RngExt;
        let mut rng = magcal_core::rng::stream_rng(7, 0);
        let mut answered = 0usize;
        let mut check = |x: f64| {
            let decimals = (Derived::DIGITS - 1 - x.abs().log10().floor() as i32).clamp(0, 40) as usize;
            let mut buf = [0u8; 48];
            if let Some(text) = fixed_by_integer(x, decimals, &mut buf) {
                assert_eq!(text, fixed_by_format(x, decimals), "{x:e} at {decimals} decimals");
                answered += 1;
            }
        };
        for _ in 0..200_000 {
            let exponent = rng.random_range(-20.0..16.0);
            let x = 10f64.powf(exponent) * if rng.random::<bool>() { -1.0 } else { 1.0 };
            check(x);
        }
        for k in 0..20_000 {
            // Halves at the 7th digit and their neighbours, and values that carry.
            let tie = (1_000_000.0 + f64::from(k)) + 0.5;
            for scale in [1e-3, 1e-1, 1.0, 10.0, 1e3] {
                let t = tie * scale;
                for x in [t, t.next_up(), t.next_down(), -t] {
                    check(x);
                }
            }
            check(9_999_999.5 - f64::from(k) * 1e-3);
        }
        assert!(answered > 150_000, "the integer path answered {answered} times");
    }
}
