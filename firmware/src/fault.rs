//! Fault handling (flight build only): every way the firmware stops leaves a record for the next boot, in the
//! reset history (`firmware::resets::Persist`) kept in RAM that a reset leaves alone (`.uninit`).
//!
//! | how it stops | handler | record |
//! |---|---|---|
//! | HardFault (also a flip-link stack overflow) | `HardFault` (assembly): MSP moved to [`FAULT_STACK`] first, then [`fdir_hard_fault`] | stacked PC/LR (when the frame could be stacked), EXC_RETURN, SP, CFSR, HFSR, BFAR/MMFAR |
//! | the crystal fails (clock security system) | `NonMaskableInt` | `ClockFailure` (CSSF cleared); the next boot runs on the HSI |
//! | an interrupt or exception without a handler | `DefaultHandler` | its exception number (IPSR) |
//! | a panic | `main.rs` panic handler, [`panic`] | line and CRC-32C of the file path |
//! | a task misses its deadline | `SysTick`, the deadline monitor, every 100 ms | the first late task and the PC thread code was at; the IWDG resets |
//! | a lock-up, the reset pin, a power dip that kept RAM | none | `Unknown`, with the reset flags |
//!
//! Each handler writes the pending record and resets (`SCB::sys_reset`); none returns. None formats anything.
#![allow(unsafe_code)] // the no-init block, the handlers and the stack switch; each use has its SAFETY note

use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;
use core::sync::atomic::{AtomicPtr, Ordering};

use cortex_m_rt::exception;
use firmware::app::ResetLog;
use firmware::resets::{BootState, Kind, Pending, Persist};
use shared::telemetry::ResetHistory;

/// The reset history; `.uninit`: neither zeroed nor initialised by cortex-m-rt's reset handler. Every field is a
/// `u32`, so every bit pattern is a valid `Persist` ([`Persist::boot`] checks its CRC).
#[unsafe(link_section = ".uninit.RESETS")]
static mut PERSIST: MaybeUninit<Persist> = MaybeUninit::uninit();

/// Bytes of the HardFault handler's own stack: its worst path (`tools/fw-check/stack.py`) with room to spare.
const FAULT_STACK_LEN: usize = 1024;

/// The HardFault handler's stack: the fault may be an overflow of the main one, so it is never used.
#[repr(C, align(8))]
struct FaultStack([u8; FAULT_STACK_LEN]);

/// `.uninit`: its contents do not matter, and it costs no start-up zeroing.
#[unsafe(link_section = ".uninit.FAULT_STACK")]
#[unsafe(no_mangle)]
static mut FAULT_STACK: MaybeUninit<FaultStack> = MaybeUninit::uninit();

fn persist() -> *mut Persist {
    addr_of_mut!(PERSIST).cast::<Persist>()
}

/// Files what ended the last boot and counts this one. Call once at boot, before any task or interrupt runs.
pub fn boot(reset_flags: u8) -> BootState {
    // SAFETY: single-threaded at boot (no task or interrupt touches the block yet); any bit pattern is a valid
    // `Persist` (all `u32` fields).
    unsafe { (*persist()).boot(reset_flags) }
}

/// Writes the pending record of `kind` with `words` and resets. From a handler, or the panic handler.
fn leave_and_reset(kind: Kind, words: [u32; 7]) -> ! {
    // SAFETY: every writer of the block is either a handler on its way to a reset (it never returns to what it
    // preempted, so no borrow it cut into is used again) or task code in a critical section (`with`); the block is
    // all `u32`.
    unsafe {
        let p = persist();
        let uptime_ms = (*p).noted_uptime_ms();
        (*p).leave(Pending::new(kind, uptime_ms, words));
    }
    cortex_m::peripheral::SCB::sys_reset()
}

/// Resets now, recording a commanded reset (`app::Platform::reset`: the update service's `Reset`).
pub fn commanded_reset() {
    cortex_m::interrupt::disable();
    leave_and_reset(Kind::Commanded, [0; 7])
}

