//! Sensor exclusion by the raw channels: rails and stuck codes (see the module docs of `fuse`).

use crate::calib::{ACCEL_RAW, GYRO_RAW, RawCounts};

/// Channels of one group: the gyros' then the accelerometer's (`update` names all 7).
const CHANNELS: usize = GYRO_RAW + ACCEL_RAW;
const _: () = assert!(GYRO_RAW == 4 && ACCEL_RAW == 3);

/// Raw-channel watch of one group's 7 channels: the last code of each and how often it repeated since it changed
/// (saturating at `u16::MAX`).
#[derive(Clone, Copy, Debug)]
pub(super) struct RawWatch {
    last: [i32; CHANNELS],
    repeats: [u16; CHANNELS],
}

impl RawWatch {
    pub(super) const NEW: Self = Self {
        last: [i32::MIN; CHANNELS],
        repeats: [0; CHANNELS],
    };

    /// Takes one sample's `raw` codes; returns `[gyro, accel]` pairs of (any channel at a rail: `code − above_min`
    /// ≥ `span` as `u32`, see `Fusion::fuse`; any channel repeated `stuck_repeats` (≥ 1) times).
    ///
    /// Written out for the 7 channels, each one's state at a fixed offset: the compiler keeps a loop over channels
    /// with a branch in it rolled (address arithmetic and spilled constants per channel), which costs more on the
    /// frame path than this (the loop shapes tried, with their `mcu-bench` costs: `docs/performance.md`, Cortex-M4
    /// cost sections).
    #[inline(always)]
    pub(super) fn update(
        &mut self,
        raw: &RawCounts,
        above_min: i32,
        span: u32,
        stuck_repeats: u16,
    ) -> [(bool, bool); 2] {
        // One channel: (rail, stuck) as 0/1.
        #[inline(always)]
        fn channel(
            code: i32,
            last: &mut i32,
            repeats: &mut u16,
            above_min: i32,
            span: u32,
            stuck_repeats: u16,
        ) -> (u32, u32) {
            // = table.saturated(code)
            let sat = u32::from(code.wrapping_sub(above_min) as u32 >= span);
            // A live channel changes almost every sample: that path only resets the count.
            if code == *last {
                *repeats = repeats.saturating_add(1);
                (sat, u32::from(*repeats >= stuck_repeats))
            } else {
                (*last, *repeats) = (code, 0);
                (sat, 0)
            }
        }
        let [a, b, c, d] = raw.gyro;
        let [e, f, g] = raw.accel;
        let [la, lb, lc, ld, le, lf, lg] = &mut self.last;
        let [ra, rb, rc, rd, re, rf, rg] = &mut self.repeats;
        let ch = |code, last, repeats| channel(code, last, repeats, above_min, span, stuck_repeats);
        // Flags folded in as they come, so that few values stay live.
        let or = |(s0, t0): (u32, u32), (s1, t1): (u32, u32)| (s0 | s1, t0 | t1);
        let gyro = ch(a, la, ra);
        let gyro = or(gyro, ch(b, lb, rb));
        let gyro = or(gyro, ch(c, lc, rc));
        let gyro = or(gyro, ch(d, ld, rd));
        let accel = ch(e, le, re);
        let accel = or(accel, ch(f, lf, rf));
        let accel = or(accel, ch(g, lg, rg));
        [(gyro.0 != 0, gyro.1 != 0), (accel.0 != 0, accel.1 != 0)]
    }
}
