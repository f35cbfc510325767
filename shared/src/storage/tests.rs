use super::*;
use crate::calib::encoded_len_max;
use embedded_storage::nor_flash::{ErrorType, ReadNorFlash};

extern crate std;
use std::vec;
use std::vec::Vec;

const SLOT_BLOCKS: usize = 3;
const G: usize = 16;

use super::mock::{ERASE, MockError, MockFlash};

/// The test flash: two slots of `SLOT_BLOCKS` erase blocks.
fn new_flash() -> MockFlash {
    MockFlash::erased(2 * SLOT_BLOCKS)
}

fn table(id: u32) -> CalibrationTable<G> {
    let mut t = CalibrationTable::factory();
    t.cal_id = id;
    t.groups[(id as usize) % G].accel_bias_q12[1] += id as i32 * 1000;
    t
}

fn scratch() -> Vec<u8> {
    vec![0u8; HEADER_LEN + encoded_len_max(G) + CRC_LEN + 8]
}

fn load(flash: MockFlash) -> Loaded<G> {
    let mut store = CalStore::new(MockFlash {
        budget: None,
        ..flash
    })
    .unwrap();
    store.load::<G>(&mut scratch()).unwrap()
}

#[test]
fn empty_flash_loads_the_factory_default() {
    let l = load(new_flash());
    assert_eq!(
        (l.table, l.seq, l.slots),
        (CalibrationTable::factory(), None, [SlotState::Empty; 2])
    );
}

#[test]
fn updates_alternate_slots_and_the_newest_wins() {
    let mut store = CalStore::new(new_flash()).unwrap();
    let mut s = scratch();
    assert_eq!(store.store(&table(1), &mut s), Ok(1));
    assert_eq!(store.store(&table(2), &mut s), Ok(2));
    assert_eq!(store.store(&table(3), &mut s), Ok(3));
    let l = store.load::<G>(&mut s).unwrap();
    assert_eq!(
        (l.table, l.seq, l.slots),
        (
            table(3),
            Some(3),
            [SlotState::Valid(3), SlotState::Valid(2)]
        )
    );
}

/// Writes a valid record of `table(id)` with sequence number `seq` at the start of `slot` (0 = A, 1 = B), byte for
/// byte as `store` would, to start from any sequence number without 2³² updates.
fn put_record(flash: &mut MockFlash, slot: usize, seq: u32, id: u32) {
    let mut payload = scratch();
    let len = table(id).encode(&mut payload).unwrap().len();
    let mut record = Vec::new();
    record.extend_from_slice(&MAGIC.to_le_bytes());
    record.extend_from_slice(&seq.to_le_bytes());
    record.extend_from_slice(&(len as u32).to_le_bytes());
    record.extend_from_slice(&payload[..len]);
    let crc = crate::crc::crc32c(&record);
    record.extend_from_slice(&crc.to_le_bytes());
    let at = slot * SLOT_BLOCKS * ERASE;
    flash.mem[at..at + record.len()].copy_from_slice(&record);
}

/// Writes a record whose CRC is right but whose payload does not decode as a table (another format version).
fn put_undecodable_record(flash: &mut MockFlash, slot: usize, seq: u32) {
    let payload = [0xA5u8; 40];
    let mut record = Vec::new();
    record.extend_from_slice(&MAGIC.to_le_bytes());
    record.extend_from_slice(&seq.to_le_bytes());
    record.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    record.extend_from_slice(&payload);
    let crc = crate::crc::crc32c(&record);
    record.extend_from_slice(&crc.to_le_bytes());
    let at = slot * SLOT_BLOCKS * ERASE;
    flash.mem[at..at + record.len()].copy_from_slice(&record);
}

#[test]
fn an_undecodable_newer_record_is_not_current_for_store_either() {
    // Slot A: the table that loads (seq 5). Slot B: a newer record with a valid CRC whose table does not decode.
    // `load` skips B; `store` must also treat A as current and write into B, so that a power cut at any step still
    // leaves A's table (before the fix it erased A, the only loadable record, and a cut left the factory default).
    let mut flash = new_flash();
    put_record(&mut flash, 0, 5, 1);
    put_undecodable_record(&mut flash, 1, 6);
    let l = load(flash.clone());
    assert_eq!((l.table, l.slots[1]), (table(1), SlotState::Invalid));
    cut_power_at_every_step_of_updates(flash, Some(table(1)), 2..=3);
}