/// Runs `f` on the block with interrupts off (task code).
fn with<R>(f: impl FnOnce(&mut Persist) -> R) -> R {
    cortex_m::interrupt::free(|_| {
        // SAFETY: interrupts are off; a fault or NMI that preempts `f` resets and never returns here.
        f(unsafe { &mut *persist() })
    })
}

/// The reset history as the tasks reach it (`app::Platform::resets`).
pub struct Log;

/// The one [`Log`].
pub static LOG: Log = Log;

impl ResetLog for Log {
    fn report(&self, safe_mode: bool) -> ResetHistory {
        with(|p| p.report(safe_mode))
    }
    fn clear(&self) {
        with(Persist::clear);
    }
    fn note_uptime(&self, uptime_ms: u32, fed: bool) {
        with(|p| {
            p.note_uptime(uptime_ms);
            if fed {
                // Fed again: a deadline miss the monitor filed did not lead to a reset.
                p.cancel(Kind::Watchdog);
            }
        });
    }
    fn end_crash_loop(&self) {
        with(Persist::end_crash_loop);
    }
}

/// Records a panic at `location` and resets.
pub fn panic(location: Option<&core::panic::Location<'_>>) -> ! {
    let (line, file) = location.map_or((0, 0), |l| {
        (l.line(), shared::crc::crc32c(l.file().as_bytes()))
    });
    leave_and_reset(Kind::Panic, [line, file, 0, 0, 0, 0, 0])
}

// The HardFault entry, in the vector table in place of cortex-m-rt's: before anything touches memory, MSP moves to
// the fault stack (after a flip-link overflow MSP points below RAM, and the first push would lock the core up).
// r0 = MSP and r1 = PSP at entry, r2 = EXC_RETURN.
core::arch::global_asm!(
    ".section .HardFault.user, \"ax\"",
    ".global HardFault",
    ".type HardFault,%function",
    ".thumb_func",
    "HardFault:",
    "  mrs r0, msp",
    "  mrs r1, psp",
    "  mov r2, lr",
    "  ldr r3, ={stack}+{len}",
    "  msr msp, r3",
    "  b {handler}",
    stack = sym FAULT_STACK,
    len = const FAULT_STACK_LEN,
    handler = sym fdir_hard_fault,
);

/// Is `[addr, addr + 32)` in SRAM or CCM, where an exception frame can be (a frame stacked below RAM after an
/// overflow cannot be read: that would fault again, inside the fault handler)?
fn frame_readable(addr: u32) -> bool {
    const RAMS: [(u32, u32); 2] = [(0x2000_0000, 0x2002_0000), (0x1000_0000, 0x1001_0000)];
    addr.is_multiple_of(4)
        && RAMS
            .iter()
            .any(|&(lo, hi)| addr >= lo && addr.checked_add(32).is_some_and(|end| end <= hi))
}

/// The HardFault handler proper, on the fault stack: reads the fault registers and the stacked frame (if it was
/// stacked where it can be read), records them and resets.
#[unsafe(no_mangle)]
extern "C" fn fdir_hard_fault(msp: u32, psp: u32, exc_return: u32) -> ! {
    // SAFETY: reads of the SCB's fault status and address registers, which have no side effects.
    let (cfsr, hfsr, mmfar, bfar) = unsafe {
        let scb = &*cortex_m::peripheral::SCB::PTR;
        (
            scb.cfsr.read(),
            scb.hfsr.read(),
            scb.mmfar.read(),
            scb.bfar.read(),
        )
    };
    // EXC_RETURN bit 2: the frame is on the process stack.
    let sp = if exc_return & 0b100 != 0 { psp } else { msp };
    // CFSR: MSTKERR (bit 4), STKERR (bit 12): the frame was not (fully) stacked.
    let stacked = cfsr & (1 << 4 | 1 << 12) == 0 && frame_readable(sp);
    let (pc, lr) = if stacked {
        // SAFETY: the frame is in RAM (checked above) and word aligned: r0–r3, r12, LR, PC, xPSR.
        unsafe {
            (
                core::ptr::read_volatile(sp.wrapping_add(24) as *const u32),
                core::ptr::read_volatile(sp.wrapping_add(20) as *const u32),
            )
        }
    } else {
        (0, 0)
    };
    // BFARVALID (bit 15), MMARVALID (bit 7).
    let fault_addr = if cfsr & (1 << 15) != 0 {
        bfar
    } else if cfsr & (1 << 7) != 0 {
        mmfar
    } else {
        0
    };
    leave_and_reset(
        Kind::HardFault,
        [pc, lr, exc_return, sp, cfsr, hfsr, fault_addr],
    )
}

