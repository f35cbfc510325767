//! The ground side of the in-orbit update (`docs/update.md`): the application's flash contents from its ELF
//! ([`image_from_elf`]), the signed image ([`sign`], [`SignedImage`]), the signing keys ([`generate_keypair`], PKCS#8
//! PEM private keys, hex public keys), the upload client ([`Uploader`], sans-IO) and its driver over a serial link
//! ([`link`]).
//!
//! The image format and the satellite's receiver are `shared::update`'s; this module only builds what they check.
//! The cryptography is `ed25519-dalek`'s and `sha2`'s, the ELF reading `object`'s.

pub mod link;
pub mod uploader;

pub use link::{BusAddrs, Link, LinkError, SerialLink, UpdateFramer, upload};
pub use uploader::{UploadConfig, UploadError, UploadEvent, UploadSummary, Uploader};

use ed25519_dalek::pkcs8::{
    DecodePrivateKey, EncodePrivateKey, KeypairBytes, spki::der::pem::LineEnding,
};
use ed25519_dalek::{Signer, SigningKey, VerifyingKey};
use object::read::elf::{ElfFile32, ProgramHeader};
use sha2::{Digest, Sha512};
use shared::update::image::{HEADER_LEN, Header, OPEN_LEN};
use std::path::{Path, PathBuf};

/// Start of the flash (STM32F405, RM0090 table 5).
pub const FLASH_START: u32 = 0x0800_0000;
/// End of the flash (1 MiB), exclusive.
pub const FLASH_END: u32 = 0x0810_0000;
/// The ACTIVE slot (sectors 5–6, `docs/update.md` "Memory map").
pub const ACTIVE_SLOT: u32 = 0x0802_0000;
/// Size of the ACTIVE slot, bytes: the largest image, header included.
pub const ACTIVE_LEN: u32 = 256 * 1024;
/// Where the application links: the ACTIVE slot after the image header (its vector table, 512-byte aligned).
pub const APP_BASE: u32 = ACTIVE_SLOT + HEADER_LEN as u32;
/// Largest payload: the ACTIVE slot less the header.
pub const PAYLOAD_MAX: u32 = ACTIVE_LEN - HEADER_LEN as u32;

/// The application's flash contents, as they go after the image header.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Payload {
    /// Flash address of the first byte (the vector table: [`APP_BASE`]).
    pub base: u32,
    /// The bytes, from `base` to the end of the last loaded byte, gaps filled with `0xFF` (erased flash).
    pub bytes: Vec<u8>,
}

/// Why an ELF file does not give a payload.
#[derive(Debug, thiserror::Error)]
pub enum ElfError {
    /// Not a 32-bit ELF file, or its program headers do not parse.
    #[error("not a 32-bit ELF file: {0}")]
    Parse(#[from] object::Error),
    /// A segment's file range lies outside the file.
    #[error("the segment at {0:#010x} lies outside the file (a truncated ELF?)")]
    SegmentData(u32),
    /// No `PT_LOAD` segment with file contents lies in flash.
    #[error("no loadable segment in flash ({FLASH_START:#010x}..{FLASH_END:#010x})")]
    NoFlashSegment,
    /// A segment starts in flash but runs past its end.
    #[error("the segment at {start:#010x} ({len} bytes) runs past the end of the flash")]
    PastFlash {
        /// Its load address.
        start: u32,
        /// Its file size.
        len: u32,
    },
    /// The lowest load address is not 512-byte aligned (VTOR needs it for the vector table).
    #[error("the flash contents start at {0:#010x}, which is not 512-byte aligned")]
    Misaligned(u32),
    /// The application does not link at the ACTIVE slot after the header.
    #[error(
        "the flash contents start at {found:#010x}, not at {APP_BASE:#010x} (the ACTIVE slot + the 512-byte \
         header): is this the application built for the bootloader?"
    )]
    Base {
        /// The lowest load address.
        found: u32,
    },
    /// Two segments load at the same flash bytes.
    #[error("segments overlap at {0:#010x}")]
    Overlap(u32),
    /// The payload does not fit the ACTIVE slot.
    #[error(
        "the flash contents are {len} bytes; the ACTIVE slot holds {PAYLOAD_MAX} after the header"
    )]
    TooLarge {
        /// Payload length, bytes.
        len: u64,
    },
}

