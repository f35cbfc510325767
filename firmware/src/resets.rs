//! The reset history, independent of the board: what the fault handlers leave before a reset, and how the next
//! boot turns it into a [`ResetRecord`] kept with the last [`RESET_HISTORY_LEN`] others, the boot counter and the
//! crash-loop counter. The flight build keeps one [`Persist`] in RAM that a reset leaves alone (`fault.rs`,
//! `.uninit`); the host tests run the same code on a plain value.
//!
//! # Layout and power-cut rules
//! - The **history** (magic, counters, records) is covered by a CRC-32C. Only the boot code ([`Persist::boot`],
//!   before any task or interrupt runs) and the `ClearResets` command ([`Persist::clear`]) rewrite it. A block whose
//!   CRC fails (a power-on: RAM holds garbage) starts again at boot 1 with no record.
//! - The **pending record** is what a handler writes just before it resets (HardFault, NMI, `DefaultHandler`, the
//!   panic handler, the deadline monitor): a handful of word stores, outside the CRC, valid only when its key word
//!   matches its kind, so that a record cut short by a second fault is never mistaken for one.
//! - The **uptime** the running firmware notes every watchdog period (≤ 250 ms old) is a word and its complement,
//!   outside the CRC too: a reset while it is written loses that note, never the history.
//!
//! # Crash loop
//! A reset that comes less than [`SHORT_RUN_MS`] after its boot is a *short run*; after [`CRASH_LOOP_RUNS`] in a
//! row the next boot is in **safe mode** (`main.rs`: factory calibration, no FPGA tasks, the bus and housekeeping
//! still served) until the ground clears the counter (`ClearResets`) or a boot outlives [`SHORT_RUN_MS`]. There is
//! no clock that survives a reset, so "K resets within T" is counted as K consecutive runs each shorter than T.

use shared::telemetry::{
    HardFaultInfo, RESET_HISTORY_LEN, ResetCause, ResetHistory, ResetRecord, TaskId,
};

/// A run shorter than this counts towards the crash loop, ms.
pub const SHORT_RUN_MS: u32 = 60_000;
/// Consecutive short runs that put the next boot in safe mode.
pub const CRASH_LOOP_RUNS: u32 = 3;

/// Marks a valid history (with its CRC).
const MAGIC: u32 = 0x5245_5354; // "REST"
/// A pending record is valid when `key == PENDING_KEY ^ kind`.
const PENDING_KEY: u32 = 0xFA17_C0DE;

/// Kinds of pending record (the word a handler writes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum Kind {
    /// [`ResetCause::HardFault`]: words = pc, lr, exc_return, sp, cfsr, hfsr, fault address.
    HardFault = 1,
    /// [`ResetCause::ClockFailure`].
    ClockFailure = 2,
    /// [`ResetCause::Nmi`].
    Nmi = 3,
    /// [`ResetCause::UnhandledIrq`]: `words[0]` = IPSR.
    UnhandledIrq = 4,
    /// [`ResetCause::Panic`]: words = line, file CRC.
    Panic = 5,
    /// [`ResetCause::Watchdog`]: words = task number, pc.
    Watchdog = 6,
    /// [`ResetCause::Commanded`].
    Commanded = 7,
}

/// A record as it sits in RAM: `kind` 0 is none.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(C)]
pub struct RawRecord {
    /// [`Kind`] as a word (0: no record; anything unknown reads as [`ResetCause::Unknown`]).
    pub kind: u32,
    /// The boot that ended.
    pub boot: u32,
    /// Its uptime, ms.
    pub uptime_ms: u32,
    /// Reset flags found by the next boot.
    pub flags: u32,
    /// The kind's words.
    pub words: [u32; 7],
}

impl RawRecord {
    const EMPTY: Self = Self {
        kind: 0,
        boot: 0,
        uptime_ms: 0,
        flags: 0,
        words: [0; 7],
    };

