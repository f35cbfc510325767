//! Calibration records in two flash slots, A and B, that survive a power cut at any point of an update
//! (spec: `docs/storage.md`). Generic over the `embedded-storage` NOR-flash traits.
//!
//! Slot A is the first half of the flash region, slot B the second; each half is a whole number of erase blocks.
//! A record, at the start of its slot:
//!
//! ```text
//! offset  size  field
//!      0     4  magic "CAL1" (0x314C4143 little-endian), written last
//!      4     4  sequence number, u32 LE, +1 per update (wrapping)
//!      8     4  payload length L, u32 LE
//!     12     L  payload: an encoded `CalibrationTable` (which has its own CRC)
//!   12+L     4  CRC-32C of bytes 0 .. 12+L (magic included)
//! ```
//! padded with 0xFF to the flash's write size. Boot loads the newer of the valid records; an update erases the
//! *other* slot, writes everything but the magic, then the magic. A cut before the magic is written leaves that
//! slot without a record; a cut inside an erase leaves garbage that fails the CRC; the old record is untouched
//! either way. `tests::power_cut_at_every_step_always_loads_a_valid_calibration` cuts power at every single erase
//! and word write of several consecutive updates.
//!
//! # Which record is newer
//! Sequence numbers wrap (0xFFFFFFFF + 1 = 0), so they are compared by serial-number arithmetic (RFC 1982): `b` is
//! newer than `a` iff `b.wrapping_sub(a)`, read as an `i32`, is positive ([`is_newer`]). Two valid records written
//! by [`CalStore::store`] always differ by exactly 1, so the rule is never ambiguous for them; records that are
//! equal or 2³¹ apart (neither newer) count slot A as the newer, in both `load` and `store`.

use crate::calib::CalibrationTable;
use crate::crc::Crc32c;
use embedded_storage::nor_flash::NorFlash;

/// Record magic, "CAL1".
pub const MAGIC: u32 = u32::from_le_bytes(*b"CAL1");
const HEADER_LEN: usize = 12;
const CRC_LEN: usize = 4;
/// Bytes read or written per flash call (a multiple of every sane write size).
const CHUNK: usize = 64;

/// Whether sequence number `b` is newer than `a`: serial-number arithmetic (RFC 1982) on `u32`, so that `0` is
/// newer than `0xFFFFFFFF`. False if they are equal or exactly 2³¹ apart.
pub fn is_newer(b: u32, a: u32) -> bool {
    (b.wrapping_sub(a) as i32) > 0
}

/// The slot holding the newer of two valid records, and its sequence number (`seqs`: the sequence numbers of
/// slots A and B, `None` for a slot without a valid record); slot A if neither is newer. `None` if neither slot
/// holds one.
fn newest(seqs: [Option<u32>; 2]) -> Option<(usize, u32)> {
    match seqs {
        [Some(a), Some(b)] if is_newer(b, a) => Some((1, b)),
        [Some(a), _] => Some((0, a)),
        [None, Some(b)] => Some((1, b)),
        [None, None] => None,
    }
}

/// What a slot holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SlotState {
    /// No magic: erased, or an update was cut before it completed.
    Empty,
    /// Magic present but length, CRC or contents invalid.
    Invalid,
    /// A valid record with this sequence number.
    Valid(u32),
}

/// Why the store failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StoreError<E> {
    /// The region cannot hold two slots of whole erase blocks, or the record does not fit a slot.
    Geometry,
    /// The table could not be encoded into the scratch buffer.
    Encode,
    /// The flash driver failed.
    Flash(E),
    /// The record read back is not the one written (the flash did not take it).
    Verify,
}

/// The outcome of [`CalStore::load`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Loaded<const G: usize> {
    /// The table to use: the newest valid record, or the factory default.
    pub table: CalibrationTable<G>,
    /// Sequence number of the record, `None` for the factory default.
    pub seq: Option<u32>,
    /// What each slot held: `[A, B]`.
    pub slots: [SlotState; 2],
}

/// What [`CalStore::load_into`] found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LoadInfo {
    /// Sequence number of the record loaded, `None`: the factory default.
    pub seq: Option<u32>,
    /// What each slot held: `[A, B]`.
    pub slots: [SlotState; 2],
}

/// Two-slot calibration store over a NOR flash region.
pub struct CalStore<F> {
    flash: F,
    slot_size: u32,
}

impl<F: NorFlash> CalStore<F> {
    /// Uses the whole of `flash`: slot A its first half, slot B its second. The region must be addressable with
    /// `u32` offsets (as `NorFlash` addresses it), so that no offset computed in a slot can wrap.
    pub fn new(flash: F) -> Result<Self, StoreError<F::Error>> {
        let Ok(capacity) = u32::try_from(flash.capacity()) else {
            return Err(StoreError::Geometry);
        };
        let slot_size = capacity / 2;
        if slot_size == 0
            || !(slot_size as usize).is_multiple_of(F::ERASE_SIZE)
            || !CHUNK.is_multiple_of(F::WRITE_SIZE.max(1))
        {
            return Err(StoreError::Geometry);
        }
        Ok(Self { flash, slot_size })
    }

