//! STM32F405 facts shared by the board support (`board.rs`, flight), the bootloader (`bootloader/`) and the host
//! models (`sim`): the flash memory map, where the calibration lives, the watchdog's timing and how fast the lines
//! run. Pins, DMA streams and clocks stay in `board.rs`. It depends on no other module of this crate (`shared`
//! only): the task loops (`app`) use it, never the other way round.
//!
//! # Memory map (`docs/update.md`; RM0090 §3.3, table 5)
//!
//! | region | sectors | address | size |
//! |---|---|---|---:|
//! | bootloader | 0–1 | [`BOOTLOADER_BASE`] `0x0800_0000` | 32 KiB |
//! | calibration slots A, B | 2, 3 | [`CAL_FLASH_BASE`] `0x0800_8000` | 2 × 16 KiB |
//! | boot state (embassy-boot `STATE`) | 4 | [`STATE_BASE`] `0x0801_0000` | 64 KiB |
//! | ACTIVE (the running image: header, then the application) | 5–6 | [`ACTIVE_BASE`] `0x0802_0000` | 256 KiB |
//! | DFU (the image being received, one sector larger) | 7–9 | [`DFU_BASE`] `0x0806_0000` | 384 KiB |
//! | spare | 10–11 | `0x080C_0000` | 256 KiB |
//!
//! The application links at [`APP_FLASH_BASE`] (ACTIVE + [`IMAGE_HEADER_LEN`]); `firmware/memory.x` and
//! `bootloader/memory.x` say the same (the tests below read both). The first [`BOOT_REPORT_LEN`] bytes of SRAM are
//! the boot report, which neither ELF links.

/// Start of the flash, bytes (the bootloader's reset vector is here).
pub const FLASH_BASE: u32 = 0x0800_0000;
/// Size of the F405RG's flash (single bank), bytes.
pub const FLASH_LEN: u32 = 1024 * 1024;
/// Where each flash sector starts (RM0090 table 5: four of 16 KiB, one of 64 KiB, seven of 128 KiB); the flash
/// ends at `FLASH_BASE + FLASH_LEN`.
pub const SECTOR_STARTS: [u32; 12] = [
    0x0800_0000,
    0x0800_4000,
    0x0800_8000,
    0x0800_C000,
    0x0801_0000,
    0x0802_0000,
    0x0804_0000,
    0x0806_0000,
    0x0808_0000,
    0x080A_0000,
    0x080C_0000,
    0x080E_0000,
];

/// The bootloader: sectors 0–1.
pub const BOOTLOADER_BASE: u32 = 0x0800_0000;
/// The bootloader's flash, bytes (its budget: `tools/fw-check/size.py` fails the build's ELF over it).
pub const BOOTLOADER_LEN: u32 = 32 * 1024;

/// Calibration slots: sectors 2 (A) and 3 (B), at 0x0800_8000 (RM0090 §3.3, table 5); no ELF links anything
/// there (the bootloader ends before them, the application starts after the boot state).
pub const CAL_FLASH_BASE: u32 = 0x0800_8000;
/// Size of one calibration sector, bytes (the F405's sectors 0–3 are 16 KiB: a record of ≤ 3.8 KiB fits, and an
/// erase stalls the CPU ≤ 0.5 s at x32 instead of ≤ 4 s for a 128 KiB sector at x8; `docs/storage.md`).
pub const CAL_SECTOR_LEN: usize = 16 * 1024;
/// Calibration sectors (one per slot).
pub const CAL_SECTORS: usize = 2;

