//! The stages of one frame's path, as functions over explicit state. [`super::Pipeline`] calls them in this order
//! for every frame, and `mcu-bench` times each one on the Cortex-M4: the same code, not a copy of it.
//!
//! 1. [`decode`]: the next frame out of the link bytes (sync, CRC-32C, sequence gap), its ADC codes into signed
//!    counts where the frame lies;
//! 2. [`calibrate`]: the groups' maps at the frame's temperature, then the 16 groups' calibration;
//! 3. fusion: [`crate::fuse::Fusion::fuse_into`];
//! 4. [`hold_valid`], then the Allan channels: [`crate::allan::AllanSet::push_parts`];
//! 5. [`nav_add`]: the fused sample into the navigation increments.

use crate::calib::thermal::ThermalComp;
use crate::calib::{AXES, CalibrationTable, RawCounts};
use crate::fuse::FusedSample;
use crate::nav::NavIntegrator;
use crate::wire::frame::GROUPS;
use crate::wire::{FrameDecoder, SeqGap};

/// The fields of a frame besides its ADC codes that the pipeline uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameHead {
    /// The FPGA's decimation N (a frame every N + 1 base ticks).
    pub decimation: u16,
    /// The board temperature, 0.01 °C (`None`: no reading).
    pub temp_cdeg: Option<i16>,
}

/// Stage 1: the next whole frame from the front of `input`, its signed counts into `raw` (read where the frame lies,
/// never copied); `None` when `input` holds no whole frame any more.
pub fn decode(
    decoder: &mut FrameDecoder,
    input: &mut &[u8],
    raw: &mut [RawCounts; GROUPS],
) -> Option<(FrameHead, SeqGap)> {
    let mut head = FrameHead::default();
    let gap = decoder.decode_with(input, |frame| {
        head = FrameHead {
            decimation: frame.decimation(),
            temp_cdeg: frame.temp_cdeg(),
        };
        RawCounts::read_frame(frame, raw);
    })?;
    Some((head, gap))
}

/// Stage 2: the groups' maps at `temp_cdeg` (recomputed only when it changes), then each group's calibrated axes.
pub fn calibrate(
    thermal: &mut ThermalComp<GROUPS>,
    table: &CalibrationTable<GROUPS>,
    temp_cdeg: Option<i16>,
    raw: &[RawCounts; GROUPS],
    axes: &mut [[i32; AXES]; GROUPS],
) {
    thermal.update(table, temp_cdeg);
    // Loops into initialised arrays, not `array::map`, `from_fn` or `each_ref().map`: those stage the arrays through
    // copies on the M4 (`docs/performance.md`, Cortex-M4 cost sections).
    for ((out, r), group) in axes.iter_mut().zip(raw.iter()).zip(thermal.groups()) {
        *out = group.apply(r);
    }
}

/// Before the Allan stage: `hold` takes the fused axes that had a valid sensor and keeps its last value on the
/// others (a fused Allan channel repeats the last valid value while its axis has none).
pub fn hold_valid(hold: &mut [i32; AXES], fused: &FusedSample) {
    for ((hold, &x), &used) in hold.iter_mut().zip(&fused.axes).zip(&fused.used) {
        if used > 0 {
            *hold = x;
        }
    }
}

/// Stage 5: a valid fused sample (µ°/s, µg) into `nav`, in SI units (`f32`), over the frame's time step `dt_s`.
pub fn nav_add(nav: &mut NavIntegrator, fused: &FusedSample, dt_s: f32) {
    const RAD_PER_UDEG: f32 = core::f32::consts::PI / 180.0e6;
    const MPS2_PER_UG: f32 = 9.806_65e-6;
    let [gx, gy, gz, ax, ay, az] = fused.axes.map(|x| x as f32);
    nav.add(
        [gx * RAD_PER_UDEG, gy * RAD_PER_UDEG, gz * RAD_PER_UDEG],
        [ax * MPS2_PER_UG, ay * MPS2_PER_UG, az * MPS2_PER_UG],
        dt_s,
    );
}

/// A frame's time step, s: N + 1 base periods at `base_rate_millihz` (`f32`, for the navigation stage).
pub fn frame_dt_s(decimation: u16, base_rate_millihz: u64) -> f32 {
    (f32::from(decimation) + 1.0) * 1000.0 / base_rate_millihz.max(1) as f32
}
