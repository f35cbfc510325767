//! The receive-error side of the board's interrupts: each USART's and DMA stream's own handler, which runs before
//! embassy's (bound in `board::Irqs`), takes and counts the errors so that the DMA rings keep running.

/// Receive errors the interrupt handlers took before the drivers saw them: [FPGA link, bus] × [overrun, line].
static UART_ERRORS: [[core::sync::atomic::AtomicU32; 2]; 2] =
    [const { [const { core::sync::atomic::AtomicU32::new(0) }; 2] }; 2];
/// DMA transfer errors (any of the four streams), counted and recovered instead of embassy's panic.
static DMA_ERRORS: core::sync::atomic::AtomicU32 = core::sync::atomic::AtomicU32::new(0);

/// Receive errors taken by the handlers, as `[FPGA link, bus]` counts (`app::Platform::uart_errors`).
pub fn uart_errors() -> firmware::app::UartErrors {
    use core::sync::atomic::Ordering::Relaxed;
    let counts = |i: usize| {
        UART_ERRORS
            .get(i)
            .map_or(shared::telemetry::RxErrorCounts::default(), |c| {
                shared::telemetry::RxErrorCounts {
                    overrun: c[0].load(Relaxed),
                    line: c[1].load(Relaxed),
                    other: 0,
                }
            })
    };
    firmware::app::UartErrors {
        link: counts(0),
        bus: counts(1),
        dma: DMA_ERRORS.load(Relaxed),
    }
}

/// Takes a USART's receive errors (framing, noise, parity, overrun) before embassy's driver sees them: counts them
/// and clears them (SR read, then DR read: RM0090 §30.6.1), and the DMA ring runs on. embassy-stm32 0.6.0's
/// ring-buffered receiver stops its DMA stream on every error and restarts it on the next read without
/// reprogramming it; whether the F4's stream then resumes in place or from the buffer's start (and whether the
/// disable set TCIF, which the driver counts as a lap) is not settled (upstream issue 6592 reports the F411 resumes
/// in place; AN4031 and RM0090 §10.3.17 allow the other), and the later upstream ring-buffer fixes are not released.
/// Taking the errors here keeps the stream running through an error storm whichever it is (`tools/fw-check`
/// models the restart from the start, and its line-noise scenario found stale frames replayed without this). The
/// byte that carried the error is in the ring (the decoder's CRC drops its frame); a byte arriving between the two
/// reads would be lost too (< 1 µs at 2 Mbaud, 5 µs per byte).
pub struct LineErrors;

fn take_line_errors(
    r: embassy_stm32::pac::usart::Usart,
    counts: &[core::sync::atomic::AtomicU32; 2],
) {
    use core::sync::atomic::Ordering::Relaxed;
    let sr = r.sr().read();
    if sr.ore() || sr.fe() || sr.ne() || sr.pe() {
        // The second half of the clearing sequence (the first is the SR read above).
        let _ = r.dr().read();
        let [overrun, line] = counts;
        if sr.ore() {
            overrun.fetch_add(1, Relaxed);
        }
        if sr.fe() || sr.ne() || sr.pe() {
            line.fetch_add(1, Relaxed);
        }
    }
}

impl embassy_stm32::interrupt::typelevel::Handler<embassy_stm32::interrupt::typelevel::USART1>
    for LineErrors
{
    #[allow(unsafe_code)]
    unsafe fn on_interrupt() {
        if let Some(c) = UART_ERRORS.first() {
            take_line_errors(embassy_stm32::pac::USART1, c);
        }
    }
}

impl embassy_stm32::interrupt::typelevel::Handler<embassy_stm32::interrupt::typelevel::USART2>
    for LineErrors
{
    #[allow(unsafe_code)]
    unsafe fn on_interrupt() {
        if let Some(c) = UART_ERRORS.get(1) {
            take_line_errors(embassy_stm32::pac::USART2, c);
        }
    }
}

/// Takes a DMA stream's transfer error (TEIF) before embassy's handler, which panics on it: counts it, clears it,
/// and clears the USART's DMA request enable, so that the ring-buffered receiver restarts its stream on its next
/// read (a transmit stream's write times out in the tasks and is counted there).
pub struct DmaErrors;

/// TEIF of `stream` (0–7) of `dma`: clears it and the USART's DMAR if it was set; counts it.
fn take_dma_error(
    dma: embassy_stm32::pac::dma::Dma,
    stream: usize,
    usart: embassy_stm32::pac::usart::Usart,
) {
    let (reg, bit) = (stream / 4, stream % 4);
    if dma.isr(reg).read().teif(bit) {
        dma.ifcr(reg).write(|w| w.set_teif(bit, true));
        usart.cr3().modify(|w| w.set_dmar(false));
        DMA_ERRORS.fetch_add(1, core::sync::atomic::Ordering::Relaxed);
    }
}

macro_rules! dma_errors {
    ($($irq:ident => $dma:ident, $stream:literal, $usart:ident;)*) => {
        $(
            impl embassy_stm32::interrupt::typelevel::Handler<embassy_stm32::interrupt::typelevel::$irq>
                for DmaErrors
            {
                #[allow(unsafe_code)]
                unsafe fn on_interrupt() {
                    take_dma_error(embassy_stm32::pac::$dma, $stream, embassy_stm32::pac::$usart);
                }
            }
        )*
    };
}

dma_errors! {
    DMA1_STREAM5 => DMA1, 5, USART2;
    DMA1_STREAM6 => DMA1, 6, USART2;
    DMA2_STREAM2 => DMA2, 2, USART1;
    DMA2_STREAM7 => DMA2, 7, USART1;
}