/// The application's flash contents from its ELF: the `PT_LOAD` segments with file contents whose physical (load)
/// address lies in flash, from the lowest address, gaps filled with `0xFF`. The lowest address must be
/// [`APP_BASE`] (512-byte aligned, as the vector table needs).
pub fn image_from_elf(elf: &[u8]) -> Result<Payload, ElfError> {
    let file = ElfFile32::<object::Endianness>::parse(elf)?;
    let endian = file.endian();
    let mut segments: Vec<(u32, &[u8])> = Vec::new();
    for ph in file.elf_program_headers() {
        if ph.p_type(endian) != object::elf::PT_LOAD || ph.p_filesz(endian) == 0 {
            continue;
        }
        let start = ph.p_paddr(endian);
        if !(FLASH_START..FLASH_END).contains(&start) {
            continue;
        }
        let data = ph
            .data(endian, elf)
            .map_err(|()| ElfError::SegmentData(start))?;
        let len = ph.p_filesz(endian);
        if u64::from(start) + u64::from(len) > u64::from(FLASH_END) {
            return Err(ElfError::PastFlash { start, len });
        }
        segments.push((start, data));
    }
    segments.sort_by_key(|&(start, _)| start);
    let base = segments.first().ok_or(ElfError::NoFlashSegment)?.0;
    if !base.is_multiple_of(HEADER_LEN as u32) {
        return Err(ElfError::Misaligned(base));
    }
    if base != APP_BASE {
        return Err(ElfError::Base { found: base });
    }
    let end = segments
        .iter()
        .map(|&(s, d)| u64::from(s) + d.len() as u64)
        .max()
        .unwrap_or(u64::from(base));
    let len = end - u64::from(base);
    if len > u64::from(PAYLOAD_MAX) {
        return Err(ElfError::TooLarge { len });
    }
    let mut bytes = vec![0xFF; len as usize];
    let mut filled_to = u64::from(base);
    for (start, data) in segments {
        if u64::from(start) < filled_to {
            return Err(ElfError::Overlap(start));
        }
        let at = (start - base) as usize;
        bytes[at..at + data.len()].copy_from_slice(data);
        filled_to = u64::from(start) + data.len() as u64;
    }
    Ok(Payload { base, bytes })
}

/// Why an image cannot be signed.
#[derive(Debug, thiserror::Error)]
pub enum SignError {
    /// An empty payload (the satellite refuses it).
    #[error("the payload is empty")]
    Empty,
    /// A payload larger than the ACTIVE slot holds.
    #[error("the payload is {0} bytes; the ACTIVE slot holds {PAYLOAD_MAX} after the header")]
    TooLarge(usize),
}

/// The signed image: the 512-byte header (the signed 128 bytes and their Ed25519 signature, then `0xFF`: the
/// receiver's erase marks go there in the DFU slot) followed by `payload`.
pub fn sign(
    payload: &[u8],
    key: &SigningKey,
    version: u32,
    board_id: u32,
) -> Result<Vec<u8>, SignError> {
    if payload.is_empty() {
        return Err(SignError::Empty);
    }
    let payload_len = u32::try_from(payload.len())
        .ok()
        .filter(|&n| n <= PAYLOAD_MAX)
        .ok_or(SignError::TooLarge(payload.len()))?;
    let mut header = Header {
        board_id,
        version,
        payload_len,
        payload_sha512: Sha512::digest(payload).into(),
        signature: [0; 64],
    };
    header.signature = key.sign(&header.signed_bytes()).to_bytes();
    let mut image = Vec::with_capacity(HEADER_LEN + payload.len());
    image.extend_from_slice(&header.emit());
    image.resize(HEADER_LEN, 0xFF);
    image.extend_from_slice(payload);
    Ok(image)
}