    /// Gives the flash back.
    pub fn into_inner(self) -> F {
        self.flash
    }

    fn base(&self, slot: usize) -> u32 {
        if slot == 0 { 0 } else { self.slot_size }
    }

    /// Reads and checks `slot`; on success the payload is in `scratch[..len]`.
    fn read_slot(
        &mut self,
        slot: usize,
        scratch: &mut [u8],
    ) -> Result<(SlotState, usize), F::Error> {
        let base = self.base(slot);
        let mut head = [0u8; HEADER_LEN];
        self.flash.read(base, &mut head)?;
        let [m0, m1, m2, m3, s0, s1, s2, s3, l0, l1, l2, l3] = head;
        if u32::from_le_bytes([m0, m1, m2, m3]) != MAGIC {
            return Ok((SlotState::Empty, 0));
        }
        // The length comes from flash (an erased word reads 0xFFFFFFFF), so it is checked against the slot in u32
        // with checked arithmetic: `HEADER_LEN + len + CRC_LEN` in usize overflowed on a 32-bit target.
        let (seq, len) = (
            u32::from_le_bytes([s0, s1, s2, s3]),
            u32::from_le_bytes([l0, l1, l2, l3]),
        );
        let fits = len
            .checked_add((HEADER_LEN + CRC_LEN) as u32)
            .is_some_and(|end| end <= self.slot_size);
        let Some(payload) = fits
            .then_some(len as usize)
            .and_then(|len| scratch.get_mut(..len))
        else {
            return Ok((SlotState::Invalid, 0));
        };
        let len = payload.len();
        let mut crc = Crc32c::new();
        crc.update(&head);
        // Offsets stay below base + slot_size ≤ capacity < 2³² (`new`; `fits` above): the sums cannot wrap.
        let mut at = base.wrapping_add(HEADER_LEN as u32);
        for chunk in payload.chunks_mut(CHUNK) {
            self.flash.read(at, chunk)?;
            crc.update(chunk);
            at = at.wrapping_add(chunk.len() as u32);
        }
        let mut stored = [0u8; CRC_LEN];
        self.flash.read(at, &mut stored)?;
        if crc.finish() != u32::from_le_bytes(stored) {
            return Ok((SlotState::Invalid, 0));
        }
        Ok((SlotState::Valid(seq), len))
    }

    /// Reads `slot` and checks its table: the one rule of validity that `load` and `store` share. A record whose
    /// CRC is right but whose table does not decode (another format version, another group count) is `Invalid`.
    /// On `Valid`, the encoded table is in `scratch[..len]`.
    fn read_table<const G: usize>(
        &mut self,
        slot: usize,
        scratch: &mut [u8],
    ) -> Result<(SlotState, usize), F::Error> {
        let (s, len) = self.read_slot(slot, scratch)?;
        if !matches!(s, SlotState::Valid(_)) {
            return Ok((s, 0));
        }
        Ok(match scratch.get(..len).map(CalibrationTable::<G>::check) {
            Some(Ok(())) => (s, len),
            _ => (SlotState::Invalid, 0),
        })
    }

    /// Loads the newest valid calibration (by [`is_newer`]) into `out`, or the factory default if no slot holds
    /// one. `scratch` must hold an encoded table (`calib::encoded_len_max(G)` bytes). In place: the slots are
    /// checked first, then the newest is read again and decoded into `out` ([`CalibrationTable::decode_into`]), so
    /// that no table is ever a temporary (`docs/firmware.md`, stack). On a flash error `out` is unchanged.
    pub fn load_into<const G: usize>(
        &mut self,
        scratch: &mut [u8],
        out: &mut CalibrationTable<G>,
    ) -> Result<LoadInfo, F::Error> {
        let mut slots = [SlotState::Empty; 2];
        let mut best: Option<(usize, u32)> = None;
        for (slot, state) in slots.iter_mut().enumerate() {
            let (s, _) = self.read_table::<G>(slot, scratch)?;
            *state = s;
            if let SlotState::Valid(seq) = s {
                // Slot A is read first: on a tie (neither newer) it stays, as in `newest`.
                if best.is_none_or(|(_, b)| is_newer(seq, b)) {
                    best = Some((slot, seq));
                }
            }
        }
        let Some((slot, seq)) = best else {
            out.set_factory();
            return Ok(LoadInfo { seq: None, slots });
        };
        let (s, len) = self.read_table::<G>(slot, scratch)?;
        let bytes = scratch.get(..len).unwrap_or(&[]);
        // The slot checked valid a moment ago; if it reads otherwise now, the factory default (and the slot as seen).
        if s != SlotState::Valid(seq) || out.decode_into(bytes).is_err() {
            out.set_factory();
            if let Some(state) = slots.get_mut(slot) {
                *state = s;
            }
            return Ok(LoadInfo { seq: None, slots });
        }
        Ok(LoadInfo {
            seq: Some(seq),
            slots,
        })
    }

