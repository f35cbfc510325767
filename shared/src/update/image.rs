//! The signed image: a 512-byte header, then the payload (the application's flash contents from its vector table
//! on). Layout and rules: `docs/update.md`.
//!
//! The signature is Ed25519 (RFC 8032, `verify_strict`: no small-order keys, no malleable signatures) over the
//! header's first [`SIGNED_LEN`] bytes, which hold the payload's SHA-512: one signature binds the board, the version,
//! the length and every payload byte, and a verifier streams the payload through the hash instead of holding it.
//! `ed25519-dalek` and `sha2` (RustCrypto) do the cryptography; nothing here is hand-written crypto.

use embedded_storage::nor_flash::ReadNorFlash;
use sha2::{Digest, Sha512};

/// Header length, bytes: the application's vector table follows it (aligned to 512 B, as VTOR needs).
pub const HEADER_LEN: usize = 512;
/// Bytes the signature covers (magic … payload hash, reserved bytes included).
pub const SIGNED_LEN: usize = 128;
/// The signed bytes and the signature: what an upload's `Open` carries and what a slot's header starts with.
pub const OPEN_LEN: usize = SIGNED_LEN + SIGNATURE_LEN;
/// Ed25519 signature length, bytes.
pub const SIGNATURE_LEN: usize = 64;
/// SHA-512 digest length, bytes.
pub const HASH_LEN: usize = 64;
/// Header magic, `"IMUF"`.
pub const MAGIC: [u8; 4] = *b"IMUF";
/// Header format this code writes and reads.
pub const FORMAT: u16 = 1;
/// Where the payload's hash sits in the header.
const HASH_OFFSET: usize = 32;

/// Why an image (or an upload's header) is refused: each has its own code in telemetry and the boot report.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ImageError {
    /// Not an image header (magic).
    Magic,
    /// A header format or length this code does not read.
    Format,
    /// Built for another board.
    Board,
    /// Its version does not exceed the running image's (anti-rollback).
    Rollback,
    /// Header and payload do not fit the slot.
    TooLarge,
    /// The signature does not verify with our public key (or the key is not a valid point).
    Signature,
    /// The payload's SHA-512 is not the header's (a truncated or corrupted payload).
    Hash,
    /// The slot could not be read.
    Flash,
}

impl ImageError {
    /// A stable non-zero code (the boot report, telemetry counters): 1 … 8 in declaration order.
    pub const fn code(self) -> u8 {
        match self {
            Self::Magic => 1,
            Self::Format => 2,
            Self::Board => 3,
            Self::Rollback => 4,
            Self::TooLarge => 5,
            Self::Signature => 6,
            Self::Hash => 7,
            Self::Flash => 8,
        }
    }

    /// The error with [`code`](Self::code) `code`, if any.
    pub const fn from_code(code: u8) -> Option<Self> {
        Some(match code {
            1 => Self::Magic,
            2 => Self::Format,
            3 => Self::Board,
            4 => Self::Rollback,
            5 => Self::TooLarge,
            6 => Self::Signature,
            7 => Self::Hash,
            8 => Self::Flash,
            _ => return None,
        })
    }
}

/// A parsed image header (`docs/update.md`, "Image").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    /// The board the image is for (`firmware::layout::BOARD_ID`).
    pub board_id: u32,
    /// Firmware version: an image is accepted only above the running one.
    pub version: u32,
    /// Payload length, bytes (after the header).
    pub payload_len: u32,
    /// SHA-512 of the payload.
    pub payload_sha512: [u8; HASH_LEN],
    /// Ed25519 signature over the first [`SIGNED_LEN`] bytes.
    pub signature: [u8; SIGNATURE_LEN],
}

fn le_u32(b: &[u8], at: usize) -> u32 {
    let mut w = [0u8; 4];
    if let Some(s) = b.get(at..at.saturating_add(4)) {
        w.copy_from_slice(s);
    }
    u32::from_le_bytes(w)
}

impl Header {
    /// Parses the first [`OPEN_LEN`] bytes of `bytes` (a slot's start, or an upload's `Open`): magic, format and
    /// header length; nothing is trusted before [`check`](Self::check).
    pub fn parse(bytes: &[u8]) -> Result<Self, ImageError> {
        let b = bytes.get(..OPEN_LEN).ok_or(ImageError::Format)?;
        if b.get(..4) != Some(&MAGIC[..]) {
            return Err(ImageError::Magic);
        }
        let format = le_u32(b, 4);
        if format & 0xFFFF != u32::from(FORMAT) || (format >> 16) as usize != HEADER_LEN {
            return Err(ImageError::Format);
        }
        let mut payload_sha512 = [0u8; HASH_LEN];
        let mut signature = [0u8; SIGNATURE_LEN];
        payload_sha512.copy_from_slice(
            b.get(HASH_OFFSET..HASH_OFFSET + HASH_LEN)
                .unwrap_or(&[0; HASH_LEN]),
        );
        signature.copy_from_slice(b.get(SIGNED_LEN..OPEN_LEN).unwrap_or(&[0; SIGNATURE_LEN]));
        Ok(Self {
            board_id: le_u32(b, 8),
            version: le_u32(b, 12),
            payload_len: le_u32(b, 16),
            payload_sha512,
            signature,
        })
    }

