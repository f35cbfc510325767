use super::*;
use proptest::prelude::*;

extern crate std;

/// The f64 reference of `M · (raw − b)` with the table's own (quantised) coefficients.
fn reference<const N: usize>(m: &[[i32; N]; 3], b: &[i32; N], raw: &[i32; N]) -> [f64; 3] {
    let scale = f64::from(1u32 << FRAC_BITS);
    m.map(|row| {
        row.iter()
            .zip(b)
            .zip(raw)
            .map(|((&mij, &bj), &rj)| {
                (f64::from(mij) / scale) * (f64::from(rj) - f64::from(bj) / scale)
            })
            .sum()
    })
}

fn check_against_reference(cal: &GroupCal, raw: &RawCounts) -> Result<(), TestCaseError> {
    let got = cal.apply(raw);
    let g = reference(&cal.gyro_matrix_q12, &cal.gyro_bias_q12, &raw.gyro);
    let a = reference(&cal.accel_matrix_q12, &cal.accel_bias_q12, &raw.accel);
    for (axis, (&out, &want)) in got.iter().zip(g.iter().chain(&a)).enumerate() {
        let clamped = want.clamp(f64::from(i32::MIN), f64::from(i32::MAX));
        // f64 carries ~1e-16 relative error on sums up to 2^62 / 2^24: allow 1e-6 LSB above the bound.
        prop_assert!(
            (f64::from(out) - clamped).abs() <= 0.5 + 1e-6,
            "axis {axis}: fixed {out}, f64 {want}"
        );
    }
    Ok(())
}

fn any_matrix<const N: usize>() -> impl Strategy<Value = [[i32; N]; 3]> {
    proptest::array::uniform3(proptest::array::uniform::<_, N>(any::<i32>()))
}

fn bias<const N: usize>() -> impl Strategy<Value = [i32; N]> {
    proptest::array::uniform::<_, N>(-BIAS_LIMIT_Q12..=BIAS_LIMIT_Q12)
}

prop_compose! {
    fn any_cal()(gm in any_matrix::<GYRO_RAW>(), gb in bias::<GYRO_RAW>(), am in any_matrix::<ACCEL_RAW>(),
                 ab in bias::<ACCEL_RAW>()) -> GroupCal {
        GroupCal { gyro_matrix_q12: gm, gyro_bias_q12: gb, accel_matrix_q12: am, accel_bias_q12: ab }
    }
}

prop_compose! {
    /// Raw readings over the whole input range: 16-bit ADC codes and signed 16-bit words.
    fn any_raw()(g in proptest::array::uniform4(-RAW_LIMIT..=RAW_LIMIT),
                 a in proptest::array::uniform3(-RAW_LIMIT..=RAW_LIMIT)) -> RawCounts {
        RawCounts { gyro: g, accel: a }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4000))]

    /// Any matrix, any bias within limits, any raw reading: error ≤ 0.5 output LSB against f64, saturating.
    #[test]
    fn fixed_point_matches_f64_reference(cal in any_cal(), raw in any_raw()) {
        check_against_reference(&cal, &raw)?;
    }

    /// Realistic scales (the nominal board chain ± 10 % with small cross terms) over all ADC codes.
    #[test]
    fn nominal_scales_match_f64_reference(
        scale in proptest::array::uniform3(0.9f64..1.1), cross in proptest::array::uniform3(-0.02f64..0.02),
        codes in proptest::array::uniform7(any::<u16>()),
    ) {
        let mut cal = board::NOMINAL;
        for (i, row) in cal.accel_matrix_q12.iter_mut().enumerate() {
            for (j, m) in row.iter_mut().enumerate() {
                let f = if i == j { scale[i] } else { cross[(i + j) % 3] };
                *m = (f64::from(board::ACCEL_UG_PER_COUNT_Q12) * f).round() as i32;
            }
        }
        check_against_reference(&cal, &RawCounts::from_adc(&codes))?;
    }

    /// Decoding never panics, whatever the bytes.
    #[test]
    fn decode_arbitrary_bytes_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..3000)) {
        let _ = CalibrationTable::<16>::decode(&bytes);
    }
}

