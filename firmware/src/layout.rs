//! STM32F405 facts shared by the board support (`board.rs`, flight) and the host models (`sim`): where the
//! calibration lives in flash and how fast the lines run. Pins, DMA streams and clocks stay in `board.rs`.

/// Calibration slots: sectors 1 (A) and 2 (B), at 0x0800_4000 (RM0090 §3.3, table 5); `memory.x` starts the code
/// at sector 3 (`_stext`), so nothing is linked there.
pub const CAL_FLASH_BASE: u32 = 0x0800_4000;
/// Size of one calibration sector, bytes (the F405's sectors 0–3 are 16 KiB: a record of ≤ 3.8 KiB fits, and an
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

/// The stack region the flight build leaves, at least, bytes: the SRAM (128 KiB) that `.data`, `.bss` and
/// `.uninit` do not use (flip-link puts the stack below them). `tools/fw-check/stack.py --min-region` checks the ELF
/// against it in CI, and the host runs the tasks on a thread of this size (`sim::clock::run_on_mcu_stack`).
pub const MCU_STACK_LEN: usize = 64 * 1024;

/// FPGA link line rate, baud (8N1): USART1 on PCLK2 = 84 MHz / 42.
pub const FPGA_BAUD: u32 = 2_000_000;
/// CubeSat bus line rate, baud (8N1).
pub const BUS_BAUD: u32 = 115_200;
/// DMA ring of the FPGA link, bytes: 8 KiB = 41 ms at 2 Mbaud = 34 frames of slack.
pub const FPGA_RX_RING_LEN: usize = 8 * 1024;
/// DMA ring of the bus receiver, bytes: 16 KiB = 1.42 s at 115200 baud, at least twice the longest calibration
/// store ([`STORE_STALL_MAX_US`], checked below), so that commands arriving while no task runs wait in the ring (the
/// DMA runs while the CPU is stalled or busy).
pub const BUS_RX_RING_LEN: usize = 16 * 1024;

/// Bytes of the largest calibration record a store programs (header, encoded table, CRC: `app::CAL_SCRATCH`).
const RECORD_LEN_MAX: u64 = crate::app::CAL_SCRATCH as u64;

/// Slot reads and decodes of one store, µs, bounded: `CalStore::store` reads both slots before the erase and the
/// new record after it (three reads of ≤ 3.8 KB with a CRC-32C and a table decode, ≈ 0.1 ms each at 168 MHz;
/// allowed 2 ms).
const STORE_READS_MAX_US: u64 = 2_000;

/// Longest a calibration store keeps every task from running, µs: `CalStore::store` is synchronous (the storage
/// task calls it with the pipeline locked; the CPU stalls on the erase and on each word program, and runs the
/// reads), so nothing else runs from its start to its end: the sector erase, every word program of the largest
/// record and the reads, at their maxima (0.5 s + 971 × 100 µs + 2 ms = 0.599 s; `tests` keeps the figures of
/// this comment and `docs/storage.md` in step with the constants).
pub const STORE_STALL_MAX_US: u64 = (ERASE_SECTOR_US[1] as u64)
    + RECORD_LEN_MAX.div_ceil(FLASH_WRITE_LEN as u64) * (PROGRAM_WORD_US[1] as u64)
    + STORE_READS_MAX_US;

const _: () = assert!(
    (BUS_RX_RING_LEN as u64) * 10 * 1_000_000 / (BUS_BAUD as u64) >= 2 * STORE_STALL_MAX_US,
    "the bus ring must hold twice the longest store stall"
);

/// FPGA frames a calibration store can cost at most, at `frames_per_s_milli` (the default is 604 800): everything
/// that arrives while no task runs ([`STORE_STALL_MAX_US`]), plus everything the DMA ring held when the link task,
/// seeing that a store ran, drops the ring's contents (`app::link_loop`: lapped during the stall, they are bytes
/// of different laps), plus the frame cut at each end. `docs/storage.md` derives it; the scenario test checks it.
pub const fn store_frames_lost_max(frames_per_s_milli: u64) -> u64 {
    let during = STORE_STALL_MAX_US
        .saturating_mul(frames_per_s_milli)
        .div_ceil(1_000_000_000);
    let ring = (FPGA_RX_RING_LEN as u64).div_ceil(shared::wire::frame::FRAME_LEN as u64);
    during.saturating_add(ring).saturating_add(2)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The figures `docs/storage.md` and `docs/firmware.md` quote, from the constants: a change of either shows here.
    #[test]
    fn documented_store_figures() {
        assert_eq!(
            RECORD_LEN_MAX.div_ceil(FLASH_WRITE_LEN as u64),
            971,
            "word programs"
        );
        assert_eq!(STORE_STALL_MAX_US, 599_100);
        assert_eq!(store_frames_lost_max(604_800), 400);
        // The bus ring: 16 KiB = 1.42 s at 115200 baud, ≥ 2 × 0.599 s.
        assert_eq!(
            (BUS_RX_RING_LEN as u64) * 10 * 1000 / (BUS_BAUD as u64),
            1422
        );
    }
}