#[test]
fn the_update_after_sequence_number_u32_max_is_the_one_loaded() {
    // Slot A holds seq 0xFFFFFFFF; the next update is seq 0 in slot B, and it is newer (serial-number arithmetic).
    let mut flash = new_flash();
    put_record(&mut flash, 0, u32::MAX, 1);
    assert_eq!(load(flash.clone()).seq, Some(u32::MAX));
    let mut store = CalStore::new(flash).unwrap();
    let mut s = scratch();
    assert_eq!(store.store(&table(2), &mut s), Ok(0));
    let l = store.load::<G>(&mut s).unwrap();
    assert_eq!(
        (l.table.cal_id, l.seq, l.slots),
        (
            2,
            Some(0),
            [SlotState::Valid(u32::MAX), SlotState::Valid(0)]
        )
    );
    assert!(l.table == table(2));
    // The update after that goes to slot A (not over the newest record in B).
    assert_eq!(store.store(&table(3), &mut s), Ok(1));
    let l = store.load::<G>(&mut s).unwrap();
    assert_eq!(
        (l.table.cal_id, l.seq, l.slots),
        (3, Some(1), [SlotState::Valid(1), SlotState::Valid(0)])
    );
    assert!(l.table == table(3));
}

#[test]
fn updates_from_any_sequence_number_alternate_slots_and_the_newest_wins() {
    // Around 0, the i32 sign boundary and the u32 wrap, from either slot.
    let starts = [
        0,
        1,
        0x7FFF_FFFE,
        0x7FFF_FFFF,
        0x8000_0000,
        u32::MAX - 2,
        u32::MAX - 1,
        u32::MAX,
    ];
    for start in starts {
        for first_slot in 0..2 {
            let mut flash = new_flash();
            put_record(&mut flash, first_slot, start, 1);
            let mut store = CalStore::new(flash).unwrap();
            let mut s = scratch();
            let mut slot = first_slot;
            for k in 1..=4u32 {
                let id = 1 + k;
                let seq = start.wrapping_add(k);
                assert_eq!(
                    store.store(&table(id), &mut s),
                    Ok(seq),
                    "start {start:#x}, update {k}"
                );
                slot = 1 - slot;
                let l = store.load::<G>(&mut s).unwrap();
                assert!(l.table == table(id), "start {start:#x}, update {k}");
                assert_eq!(
                    (l.table.cal_id, l.seq, l.slots[slot], l.slots[1 - slot]),
                    (
                        id,
                        Some(seq),
                        SlotState::Valid(seq),
                        SlotState::Valid(seq.wrapping_sub(1))
                    ),
                    "start {start:#x}, first slot {first_slot}, update {k}"
                );
            }
        }
    }
}

#[test]
fn sequence_numbers_compare_as_serial_numbers() {
    assert!(is_newer(1, 0) && is_newer(0, u32::MAX) && is_newer(0x7FFF_FFFF, 0));
    assert!(is_newer(0x8000_0000, 0x7FFF_FFFF) && is_newer(5, u32::MAX - 5));
    assert!(!is_newer(0, 1) && !is_newer(u32::MAX, 0) && !is_newer(7, 7));
    // Exactly 2³¹ apart: neither is newer.
    assert!(!is_newer(0x8000_0000, 0) && !is_newer(0, 0x8000_0000));
}

#[test]
fn records_neither_newer_than_the_other_count_slot_a_in_load_and_store() {
    // Equal, or 2³¹ apart: load takes slot A, and store (agreeing) writes slot B with A's seq + 1.
    for b_seq in [5, 0x8000_0005] {
        let mut flash = new_flash();
        put_record(&mut flash, 0, 5, 1);
        put_record(&mut flash, 1, b_seq, 2);
        let l = load(flash.clone());
        assert_eq!((l.table.cal_id, l.seq), (1, Some(5)), "B {b_seq:#x}");
        let mut store = CalStore::new(flash).unwrap();
        let mut s = scratch();
        assert_eq!(store.store(&table(3), &mut s), Ok(6));
        let l = store.load::<G>(&mut s).unwrap();
        assert_eq!(
            (l.table.cal_id, l.seq, l.slots),
            (3, Some(6), [SlotState::Valid(5), SlotState::Valid(6)])
        );
    }
}

#[test]
fn a_damaged_record_falls_back_to_the_other_slot() {
    let mut store = CalStore::new(new_flash()).unwrap();
    let mut s = scratch();
    store.store(&table(1), &mut s).unwrap();
    store.store(&table(2), &mut s).unwrap(); // in slot B
    let mut flash = store.into_inner();
    flash.mem[SLOT_BLOCKS * ERASE + 40] ^= 0x01;
    let l = load(flash);
    assert_eq!(
        (l.table, l.seq, l.slots),
        (table(1), Some(1), [SlotState::Valid(1), SlotState::Invalid])
    );
}

#[test]
fn power_cut_at_every_step_always_loads_a_valid_calibration() {
    // Three consecutive updates (slot A, B, A again) from an empty flash; power cut at every operation of each.
    cut_power_at_every_step_of_updates(new_flash(), None, 1..=3);
}

