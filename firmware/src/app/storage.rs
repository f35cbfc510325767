//! The `storage` task, the one that writes flash: the calibration persisted on a committed upload (and reloaded when
//! the table in RAM fails its CRC), the update service's requests, a trial image's confirmation; and the
//! calibration's load at boot ([`load_calibration`]).

use core::sync::atomic::Ordering;

use embassy_futures::select::{Either3, select3};
use embassy_time::{Instant, Timer, with_timeout};
use embedded_storage::nor_flash::NorFlash;
use shared::bus::MAX_PAYLOAD;
use shared::pipeline::{Pipeline, PipelineMemory};
use shared::storage::{CalStore, StoreError};
use shared::telemetry::{CalSource, Mode, StoreOutcome, TaskId, Telemetry};
use shared::update::UpdateError;

use super::counters::Counter;
use super::state::{App, BusOut, UpdateIn};
use super::{EVENT_WAIT, RESET_AFTER};
use crate::layout::CAL_SCRATCH;
use crate::log::Loggable;
use crate::update::{CONFIRM_AFTER_MS, Updater};

/// Minimum VDD for a calibration store, mV: x32 programming needs 2.7 V (DS8626), and a store at a sagging rail
/// can leave weak bits the read-back does not see. Measured as VDDA (VREFINT), which the board ties to VDD.
pub const STORE_VDD_MIN_MV: u16 = 2_800;

/// Loads the stored calibration into the pipeline (newest valid record, else the factory default).
pub fn load_calibration<F: NorFlash, B: core::borrow::BorrowMut<PipelineMemory>>(
    store: &mut CalStore<F>,
    pipeline: &mut Pipeline<B>,
) where
    F::Error: Loggable,
{
    let mut scratch = [0u8; CAL_SCRATCH];
    // In place, into the pipeline's own table: a table-sized temporary broke the 8 KiB frame limit.
    pipeline.load_calibration_with(|table| match store.load_into(&mut scratch, table) {
        Ok(loaded) => {
            let source = match loaded.seq {
                Some(_) => CalSource::Stored,
                None => CalSource::Factory,
            };
            info!(
                "calibration: id {:?} from {:?} (seq {:?}, slots {:?})",
                table.cal_id, source, loaded.seq, loaded.slots
            );
            source
        }
        Err(e) => {
            error!("calibration: flash read failed ({:?}), factory default", e);
            table.set_factory();
            CalSource::Factory
        }
    });
}

/// VDD, mV, when it is below [`STORE_VDD_MIN_MV`] (no reading: not known to be low): flash writes (a calibration
/// store, an update) are refused then.
fn vdd_too_low<B>(app: &App<B>) -> Option<u16> {
    app.platform
        .mcu_sensors
        .and_then(|read| read())
        .map(|(_, mv)| mv)
        .filter(|&mv| mv < STORE_VDD_MIN_MV)
}

/// One request to the update service: handled on the DFU slot (flash writes only in `Mode::Idle` and at a VDD fit
/// for programming), answered on the reply queue, the service's state published for housekeeping.
async fn serve_update<B, D, S>(app: &App<B>, update: &mut Updater<D, S>, request: UpdateIn)
where
    B: core::borrow::BorrowMut<PipelineMemory>,
    D: NorFlash,
    S: NorFlash,
{
    let idle = app.pipeline.lock().await.mode() == Mode::Idle;
    let writable = if !idle {
        Err(UpdateError::NotIdle)
    } else if vdd_too_low(app).is_some() {
        app.count(Counter::LowVdd);
        Err(UpdateError::LowVoltage)
    } else {
        Ok(())
    };
    let mut out = [0u8; MAX_PAYLOAD];
    let n = update.handle(&request.payload, writable, &mut out);
    if writable.is_ok() {
        // Any flash operation stalled every task (a DFU sector erase ≤ 2 s): the link task drops its ring. In
        // `Idle` the FPGA is not streaming, so nothing is lost.
        app.link_stale.store(true, Ordering::Release);
    }
    app.update_status.lock(|c| c.set(update.status()));
    match n.and_then(|n| out.get(..n)) {
        Some(reply) => {
            let payload = heapless::Vec::from_slice(reply).unwrap_or_default();
            app.replies
                .send(BusOut::Reply {
                    header: request.header,
                    payload,
                })
                .await;
        }
        None => error!("update: a reply did not fit a packet"),
    }
    if update.receiver.take_reset() {
        // The reply (and whatever is queued before it: ≤ 4 replies of ≤ 0.5 KB, 0.18 s at 115200 baud) leaves first.
        Timer::after(RESET_AFTER).await;
        match app.platform.reset {
            Some(reset) => {
                info!("update: reset by command");
                reset();
            }
            None => warn!("update: Reset asked, but this platform cannot reset"),
        }
    }
}

