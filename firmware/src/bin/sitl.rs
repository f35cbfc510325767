//! SITL: the firmware's tasks on the PC (`docs/sitl.md`). A frame log plays the FPGA, the CubeSat bus is a serial
//! device or pseudo-terminal (KISS, 115200 baud), the calibration flash is a file.
//!
//! ```sh
//! socat -d -d pty,raw,echo=0,link=/tmp/obc pty,raw,echo=0,link=/tmp/ground &
//! cargo run --release -p firmware --bin sitl -- --frames rec.bin --bus /tmp/obc --flash cal.img
//! ```
//! When the log ends the FPGA stays silent and the tasks keep running (Health every second) until Ctrl-C or
//! SIGTERM.
#![allow(clippy::arithmetic_side_effects, clippy::indexing_slicing)] // host tool: sizes of files in memory

use std::fs::File;
use std::io::{Read as _, Write as _};
use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use embassy_futures::select::{Either3, select3};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::Duration;
use firmware::app::{self, App};
use firmware::sim::clock::{self, Mode};
use firmware::sim::flash::{FileFlash, Stalling};
use firmware::sim::node::{self, Board};
use shared::bus::BusConfig;
use shared::bus::csp::CspVersion;
use shared::pipeline::{PipelineConfig, PipelineMemory};
use shared::storage::CalStore;
use shared::wire::FrameDecoder;

/// Runs the firmware's tasks on the PC against a frame log and a serial bus.
#[derive(Parser, Debug)]
#[command(version, about)]
struct Args {
    /// FPGA frame log to replay as the link (raw bytes as recorded; empty is valid: a silent FPGA).
    #[arg(long)]
    frames: PathBuf,
    /// Serial device or pseudo-terminal for the CubeSat bus (KISS, 115200 baud, 8N1).
    #[arg(long)]
    bus: PathBuf,
    /// Calibration flash image (created erased if missing; default: a temporary file, removed at exit).
    #[arg(long)]
    flash: Option<PathBuf>,
    /// Feed the log as fast as the tasks take it instead of at its frame rate.
    #[arg(long)]
    fast: bool,
    /// CSP header version on the bus: 1 (libcsp 1.x, Yamcs) or 2 (libcsp 2.x's default, 14-bit addresses).
    #[arg(long, default_value = "1")]
    csp_version: CspVersion,
    /// Our CSP address (v1 ≤ 31, v2 ≤ 16383).
    #[arg(long, default_value_t = BusConfig::DEFAULT.addr)]
    addr: u16,
    /// The ground station's CSP address: destination of telemetry.
    #[arg(long, default_value_t = BusConfig::DEFAULT.ground_addr)]
    ground_addr: u16,
}

static STOP: Signal<CriticalSectionRawMutex, ()> = Signal::new();

fn main() -> ExitCode {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("info")).init();
    let args = Args::parse();
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("sitl: {e}");
            ExitCode::from(2)
        }
    }
}

fn run(args: &Args) -> Result<(), String> {
    let version = args.csp_version;
    if args.addr.max(args.ground_addr) > version.max_addr() {
        return Err(format!(
            "CSP v{} addresses are at most {} (--addr {}, --ground-addr {})",
            version.number(),
            version.max_addr(),
            args.addr,
            args.ground_addr
        ));
    }
    let frames = std::fs::read(&args.frames)
        .map_err(|e| format!("reading {}: {e}", args.frames.display()))?;
    let (flash_path, temporary) = match &args.flash {
        Some(p) => (p.clone(), false),
        None => (
            std::env::temp_dir().join(format!("sitl-flash-{}.img", std::process::id())),
            true,
        ),
    };
    let flash = FileFlash::open(&flash_path)
        .map_err(|e| format!("flash image {}: {e}", flash_path.display()))?;
    let bus = open_bus(&args.bus)?;

    let board: &'static Board = Box::leak(Box::new(Board::new()));
    spawn_bus_io(board, bus)?;
    ctrlc::set_handler(|| STOP.signal(())).map_err(|e| format!("signal handler: {e}"))?;

    let config = PipelineConfig::DEFAULT;
    // Erases and programs stall the tasks for the F405's worst-case times, as on the MCU.
    let mut store = CalStore::new(Stalling(flash)).map_err(|e| format!("flash geometry: {e:?}"))?;
    let bus_config = BusConfig {
        version,
        addr: args.addr,
        ground_addr: args.ground_addr,
        ..BusConfig::DEFAULT
    };
    let mut app = App::new(
        config,
        Box::new(PipelineMemory::new()),
        bus_config,
        app::Platform::default(),
    );
    app::load_calibration(&mut store, app.pipeline.get_mut());
    // The update service on RAM models of the DFU slot and the boot state (a SITL has no image of its own: version
    // 0), checking uploads with the built-in key.
    let mut update = firmware::sim::flash::updater(firmware::update::UPDATE_PUBLIC_KEY, 0);
    log::info!(
        "sitl: {} bytes of frames ({}), bus {} (CSP v{}), flash {}",
        frames.len(),
        if args.fast {
            "as fast as taken"
        } else {
            "at the log's frame rate"
        },
        args.bus.display(),
        version.number(),
        flash_path.display()
    );

    let outcome = clock::run(
        Mode::Real,
        Duration::MAX,
        select3(
            node::tasks(&app, board, &mut store, &mut update),
            feed(board, &frames, args.fast, config.fpga_base_rate_millihz),
            STOP.wait(),
        ),
    );
    let p = app
        .pipeline
        .try_lock()
        .map(|p| (*p.link_counters(), p.health()));
    if let Ok((link, health)) = p {
        log::info!(
            "sitl: stopped; link {link:?}; telemetry dropped {}; commands {:?}; shell {:?}",
            health.telemetry_dropped,
            health.commands,
            app.counters()
        );
    }
    if temporary {
        let _ = std::fs::remove_file(&flash_path);
    }
    match outcome {
        Ok(Either3::Third(())) => Ok(()),
        Ok(_) => Err("the firmware's tasks ended".into()),
        Err(e) => Err(format!("executor: {e:?}")),
    }
}

