//! The fault record (flight build only): what stopped the firmware — a HardFault (with flip-link, also a stack
//! overflow: the stack sits at the bottom of RAM, so overflowing it faults instead of corrupting `.data`/`.bss`) or
//! a panic — kept in RAM that a reset leaves alone (`.uninit`), and reported in housekeeping after the next boot.
//!
//! If a stack overflow leaves the fault handler no stack for its own frame, the core locks up; the IWDG then resets
//! it within 8 s, and `reset_flags` says so (no record is written in that case).
#![allow(unsafe_code)] // the no-init record and the exception handler; each use has its SAFETY note

use core::mem::MaybeUninit;
use core::ptr::{addr_of, addr_of_mut};

use cortex_m_rt::{ExceptionFrame, exception};
use shared::telemetry::{FaultKind, FaultRecord};

/// Marks a record as written (anything else in RAM after a power-on is no record).
const MAGIC: u32 = 0xFA17_C0DE;

/// `[MAGIC, kind, pc, cfsr]`; `.uninit`: neither zeroed nor initialised by cortex-m-rt's reset handler.
#[unsafe(link_section = ".uninit.FAULT_RECORD")]
static mut RECORD: MaybeUninit<[u32; 4]> = MaybeUninit::uninit();

/// The record left before this reset, if any; clears it. Call once at boot, before any task runs.
pub fn take() -> Option<FaultRecord> {
    // SAFETY: single-threaded at boot (no task or interrupt touches RECORD yet); volatile word reads of RAM that
    // holds some bit pattern after any reset, every pattern being a valid `u32`.
    let [magic, kind, pc, cfsr] =
        unsafe { core::ptr::read_volatile(addr_of!(RECORD).cast::<[u32; 4]>()) };
    // SAFETY: as above; a plain volatile store.
    unsafe { core::ptr::write_volatile(addr_of_mut!(RECORD).cast::<[u32; 4]>(), [0; 4]) };
    if magic != MAGIC {
        return None;
    }
    let kind = match kind {
        0 => FaultKind::HardFault,
        _ => FaultKind::Panic,
    };
    Some(FaultRecord { kind, pc, cfsr })
}

/// Writes the record (from a fault handler or the panic handler, just before the reset).
pub fn record(kind: FaultKind, pc: u32, cfsr: u32) {
    let kind = match kind {
        FaultKind::HardFault => 0,
        FaultKind::Panic => 1,
    };
    // SAFETY: called with interrupts effectively stopped (in the HardFault handler, or the panic handler right
    // before the reset): nothing else accesses RECORD.
    unsafe {
        core::ptr::write_volatile(
            addr_of_mut!(RECORD).cast::<[u32; 4]>(),
            [MAGIC, kind, pc, cfsr],
        )
    };
}

/// Records the fault (faulting PC and CFSR) and resets.
#[exception]
unsafe fn HardFault(ef: &ExceptionFrame) -> ! {
    // SAFETY: a read of the SCB's CFSR register, which has no side effects.
    let cfsr = unsafe { (*cortex_m::peripheral::SCB::PTR).cfsr.read() };
    record(FaultKind::HardFault, ef.pc(), cfsr);
    cortex_m::peripheral::SCB::sys_reset()
}