#[test]
fn nominal_chain_in_physical_units() {
    // 1 V above the gyro zero level = 100 °/s; 0.3 V above the accel zero = 1 g.
    let zero_g = (board::GYRO_ZERO_UV / board::ADC_UV_PER_COUNT) as i32;
    let zero_a = (board::ACCEL_ZERO_UV / board::ADC_UV_PER_COUNT) as i32;
    let dps100 = (1_000_000.0 / board::ADC_UV_PER_COUNT) as i32; // 16000 counts
    let g1 = (board::ACCEL_UV_PER_G / board::ADC_UV_PER_COUNT) as i32; // 4800 counts
    let raw = RawCounts {
        gyro: [
            zero_g + dps100,
            zero_g - dps100 / 2,
            zero_g - dps100,
            zero_g + dps100 / 2,
        ],
        accel: [zero_a, zero_a - g1, zero_a + g1],
    };
    let out = board::NOMINAL.apply(&raw);
    // z = mean of both z outputs = 0; accel 853333 / 4096 µg per count × 4800 = 999 999.6 µg.
    assert_eq!(
        out,
        [100_000_000, -100_000_000, 0, 0, -1_000_000, 1_000_000]
    );
}

/// `round_q24_sat` against exact rational rounding (i128, |acc| / 2²⁴ rounded half up, sign restored) on its
/// domain |acc| < 2⁶²: every half, ±1 around it, the domain's ends and 100 000 random values.
#[test]
fn rounding_matches_exact_reference() {
    fn reference(acc: i64) -> i32 {
        let (a, unit) = (i128::from(acc), 1i128 << 24);
        let q = (a.abs() + unit / 2) / unit;
        let q = if a < 0 { -q } else { q };
        q.clamp(i32::MIN.into(), i32::MAX.into()) as i32
    }
    let mut rng = crate::testutil::Rng::new(77);
    let (half, end) = (1i64 << 23, (1i64 << 62) - 1);
    let mut cases = std::vec![0, 1, -1, end, -end, end - half, half - end];
    for k in [
        -3i64,
        -2,
        -1,
        0,
        1,
        2,
        3,
        1 << 20,
        -(1 << 20),
        1 << 37,
        -(1 << 37),
    ] {
        let center = k * 2 * half + half;
        for c in [center, -center] {
            cases.extend([c - 1, c, c + 1]);
        }
    }
    cases.extend((0..100_000).map(|_| (rng.next_u64() as i64) >> (2 + rng.next_u64() % 62)));
    for acc in cases {
        assert_eq!(round_q24_sat(acc), reference(acc), "{acc}");
    }
}

#[test]
fn rounding_is_half_away_from_zero() {
    assert_eq!(round_q24_sat(3 << 21), 0); // 0.375 → 0
    assert_eq!(round_q24_sat(3 << 23), 2); // 1.5 → 2
    assert_eq!(round_q24_sat(1 << 23), 1); // +0.5 → 1
    assert_eq!(round_q24_sat(-(1 << 23)), -1); // −0.5 → −1
    assert_eq!(round_q24_sat(-(3 << 23)), -2); // −1.5 → −2
    assert_eq!(round_q24_sat((1 << 23) - 1), 0);
    assert_eq!(round_q24_sat(1 - (1 << 23)), 0);
    assert_eq!(round_q24_sat(i64::MAX >> 2), i32::MAX);
    assert_eq!(round_q24_sat(i64::MIN >> 2), i32::MIN);
}

#[test]
fn table_round_trip_and_damage() {
    let mut t = CalibrationTable::<16>::factory();
    t.cal_id = 0xC0FFEE;
    t.groups[3].accel_matrix_q12[1][2] = -12345;
    let mut buf = [0u8; encoded_len_max(16)];
    let bytes = t.encode(&mut buf).unwrap().to_vec();
    assert_eq!(CalibrationTable::<16>::decode(&bytes), Ok(t));
    assert_eq!(
        CalibrationTable::<8>::decode(&bytes),
        Err(CalError::GroupCount(16))
    );
    for i in 0..bytes.len() {
        let mut b = bytes.clone();
        b[i] ^= 0x01;
        assert_eq!(
            CalibrationTable::<16>::decode(&b),
            Err(CalError::Crc),
            "byte {i}"
        );
    }
    assert_eq!(
        CalibrationTable::<16>::decode(&bytes[..5]),
        Err(CalError::Crc)
    );
    assert_eq!(
        CalibrationTable::<16>::decode(&bytes[..3]),
        Err(CalError::Truncated)
    );
    let mut small = [0u8; 100];
    assert_eq!(t.encode(&mut small), Err(CalError::BufferTooSmall));
}