/// embassy-boot's state partition (`STATE`): sector 4. Its magic word says whether a swap is pending; the swap's
/// progress words follow (`docs/update.md`).
pub const STATE_BASE: u32 = 0x0801_0000;
/// Size of the state partition, bytes (one 64 KiB sector: embassy-boot needs 4 × 2 + 2 words of it).
pub const STATE_LEN: u32 = 64 * 1024;
/// ACTIVE, the running image: sectors 5–6. Its first [`IMAGE_HEADER_LEN`] bytes are the image header.
pub const ACTIVE_BASE: u32 = 0x0802_0000;
/// Size of ACTIVE, bytes.
pub const ACTIVE_LEN: u32 = 256 * 1024;
/// DFU, where an uploaded image waits for the swap: sectors 7–9, one sector more than ACTIVE (embassy-boot's swap
/// moves ACTIVE's pages one sector up in DFU).
pub const DFU_BASE: u32 = 0x0806_0000;
/// Size of DFU, bytes.
pub const DFU_LEN: u32 = 384 * 1024;
/// Erase unit of ACTIVE and DFU, bytes (their 128 KiB sectors: embassy-boot's page).
pub const IMAGE_SECTOR_LEN: u32 = 128 * 1024;
/// The image header in front of the application (`shared::update::image::HEADER_LEN`), bytes: also the vector
/// table's alignment (VTOR wants the table's size rounded up to a power of two: 98 vectors, 392 B → 512).
pub const IMAGE_HEADER_LEN: u32 = 512;
/// Where the application links: its vector table, then `.text`, `.rodata` and the image of `.data`.
pub const APP_FLASH_BASE: u32 = ACTIVE_BASE + IMAGE_HEADER_LEN;
/// The application's flash budget, bytes: 75 % of ACTIVE (192 KiB), the rest kept for growth (CI:
/// `tools/fw-check/size.py`).
pub const APP_FLASH_BUDGET: u32 = ACTIVE_LEN / 4 * 3;

/// This board's identity in an image header (`shared::update::image::Header::board_id`): an image built for
/// another board is refused. "O5" (0x4F05) for the STM32F405, then the IMU cluster board's revision 16.01. A new
/// board (or one whose images must not cross) takes a new number.
pub const BOARD_ID: u32 = shared::update::BOARD_ID;

/// Start of SRAM1 + SRAM2 (128 KiB, contiguous).
pub const SRAM_BASE: u32 = 0x2000_0000;
/// Size of SRAM1 + SRAM2, bytes.
pub const SRAM_LEN: u32 = 128 * 1024;
/// The boot report the bootloader leaves for the application (`shared::update::BootReport`): the first bytes of
/// SRAM, which neither ELF links (both `memory.x` files start RAM after them). Reset keeps SRAM.
pub const BOOT_REPORT_ADDR: u32 = SRAM_BASE;
/// Size of the boot report's window, bytes (the report uses 24 of them).
pub const BOOT_REPORT_LEN: u32 = 32;
/// SRAM the bootloader may use (stack, `.data`, `.bss`), bytes, right after the boot report: inside what the
/// application leaves to its stack (at least [`MCU_STACK_LEN`]; flip-link puts the application's `.data`, `.bss`
/// and `.uninit` at the top of SRAM), so that the bootloader never overwrites the application's reset history
/// (`.uninit`), which must survive from one boot to the next.
pub const BOOTLOADER_RAM_LEN: u32 = 24 * 1024;

/// Whether an application's first two vector-table words can start it: the initial stack pointer word-aligned in
/// SRAM past the boot report (it may be SRAM's end: the stack grows down), the reset vector a Thumb address
/// (bit 0 set) inside ACTIVE, after the vector table's first two words. The bootloader checks this before it jumps
/// (an erased or half-written ACTIVE reads `0xFFFF_FFFF`).
pub const fn app_vectors_plausible(initial_sp: u32, reset: u32) -> bool {
    let sp_ok = initial_sp.is_multiple_of(4)
        && initial_sp > SRAM_BASE + BOOT_REPORT_LEN
        && initial_sp <= SRAM_BASE + SRAM_LEN;
    let pc = reset & !1;
    sp_ok && reset & 1 == 1 && pc >= APP_FLASH_BASE + 8 && pc < ACTIVE_BASE + ACTIVE_LEN
}

/// Whether `addr` is the start of a flash sector or the end of the flash.
const fn sector_boundary(addr: u32) -> bool {
    if addr == FLASH_BASE + FLASH_LEN {
        return true;
    }
    let mut rest: &[u32] = &SECTOR_STARTS;
    while let [start, tail @ ..] = rest {
        if *start == addr {
            return true;
        }
        rest = tail;
    }
    false
}

