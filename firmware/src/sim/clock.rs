//! Time and execution on the host: an `embassy-time` driver and a one-thread executor for the firmware's loops.
//!
//! Each [`run`] owns a clock for its thread:
//! - [`Mode::Virtual`]: time stands still while any task can run, and jumps to the next timer when none can — a
//!   discrete-event simulation. Scenarios are deterministic, and an hour of flight takes as long as its work.
//! - [`Mode::Real`]: time is the PC's monotonic clock; the thread sleeps until the next timer or a wake-up from
//!   another thread (the SITL's serial I/O). The SITL runs this way.
//!
//! The state is thread-local, so tests on parallel threads each have their own clock. `embassy-time`'s `Instant`,
//! `Timer`, `Ticker` and `with_timeout` read it through the driver; the executor polls one future (the tasks joined,
//! as the MCU's executor polls its spawned tasks) with a waker that any thread may use.
//!
//! [`settle`] waits until every task is blocked (before virtual time moves on): "let the firmware react".
#![allow(unsafe_code)] // `time_driver_impl!` exports two `#[no_mangle]` functions: the driver's registration.

use core::future::Future;
use core::pin::pin;
use core::task::{Context, Poll, Waker};
use std::cell::{Cell, RefCell};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::task::Wake;
use std::thread::{self, Thread};
use std::thread_local;
use std::time::Instant as StdInstant;
use std::vec::Vec;

use embassy_time_queue_utils::queue_generic::ConstGenericQueue;

/// How time passes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Time advances only when every task waits for a timer (tests).
    Virtual,
    /// Wall-clock time (the SITL).
    Real,
}

/// Why a run ended without its future's result.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RunError {
    /// Virtual time passed the run's limit: the scenario waited for something that never happened.
    TimeLimit,
    /// No task can ever run again: nothing is ready, no timer is pending and no other thread can wake it.
    Deadlock,
    /// The thread to run on could not be started.
    Thread,
}

struct Clock {
    mode: Mode,
    start: StdInstant,
    virtual_ticks: u64,
    queue: ConstGenericQueue<64>,
    /// Incremented each time the executor finds every task blocked.
    idle_epoch: u64,
    idle_waiters: Vec<Waker>,
}

thread_local! {
    static CLOCK: RefCell<Option<Clock>> = const { RefCell::new(None) };
    static EPOCH: Cell<u64> = const { Cell::new(0) };
}

const TICK_HZ: u64 = embassy_time_driver::TICK_HZ;

fn ticks_since(start: StdInstant) -> u64 {
    let d = start.elapsed();
    // u128 → u64: 2⁶⁴ µs are 584 000 years.
    (d.as_nanos().saturating_mul(u128::from(TICK_HZ)) / 1_000_000_000) as u64
}

impl Clock {
    fn now(&self) -> u64 {
        match self.mode {
            Mode::Virtual => self.virtual_ticks,
            Mode::Real => ticks_since(self.start),
        }
    }
}

struct Driver;

impl embassy_time_driver::Driver for Driver {
    fn now(&self) -> u64 {
        CLOCK.with(|c| c.borrow().as_ref().map_or(0, Clock::now))
    }

    fn schedule_wake(&self, at: u64, waker: &Waker) {
        CLOCK.with(|c| match c.borrow_mut().as_mut() {
            Some(clock) => {
                clock.queue.schedule_wake(at, waker);
            }
            // Outside a run nothing can be waiting for time: wake at once, the caller re-checks.
            None => waker.wake_by_ref(),
        });
    }
}

// SAFETY: the macro defines `_embassy_time_now` and `_embassy_time_schedule_wake` once for the whole program (the
// host build only; on the MCU embassy-stm32's TIM5 driver defines them), with the signatures embassy-time declares.
embassy_time_driver::time_driver_impl!(static DRIVER: Driver = Driver);

struct Flag {
    woken: AtomicBool,
    thread: Thread,
}

impl Wake for Flag {
    fn wake(self: Arc<Self>) {
        self.wake_by_ref();
    }
    fn wake_by_ref(self: &Arc<Self>) {
        self.woken.store(true, Ordering::Release);
        self.thread.unpark();
    }
}

/// Runs `fut` to completion on this thread with a clock in `mode`. In virtual mode the run fails once virtual time
/// passes `limit` (real mode ignores it).
pub fn run<F: Future>(
    mode: Mode,
    limit: embassy_time::Duration,
    fut: F,
) -> Result<F::Output, RunError> {
    let previous = CLOCK.with(|c| {
        c.replace(Some(Clock {
            mode,
            start: StdInstant::now(),
            virtual_ticks: 0,
            queue: ConstGenericQueue::new(),
            idle_epoch: 0,
            idle_waiters: Vec::new(),
        }))
    });
    let result = run_inner(limit.as_ticks(), fut);
    CLOCK.with(|c| c.replace(previous));
    result
}