    /// The bytes the signature covers (reserved bytes zero).
    pub fn signed_bytes(&self) -> [u8; SIGNED_LEN] {
        let mut b = [0u8; SIGNED_LEN];
        let format = u32::from(FORMAT) | ((HEADER_LEN as u32) << 16);
        for (at, v) in [
            (4usize, format),
            (8, self.board_id),
            (12, self.version),
            (16, self.payload_len),
        ] {
            if let Some(w) = b.get_mut(at..at.saturating_add(4)) {
                w.copy_from_slice(&v.to_le_bytes());
            }
        }
        if let Some(m) = b.get_mut(..4) {
            m.copy_from_slice(&MAGIC);
        }
        if let Some(h) = b.get_mut(HASH_OFFSET..HASH_OFFSET + HASH_LEN) {
            h.copy_from_slice(&self.payload_sha512);
        }
        b
    }

    /// The header as an upload's `Open` carries it and a slot starts with: signed bytes, then the signature.
    pub fn emit(&self) -> [u8; OPEN_LEN] {
        let mut b = [0u8; OPEN_LEN];
        let (signed, sig) = b.split_at_mut(SIGNED_LEN);
        signed.copy_from_slice(&self.signed_bytes());
        sig.copy_from_slice(&self.signature);
        b
    }

    /// Everything but the payload's hash: the board, the version against `running_version`, the size against
    /// `max_image_len` (header included), and the signature with `public_key`.
    pub fn check(
        &self,
        public_key: &[u8; 32],
        board_id: u32,
        running_version: u32,
        max_image_len: u32,
    ) -> Result<(), ImageError> {
        if self.board_id != board_id {
            return Err(ImageError::Board);
        }
        if self.version <= running_version {
            return Err(ImageError::Rollback);
        }
        let total = u64::from(self.payload_len).saturating_add(HEADER_LEN as u64);
        if self.payload_len == 0 || total > u64::from(max_image_len) {
            return Err(ImageError::TooLarge);
        }
        let key = ed25519_dalek::VerifyingKey::from_bytes(public_key)
            .map_err(|_| ImageError::Signature)?;
        let sig = ed25519_dalek::Signature::from_bytes(&self.signature);
        key.verify_strict(&self.signed_bytes(), &sig)
            .map_err(|_| ImageError::Signature)
    }
}

/// SHA-512 of `len` bytes of `slot` from `offset`, read 256 bytes at a time.
pub fn slot_sha512<F: ReadNorFlash>(
    slot: &mut F,
    offset: u32,
    len: u32,
) -> Result<[u8; HASH_LEN], ImageError> {
    let mut hasher = Sha512::new();
    let mut buf = [0u8; 256];
    let mut done = 0u32;
    while done < len {
        let n = len.saturating_sub(done).min(buf.len() as u32);
        let chunk = buf.get_mut(..n as usize).ok_or(ImageError::Flash)?;
        let at = offset.checked_add(done).ok_or(ImageError::TooLarge)?;
        slot.read(at, chunk).map_err(|_| ImageError::Flash)?;
        hasher.update(&*chunk);
        done = done.saturating_add(n);
    }
    Ok(hasher.finalize().into())
}

/// The header at the start of `slot`, if it parses (not checked: what a slot claims to hold, e.g. the running
/// image's version).
pub fn read_header<F: ReadNorFlash>(slot: &mut F) -> Result<Header, ImageError> {
    let mut b = [0u8; OPEN_LEN];
    slot.read(0, &mut b).map_err(|_| ImageError::Flash)?;
    Header::parse(&b)
}

/// The whole check of the image in `slot`: its header ([`Header::check`]; the image, header included, at most
/// `max_image_len` bytes) and its payload's SHA-512. What the bootloader runs before a swap and the firmware before
/// it commits one.
pub fn verify_slot<F: ReadNorFlash>(
    slot: &mut F,
    public_key: &[u8; 32],
    board_id: u32,
    running_version: u32,
    max_image_len: u32,
) -> Result<Header, ImageError> {
    let header = read_header(slot)?;
    header.check(public_key, board_id, running_version, max_image_len)?;
    if slot_sha512(slot, HEADER_LEN as u32, header.payload_len)? != header.payload_sha512 {
        return Err(ImageError::Hash);
    }
    Ok(header)
}
