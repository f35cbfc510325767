//! KISS framing as libcsp's serial interface uses it (spec: `docs/bus.md`).
//!
//! A frame on the wire is `FEND, 0x00 (data, KISS port 0), escaped bytes…, FEND`; inside, `FEND` is sent as
//! `FESC TFEND` and `FESC` as `FESC TFESC`. Every frame carries its own opening `FEND` (libcsp loses a frame that
//! shares its delimiter with the previous one), and we never send empty frames.
//!
//! The decoder is stricter than libcsp where libcsp loses data silently: an invalid escape, a non-data command byte
//! or an oversize frame gives a typed error (and the frame is dropped), and decoding resumes at the next `FEND`.

/// Frame end / start.
pub const FEND: u8 = 0xC0;
/// Escape.
pub const FESC: u8 = 0xDB;
/// Escaped FEND.
pub const TFEND: u8 = 0xDC;
/// Escaped FESC.
pub const TFESC: u8 = 0xDD;
/// KISS command byte of a data frame on port 0.
pub const CMD_DATA: u8 = 0x00;

/// Why a KISS frame was dropped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum KissError {
    /// `FESC` followed by something other than `TFEND`/`TFESC`.
    BadEscape,
    /// A command byte other than a data frame on port 0 (the byte received).
    Command(u8),
    /// More bytes than the decoder's buffer holds.
    Oversize,
    /// The output buffer of the encoder is too small.
    BufferTooSmall,
}

/// Largest encoded size of a frame of `n` bytes (saturating: no buffer is `usize::MAX` bytes long).
pub const fn encoded_len_max(n: usize) -> usize {
    n.saturating_mul(2).saturating_add(3)
}

/// Writes one frame holding `parts` (concatenated) into `out`; returns the encoded length.
pub fn encode(parts: &[&[u8]], out: &mut [u8]) -> Result<usize, KissError> {
    let mut w = Writer { out, at: 0 };
    w.put(FEND)?;
    w.put(CMD_DATA)?;
    for &b in parts.iter().flat_map(|p| p.iter()) {
        match b {
            FEND => w.put2(FESC, TFEND)?,
            FESC => w.put2(FESC, TFESC)?,
            _ => w.put(b)?,
        }
    }
    w.put(FEND)?;
    Ok(w.at)
}

struct Writer<'a> {
    out: &'a mut [u8],
    at: usize,
}

impl Writer<'_> {
    fn put(&mut self, b: u8) -> Result<(), KissError> {
        *self.out.get_mut(self.at).ok_or(KissError::BufferTooSmall)? = b;
        // `at` < `out.len()` here: cannot wrap.
        self.at = self.at.wrapping_add(1);
        Ok(())
    }

    fn put2(&mut self, a: u8, b: u8) -> Result<(), KissError> {
        self.put(a)?;
        self.put(b)
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum State {
    /// Waiting for FEND.
    Idle,
    /// After FEND: the next byte is the command (further FENDs are ignored).
    Command,
    /// Collecting data.
    Data,
    /// After FESC.
    Escaped,
    /// Dropping the rest of a bad frame until FEND.
    Skip,
}

/// Streaming KISS decoder with an `N`-byte frame buffer.
#[derive(Clone, Debug)]
pub struct KissDecoder<const N: usize> {
    buf: [u8; N],
    len: usize,
    state: State,
}

impl<const N: usize> Default for KissDecoder<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> KissDecoder<N> {
    /// A decoder waiting for the first `FEND`.
    pub const fn new() -> Self {
        Self {
            buf: [0; N],
            len: 0,
            state: State::Idle,
        }
    }

    /// Consumes bytes from `input` until a frame ends (its unescaped bytes, or why it was dropped) or `input` is
    /// used up (`None`). Empty frames (`FEND FEND`) are skipped silently.
    pub fn decode(&mut self, input: &mut &[u8]) -> Option<Result<&[u8], KissError>> {
        while let Some((&b, rest)) = input.split_first() {
            *input = rest;
            match (self.state, b) {
                (State::Idle | State::Skip, FEND) => self.state = State::Command,
                (State::Idle | State::Skip, _) => {}
                (State::Command, FEND) => {}
                (State::Command, CMD_DATA) => {
                    self.len = 0;
                    self.state = State::Data;
                }
                (State::Command, c) => {
                    self.state = State::Skip;
                    return Some(Err(KissError::Command(c)));
                }
                (State::Data, FEND) => {
                    self.state = State::Command;
                    if self.len > 0 {
                        return Some(Ok(self.buf.get(..self.len).unwrap_or(&[])));
                    }
                }
                (State::Data, FESC) => self.state = State::Escaped,
                (State::Data, _) => {
                    if let Some(e) = self.store(b) {
                        return Some(Err(e));
                    }
                }
                (State::Escaped, TFEND | TFESC) => {
                    self.state = State::Data;
                    if let Some(e) = self.store(if b == TFEND { FEND } else { FESC }) {
                        return Some(Err(e));
                    }
                }
                (State::Escaped, FEND) => {
                    // A frame cut inside an escape: drop it, and this FEND opens the next frame.
                    self.state = State::Command;
                    return Some(Err(KissError::BadEscape));
                }
                (State::Escaped, _) => {
                    self.state = State::Skip;
                    return Some(Err(KissError::BadEscape));
                }
            }
        }
        None
    }

    /// The bytes of the last frame returned by [`Self::decode`] (until the next call).
    pub fn last_frame(&self) -> &[u8] {
        self.buf.get(..self.len).unwrap_or(&[])
    }

    fn store(&mut self, b: u8) -> Option<KissError> {
        match self.buf.get_mut(self.len) {
            Some(slot) => {
                *slot = b;
                // `len` < N here: cannot wrap.
                self.len = self.len.wrapping_add(1);
                None
            }
            None => {
                self.state = State::Skip;
                Some(KissError::Oversize)
            }
        }
    }
}
