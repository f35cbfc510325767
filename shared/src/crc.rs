//! CRC-32C (Castagnoli): the checksum of the FPGA frames, the calibration records and CSP packets.
//!
//! Parameters (Rocksoft model): poly `0x1EDC6F41` (reflected `0x82F63B78`), init `0xFFFFFFFF`, refin/refout true,
//! xorout `0xFFFFFFFF`, check (`"123456789"`) `0xE3069283`: the catalogue's CRC-32/ISCSI. libcsp's `csp_crc32` is
//! this CRC.
//!
//! Computed by the `crc` crate (`no_std`, no `unsafe`) with its one 1 KiB table, built at compile time. Its
//! sixteen-table variant ("slicing-by-16") saves ≈ 300 instructions per 240-byte frame on the Cortex-M4 (`mcu-bench`,
//! `docs/performance.md`) for 15 KiB more flash. The one-table variant stays since the application's budget grew
//! to 192 KiB (the update issue's memory map): 300 instructions are 1.2 % of a frame's 24.6 k, 15 KiB would be 8 %
//! of the budget. On a host (`target_os` not `none`) the sixteen tables are used: the ground tools check every
//! frame of recordings of hundreds of MB, and an 8-h frame log (131 MB) decodes in 0.22 s instead of 0.55 s (both
//! on a loaded machine). This module only names the algorithm and keeps the incremental interface the callers use.

use crc::{CRC_32_ISCSI, Crc, Digest, Table};

/// The tables: one on the MCU (flash, above).
#[cfg(target_os = "none")]
type Tables = Table<1>;
/// The tables: sixteen on a host (above), tested against the one-table form here.
#[cfg(not(target_os = "none"))]
type Tables = Table<16>;

/// The algorithm with its tables.
static CASTAGNOLI: Crc<u32, Tables> = Crc::<u32, Tables>::new(&CRC_32_ISCSI);

/// Incremental CRC-32C over several slices.
#[derive(Clone)]
pub struct Crc32c {
    digest: Digest<'static, u32, Tables>,
}

impl core::fmt::Debug for Crc32c {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Crc32c").finish_non_exhaustive()
    }
}

impl Default for Crc32c {
    fn default() -> Self {
        Self::new()
    }
}

impl Crc32c {
    /// A fresh computation.
    pub const fn new() -> Self {
        Self {
            digest: CASTAGNOLI.digest(),
        }
    }

    /// Feeds `bytes`.
    pub fn update(&mut self, bytes: &[u8]) {
        self.digest.update(bytes);
    }

    /// The CRC of everything fed so far.
    pub fn finish(&self) -> u32 {
        self.digest.clone().finalize()
    }
}

/// CRC-32C of one slice.
pub fn crc32c(bytes: &[u8]) -> u32 {
    CASTAGNOLI.checksum(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn check_value() {
        // The catalogue check value of CRC-32/ISCSI (= CRC-32C).
        assert_eq!(crc32c(b"123456789"), 0xE306_9283);
        assert_eq!(crc32c(b""), 0);
    }

    #[test]
    fn rfc3720_vectors() {
        // RFC 3720 (iSCSI), appendix B.4: 32 bytes of zeros, of 0xFF, and an ascending sequence.
        assert_eq!(crc32c(&[0u8; 32]), 0x8A91_36AA);
        assert_eq!(crc32c(&[0xFFu8; 32]), 0x62A8_AB43);
        let asc: [u8; 32] = core::array::from_fn(|i| i as u8);
        assert_eq!(crc32c(&asc), 0x46DD_794E);
    }

    #[test]
    fn incremental_equals_one_shot() {
        let data: [u8; 100] = core::array::from_fn(|i| (i * 37 + 11) as u8);
        let mut c = Crc32c::new();
        c.update(&data[..13]);
        c.update(&data[13..]);
        assert_eq!(c.finish(), crc32c(&data));
    }

    #[test]
    fn the_host_tables_give_the_mcu_tables_crc() {
        // The MCU's one-table form, which the host's tests would otherwise not run, on lengths around the
        // sixteen-byte stride.
        let mcu = Crc::<u32, Table<1>>::new(&CRC_32_ISCSI);
        let data: [u8; 300] = core::array::from_fn(|i| (i * 131 + 7) as u8);
        for len in [0, 1, 15, 16, 17, 31, 240, 300] {
            assert_eq!(crc32c(&data[..len]), mcu.checksum(&data[..len]), "{len}");
        }
    }
}
