//! STM32F405 facts shared by the board support (`board.rs`, flight) and the host models (`sim`): where the
//! calibration lives in flash and how fast the lines run. Pins, DMA streams and clocks stay in `board.rs`.

/// Calibration slots: sectors 10 (A) and 11 (B) of bank 1, at 0x080C_0000 (RM0090 §3.3, table 5).
pub const CAL_FLASH_BASE: u32 = 0x080C_0000;
/// Size of one calibration sector, bytes (the F405's sectors 5–11 are 128 KiB).
pub const CAL_SECTOR_LEN: usize = 128 * 1024;
/// Calibration sectors (one per slot).
pub const CAL_SECTORS: usize = 2;
/// Program granularity of the F405 flash as embassy-stm32 drives it, bytes.
pub const FLASH_WRITE_LEN: usize = 4;

/// FPGA link line rate, baud (8N1): USART1 on PCLK2 = 84 MHz / 42.
pub const FPGA_BAUD: u32 = 2_000_000;
/// CubeSat bus line rate, baud (8N1).
pub const BUS_BAUD: u32 = 115_200;
/// DMA ring of the FPGA link, bytes: 8 KiB = 41 ms at 2 Mbaud = 34 frames of slack.
pub const FPGA_RX_RING_LEN: usize = 8 * 1024;