/// Why bytes are not a signed image.
#[derive(Debug, thiserror::Error)]
pub enum ImageFileError {
    /// The header does not parse (magic, format, length).
    #[error("not a signed image: {0:?} (the header does not parse)")]
    Header(shared::update::ImageError),
    /// The file's length is not the header's plus its payload length.
    #[error("the image is {found} bytes; its header says {expected} (512 + the payload)")]
    Length {
        /// Bytes in the file.
        found: usize,
        /// Header plus payload length.
        expected: u64,
    },
    /// The payload's SHA-512 is not the header's.
    #[error("the payload's SHA-512 is not the header's: the file is corrupted")]
    Hash,
    /// The signature does not verify with the given public key.
    #[error("the signature does not verify with the public key {0}")]
    Signature(String),
}

/// A signed image read back: its header, the bytes an upload's `Open` carries, and the payload.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SignedImage {
    /// The parsed header.
    pub header: Header,
    /// The payload.
    pub payload: Vec<u8>,
}

impl SignedImage {
    /// Parses `bytes` (what [`sign`] wrote): the header, the length, the payload's hash. The signature is not
    /// checked here ([`SignedImage::check_signature`]).
    pub fn parse(bytes: &[u8]) -> Result<Self, ImageFileError> {
        let header = Header::parse(bytes).map_err(ImageFileError::Header)?;
        let expected = HEADER_LEN as u64 + u64::from(header.payload_len);
        if bytes.len() as u64 != expected {
            return Err(ImageFileError::Length {
                found: bytes.len(),
                expected,
            });
        }
        let payload = bytes[HEADER_LEN..].to_vec();
        if <[u8; 64]>::from(Sha512::digest(&payload)) != header.payload_sha512 {
            return Err(ImageFileError::Hash);
        }
        Ok(Self { header, payload })
    }

    /// The header as `Open` carries it.
    pub fn open_bytes(&self) -> [u8; OPEN_LEN] {
        self.header.emit()
    }

    /// Whether the signature verifies with `public_key` (strictly, as the satellite checks it).
    pub fn check_signature(&self, public_key: &VerifyingKey) -> Result<(), ImageFileError> {
        let sig = ed25519_dalek::Signature::from_bytes(&self.header.signature);
        public_key
            .verify_strict(&self.header.signed_bytes(), &sig)
            .map_err(|_| ImageFileError::Signature(public_key_hex(public_key)))
    }
}

/// Why a key cannot be read or written.
#[derive(Debug, thiserror::Error)]
pub enum KeyError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// Not an Ed25519 private key in PKCS#8 PEM.
    #[error("{path}: not an Ed25519 private key in PKCS#8 PEM ({source})")]
    Pem {
        /// The file.
        path: PathBuf,
        /// The cause.
        #[source]
        source: ed25519_dalek::pkcs8::Error,
    },
    /// Not 64 hex digits.
    #[error("{path}: a public key is 64 hex digits (lines starting with # are comments): {reason}")]
    PublicHex {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// 32 bytes that are not an Ed25519 public key (not a curve point).
    #[error("{path}: not an Ed25519 public key (not a point of the curve)")]
    PublicPoint {
        /// The file.
        path: PathBuf,
    },
    /// The operating system gave no random bytes.
    #[error("no random bytes from the operating system: {0}")]
    Random(String),
    /// PKCS#8 encoding failed.
    #[error("encoding the private key: {0}")]
    Encode(String),
}

/// A fresh signing key from the operating system's random numbers.
pub fn generate_keypair() -> Result<SigningKey, KeyError> {
    let mut seed = [0u8; 32];
    getrandom::fill(&mut seed).map_err(|e| KeyError::Random(e.to_string()))?;
    Ok(SigningKey::from_bytes(&seed))
}