    /// The record as telemetry, `None` when empty.
    pub fn decode(&self) -> Option<ResetRecord> {
        if self.kind == 0 {
            return None;
        }
        let [w0, w1, w2, w3, w4, w5, w6] = self.words;
        let cause = match self.kind {
            k if k == Kind::HardFault as u32 => ResetCause::HardFault(HardFaultInfo {
                pc: w0,
                lr: w1,
                exc_return: w2,
                sp: w3,
                cfsr: w4,
                hfsr: w5,
                fault_addr: w6,
            }),
            k if k == Kind::ClockFailure as u32 => ResetCause::ClockFailure,
            k if k == Kind::Nmi as u32 => ResetCause::Nmi,
            k if k == Kind::UnhandledIrq as u32 => ResetCause::UnhandledIrq {
                exception: u16::try_from(w0 & 0x1FF).unwrap_or(u16::MAX),
            },
            k if k == Kind::Panic as u32 => ResetCause::Panic {
                line: w0,
                file_crc: w1,
            },
            k if k == Kind::Watchdog as u32 => ResetCause::Watchdog {
                task: task_id(w0),
                pc: w1,
            },
            k if k == Kind::Commanded as u32 => ResetCause::Commanded,
            _ => ResetCause::Unknown,
        };
        Some(ResetRecord {
            boot: self.boot,
            uptime_ms: self.uptime_ms,
            reset_flags: u8::try_from(self.flags & 0xFF).unwrap_or(u8::MAX),
            cause,
        })
    }
}

/// The task of number `n` (the order of [`TaskId`]'s named variants).
pub fn task_id(n: u32) -> TaskId {
    match n {
        0 => TaskId::Link,
        1 => TaskId::FpgaCtrl,
        2 => TaskId::BusRx,
        3 => TaskId::BusTx,
        4 => TaskId::Storage,
        5 => TaskId::Watchdog,
        6 => TaskId::Housekeeping,
        7 => TaskId::Pps,
        other => TaskId::Other(u8::try_from(other).unwrap_or(u8::MAX)),
    }
}

/// What a handler leaves for the next boot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(C)]
pub struct Pending {
    /// `PENDING_KEY ^ kind` when valid.
    pub key: u32,
    /// [`Kind`] as a word.
    pub kind: u32,
    /// The uptime the handler read from the noted uptime, ms.
    pub uptime_ms: u32,
    /// The kind's words.
    pub words: [u32; 7],
}

impl Pending {
    /// The pending record of `kind` with `words` at `uptime_ms`.
    pub const fn new(kind: Kind, uptime_ms: u32, words: [u32; 7]) -> Self {
        Self {
            key: PENDING_KEY ^ (kind as u32),
            kind: kind as u32,
            uptime_ms,
            words,
        }
    }

    fn valid(&self) -> bool {
        self.kind != 0 && self.key == PENDING_KEY ^ self.kind
    }
}

/// The block kept across resets.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(C)]
pub struct Persist {
    magic: u32,
    boot_count: u32,
    short_runs: u32,
    dropped: u32,
    records: [RawRecord; RESET_HISTORY_LEN],
    crc: u32,
    /// Outside the CRC: the last record a handler wrote.
    pending: Pending,
    /// Outside the CRC: the uptime the running boot noted, and its complement.
    uptime: [u32; 2],
}

/// What the boot code learns from the history.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BootState {
    /// This boot's number.
    pub boot_count: u32,
    /// The crash-loop counter reached [`CRASH_LOOP_RUNS`].
    pub safe_mode: bool,
    /// The boot before this one ended with a clock failure (the crystal is not to be trusted).
    pub after_clock_failure: bool,
}

impl Persist {
    /// An empty block (what RAM holds after a power-on is anything; [`Self::boot`] finds out).
    pub const EMPTY: Self = Self {
        magic: 0,
        boot_count: 0,
        short_runs: 0,
        dropped: 0,
        records: [RawRecord::EMPTY; RESET_HISTORY_LEN],
        crc: 0,
        pending: Pending {
            key: 0,
            kind: 0,
            uptime_ms: 0,
            words: [0; 7],
        },
        uptime: [0, 0],
    };

    fn checksum(&self) -> u32 {
        let mut c = shared::crc::Crc32c::new();
        for w in [self.magic, self.boot_count, self.short_runs, self.dropped] {
            c.update(&w.to_le_bytes());
        }
        for r in &self.records {
            for w in [r.kind, r.boot, r.uptime_ms, r.flags] {
                c.update(&w.to_le_bytes());
            }
            for w in r.words {
                c.update(&w.to_le_bytes());
            }
        }
        c.finish()
    }

    fn seal(&mut self) {
        self.magic = MAGIC;
        self.crc = self.checksum();
    }

    /// Whether the history survived (its magic and CRC hold).
    pub fn valid(&self) -> bool {
        self.magic == MAGIC && self.crc == self.checksum()
    }