#[test]
fn out_of_range_bias_is_refused() {
    let mut t = CalibrationTable::<2>::factory();
    t.groups[1].gyro_bias_q12[0] = BIAS_LIMIT_Q12 + 1;
    let mut buf = [0u8; encoded_len_max(2)];
    let bytes = t.encode(&mut buf).unwrap().to_vec();
    assert_eq!(
        CalibrationTable::<2>::decode(&bytes),
        Err(CalError::BiasOutOfRange)
    );
}

/// The f64 reference of a shifted bias: `b + lin·ΔT + quad·ΔT²` with the coefficients as exact reals (Q12 counts).
fn shifted_reference(b: i32, lin: i32, quad: i32, dt: i32) -> f64 {
    let dt = f64::from(dt);
    f64::from(b)
        + f64::from(lin) / f64::from(1u32 << 16) * dt
        + f64::from(quad) / 2f64.powi(28) * dt * dt
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4000))]
    /// The thermal bias shift is the exactly rounded real value (≤ 0.5 Q12 LSB = 2⁻¹³ count), wherever the result
    /// stays within the bias limit, for any coefficients and any ΔT the board can report.
    #[test]
    fn thermal_shift_is_exactly_rounded(
        b in -BIAS_LIMIT_Q12..=BIAS_LIMIT_Q12,
        lin in any::<i32>(),
        quad in any::<i32>(),
        dt in -thermal::DT_LIMIT_CDEG..=thermal::DT_LIMIT_CDEG,
    ) {
        let want = shifted_reference(b, lin, quad, dt);
        let got = thermal::shifted(b, lin, quad, dt);
        let limit = f64::from(BIAS_LIMIT_Q12);
        if want.abs() <= limit {
            // f64 carries ~2⁻⁵² relative error on values < 2⁶²⁻²⁸: 1e-6 LSB of slack.
            prop_assert!((f64::from(got) - want).abs() <= 0.5 + 1e-6, "got {got}, want {want}");
        } else {
            prop_assert_eq!(f64::from(got), limit.copysign(want));
        }
    }
}

#[test]
fn thermal_shift_of_a_typical_gyro() {
    // 0.05 (°/s)/°C on a 6250 µ°/s-per-count channel = 8 counts/°C = 0.08 counts per c°C; +10 °C → +80 counts.
    let lin = (0.08 * 2f64.powi(28)).round() as i32;
    let b = board::GYRO_ZERO_Q12;
    assert_eq!(thermal::shifted(b, lin, 0, 1000), b + 80 * 4096);
    assert_eq!(thermal::shifted(b, lin, 0, -1000), b - 80 * 4096);
    // A quadratic 0.01 counts/°C² = 1e-6 counts per c°C²: +1 count at 10 °C either side.
    let quad = (1e-6 * 2f64.powi(40)).round() as i32;
    assert_eq!(thermal::shifted(b, 0, quad, 1000), b + 4096);
    assert_eq!(thermal::shifted(b, 0, quad, -1000), b + 4096);
    // Beyond ±200 °C the difference is clamped (a corrupt reading cannot overflow).
    assert_eq!(
        thermal::shifted(b, lin, 0, i32::MAX),
        thermal::shifted(b, lin, 0, thermal::DT_LIMIT_CDEG)
    );
}

fn thermal_table() -> CalibrationTable<2> {
    let mut t = CalibrationTable::<2>::factory();
    t.t_ref_cdeg = 2000;
    t.thermal[1].gyro_lin_q28[2] = 1 << 28; // 1 count per c°C on group 1, raw gyro channel 2 (B y)
    t.thermal[0].accel_quad_q40[0] = 1 << 30; // 2⁻¹⁰ counts per c°C² on group 0, accel x
    t
}

