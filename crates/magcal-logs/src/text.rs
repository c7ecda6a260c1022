//! Numbers written for a person: in messages, reports, the calibration file's sentences and the
//! command line's tables. The core computes and does not format for screens; its own sentences
//! (verdicts, reasons) follow the same rule.

/// `x` with `digits` significant digits: fixed notation from 1e-4 to 1e7, scientific beyond
/// (`0.0001234`, `48277.79`, `1.234e-10`, `1.000e-300`); `0` for zero, `NaN`, `inf`.
pub fn significant(x: f64, digits: usize) -> String {
    let digits = digits.max(1);
    if !x.is_finite() {
        return format!("{x}");
    }
    if x == 0.0 {
        return "0".to_string();
    }
    let e = x.abs().log10().floor();
    if (-4.0..7.0).contains(&e) {
        let decimals = (digits as f64 - 1.0 - e).max(0.0) as usize;
        format!("{x:.decimals$}")
    } else {
        format!("{x:.*e}", digits - 1)
    }
}

#[cfg(test)]
mod tests {
    use super::significant;

    #[test]
    fn fixed_between_1e_minus_4_and_1e7_scientific_beyond() {
        assert_eq!(significant(0.000_123_4, 4), "0.0001234");
        assert_eq!(significant(48_277.791, 7), "48277.79");
        assert_eq!(significant(1.234e-10, 4), "1.234e-10");
        assert_eq!(significant(1e-300, 4), "1.000e-300");
        assert_eq!(significant(-2.5e7, 3), "-2.50e7");
        assert_eq!(significant(0.0, 5), "0");
        assert_eq!(significant(f64::NAN, 5), "NaN");
        assert_eq!(significant(f64::NEG_INFINITY, 5), "-inf");
        // At least one digit.
        assert_eq!(significant(3.7, 0), "4");
    }
}
