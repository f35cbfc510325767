//! The bootloader's decision (`boot::prepare`) on models of ACTIVE, DFU and the state partition.

use super::*;
use crate::update::boot;
use core::cell::Cell;
use embassy_boot::BlockingFirmwareState;
use embedded_storage::nor_flash::{ErrorType, ReadNorFlash};
use std::rc::Rc;

const STATE_SECTOR: usize = 64 * 1024;

/// A flash that shares one power-cut budget (in erase and write calls) with the others of a test: the cut
/// call fails, an erase leaving its block half garbage, a write of n words having written n/2.
struct Cut<const E: usize> {
    inner: MockFlash<E>,
    left: Rc<Cell<Option<usize>>>,
    calls: Rc<Cell<usize>>,
}

impl<const E: usize> Cut<E> {
    fn before(&mut self, words: usize) {
        self.calls.set(self.calls.get() + 1);
        match self.left.get() {
            Some(0) => self.inner.budget = Some(self.inner.ops),
            Some(1) => {
                self.left.set(Some(0));
                self.inner.budget = Some(self.inner.ops + words / 2);
            }
            Some(n) => self.left.set(Some(n - 1)),
            None => {}
        }
    }
}

impl<const E: usize> ErrorType for Cut<E> {
    type Error = crate::storage::mock::MockError;
}

impl<const E: usize> ReadNorFlash for Cut<E> {
    const READ_SIZE: usize = 1;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.inner.read(offset, bytes)
    }
    fn capacity(&self) -> usize {
        self.inner.capacity()
    }
}

impl<const E: usize> NorFlash for Cut<E> {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = E;
    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.before(0);
        self.inner.erase(from, to)
    }
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.before(bytes.len() / 4);
        self.inner.write(offset, bytes)
    }
}

/// The three partitions, sharing a budget.
struct Board {
    active: Cut<SECTOR>,
    dfu: Cut<SECTOR>,
    state: Cut<STATE_SECTOR>,
    left: Rc<Cell<Option<usize>>>,
    calls: Rc<Cell<usize>>,
}

impl Board {
    fn new(active: Dfu, dfu: Dfu, state: MockFlash<STATE_SECTOR>) -> Self {
        let (left, calls) = (Rc::new(Cell::new(None)), Rc::new(Cell::new(0)));
        Self {
            active: Cut {
                inner: active,
                left: left.clone(),
                calls: calls.clone(),
            },
            dfu: Cut {
                inner: dfu,
                left: left.clone(),
                calls: calls.clone(),
            },
            state: Cut {
                inner: state,
                left: left.clone(),
                calls: calls.clone(),
            },
            left,
            calls,
        }
    }

    fn copy(&self) -> Self {
        Self::new(
            self.active.inner.clone(),
            self.dfu.inner.clone(),
            self.state.inner.clone(),
        )
    }

    /// One reset: the bootloader's decision, with the power cut after `cut` flash calls (`None`: no cut).
    fn boot(
        &mut self,
        cut: Option<usize>,
        pk: &[u8; 32],
    ) -> Result<BootReport, boot::BootFlashError> {
        self.left.set(cut);
        for f in [&mut self.active.inner, &mut self.dfu.inner] {
            f.budget = None;
        }
        self.state.inner.budget = None;
        let mut aligned = [0u8; 4096];
        let mut scratch = [0u8; 4];
        boot::prepare(
            &mut self.active,
            &mut self.dfu,
            &mut self.state,
            &mut aligned,
            &mut scratch,
            pk,
            BOARD,
        )
    }

    fn boot_state(&mut self) -> embassy_boot::State {
        let mut scratch = [0u8; 4];
        BlockingFirmwareState::new(&mut self.state.inner, &mut scratch)
            .get_state()
            .unwrap()
    }

    fn mark(&mut self, updated: bool) {
        let mut scratch = [0u8; 4];
        let mut s = BlockingFirmwareState::new(&mut self.state.inner, &mut scratch);
        if updated {
            s.mark_updated().unwrap()
        } else {
            s.mark_booted().unwrap()
        }
    }
}

/// A slot image: header (512 B, 0xFF after the signature) and payload.
fn slot_bytes(header: &[u8; image::OPEN_LEN], payload: &[u8]) -> std::vec::Vec<u8> {
    let mut b = header.to_vec();
    b.resize(image::HEADER_LEN, 0xFF);
    b.extend_from_slice(payload);
    b
}

/// ACTIVE with version 3, DFU with a signed version 4 uploaded through the receiver and committed.
fn committed(corrupt: bool) -> (Board, std::vec::Vec<u8>, std::vec::Vec<u8>, [u8; 32]) {
    let k = key();
    let pk = k.verifying_key().to_bytes();
    let (old_h, old_p) = image(180_000, 3, BOARD, &k);
    let (new_h, mut new_p) = image(150_000, 4, BOARD, &k);
    let old = slot_bytes(&old_h, &old_p);
    let mut active = Dfu::erased(2);
    active.mem[..old.len()].copy_from_slice(&old);
    let (mut dfu, mut b, mut rx) = (Dfu::erased(3), Boot::default(), Receiver::default());
    if corrupt {
        new_p[77_777] ^= 0x80;
    }
    upload(&mut rx, &mut dfu, &mut b, &new_h, &new_p);
    let mut board = Board::new(active, dfu, MockFlash::erased(1));
    board.mark(true);
    let new = slot_bytes(&new_h, &new_p);
    (board, old, new, pk)
}