// The map, checked at compile time: every region starts and ends on a sector boundary, the regions follow each other
// without overlapping, everything fits the 1 MiB, and DFU holds ACTIVE plus the one sector embassy-boot's swap
// needs.
const _: () = {
    let regions: [(u32, u32); 5] = [
        (BOOTLOADER_BASE, BOOTLOADER_LEN),
        (CAL_FLASH_BASE, (CAL_SECTORS * CAL_SECTOR_LEN) as u32),
        (STATE_BASE, STATE_LEN),
        (ACTIVE_BASE, ACTIVE_LEN),
        (DFU_BASE, DFU_LEN),
    ];
    let mut end = FLASH_BASE;
    let mut rest: &[(u32, u32)] = &regions;
    while let [(base, len), tail @ ..] = rest {
        assert!(*base >= end, "flash regions overlap or are out of order");
        assert!(
            sector_boundary(*base) && sector_boundary(*base + *len),
            "a flash region is not whole sectors"
        );
        end = *base + *len;
        rest = tail;
    }
    assert!(
        end <= FLASH_BASE + FLASH_LEN,
        "the flash regions do not fit the 1 MiB"
    );
    assert!(
        DFU_LEN >= ACTIVE_LEN + IMAGE_SECTOR_LEN,
        "DFU must be ACTIVE plus one sector"
    );
    assert!(
        ACTIVE_LEN.is_multiple_of(IMAGE_SECTOR_LEN) && DFU_LEN.is_multiple_of(IMAGE_SECTOR_LEN)
    );
    assert!(
        ACTIVE_BASE >= 0x0802_0000 && DFU_BASE >= 0x0802_0000,
        "ACTIVE and DFU are in the 128 KiB sectors"
    );
    assert!(
        APP_FLASH_BASE.is_multiple_of(512),
        "VTOR needs the vector table on a 512-byte boundary"
    );
    assert!(
        BOOTLOADER_RAM_LEN as usize <= MCU_STACK_LEN,
        "the bootloader's RAM must lie in the app's stack region"
    );
};
/// Erase time of a 16 KiB sector at x32 parallelism, µs, typical and maximum (DS8626 "Flash memory programming":
/// t_ERASE16KB; x32 needs VDD 2.7–3.6 V, our 3.3 V rail). The CPU stalls for all of it (single bank).
pub const ERASE_SECTOR_US: [u32; 2] = [250_000, 500_000];
/// Erase time of a 64 KiB sector (the boot state) at x32, µs, typical and maximum (DS8626: t_ERASE64KB).
pub const ERASE_STATE_SECTOR_US: [u32; 2] = [550_000, 1_100_000];
/// Erase time of a 128 KiB sector (ACTIVE's and DFU's) at x32, µs, typical and maximum (DS8626: t_ERASE128KB).
pub const ERASE_IMAGE_SECTOR_US: [u32; 2] = [1_000_000, 2_000_000];
/// Program time of one 32-bit word, µs, typical and maximum (DS8626: t_prog, x32).
pub const PROGRAM_WORD_US: [u32; 2] = [16, 100];
/// Program granularity of the F405 flash as embassy-stm32 drives it, bytes.
pub const FLASH_WRITE_LEN: usize = 4;

/// The stack region the flight build leaves, at least, bytes: the SRAM (128 KiB) that `.data`, `.bss` and
/// `.uninit` do not use (flip-link puts the stack below them). `tools/fw-check/stack.py --min-region` checks the ELF
/// against it in CI, and the host runs the tasks on a thread of this size (`sim::clock::run_on_mcu_stack`).
pub const MCU_STACK_LEN: usize = 64 * 1024;

