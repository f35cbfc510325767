//! Fault injection (the `fault-injection` build only, `cargo fw-inject`; never in the flight ELF, whose symbols CI
//! checks): the emulated board (`tools/fw-check`) writes `[INJECT_KEY, kind]` into [`FDIR_INJECT`] before a boot;
//! the firmware reads and clears it at boot and, one second later, stops the way `kind` says, so that each scenario
//! of the FDIR table (`docs/firmware.md`) can be proven on the real code.
#![allow(unsafe_code, clippy::panic)] // the no-init word, the injected faults themselves

use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;

use embassy_time::{Duration, Timer};
use shared::telemetry::TaskId;

/// Marks a valid request.
const INJECT_KEY: u32 = 0x1A7E_C7ED;

/// `[INJECT_KEY, kind]`, in no-init RAM: written by the emulator before a reset, read and cleared at boot.
#[unsafe(no_mangle)]
#[unsafe(link_section = ".uninit.FDIR_INJECT")]
static mut FDIR_INJECT: MaybeUninit<[u32; 2]> = MaybeUninit::uninit();

/// The injection asked for, if any (cleared: it happens once).
pub fn take() -> u32 {
    let p = addr_of_mut!(FDIR_INJECT).cast::<[u32; 2]>();
    // SAFETY: at boot, before any task; volatile word accesses of no-init RAM, any pattern a valid `[u32; 2]`.
    let [key, kind] = unsafe { core::ptr::read_volatile(p) };
    // SAFETY: as above.
    unsafe { core::ptr::write_volatile(p, [0, 0]) };
    if key == INJECT_KEY { kind } else { 0 }
}

/// Deep enough to leave the stack region whatever the frame size.
#[inline(never)]
fn recurse(depth: u32) -> u32 {
    let pad = core::hint::black_box([depth; 64]);
    let below = if core::hint::black_box(true) {
        recurse(depth.wrapping_add(1))
    } else {
        0
    };
    pad.iter().fold(below, |a, &b| a ^ b)
}

/// Waits one second, then injects `kind`: 1 stack overflow, 2 panic, 3 the housekeeping task hangs (awaits for
/// ever), 4 this task spins without yielding, 5 an interrupt without a handler (EXTI0) is pended, 6 a read of an
/// unmapped address (BusFault → HardFault).
pub async fn run(app: &'static crate::FwApp, kind: u32) {
    Timer::after(Duration::from_secs(1)).await;
    defmt::warn!("fault injection: kind {=u32}", kind);
    match kind {
        1 => {
            core::hint::black_box(recurse(0));
        }
        2 => panic!("fault injection"),
        3 => app.inject_hang(TaskId::Housekeeping),
        4 => loop {
            cortex_m::asm::nop();
        },
        5 => {
            use embassy_stm32::pac::Interrupt;
            // SAFETY: EXTI0 has no handler (`DefaultHandler`): the point of the test.
            unsafe { cortex_m::peripheral::NVIC::unmask(Interrupt::EXTI0) };
            cortex_m::peripheral::NVIC::pend(Interrupt::EXTI0);
        }
        6 => {
            // SAFETY: not safe at all: 0x3000_0000 is reserved on the F405, the read bus-faults. The point.
            core::hint::black_box(unsafe { core::ptr::read_volatile(0x3000_0000 as *const u32) });
        }
        _ => {}
    }
}
