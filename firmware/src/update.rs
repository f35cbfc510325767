//! The update service's edge (`docs/update.md`): the DFU slot, embassy-boot's state partition and
//! `shared::update::Receiver`, owned by the storage task (the one task that writes flash). The same code runs on
//! the STM32 (the F405's sectors 4 and 7–9, `board.rs`) and on the host (the NOR-flash model).

use embassy_boot::{BlockingFirmwareState, State};
use embedded_storage::nor_flash::NorFlash;
use shared::update::{
    BootAction, BootControl, BootReport, BootState, BootStateError, Context, Receiver, UpdateError,
    UpdateOutcome, UpdateStatus,
};

include!(concat!(env!("OUT_DIR"), "/update_pubkey.rs"));

/// A trial image (swapped in by the bootloader) confirms itself after this much uptime without a missed deadline
/// (`app::storage_loop`); one that resets before, for any reason, is reverted by the bootloader at the next boot.
pub const CONFIRM_AFTER_MS: u64 = 30_000;

/// embassy-boot's state partition as the receiver drives it (`BlockingFirmwareState`: the magic words and the swap
/// progress the bootloader reads). Every change erases the partition: on the F405 its 64 KiB sector, ≤ 1.1 s.
pub struct BootStatePartition<S> {
    state: S,
    aligned: [u8; 4],
}

impl<S: NorFlash> BootStatePartition<S> {
    /// The partition on `state` (a program word of 4 bytes, as the F405 and the host model have).
    pub const fn new(state: S) -> Self {
        const {
            assert!(
                S::WRITE_SIZE == 4,
                "embassy-boot's state word is the flash's program word"
            )
        };
        Self {
            state,
            aligned: [0; 4],
        }
    }

    fn with<T>(&mut self, f: impl FnOnce(&mut BlockingFirmwareState<'_, &mut S>) -> T) -> T {
        let mut s = BlockingFirmwareState::new(&mut self.state, &mut self.aligned);
        f(&mut s)
    }

    /// The flash under it (tests inspect it).
    pub fn flash(&mut self) -> &mut S {
        &mut self.state
    }
}

impl<S: NorFlash> BootControl for BootStatePartition<S> {
    fn state(&mut self) -> BootState {
        match self.with(|s| s.get_state()) {
            Ok(State::Boot | State::DfuDetach) => BootState::Boot,
            Ok(State::Swap) => BootState::Swap,
            Ok(State::Revert) => BootState::Revert,
            Err(_) => BootState::Unknown,
        }
    }

    fn mark_updated(&mut self) -> Result<(), BootStateError> {
        self.with(|s| s.mark_updated()).map_err(|_| BootStateError)
    }

    fn mark_booted(&mut self) -> Result<(), BootStateError> {
        self.with(|s| s.mark_booted()).map_err(|_| BootStateError)
    }
}

/// What the update service needs: the slots, the key, and what the board knows of this boot.
pub struct Updater<D, S> {
    /// The DFU slot.
    pub dfu: D,
    /// The boot state partition.
    pub boot: BootStatePartition<S>,
    /// The protocol's state.
    pub receiver: Receiver,
    /// The key images are signed with (built in: `FW_UPDATE_PUBKEY`).
    pub public_key: [u8; 32],
    /// This board (`layout::BOARD_ID`).
    pub board_id: u32,
    /// The running image's version (its header in ACTIVE; 0 without one).
    pub running_version: u32,
    /// Largest image, header included (the ACTIVE slot).
    pub max_image_len: u32,
    /// This boot is a trial: the bootloader swapped the image in and it has not confirmed itself yet.
    pub trial: bool,
}

impl<D: NorFlash, S: NorFlash> Updater<D, S> {
    /// The service at boot: `report` is what the bootloader left (`None`: no bootloader, e.g. the SITL or a probe
    /// build); the trial flag comes from the state partition.
    pub fn new(
        dfu: D,
        state: S,
        public_key: [u8; 32],
        board_id: u32,
        running_version: u32,
        max_image_len: u32,
        report: Option<BootReport>,
    ) -> Self {
        let mut boot = BootStatePartition::new(state);
        let trial = boot.state() == BootState::Swap;
        let last = match report {
            Some(r) => match r.action {
                BootAction::Booted => UpdateOutcome::None,
                BootAction::Swapped => UpdateOutcome::Swapped(r.active_version),
                BootAction::Reverted => UpdateOutcome::Reverted(r.dfu_version),
                BootAction::Refused => shared::update::ImageError::from_code(r.refusal)
                    .map_or(UpdateOutcome::None, UpdateOutcome::BootRefused),
            },
            None => UpdateOutcome::None,
        };
        Self {
            dfu,
            boot,
            receiver: Receiver::new(last),
            public_key,
            board_id,
            running_version,
            max_image_len,
            trial,
        }
    }

    /// Handles one request (a CSP payload); the reply's payload goes to `out`, its length is returned.
    pub fn handle(
        &mut self,
        request: &[u8],
        writable: Result<(), UpdateError>,
        out: &mut [u8],
    ) -> Option<usize> {
        let (receiver, dfu, boot, ctx) = self.parts(writable);
        receiver.handle_bytes(request, dfu, &ctx, boot, out).ok()
    }

    /// The service's state (reads the DFU slot's header).
    pub fn status(&mut self) -> UpdateStatus {
        let (receiver, dfu, boot, ctx) = self.parts(Ok(()));
        receiver.status(dfu, &ctx, boot)
    }

    /// The receiver, the slots it writes, and its context from this boot's facts (the fields borrowed apart).
    fn parts(
        &mut self,
        writable: Result<(), UpdateError>,
    ) -> (
        &mut Receiver,
        &mut D,
        &mut BootStatePartition<S>,
        Context<'_>,
    ) {
        let Self {
            dfu,
            boot,
            receiver,
            public_key,
            board_id,
            running_version,
            max_image_len,
            ..
        } = self;
        let ctx = Context {
            public_key,
            board_id: *board_id,
            running_version: *running_version,
            max_image_len: *max_image_len,
            writable,
        };
        (receiver, dfu, boot, ctx)
    }

    /// The trial image confirms itself (`mark_booted`); `false` if the state partition could not be written.
    /// Tried once: if it fails, the image stays unconfirmed and the next reset reverts it.
    pub fn confirm(&mut self) -> bool {
        self.trial = false;
        if self.boot.mark_booted().is_err() {
            return false;
        }
        self.receiver
            .set_last(UpdateOutcome::Confirmed(self.running_version));
        true
    }
}