    /// The uptime the last boot noted, ms (0 when the note is torn or absent).
    pub fn noted_uptime_ms(&self) -> u32 {
        let [u, not_u] = self.uptime;
        if u == !not_u { u } else { 0 }
    }

    /// Notes the running boot's uptime (every watchdog period).
    pub fn note_uptime(&mut self, uptime_ms: u32) {
        self.uptime = [uptime_ms, !uptime_ms];
    }

    /// Leaves `pending` for the next boot (a handler, just before it resets). A second record in the same boot
    /// (a fault inside the handler of another) keeps the first.
    pub fn leave(&mut self, pending: Pending) {
        if !self.pending.valid() {
            self.pending = pending;
        }
    }

    /// Withdraws a pending record of `kind` (the watchdog fed again after the monitor filed a deadline miss).
    pub fn cancel(&mut self, kind: Kind) {
        if self.pending().is_some_and(|p| p.kind == kind as u32) {
            self.pending = Self::EMPTY.pending;
        }
    }

    /// The pending record left in this boot, if any.
    pub fn pending(&self) -> Option<Pending> {
        Some(self.pending).filter(Pending::valid)
    }

    /// At boot, before anything else uses the block: files what ended the last boot (the pending record, or an
    /// `Unknown` one) with `reset_flags`, counts the boot and the crash loop. A block that does not hold (power-on)
    /// starts again, with no record.
    pub fn boot(&mut self, reset_flags: u8) -> BootState {
        let pending = self.pending();
        let mut after_clock_failure = false;
        if self.valid() {
            let uptime_ms = pending.map_or(self.noted_uptime_ms(), |p| p.uptime_ms);
            let (kind, words) = pending.map_or((0xFFFF_FFFF, [0; 7]), |p| (p.kind, p.words));
            after_clock_failure = kind == Kind::ClockFailure as u32;
            self.push(RawRecord {
                kind,
                boot: self.boot_count,
                uptime_ms,
                flags: u32::from(reset_flags),
                words,
            });
            self.short_runs = if uptime_ms < SHORT_RUN_MS {
                self.short_runs.saturating_add(1)
            } else {
                0
            };
        } else {
            *self = Self::EMPTY;
        }
        self.boot_count = self.boot_count.wrapping_add(1);
        self.pending = Self::EMPTY.pending;
        self.uptime = [0, !0];
        self.seal();
        BootState {
            boot_count: self.boot_count,
            safe_mode: self.short_runs >= CRASH_LOOP_RUNS,
            after_clock_failure,
        }
    }

    fn push(&mut self, r: RawRecord) {
        if self.records.last().is_some_and(|last| last.kind != 0) {
            self.dropped = self.dropped.wrapping_add(1);
        }
        self.records.rotate_right(1);
        if let Some(first) = self.records.first_mut() {
            *first = r;
        }
    }

    /// Clears the records, the dropped count and the crash-loop counter (`ClearResets`); the boot counter stays.
    pub fn clear(&mut self) {
        self.records = [RawRecord::EMPTY; RESET_HISTORY_LEN];
        self.dropped = 0;
        self.short_runs = 0;
        self.seal();
    }

    /// A run that outlived [`SHORT_RUN_MS`] ends the crash loop (called once, by the housekeeping task).
    pub fn end_crash_loop(&mut self) {
        if self.short_runs != 0 {
            self.short_runs = 0;
            self.seal();
        }
    }