/// A trial image (the bootloader swapped it in) confirms itself once it has run [`CONFIRM_AFTER_MS`] without a
/// missed deadline; if one was missed it stays a trial, and the next reset reverts it.
async fn confirm_trial<B, D, S>(app: &App<B>, update: &mut Updater<D, S>)
where
    B: core::borrow::BorrowMut<PipelineMemory>,
    D: NorFlash,
    S: NorFlash,
{
    if !update.trial
        || Instant::now().as_millis() < CONFIRM_AFTER_MS
        || app.counters.get(Counter::WatchdogMiss) != 0
    {
        return;
    }
    let confirmed = update.confirm();
    app.link_stale.store(true, Ordering::Release);
    if confirmed {
        info!(
            "update: version {:?} confirmed itself",
            update.running_version
        );
    } else {
        error!("update: the boot state could not be written; the next reset reverts");
    }
    app.update_status.lock(|c| c.set(update.status()));
}

/// Persists the calibration in force whenever an upload is committed, then sends the commit's ack: `Ok` only once
/// the record is written and read back (`CalStore::store`), `Storage` otherwise. The erase stalls the CPU
/// (single-bank flash, `docs/storage.md`): FPGA bytes arriving meanwhile overrun the ring and are counted, bus bytes
/// wait in the bus's DMA ring.
pub async fn storage_loop<B, F, D, S>(
    app: &App<B>,
    store: &mut CalStore<F>,
    update: &mut Updater<D, S>,
) -> !
where
    B: core::borrow::BorrowMut<PipelineMemory>,
    F: NorFlash,
    F::Error: Loggable,
    D: NorFlash,
    S: NorFlash,
{
    let mut scratch = [0u8; CAL_SCRATCH];
    app.update_status.lock(|c| c.set(update.status()));
    loop {
        app.beat(TaskId::Storage).await;
        confirm_trial(app, update).await;
        let Ok(event) = with_timeout(
            EVENT_WAIT,
            select3(
                app.persist.wait(),
                app.reload.wait(),
                app.update_in.receive(),
            ),
        )
        .await
        else {
            continue;
        };
        let tag = match event {
            Either3::First(tag) => tag,
            Either3::Third(request) => {
                serve_update(app, update, request).await;
                continue;
            }
            Either3::Second(()) => {
                // The table in RAM failed its CRC: the newest stored one (or the factory default) replaces it; in
                // safe mode always the factory default (a stored table may be what crashed the boots before).
                let mut pipeline = app.pipeline.lock().await;
                if app.platform.boot.safe_mode {
                    pipeline.load_calibration_with(|table| {
                        table.set_factory();
                        CalSource::Factory
                    });
                } else {
                    load_calibration(store, &mut *pipeline);
                }
                drop(pipeline);
                app.count(Counter::CalRamRepairs);
                continue;
            }
        };
        // The store is synchronous (the CPU stalls on the erase and the word programs anyway), so the lock is held
        // through it and the table is not copied into this task's state (1.8 KiB of RAM); no task runs until it
        // returns (`layout::STORE_STALL_MAX_US`: the bus ring holds twice that, the link task drops its ring).
        // VDD first: a store below the x32 programming minimum could write weak bits the read-back passes.
        if let Some(vdd_mv) = vdd_too_low(app) {
            app.count(Counter::LowVdd);
            error!("calibration: store refused, VDD {:?} mV", vdd_mv);
            app.last_store.lock(|c| c.set(StoreOutcome::Failed));
            let ack = app.pipeline.lock().await.calibration_persisted(tag, false);
            app.replies
                .send(BusOut::Telemetry(Telemetry::Ack(ack)))
                .await;
            continue;
        }
        let (cal_id, result) = {
            let pipeline = app.pipeline.lock().await;
            let table = pipeline.calibration();
            (table.cal_id, store.store(table, &mut scratch))
        };
        // Unless it failed before touching the flash, the store stalled every task (`layout::STORE_STALL_MAX_US`).
        if !matches!(result, Err(StoreError::Encode | StoreError::Geometry)) {
            app.link_stale.store(true, Ordering::Release);
        }
        let outcome = match result {
            Ok(seq) => {
                app.count(Counter::CalStores);
                info!("calibration: id {:?} stored as record {:?}", cal_id, seq);
                StoreOutcome::Stored(seq)
            }
            Err(e) => {
                app.count(Counter::CalStoreErrors);
                error!("calibration: store failed: {:?}", e);
                StoreOutcome::Failed
            }
        };
        app.last_store.lock(|c| c.set(outcome));
        let stored = matches!(outcome, StoreOutcome::Stored(_));
        let ack = app.pipeline.lock().await.calibration_persisted(tag, stored);
        app.replies
            .send(BusOut::Telemetry(Telemetry::Ack(ack)))
            .await;
    }
}