/// The private key as PKCS#8 v1 PEM, the seed alone: what `openssl genpkey -algorithm ed25519` writes (OpenSSL 3.0
/// does not read the v2 form with the public key attached, which `SigningKey::to_pkcs8_pem` writes).
pub fn private_key_pem(key: &SigningKey) -> Result<String, KeyError> {
    let bytes = KeypairBytes {
        secret_key: key.to_bytes(),
        public_key: None,
    };
    bytes
        .to_pkcs8_pem(LineEnding::LF)
        .map(|pem| pem.to_string())
        .map_err(|e| KeyError::Encode(e.to_string()))
}

/// Parses a PKCS#8 PEM private key (`path` names it in errors).
pub fn parse_private_key(pem: &str, path: &Path) -> Result<SigningKey, KeyError> {
    SigningKey::from_pkcs8_pem(pem).map_err(|source| KeyError::Pem {
        path: path.to_path_buf(),
        source,
    })
}

/// Reads a PKCS#8 PEM private key file.
pub fn read_private_key(path: &Path) -> Result<SigningKey, KeyError> {
    let pem = std::fs::read_to_string(path).map_err(|source| KeyError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_private_key(&pem, path)
}

/// The public key as its file holds it: 64 lower-case hex digits and a newline.
pub fn public_key_hex(key: &VerifyingKey) -> String {
    hex::encode(key.as_bytes())
}

/// Parses a public key file's text: 64 hex digits; white space and lines starting with `#` are ignored (as the
/// build scripts' reader, `keys/update_pubkey.rs`, does).
pub fn parse_public_key(text: &str, path: &Path) -> Result<VerifyingKey, KeyError> {
    let digits: String = text
        .lines()
        .filter(|l| !l.trim_start().starts_with('#'))
        .flat_map(str::chars)
        .filter(|c| !c.is_whitespace())
        .collect();
    let bad = |reason: String| KeyError::PublicHex {
        path: path.to_path_buf(),
        reason,
    };
    let mut key = [0u8; 32];
    hex::decode_to_slice(&digits, &mut key).map_err(|e| bad(format!("{e} in {digits:?}")))?;
    VerifyingKey::from_bytes(&key).map_err(|_| KeyError::PublicPoint {
        path: path.to_path_buf(),
    })
}

/// Reads a public key file (`keys/update-dev.pub` style).
pub fn read_public_key(path: &Path) -> Result<VerifyingKey, KeyError> {
    let text = std::fs::read_to_string(path).map_err(|source| KeyError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_public_key(&text, path)
}

/// `prefix` with `ext` appended (`keys/flight` → `keys/flight.pem`).
fn with_ext(prefix: &Path, ext: &str) -> PathBuf {
    let mut s = prefix.as_os_str().to_os_string();
    s.push(ext);
    PathBuf::from(s)
}

/// Writes `key` as `PREFIX.pem` (PKCS#8 PEM, created with mode 0600; an existing file is not overwritten) and its
/// public half as `PREFIX.pub` (64 hex digits); returns both paths.
pub fn write_keypair(key: &SigningKey, prefix: &Path) -> Result<(PathBuf, PathBuf), KeyError> {
    use std::io::Write;
    let (pem_path, pub_path) = (with_ext(prefix, ".pem"), with_ext(prefix, ".pub"));
    let pem = private_key_pem(key)?;
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| KeyError::Io { path, source }
    };
    let mut options = std::fs::OpenOptions::new();
    options.write(true).create_new(true);
    #[cfg(unix)]
    std::os::unix::fs::OpenOptionsExt::mode(&mut options, 0o600);
    let mut f = options.open(&pem_path).map_err(io(&pem_path))?;
    f.write_all(pem.as_bytes())
        .and_then(|()| f.sync_all())
        .map_err(io(&pem_path))?;
    std::fs::write(
        &pub_path,
        format!("{}\n", public_key_hex(&key.verifying_key())),
    )
    .map_err(io(&pub_path))?;
    Ok((pem_path, pub_path))
}