    /// The history as telemetry; `safe_mode` is the running boot's.
    pub fn report(&self, safe_mode: bool) -> ResetHistory {
        let mut records = [None; RESET_HISTORY_LEN];
        for (slot, r) in records.iter_mut().zip(self.records.iter()) {
            *slot = r.decode();
        }
        ResetHistory {
            boot_count: self.boot_count,
            short_runs: u8::try_from(self.short_runs).unwrap_or(u8::MAX),
            safe_mode,
            dropped: self.dropped,
            records,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const POR: u8 = 0b0000_0111;
    const IWDG: u8 = 0b0001_0010;
    const SOFT: u8 = 0b0000_1010;

    /// Power-on garbage starts a fresh history; each reset then files one record, newest first, with the flags the
    /// next boot found and the cause the handler left.
    #[test]
    fn files_each_reset_newest_first() {
        let mut p = Persist::EMPTY;
        p.magic = 0xDEAD_BEEF; // garbage
        let b = p.boot(POR);
        assert_eq!((b.boot_count, b.safe_mode), (1, false));
        assert_eq!(p.report(false).records, [None; RESET_HISTORY_LEN]);

        p.note_uptime(61_000);
        p.leave(Pending::new(
            Kind::Panic,
            61_000,
            [42, 0xABCD, 0, 0, 0, 0, 0],
        ));
        // A second fault in the same boot keeps the first record.
        p.leave(Pending::new(Kind::Nmi, 61_001, [0; 7]));
        p.boot(SOFT);
        p.note_uptime(1_250);
        let b = p.boot(IWDG); // no pending: a lock-up or a reset nobody recorded
        assert_eq!(b.boot_count, 3);
        let h = p.report(false);
        assert_eq!(h.boot_count, 3);
        assert_eq!(
            h.records[0],
            Some(ResetRecord {
                boot: 2,
                uptime_ms: 1_250,
                reset_flags: IWDG,
                cause: ResetCause::Unknown
            })
        );
        assert_eq!(
            h.records[1],
            Some(ResetRecord {
                boot: 1,
                uptime_ms: 61_000,
                reset_flags: SOFT,
                cause: ResetCause::Panic {
                    line: 42,
                    file_crc: 0xABCD
                }
            })
        );
        assert_eq!(h.records[2], None);
        // One short run (the second boot's), the first ran past SHORT_RUN_MS.
        assert_eq!(h.short_runs, 1);
    }

    /// The crash loop: CRASH_LOOP_RUNS short runs in a row put the next boot in safe mode; clearing or a long run
    /// ends it; the history keeps the newest RESET_HISTORY_LEN and counts the rest.
    #[test]
    fn crash_loop_and_clear() {
        let mut p = Persist::EMPTY;
        p.boot(POR);
        for i in 0..CRASH_LOOP_RUNS {
            p.leave(Pending::new(
                Kind::Watchdog,
                500,
                [6, 0x0800_1234, 0, 0, 0, 0, 0],
            ));
            let b = p.boot(IWDG);
            assert_eq!(
                b.safe_mode,
                i + 1 == CRASH_LOOP_RUNS,
                "after {} short runs",
                i + 1
            );
        }
        let h = p.report(true);
        assert_eq!(
            h.records[0].map(|r| r.cause),
            Some(ResetCause::Watchdog {
                task: TaskId::Housekeeping,
                pc: 0x0800_1234
            })
        );
        for _ in 0..3 {
            p.boot(SOFT);
        }
        assert_eq!(p.report(true).dropped, 2, "6 records, 4 kept");
        p.clear();
        let h = p.report(true);
        assert_eq!((h.short_runs, h.dropped, h.records), (0, 0, [None; 4]));
        assert!(p.valid());
        assert_eq!(
            h.boot_count,
            1 + CRASH_LOOP_RUNS + 3,
            "the boot counter stays"
        );
        // A long run ends the loop too.
        for _ in 0..CRASH_LOOP_RUNS {
            p.boot(IWDG);
        }
        p.end_crash_loop();
        assert!(!p.boot(IWDG).safe_mode);
    }

    /// A torn write is never a record: a pending key that does not match, a torn uptime note, a history whose CRC
    /// fails (everything starts again, at boot 1).
    #[test]
    fn torn_writes_are_not_records() {
        let mut p = Persist::EMPTY;
        p.boot(POR);
        p.pending = Pending::new(Kind::HardFault, 10, [1; 7]);
        p.pending.kind = Kind::Panic as u32; // key of another kind
        p.uptime = [5_000, 0];
        p.boot(SOFT);
        assert_eq!(
            p.report(false).records[0],
            Some(ResetRecord {
                boot: 1,
                uptime_ms: 0,
                reset_flags: SOFT,
                cause: ResetCause::Unknown
            })
        );
        p.records[1].boot ^= 1; // a bit flip in the history
        let b = p.boot(SOFT);
        assert_eq!(b.boot_count, 1);
        assert_eq!(p.report(false).records, [None; 4]);
    }

    /// A clock failure is filed as such, and the next boot knows it (it then runs on the HSI).
    #[test]
    fn clock_failure_is_remembered_for_one_boot() {
        let mut p = Persist::EMPTY;
        p.boot(POR);
        p.leave(Pending::new(Kind::ClockFailure, 70_000, [0; 7]));
        assert!(p.boot(SOFT).after_clock_failure);
        assert!(!p.boot(SOFT).after_clock_failure);
        let r = p.report(false).records;
        assert_eq!(r[1].map(|r| r.cause), Some(ResetCause::ClockFailure));
    }
}
