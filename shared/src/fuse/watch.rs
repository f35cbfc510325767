//! Sensor exclusion by the raw channels: rails and stuck codes (see the module docs of `fuse`).

/// Raw-channel watch of one sensor's `N` channels: the last code of each and how often it repeated since it
/// changed (saturating at `u16::MAX`).
#[derive(Clone, Copy, Debug)]
pub(super) struct ChannelWatch<const N: usize> {
    pub(super) last: [i32; N],
    pub(super) repeats: [u16; N],
}

impl<const N: usize> ChannelWatch<N> {
    pub(super) const NEW: Self = Self {
        last: [i32::MIN; N],
        repeats: [0; N],
    };

    /// Takes one sample's `codes`; returns whether any channel is at a rail (`code − above_min` ≥ `span` as
    /// `u32`, see `Fusion::fuse`) and whether any has repeated `stuck_repeats` times. A constant channel count, so
    /// the loop unrolls (7 channels in one indexed loop cost twice the instructions).
    #[inline(always)]
    pub(super) fn update(
        &mut self,
        codes: &[i32; N],
        above_min: i32,
        span: u32,
        stuck_repeats: u16,
    ) -> (bool, bool) {
        let (mut sat, mut stuck) = (false, false);
        for ((&code, last), repeats) in codes.iter().zip(&mut self.last).zip(&mut self.repeats) {
            // = table.saturated(code)
            sat |= code.wrapping_sub(above_min) as u32 >= span;
            // A live channel changes almost every sample: that path only resets the count.
            if code == *last {
                *repeats = repeats.saturating_add(1);
                stuck |= *repeats >= stuck_repeats;
            } else {
                (*last, *repeats) = (code, 0);
            }
        }
        (sat, stuck)
    }
}

/// Raw-channel watch of one group.
#[derive(Clone, Copy, Debug)]
pub(super) struct RawWatch {
    pub(super) gyro: ChannelWatch<{ crate::calib::GYRO_RAW }>,
    pub(super) accel: ChannelWatch<{ crate::calib::ACCEL_RAW }>,
}

impl RawWatch {
    pub(super) const NEW: Self = Self {
        gyro: ChannelWatch::NEW,
        accel: ChannelWatch::NEW,
    };
}