/// IWDG timeout, nominal (at the nominal LSI, [`LSI_HZ`]), µs: the flight firmware and the bootloader start it
/// with the same timeout ([`WATCHDOG_PR_RL`]). At the fastest LSI it is [`WATCHDOG_TIMEOUT_MIN_US`] (5.4 s), which
/// must exceed the longest flash stall either makes (a 128 KiB erase, ≤ 2 s: the bootloader's swap, the update
/// receiver's DFU erases) plus two of the firmware's watchdog periods (0.25 s each): 2.9 s of margin.
pub const WATCHDOG_TIMEOUT_US: u32 = 8_000_000;
/// LSI frequency the IWDG's reload is computed for, Hz (DS8626, LSI: 17–47 kHz, 32 kHz typical).
pub const LSI_HZ: u32 = 32_000;
/// Fastest LSI, Hz (DS8626): the IWDG's shortest timeout.
pub const LSI_HZ_MAX: u32 = 47_000;

/// IWDG prescaler (the PR register's value) and reload (RLR) for [`WATCHDOG_TIMEOUT_US`] at [`LSI_HZ`]: the
/// smallest prescaler 4·2^PR whose longest period (4096 counts) reaches the timeout, then the reload that gives it
/// (PR 4, ÷64; RLR 3999: 4000 counts of 2 ms).
pub const WATCHDOG_PR_RL: (u8, u16) = {
    let mut pr = 0u8;
    while pr < 6 && 4096 * (4u64 << pr) * 1_000_000 / (LSI_HZ as u64) < WATCHDOG_TIMEOUT_US as u64 {
        pr += 1;
    }
    let counts = WATCHDOG_TIMEOUT_US as u64 * (LSI_HZ as u64) / 1_000_000 / (4u64 << pr);
    assert!(counts >= 1 && counts <= 4096, "IWDG timeout out of range");
    (pr, (counts - 1) as u16)
};

/// The IWDG's timeout at the fastest LSI ([`LSI_HZ_MAX`]), µs, with the prescaler and reload in force.
pub const WATCHDOG_TIMEOUT_MIN_US: u32 = {
    let (pr, rl) = WATCHDOG_PR_RL;
    ((rl as u64 + 1) * (4u64 << pr) * 1_000_000 / (LSI_HZ_MAX as u64)) as u32
};

const _: () = assert!(
    ERASE_IMAGE_SECTOR_US[1] + 2 * 250_000 < WATCHDOG_TIMEOUT_MIN_US,
    "the IWDG must outlast the longest flash erase at the fastest LSI"
);

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

/// Scratch for the calibration store: record header, encoded table, CRC. The storage task's buffer (`app`), and
/// the largest record a store programs (the stall below).
pub const CAL_SCRATCH: usize = shared::calib::encoded_len_max(shared::wire::frame::GROUPS) + 16;