#[test]
fn power_cut_at_every_step_across_the_sequence_number_wrap() {
    // Slot A holds seq 0xFFFFFFFE; three updates (B, A, B) write seqs 0xFFFFFFFF, 0, 1.
    let mut flash = new_flash();
    put_record(&mut flash, 0, u32::MAX - 1, 1);
    cut_power_at_every_step_of_updates(flash, Some(table(1)), 2..=4);
}

/// Applies the updates `table(id)` for each of `ids` to `flash` (whose newest table is `previous`), first cutting
/// power after every possible number of operations of each update: after each cut, boot must load the old or the
/// new table (the factory default only if there never was a record).
fn cut_power_at_every_step_of_updates(
    mut flash: MockFlash,
    mut previous: Option<CalibrationTable<G>>,
    ids: core::ops::RangeInclusive<u32>,
) {
    for id in ids {
        let new = table(id);
        let mut cuts = 0;
        for budget in 0.. {
            let mut trial = CalStore::new(MockFlash {
                budget: Some(budget),
                ops: 0,
                ..flash.clone()
            })
            .unwrap();
            let result = trial.store(&new, &mut scratch());
            let after = trial.into_inner();
            if result.is_ok() {
                assert!(budget > 0);
                break;
            }
            assert_eq!(
                result,
                Err(StoreError::Flash(MockError::PowerCut)),
                "budget {budget}"
            );
            cuts += 1;
            // Reboot: old or new, never anything else; the factory default only if there never was a record.
            let l = load(after);
            match previous {
                Some(old) => assert!(
                    l.table == old || l.table == new,
                    "update {id}, cut after {budget} ops"
                ),
                None => assert!(
                    l.table == new || (l.seq.is_none() && l.table == CalibrationTable::factory())
                ),
            }
        }
        // Exactly one cut point per block erase (3) and per word of the record.
        let mut buf = scratch();
        let words = (HEADER_LEN + new.encode(&mut buf).unwrap().len() + CRC_LEN).div_ceil(4);
        assert_eq!(cuts, SLOT_BLOCKS + words, "update {id}");
        let mut store = CalStore::new(flash).unwrap();
        store.store(&new, &mut scratch()).unwrap();
        flash = store.into_inner();
        assert_eq!(load(flash.clone()).table, new);
        previous = Some(new);
    }
}

#[test]
fn a_length_word_near_u32_max_is_invalid_on_any_usize() {
    // A slot whose magic is written but whose length word is still erased (0xFFFFFFFF), or holds any length that
    // would overflow a 32-bit usize in "header + length + CRC": Invalid, the other slot's record loads, and
    // `store` (which reads both slots first) writes over the damaged slot. Run with
    // `cargo test -p shared --target i686-unknown-linux-gnu` to check it on a 32-bit usize.
    let lengths = [
        u32::MAX,
        u32::MAX - 3,
        u32::MAX - 11,
        u32::MAX - 15,
        u32::MAX - 16,
        0x8000_0000,
        (SLOT_BLOCKS * ERASE - HEADER_LEN - CRC_LEN + 1) as u32,
    ];
    for length in lengths {
        let mut flash = new_flash();
        put_record(&mut flash, 0, 7, 1);
        let b = SLOT_BLOCKS * ERASE;
        flash.mem[b..b + 4].copy_from_slice(&MAGIC.to_le_bytes());
        flash.mem[b + 8..b + 12].copy_from_slice(&length.to_le_bytes());
        let l = load(flash.clone());
        assert_eq!(
            (l.table.cal_id, l.seq, l.slots),
            (1, Some(7), [SlotState::Valid(7), SlotState::Invalid]),
            "length {length:#x}"
        );
        let mut store = CalStore::new(flash).unwrap();
        let mut s = scratch();
        assert_eq!(store.store(&table(2), &mut s), Ok(8), "length {length:#x}");
        let l = store.load::<G>(&mut s).unwrap();
        assert_eq!((l.table.cal_id, l.seq), (2, Some(8)), "length {length:#x}");
    }
}

#[test]
fn geometry_is_checked() {
    struct Odd;
    impl ErrorType for Odd {
        type Error = MockError;
    }
    impl ReadNorFlash for Odd {
        const READ_SIZE: usize = 1;
        fn read(&mut self, _: u32, _: &mut [u8]) -> Result<(), MockError> {
            Ok(())
        }
        fn capacity(&self) -> usize {
            3 * ERASE
        }
    }
    impl NorFlash for Odd {
        const WRITE_SIZE: usize = 4;
        const ERASE_SIZE: usize = ERASE;
        fn erase(&mut self, _: u32, _: u32) -> Result<(), MockError> {
            Ok(())
        }
        fn write(&mut self, _: u32, _: &[u8]) -> Result<(), MockError> {
            Ok(())
        }
    }
    assert!(matches!(CalStore::new(Odd), Err(StoreError::Geometry)));
}

