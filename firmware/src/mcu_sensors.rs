//! The MCU's own temperature and analog supply (VDDA) from its ADC's internal channels, with the factory
//! calibration words the STM32F405 keeps in system memory (DS8626, "Temperature sensor characteristics" and
//! "Embedded reference voltage": TS_CAL1 at 30 °C, TS_CAL2 at 110 °C and VREFINT_CAL, all taken at VDDA = 3.3 V).
//! The conversion is plain integer arithmetic, here so that the host tests check it; `board.rs` reads the ADC.

/// The factory calibration words (12-bit ADC codes at VDDA = 3.3 V).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FactoryCal {
    /// Temperature sensor at 30 °C.
    pub ts_cal1: u16,
    /// Temperature sensor at 110 °C.
    pub ts_cal2: u16,
    /// VREFINT.
    pub vrefint_cal: u16,
}

/// VDDA at calibration, mV.
const CAL_VDDA_MV: i64 = 3300;

/// (MCU temperature in 0.01 °C, VDDA in mV) from raw codes of the temperature sensor and VREFINT; `None` for codes
/// that cannot be real (VREFINT 0, calibration points not increasing, a result out of range).
pub fn convert(ts_raw: u16, vrefint_raw: u16, cal: FactoryCal) -> Option<(i16, u16)> {
    let (ts, vref) = (i64::from(ts_raw), i64::from(vrefint_raw));
    let (c1, c2, vcal) = (
        i64::from(cal.ts_cal1),
        i64::from(cal.ts_cal2),
        i64::from(cal.vrefint_cal),
    );
    if vref == 0 || c2 <= c1 {
        return None;
    }
    // All operands < 2¹⁶ · 2¹⁴: no i64 operation below can overflow.
    let vdda_mv = CAL_VDDA_MV.checked_mul(vcal)?.checked_div(vref)?;
    // The sensor's code as it would read at 3.3 V, in 1/1000 counts, then linear between the calibration points.
    let ts_milli = ts
        .checked_mul(vdda_mv)?
        .checked_mul(1000)?
        .checked_div(CAL_VDDA_MV)?;
    let above_cal1 = ts_milli.checked_sub(c1.checked_mul(1000)?)?;
    let cdeg = above_cal1
        .checked_mul(8000)?
        .checked_div(c2.checked_sub(c1)?.checked_mul(1000)?)?
        .checked_add(3000)?;
    Some((i16::try_from(cdeg).ok()?, u16::try_from(vdda_mv).ok()?))
}

// Test code may panic: a failed assertion is how a test reports.
#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::arithmetic_side_effects)]
mod tests {
    use super::*;

    const CAL: FactoryCal = FactoryCal {
        ts_cal1: 955,
        ts_cal2: 1203,
        vrefint_cal: 1500,
    };

    /// The f64 model: VDDA = 3.3 V · CAL / raw; T = 30 + 80 · (ts · VDDA / 3.3 − cal1) / (cal2 − cal1).
    fn model(ts: u16, vref: u16) -> (f64, f64) {
        let vdda = 3300.0 * f64::from(CAL.vrefint_cal) / f64::from(vref);
        let ts33 = f64::from(ts) * vdda / 3300.0;
        let t =
            30.0 + 80.0 * (ts33 - f64::from(CAL.ts_cal1)) / f64::from(CAL.ts_cal2 - CAL.ts_cal1);
        (t, vdda)
    }

    #[test]
    fn conversion_matches_the_f64_model_within_its_rounding() {
        // At 3.3 V, halfway between the calibration points: exactly 70 °C.
        assert_eq!(convert(1079, 1500, CAL), Some((7000, 3300)));
        for vref in [1375u16, 1450, 1500, 1560, 1650] {
            for ts in (700u16..1500).step_by(37) {
                let (t, vdda) = model(ts, vref);
                let (cdeg, mv) = convert(ts, vref, CAL).unwrap();
                assert!(
                    (f64::from(mv) - vdda).abs() < 1.0,
                    "{vref}: {mv} mV vs {vdda}"
                );
                // VDDA is truncated to whole mV: ≤ 1 mV in 3 V moves T by ≤ 0.14 °C here.
                assert!(
                    (f64::from(cdeg) / 100.0 - t).abs() < 0.15,
                    "{ts}/{vref}: {cdeg} vs {t}"
                );
            }
        }
        assert_eq!(convert(1000, 0, CAL), None);
        assert_eq!(
            convert(
                1000,
                1500,
                FactoryCal {
                    ts_cal2: 955,
                    ..CAL
                }
            ),
            None
        );
    }
}
