//! Numbers as the tools print them: one rule for every report, table and console line.

/// `x` to three significant figures: plain from 0.01 to 999 999 (`0.0886`, `2.14`, `605`, `24 600` as
/// `24600`), else in scientific notation (`1.23e-4`: no more than four digits after the point); `-` for a value that is not finite.
pub fn sig3(x: f64) -> String {
    if !x.is_finite() {
        return "-".into();
    }
    if x == 0.0 {
        return "0".into();
    }
    // Rounded first, so that a value rounding up across a decade (9.996) is printed in the next one (10.0).
    let r: f64 = format!("{x:.2e}").parse().unwrap_or(x);
    let mag = r.abs().log10().floor();
    if !(-2.0..6.0).contains(&mag) {
        return format!("{x:.2e}");
    }
    let decimals = (2.0 - mag).max(0.0) as usize;
    format!("{r:.decimals$}")
}

#[cfg(test)]
mod tests {
    use super::sig3;

    #[test]
    fn three_significant_figures() {
        let cases = [
            (0.0886, "0.0886"),
            (24641.5, "24600"),
            (604.8, "605"),
            (2.1428, "2.14"),
            (0.5, "0.500"),
            (1.5e-5, "1.50e-5"),
            (0.000_123_4, "1.23e-4"),
            (0.009_996, "0.0100"),
            (2.048, "2.05"),
            (12.345, "12.3"),
            (3276.8, "3280"),
            (65_536.0, "65500"),
            (123_456.0, "123000"),
            (-0.6, "-0.600"),
            (0.0, "0"),
            (9.996, "10.0"),
            (-0.0625, "-0.0625"),
            (62.499_999_999_999_94, "62.5"),
            (999_999.0, "1.00e6"),
            (f64::NAN, "-"),
        ];
        for (x, want) in cases {
            assert_eq!(sig3(x), want, "{x}");
        }
    }
}