#[test]
fn compensation_follows_the_frame_temperature_and_holds_the_last_valid_one() {
    let t = thermal_table();
    let mut c = thermal::ThermalComp::<2>::new();
    c.load(&t);
    let reference = c.groups()[1].gyro_bias_q12[2];
    assert_eq!(reference, t.groups[1].gyro_bias_q12[2]);
    // After a restart no temperature is known: the reference biases, counted as missing but not held.
    c.update(&t, None);
    assert_eq!(c.groups()[1].gyro_bias_q12[2], reference);
    assert_eq!(c.applied_cdeg(), None);
    assert_eq!(
        c.counts(),
        thermal::TempCounts {
            missing: 1,
            held: 0
        }
    );
    // 2.50 °C above the reference: +250 counts on that channel; accel x: +250²/1024 = 61.03515625 counts.
    c.update(&t, Some(2250));
    assert_eq!(c.groups()[1].gyro_bias_q12[2], reference + 250 * 4096);
    assert_eq!(
        c.groups()[0].accel_bias_q12[0],
        t.groups[0].accel_bias_q12[0] + 250_000
    ); // 61.035… · 4096 = 250 000
    assert_eq!(c.groups()[0].gyro_bias_q12, t.groups[0].gyro_bias_q12); // no terms there
    // A frame without temperature keeps the last valid one (held), and another table keeps that temperature.
    c.update(&t, None);
    assert_eq!(c.groups()[1].gyro_bias_q12[2], reference + 250 * 4096);
    assert_eq!(
        c.counts(),
        thermal::TempCounts {
            missing: 2,
            held: 1
        }
    );
    c.load(&t);
    assert_eq!(c.groups()[1].gyro_bias_q12[2], reference);
    c.update(&t, None);
    assert_eq!(c.groups()[1].gyro_bias_q12[2], reference + 250 * 4096);
    // A table without thermal terms: its biases, whatever the temperature; missing frames still counted.
    let plain = CalibrationTable::<2>::factory();
    c.load(&plain);
    c.update(&plain, Some(-4000));
    c.update(&plain, None);
    assert_eq!(c.groups()[1].gyro_bias_q12, plain.groups[1].gyro_bias_q12);
    assert_eq!(c.applied_cdeg(), None);
    assert_eq!(
        c.counts(),
        thermal::TempCounts {
            missing: 4,
            held: 2
        }
    );
}

#[test]
fn format_2_round_trips_and_format_1_still_loads() {
    let mut t = thermal_table();
    t.cal_id = 77;
    t.weights_q16[0] = [1 << 16, 1 << 15, 0, 1, 2, 3];
    t.weights_q16[1] = [1, 1 << 15, 9, 1, 2, 3];
    let mut buf = [0u8; encoded_len_max(2)];
    let bytes = t.encode(&mut buf).unwrap().to_vec();
    assert_eq!(bytes[0], CAL_FORMAT_VERSION as u8);
    assert_eq!(CalibrationTable::<2>::decode(&bytes), Ok(t));
    assert!(t.encodes_as(&bytes));
    let mut other = t;
    other.thermal[1].gyro_quad_q40[3] = 5;
    assert!(!other.encodes_as(&bytes));

    // A version-1 table, written as version 1 wrote it: header (1, G), id, rails, groups, CRC.
    let mut v1 = [0u8; 512];
    let mut n = postcard::to_slice(&(1u16, 2u8, 77u32, 0i32, 65535i32), &mut v1)
        .unwrap()
        .len();
    for g in &t.groups {
        n += postcard::to_slice(g, &mut v1[n..]).unwrap().len();
    }
    let crc = crate::crc::crc32c(&v1[..n]);
    v1[n..n + 4].copy_from_slice(&crc.to_le_bytes());
    let old = CalibrationTable::<2>::decode(&v1[..n + 4]).unwrap();
    assert_eq!(old.groups, t.groups);
    assert_eq!(old.cal_id, 77);
    assert!(!old.has_thermal() && !old.has_weights());
    assert_eq!(old.t_ref_cdeg, 0);
}

#[test]
fn a_failed_decode_leaves_the_table_in_force() {
    let mut bad = thermal_table();
    bad.weights_q16[0][4] = -(1 << 16);
    bad.weights_q16[1][4] = 1 << 15; // axis 4 sums to −0.5: refused
    let mut buf = [0u8; encoded_len_max(2)];
    let bytes = bad.encode(&mut buf).unwrap().to_vec();
    let mut t = thermal_table();
    let before = t;
    assert_eq!(t.decode_into(&bytes), Err(CalError::WeightOutOfRange));
    assert_eq!(t, before);
    bad.weights_q16[1][4] = (1 << 16) + 1; // beyond ±1
    let bytes = bad.encode(&mut buf).unwrap().to_vec();
    assert_eq!(
        CalibrationTable::<2>::check(&bytes),
        Err(CalError::WeightOutOfRange)
    );
    let mut f = thermal_table();
    f.set_factory();
    assert_eq!(f, CalibrationTable::factory());
}
