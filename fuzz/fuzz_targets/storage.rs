//! The A/B calibration store over NOR flash (`shared::storage::CalStore`).
//!
//! Input: initial flash contents (records planted in either slot with arbitrary sequence numbers, near the u32
//! wrap included, with valid or arbitrary payloads; then arbitrary byte damage), the table to store, and a
//! power-cut point.
//! Properties:
//! * boot (`load`) over arbitrary flash never fails or panics;
//! * `store` then `load` returns the stored table with the sequence number `store` returned, which is newer
//!   (serial-number arithmetic) than the record booted from — across the u32 wrap too;
//! * a power cut after any number of flash operations of `store` leaves a flash that boots to the table in force
//!   before the update or to the new one, never anything else;
//! * the store never writes to a word that is not erased (the mock flash refuses).
#![no_main]

#[path = "common/mod.rs"]
mod common;

use arbitrary::Arbitrary;

use libfuzzer_sys::fuzz_target;
use shared::calib::{CalibrationTable, encoded_len_max};
use shared::crc::Crc32c;
use shared::storage::mock::{ERASE, MockError, MockFlash};
use shared::storage::{CalStore, MAGIC, StoreError, is_newer};
use shared::wire::frame::GROUPS as G;

const SLOT_BLOCKS: usize = 3;
const SLOT: usize = SLOT_BLOCKS * ERASE;

#[derive(Arbitrary, Debug, Clone, Copy)]
struct TableSpec {
    cal_id: u32,
    group: u8,
    bias: i16,
}

impl TableSpec {
    fn table(&self) -> CalibrationTable<G> {
        let mut t = CalibrationTable::factory();
        t.cal_id = self.cal_id;
        t.groups[usize::from(self.group) % G].accel_bias_q12[1] += i32::from(self.bias) * 1000;
        t
    }
}

#[derive(Arbitrary, Debug)]
enum Payload {
    Table(TableSpec),
    /// Bytes that are (almost certainly) not a table, under a valid record CRC.
    Bytes(Vec<u8>),
}

#[derive(Arbitrary, Debug)]
struct Record {
    slot: bool,
    /// Sequence number as an offset back from the wrap: u32::MAX - back (so the wrap is near).
    back: u32,
    near_wrap: bool,
    payload: Payload,
    /// Leave out the magic (a cut update).
    no_magic: bool,
}

#[derive(Arbitrary, Debug)]
struct Input {
    records: Vec<Record>,
    /// A flash image laid down first (raw seeds), truncated to the flash size.
    image: Vec<u8>,
    /// (offset, byte) damage, offsets mod the flash size.
    damage: Vec<(u16, u8)>,
    new: TableSpec,
    cut: u16,
}

impl Input {
    /// Raw form: a flash image (both slots; short images are padded with erased bytes), then a store of a
    /// fixed table cut at every 16th operation.
    fn raw(bytes: &[u8]) -> Self {
        Self {
            records: Vec::new(),
            image: bytes.to_vec(),
            damage: Vec::new(),
            new: TableSpec {
                cal_id: 77,
                group: 1,
                bias: -3,
            },
            cut: 16,
        }
    }
}

fn put_record(mem: &mut [u8], r: &Record) {
    let base = if r.slot { SLOT } else { 0 };
    let mut payload = vec![0u8; encoded_len_max(G)];
    let payload: Vec<u8> = match &r.payload {
        Payload::Table(t) => t.table().encode(&mut payload).unwrap().to_vec(),
        Payload::Bytes(b) => b[..b.len().min(SLOT - 16)].to_vec(),
    };
    let seq = if r.near_wrap {
        u32::MAX.wrapping_sub(r.back % 4)
    } else {
        r.back
    };
    let mut rec = Vec::new();
    rec.extend_from_slice(&MAGIC.to_le_bytes());
    rec.extend_from_slice(&seq.to_le_bytes());
    rec.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    rec.extend_from_slice(&payload);
    let mut crc = Crc32c::new();
    crc.update(&rec);
    rec.extend_from_slice(&crc.finish().to_le_bytes());
    if r.no_magic {
        rec[..4].fill(0xFF);
    }
    let slot = &mut mem[base..base + SLOT];
    slot.fill(0xFF);
    slot[..rec.len()].copy_from_slice(&rec);
}

fn scratch() -> Vec<u8> {
    vec![0u8; 12 + encoded_len_max(G) + 4 + 8]
}

fn boot(mem: &[u8]) -> shared::storage::Loaded<G> {
    let mut store = CalStore::new(MockFlash::<ERASE> {
        mem: mem.to_vec(),
        budget: None,
        ops: 0,
    })
    .unwrap();
    store
        .load::<G>(&mut scratch())
        .expect("load over arbitrary flash")
}

fuzz_target!(|data: &[u8]| {
    // Seeds from real encodings: 'R' ++ bytes is the raw form (see `Input::raw`).
    if let Some(input) = common::input(data, Input::raw) {
        check(input);
    }
});

fn check(input: Input) {
    let mut mem = vec![0xFFu8; 2 * SLOT];
    let n = input.image.len().min(mem.len());
    mem[..n].copy_from_slice(&input.image[..n]);
    for r in input.records.iter().take(4) {
        put_record(&mut mem, r);
    }
    for &(at, b) in input.damage.iter().take(64) {
        let n = mem.len();
        mem[usize::from(at) % n] = b;
    }

    let before = boot(&mem);
    let new = input.new.table();

    // Store with no cut, then reboot.
    let mut store = CalStore::new(MockFlash::<ERASE> {
        mem: mem.clone(),
        budget: None,
        ops: 0,
    })
    .unwrap();
    let seq = store
        .store(&new, &mut scratch())
        .expect("store on a healthy flash");
    let flash = store.into_inner();
    let total_ops = flash.ops;
    let after = boot(&flash.mem);
    assert_eq!(after.table, new, "reload after store");
    assert_eq!(after.seq, Some(seq));
    if let Some(old) = before.seq {
        assert!(
            is_newer(seq, old),
            "new seq {seq} not newer than booted {old}"
        );
        if old == u32::MAX {
            assert_eq!(seq, 0, "seq wrap");
        }
    }

    // A power cut after `cut` operations: old or new, never anything else.
    let budget = usize::from(input.cut) % total_ops.max(1);
    let mut store = CalStore::new(MockFlash::<ERASE> {
        mem: mem.clone(),
        budget: Some(budget),
        ops: 0,
    })
    .unwrap();
    let result = store.store(&new, &mut scratch());
    assert_eq!(
        result,
        Err(StoreError::Flash(MockError::PowerCut)),
        "cut after {budget} of {total_ops}"
    );
    let flash = store.into_inner();
    let l = boot(&flash.mem);
    assert!(
        l.table == before.table || l.table == new,
        "power cut after {budget} of {total_ops} ops: booted neither the old table (seq {:?}) nor the new one; got seq {:?}, slots {:?} (before {:?})",
        before.seq,
        l.seq,
        l.slots,
        before.slots
    );
}
