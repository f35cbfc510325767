//! Wire formats: the FPGA link frame and its streaming decoder, and the CubeSat bus framing (CSP v1 in KISS).
//!
//! Each format follows one shape: a zero-copy view over bytes (`Frame<T>`, `CspHeader`) whose `new_checked`
//! guarantees that no accessor can fail afterwards, and a parsed representation (`…Repr`) with `parse` and `emit`
//! that mirror each other. Specifications: `docs/fpga-link.md`, `docs/bus.md`.

pub mod clock;
pub mod control;
pub mod decoder;
pub mod frame;

pub use clock::{FrameClock, Tick};
pub use control::{ControlError, FpgaControl};
pub use decoder::{Decoded, FrameDecoder, LinkCounters, SeqGap};
pub use frame::{Frame, FrameRepr, RawSample, WireError};
