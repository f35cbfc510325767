//! The FPGA link's wire formats: its frame and streaming decoder, the frame clock, and the control messages to the
//! FPGA. (The CubeSat bus framing, CSP in KISS, is `crate::bus`.)
//!
//! Each format follows one shape: a zero-copy view over bytes (`Frame<T>`) whose `new_checked`
//! guarantees that no accessor can fail afterwards, and a parsed representation (`…Repr`) with `parse` and `emit`
//! that mirror each other. Specification: `docs/fpga-link.md`.

pub mod clock;
pub mod control;
pub mod decoder;
pub mod frame;

pub use clock::{FrameClock, Tick};
pub use control::{ControlError, FpgaControl};
pub use decoder::{Decoded, FrameDecoder, LinkCounters, SeqGap};
pub use frame::{Frame, FrameRepr, RawSample, WireError};