/// [`run`] of the future `make` builds, on a thread whose stack is the flight build's stack region
/// ([`crate::layout::MCU_STACK_LEN`]), with the future on the heap as the MCU keeps its tasks' state in static
/// storage: only the polls' frames use the stack, as on the MCU. A second net, on the host, for the class of bug the
/// ELF's stack check (`tools/fw-check/stack.py`) catches first: a task whose frames outgrow the MCU's stack
/// overflows here too and fails the test (Rust's guard page aborts the process with "thread … has overflowed its
/// stack"). Host frames (x86-64, another optimisation level) are not the MCU's: this cannot replace the ELF's
/// figures.
pub fn run_on_mcu_stack<F, M>(
    mode: Mode,
    limit: embassy_time::Duration,
    make: M,
) -> Result<F::Output, RunError>
where
    M: FnOnce() -> F + Send,
    F: Future,
    F::Output: Send,
{
    thread::scope(|scope| {
        thread::Builder::new()
            .name("mcu-stack".into())
            .stack_size(crate::layout::MCU_STACK_LEN)
            .spawn_scoped(scope, move || {
                run(mode, limit, std::boxed::Box::pin(make()))
            })
            .map_err(|_| RunError::Thread)?
            .join()
            .unwrap_or_else(|e| std::panic::resume_unwind(e))
    })
}

fn run_inner<F: Future>(limit: u64, fut: F) -> Result<F::Output, RunError> {
    let flag = Arc::new(Flag {
        woken: AtomicBool::new(true),
        thread: thread::current(),
    });
    let waker = Waker::from(flag.clone());
    let mut cx = Context::from_waker(&waker);
    let mut fut = pin!(fut);
    loop {
        if flag.woken.swap(false, Ordering::AcqRel) {
            if let Poll::Ready(v) = fut.as_mut().poll(&mut cx) {
                return Ok(v);
            }
            continue;
        }
        // Nothing ready: wake expired timers, or tell settle() waiters, or let time pass.
        let step = CLOCK.with(|c| {
            let mut c = c.borrow_mut();
            let clock = c.as_mut().ok_or(RunError::Deadlock)?;
            let now = clock.now();
            let next = clock.queue.next_expiration(now);
            if flag.woken.load(Ordering::Acquire) {
                return Ok(None);
            }
            if !clock.idle_waiters.is_empty() {
                clock.idle_epoch = clock.idle_epoch.wrapping_add(1);
                EPOCH.set(clock.idle_epoch);
                clock.idle_waiters.drain(..).for_each(Waker::wake);
                return Ok(None);
            }
            match clock.mode {
                Mode::Virtual if next == u64::MAX => Err(RunError::Deadlock),
                Mode::Virtual if next > limit => Err(RunError::TimeLimit),
                Mode::Virtual => {
                    clock.virtual_ticks = next;
                    Ok(None)
                }
                Mode::Real => Ok(Some(next.saturating_sub(now))),
            }
        })?;
        if let Some(wait_ticks) = step {
            // Real time: sleep until the next timer or a wake-up from another thread (spurious wake-ups loop).
            let wait =
                core::time::Duration::from_micros(wait_ticks.saturating_mul(1_000_000) / TICK_HZ);
            thread::park_timeout(wait.min(core::time::Duration::from_secs(1)));
        }
    }
}

/// The CPU stalls for `d` without running any task: what a flash erase or program does on the single-bank F405
/// (every fetch from flash waits). In virtual time the clock jumps by `d`; in real time the thread sleeps. Timers
/// that expired meanwhile fire late, and whatever the world sent meanwhile piles up in the lines, as on the MCU.
pub fn stall(d: embassy_time::Duration) {
    let mode = CLOCK.with(|c| match c.borrow_mut().as_mut() {
        Some(clock) if clock.mode == Mode::Virtual => {
            clock.virtual_ticks = clock.virtual_ticks.saturating_add(d.as_ticks());
            None
        }
        Some(clock) => Some(clock.mode),
        None => None,
    });
    if mode == Some(Mode::Real) {
        thread::sleep(core::time::Duration::from_micros(d.as_micros()));
    }
}

/// Completes once every task of the current run is blocked (waiting for I/O or a timer), before time moves on.
pub async fn settle() {
    let start = EPOCH.get();
    core::future::poll_fn(|cx| {
        if EPOCH.get() != start {
            return Poll::Ready(());
        }
        CLOCK.with(|c| match c.borrow_mut().as_mut() {
            Some(clock) => {
                clock.idle_waiters.push(cx.waker().clone());
                Poll::Pending
            }
            None => Poll::Ready(()),
        })
    })
    .await
}