/// NMI: on the F405 the clock security system's (RCC_CIR.CSSF) or nothing. The CSS has already switched the
/// system clock to the HSI and stopped the crystal; the record makes the next boot stay on the HSI.
#[exception]
unsafe fn NonMaskableInt() {
    use embassy_stm32::pac::RCC;
    let css = RCC.cir().read().cssf();
    // CSSC: clear the flag (else the NMI comes back at once).
    RCC.cir().modify(|w| w.set_cssc(true));
    leave_and_reset(if css { Kind::ClockFailure } else { Kind::Nmi }, [0; 7])
}

/// Every exception and interrupt without a handler of its own: records which (IPSR) and resets, instead of
/// spinning until the IWDG does with nothing said.
#[exception]
unsafe fn DefaultHandler(irqn: i16) {
    let exception = u32::try_from(i32::from(irqn).saturating_add(16)).unwrap_or(0);
    leave_and_reset(Kind::UnhandledIrq, [exception, 0, 0, 0, 0, 0, 0])
}

/// The app the deadline monitor checks (set once by `main` before the tasks start).
static MONITORED: AtomicPtr<crate::FwApp> = AtomicPtr::new(core::ptr::null_mut());

/// Gives the deadline monitor the app to check.
pub fn monitor(app: &'static crate::FwApp) {
    MONITORED.store(core::ptr::from_ref(app).cast_mut(), Ordering::Release);
}

// SysTick, the deadline monitor, with the preempted frame's address in r0 (thread code runs on MSP).
core::arch::global_asm!(
    ".section .text.SysTick, \"ax\"",
    ".global SysTick",
    ".type SysTick,%function",
    ".thumb_func",
    "SysTick:",
    "  mrs r0, msp",
    "  mov r1, lr",
    "  b {handler}",
    handler = sym fdir_deadline_monitor,
);

/// Every 100 ms (SysTick, the highest priority but the faults): if a task is past its deadline, file a watchdog
/// record naming it and the PC thread code was at (a task that spins without yielding is there). The feed stops
/// anyway (the watchdog task feeds only while no task is late); the record is withdrawn if feeding resumes.
#[unsafe(no_mangle)]
extern "C" fn fdir_deadline_monitor(sp: u32, exc_return: u32) {
    let app = MONITORED.load(Ordering::Acquire);
    if app.is_null() {
        return;
    }
    // SAFETY: set once from a `&'static FwApp`; only its atomics are read.
    let app = unsafe { &*app };
    #[allow(clippy::cast_possible_truncation)] // wrapping by design, as the heartbeats
    let now_ms = embassy_time::Instant::now().as_millis() as u32;
    let Some(task) = app.late_task(now_ms) else {
        return;
    };
    // The preempted PC, if the frame is on MSP in RAM (it is: thread and handlers run on MSP).
    let pc = if exc_return & 0b100 == 0 && frame_readable(sp) {
        // SAFETY: checked to be in RAM and aligned; the stacked PC is the frame's seventh word.
        unsafe { core::ptr::read_volatile(sp.wrapping_add(24) as *const u32) }
    } else {
        0
    };
    let n = firmware::app::task_index(task)
        .and_then(|i| u32::try_from(i).ok())
        .unwrap_or(u32::MAX);
    with(|p| {
        let uptime_ms = p.noted_uptime_ms();
        p.leave(Pending::new(
            Kind::Watchdog,
            uptime_ms,
            [n, pc, 0, 0, 0, 0, 0],
        ));
    });
}