/// Bytes of the largest calibration record a store programs (header, encoded table, CRC: [`CAL_SCRATCH`]).
const RECORD_LEN_MAX: u64 = CAL_SCRATCH as u64;

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
#[allow(
    clippy::unwrap_used,
    clippy::panic,
    clippy::indexing_slicing,
    clippy::arithmetic_side_effects
)]
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

    /// The watchdog's figures the docs quote: PR 4 (÷64), 4000 counts, 8.0 s nominal, 5.45 s at the fastest LSI.
    #[test]
    fn watchdog_figures() {
        assert_eq!(WATCHDOG_PR_RL, (4, 3999));
        assert_eq!(WATCHDOG_TIMEOUT_MIN_US, 5_446_808);
    }

    /// The memory map's figures (`docs/update.md`, `docs/firmware.md`).
    #[test]
    fn memory_map_figures() {
        assert_eq!(APP_FLASH_BASE, 0x0802_0200);
        assert_eq!(APP_FLASH_BUDGET, 196_608);
        assert_eq!(
            DFU_BASE + DFU_LEN,
            0x080C_0000,
            "the spare sectors 10-11 stay free"
        );
        assert_eq!(
            CAL_FLASH_BASE + (CAL_SECTORS * CAL_SECTOR_LEN) as u32,
            STATE_BASE
        );
        assert!(sector_boundary(0x0800_C000) && !sector_boundary(0x0800_C004));
    }

    /// The bootloader's check of the application's vector table: the flight ELF's words pass, erased flash and
    /// each boundary fail.
    #[test]
    fn vector_table_check() {
        assert!(app_vectors_plausible(0x2001_0000, 0x0802_0399));
        assert!(app_vectors_plausible(0x2002_0000, 0x0803_FFFF));
        assert!(!app_vectors_plausible(0xFFFF_FFFF, 0xFFFF_FFFF), "erased");
        assert!(
            !app_vectors_plausible(0x2001_0000, 0x0802_0398),
            "ARM state"
        );
        assert!(
            !app_vectors_plausible(0x2001_0002, 0x0802_0399),
            "unaligned SP"
        );
        assert!(
            !app_vectors_plausible(0x2000_0020, 0x0802_0399),
            "SP in the boot report"
        );
        assert!(
            !app_vectors_plausible(0x2002_0004, 0x0802_0399),
            "SP past SRAM"
        );
        assert!(
            !app_vectors_plausible(0x1001_0000, 0x0802_0399),
            "SP in CCM"
        );
        assert!(
            !app_vectors_plausible(0x2001_0000, 0x0802_0201),
            "reset in the vector table"
        );
        assert!(
            !app_vectors_plausible(0x2001_0000, 0x0806_0001),
            "reset in DFU"
        );
        assert!(
            !app_vectors_plausible(0x2001_0000, 0x0800_0101),
            "reset in the bootloader"
        );
    }

    /// `ORIGIN` and `LENGTH` of `region` in the `MEMORY` block of a linker script (numbers as `0x…`, decimal or
    /// `…K`, added and subtracted).
    fn memory_region(script: &str, region: &str) -> (u32, u32) {
        let line = script
            .lines()
            .map(str::trim)
            .find(|l| l.split_whitespace().next() == Some(region))
            .unwrap_or_else(|| panic!("no {region} in the MEMORY block"));
        let term = |t: &str| -> i64 {
            let t = t.trim();
            if let Some(hex) = t.strip_prefix("0x") {
                i64::from_str_radix(hex, 16).unwrap()
            } else if let Some(k) = t.strip_suffix('K') {
                k.parse::<i64>().unwrap() * 1024
            } else {
                t.parse().unwrap()
            }
        };
        let number = |s: &str| -> u32 {
            // Terms joined by `+` and `-`, left to right.
            let mut total = 0i64;
            let mut sign = 1i64;
            let mut start = 0;
            for (i, c) in s.char_indices().chain([(s.len(), '+')]) {
                if c == '+' || c == '-' {
                    total += sign * term(&s[start..i]);
                    sign = if c == '+' { 1 } else { -1 };
                    start = i + 1;
                }
            }
            u32::try_from(total).unwrap()
        };
        let field = |name: &str| {
            let at = line.find(name).unwrap() + name.len();
            let rest = line[at..].trim_start().strip_prefix('=').unwrap();
            number(rest.split(',').next().unwrap())
        };
        (field("ORIGIN"), field("LENGTH"))
    }

    /// Both linker scripts say what this file says: the application's flash is ACTIVE after the header, the
    /// bootloader's is its two sectors, and both keep off the boot report (the bootloader inside the window the
    /// application leaves to its stack).
    #[test]
    fn linker_scripts_follow_the_map() {
        let app = include_str!("../memory.x");
        assert_eq!(
            memory_region(app, "FLASH"),
            (APP_FLASH_BASE, ACTIVE_LEN - IMAGE_HEADER_LEN)
        );
        assert_eq!(
            memory_region(app, "RAM"),
            (SRAM_BASE + BOOT_REPORT_LEN, SRAM_LEN - BOOT_REPORT_LEN)
        );
        let boot = include_str!("../../bootloader/memory.x");
        assert_eq!(
            memory_region(boot, "FLASH"),
            (BOOTLOADER_BASE, BOOTLOADER_LEN)
        );
        assert_eq!(
            memory_region(boot, "RAM"),
            (SRAM_BASE + BOOT_REPORT_LEN, BOOTLOADER_RAM_LEN)
        );
        for (region, base, len) in [
            ("BOOTLOADER_STATE", STATE_BASE, STATE_LEN),
            ("ACTIVE", ACTIVE_BASE, ACTIVE_LEN),
            ("DFU", DFU_BASE, DFU_LEN),
        ] {
            assert_eq!(memory_region(boot, region), (base, len), "{region}");
        }
    }
}