fn active_holds(board: &Board, bytes: &[u8]) -> bool {
    board.active.inner.mem[..image::OPEN_LEN] == bytes[..image::OPEN_LEN]
        && board.active.inner.mem[image::HEADER_LEN..bytes.len()] == bytes[image::HEADER_LEN..]
}

/// Boots until the decision completes (each failed attempt is a reset); returns the report.
fn boot_through(board: &mut Board, pk: &[u8; 32]) -> BootReport {
    for _ in 0..3 {
        if let Ok(r) = board.boot(None, pk) {
            return r;
        }
    }
    panic!("the boot never completed")
}

#[test]
fn swap_then_revert_unless_confirmed() {
    let (mut board, old, new, pk) = committed(false);
    let r = board.boot(None, &pk).unwrap();
    assert_eq!(
        r,
        BootReport {
            action: BootAction::Swapped,
            refusal: 0,
            active_version: 4,
            dfu_version: 4
        }
    );
    assert!(active_holds(&board, &new));
    assert_eq!(
        board.boot_state(),
        embassy_boot::State::Swap,
        "a trial until it confirms"
    );
    // Not confirmed: the next reset reverts.
    let mut unconfirmed = board.copy();
    let r = unconfirmed.boot(None, &pk).unwrap();
    assert_eq!(
        (r.action, r.active_version, r.dfu_version),
        (BootAction::Reverted, 3, 4)
    );
    assert!(active_holds(&unconfirmed, &old));
    assert_eq!(
        unconfirmed.boot(None, &pk).unwrap().action,
        BootAction::Booted
    );
    // Confirmed: it stays.
    board.mark(false);
    assert_eq!(board.boot(None, &pk).unwrap().action, BootAction::Booted);
    assert!(active_holds(&board, &new));
}

/// A power cut at every flash call of the swap, then of the revert: each boot ends with the old or the new image
/// whole in ACTIVE, never neither, and the interrupted operation completes at the next reset.
#[test]
fn power_cut_at_every_flash_call_keeps_old_or_new() {
    let (board, old, new, pk) = committed(false);
    let mut clean = board.copy();
    clean.boot(None, &pk).unwrap();
    let swap_calls = clean.calls.get();
    assert!(swap_calls > 100, "{swap_calls} calls");
    for cut in 0..swap_calls {
        let mut b = board.copy();
        let first = b.boot(Some(cut), &pk);
        assert!(first.is_err(), "cut {cut} of {swap_calls} did not cut");
        let r = boot_through(&mut b, &pk);
        assert_eq!(r.action, BootAction::Swapped, "cut {cut}");
        assert!(
            active_holds(&b, &new),
            "cut {cut}: ACTIVE is not the new image"
        );
    }
    let mut reverting = clean.copy();
    reverting.calls.set(0);
    reverting.boot(None, &pk).unwrap();
    let revert_calls = reverting.calls.get();
    std::println!(
        "power cuts: {swap_calls} flash calls of the swap, {revert_calls} of the revert, each cut once"
    );
    for cut in 0..revert_calls {
        let mut b = clean.copy();
        assert!(b.boot(Some(cut), &pk).is_err());
        let r = boot_through(&mut b, &pk);
        assert!(
            matches!(r.action, BootAction::Reverted | BootAction::Booted),
            "cut {cut}: {r:?}"
        );
        assert!(
            active_holds(&b, &old),
            "cut {cut}: ACTIVE is not the old image"
        );
    }
}

#[test]
fn a_corrupted_or_older_image_is_refused_and_active_boots_unchanged() {
    let (mut board, old, _, pk) = committed(true);
    let r = board.boot(None, &pk).unwrap();
    assert_eq!(
        r,
        BootReport {
            action: BootAction::Refused,
            refusal: ImageError::Hash.code(),
            active_version: 3,
            dfu_version: 4
        }
    );
    assert!(active_holds(&board, &old));
    assert_eq!(
        board.boot_state(),
        embassy_boot::State::Boot,
        "the request is cancelled"
    );
    assert_eq!(board.boot(None, &pk).unwrap().action, BootAction::Booted);
    // Another key: refused before anything moves.
    let (mut board, old, _, _) = committed(false);
    let other = SigningKey::from_bytes(&[9; 32]).verifying_key().to_bytes();
    let r = board.boot(None, &other).unwrap();
    assert_eq!(
        (r.action, r.refusal),
        (BootAction::Refused, ImageError::Signature.code())
    );
    assert!(active_holds(&board, &old));
}