    /// [`Self::load_into`] returning the table by value (host tools and tests; the MCU loads in place).
    pub fn load<const G: usize>(&mut self, scratch: &mut [u8]) -> Result<Loaded<G>, F::Error> {
        let mut table = CalibrationTable::factory();
        let info = self.load_into(scratch, &mut table)?;
        Ok(Loaded {
            table,
            seq: info.seq,
            slots: info.slots,
        })
    }

    /// Writes `table` as the new newest record into the slot that does not hold the current one; returns its
    /// sequence number. `scratch` must hold the record (header + encoded table + CRC).
    pub fn store<const G: usize>(
        &mut self,
        table: &CalibrationTable<G>,
        scratch: &mut [u8],
    ) -> Result<u32, StoreError<F::Error>> {
        // Which slot is current (the newer valid sequence number, valid as `load` sees it: a record whose table
        // does not decode is not current, so the only loadable record is never the one erased)?
        let mut seqs = [None; 2];
        for (slot, s) in seqs.iter_mut().enumerate() {
            if let (SlotState::Valid(seq), _) = self
                .read_table::<G>(slot, scratch)
                .map_err(StoreError::Flash)?
            {
                *s = Some(seq);
            }
        }
        let (target, seq) = match newest(seqs) {
            Some((0, s)) => (1, s.wrapping_add(1)),
            Some((_, s)) => (0, s.wrapping_add(1)),
            None => (0, 1),
        };

        // Build the record in scratch, padded to the write size.
        let len = {
            let body = scratch.get_mut(HEADER_LEN..).ok_or(StoreError::Encode)?;
            table.encode(body).map_err(|_| StoreError::Encode)?.len()
        };
        // Header, payload and CRC, padded: the record must fit the slot (so `len` fits `u32`).
        let Some(padded) = len
            .checked_add(HEADER_LEN + CRC_LEN)
            .and_then(|end| end.checked_next_multiple_of(F::WRITE_SIZE.max(1)))
            .filter(|&padded| padded <= self.slot_size as usize)
        else {
            return Err(StoreError::Geometry);
        };
        let record = scratch.get_mut(..padded).ok_or(StoreError::Encode)?;
        let (header, body) = record
            .split_first_chunk_mut::<HEADER_LEN>()
            .ok_or(StoreError::Encode)?;
        header[..4].copy_from_slice(&MAGIC.to_le_bytes());
        header[4..8].copy_from_slice(&seq.to_le_bytes());
        header[8..].copy_from_slice(&(len as u32).to_le_bytes());
        let mut crc = Crc32c::new();
        crc.update(header);
        let (payload, tail) = body.split_at_mut_checked(len).ok_or(StoreError::Encode)?;
        crc.update(payload);
        let (stored_crc, padding) = tail
            .split_first_chunk_mut::<CRC_LEN>()
            .ok_or(StoreError::Encode)?;
        *stored_crc = crc.finish().to_le_bytes();
        padding.fill(0xFF);

        // Erase, write all but the magic, then the magic. Offsets stay within the slot, below capacity < 2³²
        // (`new`): the sums cannot wrap.
        let base = self.base(target);
        self.flash
            .erase(base, base.wrapping_add(self.slot_size))
            .map_err(StoreError::Flash)?;
        let first = F::WRITE_SIZE.max(4);
        let (head, rest) = record.split_at(first.min(record.len()));
        let mut at = base.wrapping_add(head.len() as u32);
        for chunk in rest.chunks(CHUNK) {
            self.flash.write(at, chunk).map_err(StoreError::Flash)?;
            at = at.wrapping_add(chunk.len() as u32);
        }
        self.flash.write(base, head).map_err(StoreError::Flash)?;
        // Read back: the slot must load as the record written, or the caller is not told the table is safe.
        match self.read_table::<G>(target, scratch) {
            Ok((SlotState::Valid(s), len))
                if s == seq && scratch.get(..len).is_some_and(|b| table.encodes_as(b)) =>
            {
                Ok(seq)
            }
            Ok(_) => Err(StoreError::Verify),
            Err(e) => Err(StoreError::Flash(e)),
        }
    }
}

#[cfg(any(test, feature = "mock-flash"))]
pub mod mock;
#[cfg(test)]
mod tests;