/// Where the bytes of a record lie in a slot, to aim damage at its header, payload and CRC.
fn record_len(id: u32) -> usize {
    HEADER_LEN + table(id).encode(&mut scratch()).unwrap().len() + CRC_LEN
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(500))]
    /// Damage anywhere in slot B (byte flips, a length field of any value, bytes of any value) never makes boot
    /// panic or fail, never loses the intact record in slot A, and yields B's table only if B still checks.
    #[test]
    fn damaged_slot_never_panics_and_the_other_record_survives(
        flips in proptest::collection::vec((0usize..2 * 1024, 0u8..=255), 1..8),
        length in proptest::prelude::any::<u32>(),
        set_length in proptest::prelude::any::<bool>(),
    ) {
        let mut store = CalStore::new(new_flash()).unwrap();
        store.store(&table(1), &mut scratch()).unwrap();
        store.store(&table(2), &mut scratch()).unwrap(); // slot B
        let mut flash = store.into_inner();
        let b = SLOT_BLOCKS * ERASE;
        let span = record_len(2) + 8;
        for (at, x) in flips {
            flash.mem[b + at % span] ^= x.max(1);
        }
        if set_length {
            flash.mem[b + 8..b + 12].copy_from_slice(&length.to_le_bytes());
        }
        let l = load(flash);
        proptest::prop_assert_eq!(l.slots[0], SlotState::Valid(1));
        match l.slots[1] {
            SlotState::Valid(2) => proptest::prop_assert_eq!((l.table, l.seq), (table(2), Some(2))),
            _ => proptest::prop_assert_eq!((l.table, l.seq), (table(1), Some(1))),
        }
    }

    /// Flash holding anything at all (half the time behind a valid magic, so that the length and CRC checks are
    /// what refuses it) loads the factory default.
    #[test]
    fn arbitrary_flash_loads_the_factory_default(
        a in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..200),
        b in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..200),
        magic in proptest::prelude::any::<bool>(),
    ) {
        let mut flash = new_flash();
        for (slot, bytes) in [(0, &a), (SLOT_BLOCKS * ERASE, &b)] {
            flash.mem[slot..slot + bytes.len()].copy_from_slice(bytes);
            if magic && bytes.len() >= 4 {
                flash.mem[slot..slot + 4].copy_from_slice(&MAGIC.to_le_bytes());
            }
        }
        let l = load(flash);
        proptest::prop_assert_eq!((l.table, l.seq), (CalibrationTable::factory(), None));
        proptest::prop_assert!(l.slots.iter().all(|s| !matches!(s, SlotState::Valid(_))));
    }
}

/// A flash that reports success for a write it did not do (one word, at `lost`): the store must not say the
/// table is safe.
struct DropsAWrite {
    inner: MockFlash,
    lost: u32,
}

impl ErrorType for DropsAWrite {
    type Error = MockError;
}

impl ReadNorFlash for DropsAWrite {
    const READ_SIZE: usize = 1;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), MockError> {
        self.inner.read(offset, bytes)
    }
    fn capacity(&self) -> usize {
        self.inner.capacity()
    }
}

impl NorFlash for DropsAWrite {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = ERASE;
    fn erase(&mut self, from: u32, to: u32) -> Result<(), MockError> {
        self.inner.erase(from, to)
    }
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), MockError> {
        let end = offset + bytes.len() as u32;
        if (offset..end).contains(&self.lost) {
            // Everything but the lost word.
            let k = (self.lost - offset) as usize & !3;
            if k > 0 {
                self.inner.write(offset, &bytes[..k])?;
            }
            if k + 4 < bytes.len() {
                self.inner.write(offset + k as u32 + 4, &bytes[k + 4..])?;
            }
            return Ok(());
        }
        self.inner.write(offset, bytes)
    }
}

#[test]
fn a_write_the_flash_did_not_do_is_caught_by_the_read_back() {
    for lost in [4u32, 12, 40, 400] {
        let mut store = CalStore::new(DropsAWrite {
            inner: new_flash(),
            lost,
        })
        .unwrap();
        assert_eq!(
            store.store(&table(7), &mut scratch()),
            Err(StoreError::Verify),
            "word at {lost} lost"
        );
    }
    // And with nothing lost (the word is beyond the record), the store succeeds.
    let mut store = CalStore::new(DropsAWrite {
        inner: new_flash(),
        lost: (ERASE * SLOT_BLOCKS - 4) as u32,
    })
    .unwrap();
    assert_eq!(store.store(&table(7), &mut scratch()), Ok(1));
}
