//! STM32F405 facts shared by the board support (`board.rs`, flight) and the host models (`sim`): where the
//! calibration lives in flash and how fast the lines run. Pins, DMA streams and clocks stay in `board.rs`.

/// Calibration slots: sectors 1 (A) and 2 (B), at 0x0800_4000 (RM0090 §3.3, table 5); `memory.x` starts the code
/// at sector 3 (`_stext`), so nothing is linked there.
pub const CAL_FLASH_BASE: u32 = 0x0800_4000;
/// Size of one calibration sector, bytes (the F405's sectors 0–3 are 16 KiB: a record of ≤ 2.3 KiB fits, and an
/// erase stalls the CPU ≤ 0.5 s at x32 instead of ≤ 4 s for a 128 KiB sector at x8; `docs/storage.md`).
pub const CAL_SECTOR_LEN: usize = 16 * 1024;
/// Calibration sectors (one per slot).
pub const CAL_SECTORS: usize = 2;
/// Erase time of a 16 KiB sector at x32 parallelism, µs, typical and maximum (DS8626 "Flash memory programming":
/// t_ERASE16KB; x32 needs VDD 2.7–3.6 V, our 3.3 V rail). The CPU stalls for all of it (single bank).
pub const ERASE_SECTOR_US: [u32; 2] = [250_000, 500_000];
/// Program time of one 32-bit word, µs, typical and maximum (DS8626: t_prog, x32).
pub const PROGRAM_WORD_US: [u32; 2] = [16, 100];
/// Program granularity of the F405 flash as embassy-stm32 drives it, bytes.
pub const FLASH_WRITE_LEN: usize = 4;

/// FPGA link line rate, baud (8N1): USART1 on PCLK2 = 84 MHz / 42.
pub const FPGA_BAUD: u32 = 2_000_000;
/// CubeSat bus line rate, baud (8N1).
pub const BUS_BAUD: u32 = 115_200;
/// DMA ring of the FPGA link, bytes: 8 KiB = 41 ms at 2 Mbaud = 34 frames of slack.
pub const FPGA_RX_RING_LEN: usize = 8 * 1024;
/// DMA ring of the bus receiver, bytes: 6.5 KiB = 0.58 s at 115200 baud, longer than the worst flash stall
/// (0.5 s), so commands arriving during a calibration store wait in the ring (the DMA runs while the CPU is
/// stalled). Sized to keep RAM within its 96 KiB budget.
pub const BUS_RX_RING_LEN: usize = 6656;

/// FPGA frames a calibration store can cost at most, at the default 604.8 frames/s: everything that arrives during
/// the longest erase stall, plus everything the DMA ring held when embassy's ring-buffered UART, lapped, discards
/// it, plus the frame cut at each end. Word programs stall ≤ 100 µs each between which the link task runs, far
/// less than the ring's slack. `docs/storage.md` derives it; the scenario test checks it.
pub const fn store_frames_lost_max(frames_per_s_milli: u64) -> u64 {
    let during = (ERASE_SECTOR_US[1] as u64)
        .saturating_mul(frames_per_s_milli)
        .div_ceil(1_000_000_000);
    let ring = (FPGA_RX_RING_LEN as u64).div_ceil(shared::wire::frame::FRAME_LEN as u64);
    during.saturating_add(ring).saturating_add(2)
}