/// The FPGA: the log's bytes into the link's DMA ring, one frame per frame period (from the first frame's
/// decimation), or as fast as the link task reads them. Then silence.
async fn feed(board: &Board, frames: &[u8], fast: bool, base_rate_millihz: u64) {
    if fast {
        use embedded_io_async::Write as _;
        let _ = board.fpga_rx.writer(None).write_all(frames).await;
    } else {
        let mut probe = frames;
        let n = FrameDecoder::new()
            .decode(&mut probe)
            .map_or(shared::wire::clock::FLIGHT_DECIMATION, |d| {
                d.frame.decimation
            });
        node::fpga_play(board, frames, n, base_rate_millihz).await;
    }
    log::info!("sitl: frame log ended; the FPGA link is silent now");
    core::future::pending::<()>().await
}

fn open_bus(path: &PathBuf) -> Result<File, String> {
    let f = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(path)
        .map_err(|e| format!("bus device {}: {e}", path.display()))?;
    // A tty gets raw 115200 8N1 (a pseudo-terminal ignores the rate); anything else is used as it is.
    use nix::sys::termios::{self, BaudRate, SetArg};
    if let Ok(mut t) = termios::tcgetattr(&f) {
        termios::cfmakeraw(&mut t);
        termios::cfsetspeed(&mut t, BaudRate::B115200)
            .map_err(|e| format!("bus device {}: baud rate: {e}", path.display()))?;
        termios::tcsetattr(&f, SetArg::TCSANOW, &t)
            .map_err(|e| format!("bus device {}: raw mode: {e}", path.display()))?;
    }
    Ok(f)
}

/// Two threads between the serial device and the bus lines (blocking I/O; they end with the process).
fn spawn_bus_io(board: &'static Board, bus: File) -> Result<(), String> {
    let mut reader = bus.try_clone().map_err(|e| format!("bus device: {e}"))?;
    let mut writer = bus;
    std::thread::Builder::new()
        .name("bus-rx".into())
        .spawn(move || {
            let mut buf = [0u8; 256];
            loop {
                match reader.read(&mut buf) {
                    Ok(0) => std::thread::sleep(std::time::Duration::from_millis(10)),
                    Ok(n) => {
                        let lost = board.bus_rx.push(&buf[..n]);
                        if lost > 0 {
                            log::warn!("sitl: bus receive buffer full, {lost} bytes lost");
                        }
                    }
                    Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                    Err(e) => {
                        // A pty whose other end is closed reads EIO until it is reopened.
                        log::debug!("sitl: bus read: {e}");
                        std::thread::sleep(std::time::Duration::from_millis(50));
                    }
                }
            }
        })
        .map_err(|e| format!("thread: {e}"))?;
    std::thread::Builder::new()
        .name("bus-tx".into())
        .spawn(move || {
            loop {
                let bytes = board
                    .bus_tx
                    .pop_blocking(std::time::Duration::from_millis(100));
                if !bytes.is_empty()
                    && let Err(e) = writer.write_all(&bytes).and_then(|()| writer.flush())
                {
                    log::debug!("sitl: bus write: {e}");
                }
            }
        })
        .map_err(|e| format!("thread: {e}"))?;
    Ok(())
}
