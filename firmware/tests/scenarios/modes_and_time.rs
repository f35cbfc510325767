//! Scenarios of the board's modes and time: a silent FPGA, idle and the core clock, pings, a store while streaming,
//! an FPGA restart, housekeeping, spacecraft time and PPS, a store at low VDD.

use super::*;

/// A silent FPGA (no frames at all) still gives periodic Health on the bus, with the link counters at zero and the
/// uptime advancing.
#[test]
fn a_silent_fpga_still_sends_health() {
    let mut sat = Sat::fresh();
    let mut ground = Ground::new();
    sat.run(MINUTE, async |_, board| {
        Timer::after(Duration::from_millis(5500)).await;
        ground.receive(board);
    });
    let h = healths(&ground.telemetry);
    assert!(
        (4..=5).contains(&h.len()),
        "{} health reports in 5.5 s",
        h.len()
    );
    assert!(h.iter().all(|h| h.link.frames == 0));
    assert!(
        h.windows(2)
            .all(|w| w[1].uptime_ms >= w[0].uptime_ms + 1000),
        "{h:?}"
    );
    assert_eq!(fused(&ground.telemetry), 0);
}

/// `SetMode(Idle)` stops the FPGA stream and then lowers the core clock (84 MHz); `SetMode(Stream)` raises it
/// (168 MHz) and restarts the stream; Housekeeping reports the mode and the clock all along.
#[test]
fn idle_stops_the_stream_and_lowers_the_core_clock() {
    use shared::telemetry::Mode;
    const FULL_HZ: u32 = firmware::sim::node::SimCoreClock::FULL_HZ;
    let mut sat = Sat::fresh();
    let mut ground = Ground::new();
    let (clocks, fpga) = sat.run(MINUTE, async |_, board| {
        Timer::after(Duration::from_millis(1500)).await;
        let mut clocks = vec![board.core_hz.load(std::sync::atomic::Ordering::Relaxed)];
        for (tag, mode) in [(1, Mode::Idle), (2, Mode::Stream)] {
            let ack = ground.transact(board, tag, Command::SetMode(mode)).await;
            assert_eq!(ack.result, Ok(()));
            Timer::after(Duration::from_millis(2500)).await;
            clocks.push(board.core_hz.load(std::sync::atomic::Ordering::Relaxed));
        }
        ground.receive(board);
        (clocks, board.fpga_tx.take_all())
    });
    assert_eq!(
        clocks,
        [FULL_HZ, FULL_HZ / 2, FULL_HZ],
        "after boot, idle, stream"
    );
    let expected: Vec<u8> = [false, true]
        .into_iter()
        .flat_map(|on| FpgaControl::SetStreaming(on).to_bytes())
        .collect();
    assert_eq!(fpga, expected);
    let hk = housekeeping(&ground.telemetry);
    let seen: Vec<(Mode, Option<u32>)> = hk.iter().map(|h| (h.mode, h.core_clock_hz)).collect();
    assert!(seen.len() >= 5, "{seen:?}");
    assert!(seen.iter().all(|&(mode, hz)| hz
        == Some(match mode {
            Mode::Stream => FULL_HZ,
            Mode::Idle => FULL_HZ / 2,
        })));
    assert!(
        seen.iter().filter(|s| s.0 == Mode::Idle).count() >= 2,
        "{seen:?}"
    );
    assert_eq!(seen.last().map(|s| s.0), Some(Mode::Stream), "{seen:?}");
}

/// The core clock is lowered only on a quiet FPGA line: while frames still arrive after the stop (an FPGA that
/// finishes late), it stays at full speed; once no byte came for `LINE_QUIET` it is halved. Frames that never stop
/// within `LINE_QUIET_WAIT` keep the full clock, counted.
#[test]
fn the_core_clock_is_lowered_only_on_a_quiet_fpga_line() {
    use firmware::app::{LINE_QUIET, LINE_QUIET_WAIT};
    use shared::telemetry::Mode;
    const FULL_HZ: u32 = firmware::sim::node::SimCoreClock::FULL_HZ;
    // (stream after the stop, expected: lowered)
    for (tail, lowered) in [
        (LINE_QUIET_WAIT / 2, true),
        (LINE_QUIET_WAIT + Duration::from_millis(100), false),
    ] {
        let mut sat = Sat::fresh();
        let ground = Ground::new();
        let start = Duration::from_millis(300);
        let log = frames(((start + tail).as_micros() / frame_period().as_micros()) as usize);
        let (samples, last_frame_at, kept) = sat.run(MINUTE, async |app, board| {
            let t0 = Instant::now();
            let fpga = async {
                common::fpga_play(board, &log).await;
                Instant::now()
            };
            let ground_side = async {
                Timer::after(start).await;
                ground.send(board, 1, Command::SetMode(Mode::Idle));
                let mut samples = Vec::new();
                while Instant::now()
                    < t0 + start + tail + LINE_QUIET_WAIT + Duration::from_millis(100)
                {
                    Timer::after(Duration::from_millis(1)).await;
                    samples.push((
                        Instant::now(),
                        board.core_hz.load(std::sync::atomic::Ordering::Relaxed),
                    ));
                }
                samples
            };
            let (last, samples) = embassy_futures::join::join(fpga, ground_side).await;
            (samples, last, app.counters().clock_kept)
        });
        let switched = samples.iter().find(|s| s.1 != FULL_HZ).map(|s| s.0);
        if lowered {
            let at = switched.expect("the clock was lowered");
            assert!(
                at >= last_frame_at + LINE_QUIET,
                "lowered at {at:?}, last frame {last_frame_at:?}"
            );
            assert!(
                at <= last_frame_at + 3 * LINE_QUIET,
                "lowered at {at:?}, last frame {last_frame_at:?}"
            );
            assert_eq!(samples.last().map(|s| s.1), Some(FULL_HZ / 2));
            assert_eq!(kept, 0);
        } else {
            assert_eq!(switched, None, "frames never stopped in time: full clock");
            assert_eq!(kept, 1);
        }
    }
}

/// A CSP ping to our address is answered with the same payload; a ping to another address is ignored.
#[test]
fn pings_are_echoed() {
    let mut sat = Sat::fresh();
    let mut ground = Ground::new();
    let ping = ground.packet(shared::bus::csp::PORT_PING, b"abcdefgh");
    sat.run(MINUTE, async |_, board| {
        for _ in 0..3 {
            board.bus_rx.push(&ping);
            settle().await;
        }
        Timer::after(Duration::from_millis(50)).await;
        ground.receive(board);
    });
    assert_eq!(ground.pings.len(), 3);
    assert!(
        ground
            .pings
            .iter()
            .all(|(src, p)| *src == 10 && p == b"abcdefgh")
    );
}

/// A calibration store while frames stream, with the flash stalling the CPU for the F405's worst-case erase and
/// program times (`sim::flash::Stalling`): the frames lost stay within `layout::store_frames_lost_max` (and some
/// are lost: the stall is modelled), the reports' time runs on across the gap, a command the ground sends while the
/// store runs is answered, and the commit's ack comes only after the record is stored.
#[test]
fn a_store_during_streaming_loses_at_most_the_documented_frames_and_no_command() {
    let frames_n = 3 * 605; // 3 s
    let log = frames(frames_n);
    let mut sat = Sat::fresh();
    let mut ground = Ground::new();
    let cmds = upload_commands(&table(5), shared::telemetry::CAL_CHUNK_MAX, 20);
    let (commit_acked_after_store, ping_ack) = sat.run(MINUTE, async |app, board| {
        let fpga = async {
            common::fpga_play(board, &log).await;
            // Let the last frames through before the scenario ends.
            Timer::after(Duration::from_millis(200)).await;
        };
        let ground_side = async {
            Timer::after(Duration::from_millis(500)).await;
            let (commit, upload) = cmds.split_last().unwrap();
            for (tag, cmd) in upload.iter().cloned() {
                assert_eq!(ground.transact(board, tag, cmd).await.result, Ok(()));
            }
            // Commit, and a Ping 10 ms later, inside the erase stall (≥ 500 ms).
            ground.send(board, 21, commit.1.clone());
            Timer::after(Duration::from_millis(10)).await;
            ground.send(board, 22, Command::Ping);
            while ground.acks().iter().filter(|a| a.tag >= 21).count() < 2 {
                Timer::after(Duration::from_millis(5)).await;
                ground.receive(board);
            }
            let commit_ack = ground.acks().into_iter().find(|a| a.tag == 21).unwrap();
            assert_eq!(commit_ack.result, Ok(()));
            let ping = ground.acks().into_iter().find(|a| a.tag == 22).unwrap();
            (app.counters().cal_stores == 1, ping)
        };
        let (_, r) = embassy_futures::join::join(fpga, ground_side).await;
        ground.receive(board);
        r
    });
    assert!(commit_acked_after_store);
    assert_eq!(ping_ack.result, Ok(()), "the command sent during the store");

    let h = sat.app.health(&sat.app.pipeline.try_lock().unwrap());
    let lost = frames_n as u64 - u64::from(h.link.frames);
    let bound = firmware::layout::store_frames_lost_max(604_800);
    eprintln!(
        "store during streaming: {lost} of {frames_n} frames lost (bound {bound}), {} counted as dropped by sequence",
        h.link.frames_dropped
    );
    assert!(
        lost > 0 && lost <= bound,
        "{lost} frames lost, bound {bound}"
    );
    assert_eq!(
        u64::from(h.link.frames_dropped),
        lost,
        "every lost frame counted"
    );
    // The ring's contents after the stall were dropped and counted (`app::link_loop`).
    assert!(h.link.overruns >= 1, "{:?}", h.link);
    // Time runs on across the gap: the last report starts where the log's frames put it (the frame clock counts
    // the lost frames), within one output interval.
    let last = last_fused(&ground.telemetry);
    let t_end_us =
        (frames_n as u64 - 1) * 16 * 1_000_000_000 / PipelineConfig::DEFAULT.fpga_base_rate_millihz;
    let interval_us = 32 * 16 * 1_000_000_000 / PipelineConfig::DEFAULT.fpga_base_rate_millihz;
    assert!(
        last.t_us <= t_end_us && t_end_us - last.t_us < 2 * interval_us,
        "last report at {} µs, last frame at {t_end_us} µs",
        last.t_us
    );
}

/// An FPGA restart (its sequence counter starts again at 0) after 10 s of silence: the outage stays on the time
/// line of the reports — the link task stamps each read with its arrival time (`Pipeline::set_arrival_us`).
#[test]
fn an_fpga_restart_keeps_the_outage_on_the_time_line() {
    let log = frames(605); // 1 s
    let mut sat = Sat::fresh();
    let mut ground = Ground::new();
    sat.run(MINUTE, async |_, board| {
        common::fpga_play(board, &log).await;
        Timer::after(Duration::from_secs(10)).await;
        common::fpga_play(board, &log).await;
        Timer::after(Duration::from_millis(100)).await;
        ground.receive(board);
    });
    let p = sat.app.pipeline.try_lock().unwrap();
    assert_eq!(p.time_gaps(), 1);
    assert_eq!(p.link_counters().seq_restarts, 1);
    let last = last_fused(&ground.telemetry);
    // The second run's frame k is at 1 s + 10 s + k periods (its first frame one period after the 10 s wait).
    // 16 base ticks (N = 15) at the base rate: 1653.439… µs.
    let period_us = 16.0e9 / PipelineConfig::DEFAULT.fpga_base_rate_millihz as f64;
    let second_start_us = 605.0 * period_us + 10.0e6;
    let frames_into_second = (605 / 32 * 32) as f64; // the run's last full report starts before its end
    let expected_us = second_start_us + (frames_into_second - 32.0) * period_us;
    let off_frames = (last.t_us as f64 - expected_us) / period_us;
    eprintln!(
        "FPGA restart: last report at {:.3} s, expected {:.3} s ({off_frames:+.1} frames)",
        last.t_us as f64 / 1e6,
        expected_us / 1e6
    );
    // Within one 1 KiB read (≈ 4 frames) of the truth.
    assert!(off_frames.abs() <= 5.0, "{off_frames} frames off");
}

/// Housekeeping every second, streaming or not: the boot facts (reset flags, the fault recorded before the reset,
/// the firmware's commit), receive errors by kind, the last calibration store; and the periodic CRC check of the
/// calibration in RAM, which reloads the stored table after a bit flip.
#[test]
fn housekeeping_reports_the_board_and_repairs_a_corrupted_calibration() {
    use firmware::app::{BootInfo, FW_COMMIT, Platform};
    use firmware::resets::{Kind, Pending, Persist};
    use firmware::sim::line::SimRxError;
    use shared::telemetry::{HardFaultInfo, ResetCause, ResetRecord, StoreOutcome};
    // The reset history as the flight code leaves it: a first boot, then a HardFault 1.5 s in, then this boot
    // (the IWDG and pin flags, as the chip would set them after `sys_reset`... here the IWDG's).
    let mut persist = Persist::EMPTY;
    persist.boot(0b0000_0111);
    persist.note_uptime(1_500);
    let words = [
        0x0800_C123,
        0x0800_C001,
        0xFFFF_FFF9,
        0x2000_0F00,
        0x0000_8200,
        1 << 30,
        0x3000_0000,
    ];
    persist.leave(Pending::new(Kind::HardFault, 1_500, words));
    let state = persist.boot(1 << 4);
    let resets: &'static firmware::sim::SimResets = Box::leak(Box::new(firmware::sim::SimResets(
        std::sync::Mutex::new(persist),
    )));
    let fault = ResetRecord {
        boot: 1,
        uptime_ms: 1_500,
        reset_flags: 1 << 4,
        cause: ResetCause::HardFault(HardFaultInfo {
            pc: 0x0800_C123,
            lr: 0x0800_C001,
            exc_return: 0xFFFF_FFF9,
            sp: 0x2000_0F00,
            cfsr: 0x0000_8200,
            hfsr: 1 << 30,
            fault_addr: 0x3000_0000,
        }),
    };
    let mut sat = Sat::boot_on(
        simflash::erased(),
        Some(firmware::layout::BUS_BAUD),
        PipelineConfig::DEFAULT,
        Platform {
            boot: BootInfo {
                reset_flags: 1 << 4, // IWDG
                boot_count: state.boot_count,
                safe_mode: state.safe_mode,
                ..BootInfo::default()
            },
            resets: Some(resets),
            ..Platform::default()
        },
    );
    let mut ground = Ground::new();
    let table7 = table(7);
    sat.run(MINUTE, async |app, board| {
        Timer::after(Duration::from_millis(2500)).await;
        for (tag, cmd) in upload_commands(&table7, shared::telemetry::CAL_CHUNK_MAX, 3) {
            assert_eq!(ground.transact(board, tag, cmd).await.result, Ok(()));
        }
        // A line error on the bus, then a bit flip in the calibration held in RAM.
        board.bus_rx.inject(SimRxError::Framing, 0);
        board.bus_rx.push(&[0x55]);
        app.pipeline.lock().await.inject_calibration_bit_flip(3, 11);
        Timer::after(Duration::from_millis(2500)).await;
        ground.receive(board);
        // Clearing names the boot the ground saw: an older one is refused, this one clears.
        let stale = ground
            .transact(board, 20, Command::ClearResets { boot_count: 1 })
            .await;
        assert_eq!(stale.result, Err(Reject::BadArgument));
        let clear = ground
            .transact(board, 21, Command::ClearResets { boot_count: 2 })
            .await;
        assert_eq!(clear.result, Ok(()));
        Timer::after(Duration::from_millis(1100)).await;
        ground.receive(board);
    });
    let hk = housekeeping(&ground.telemetry);
    assert!((5..=8).contains(&hk.len()), "{} reports in ≈ 6 s", hk.len());
    // On a 1 s grid (one report runs late after the store's 0.5 s flash stall).
    assert!(hk.windows(2).all(|w| w[1].uptime_ms > w[0].uptime_ms));
    let first = hk[0];
    let mean_period = (hk.last().unwrap().uptime_ms - first.uptime_ms) / (hk.len() as u64 - 1);
    assert_eq!(mean_period, 1000);
    assert_eq!(
        (
            first.reset_flags,
            first.boot_count,
            first.safe_mode,
            first.fw_commit,
            first.fw_dirty
        ),
        (1 << 4, 2, false, FW_COMMIT.0, FW_COMMIT.1)
    );
    // The history goes with every Housekeeping, the HardFault on top, until the ground clears it.
    let histories = common::reset_histories(&ground.telemetry);
    assert_eq!(histories.len(), hk.len());
    assert_eq!(histories[0].records[0], Some(fault));
    assert_eq!((histories[0].boot_count, histories[0].short_runs), (2, 1));
    let cleared = histories.last().unwrap();
    assert_eq!(
        (cleared.boot_count, cleared.short_runs, cleared.records[0]),
        (2, 0, None)
    );
    assert_eq!(first.last_store, StoreOutcome::None);
    assert_eq!(
        first.core_load_permille, None,
        "the host has no cycle counter"
    );
    let last = *hk.last().unwrap();
    assert_eq!(last.last_store, StoreOutcome::Stored(1));
    assert_eq!(last.cal_stores, [1, 0]);
    assert_eq!(last.bus_rx_errors.line, 1);
    assert_eq!(last.cal_ram_repairs, 1);
    let p = sat.app.pipeline.try_lock().unwrap();
    assert!(p.calibration_intact());
    assert_eq!(p.calibration(), &table7, "the stored table is back");
    assert_eq!(p.calibration_source(), CalSource::Stored);
}

/// `SetTime` through the tasks while frames stream: the ground maps every later report to spacecraft time
/// (`ground decode`'s `unix_us`) within 10 ms of the truth (the correlation takes the last frame as "now").
#[test]
fn set_time_puts_the_reports_on_spacecraft_time() {
    let log = frames(3 * 605);
    let mut sat = Sat::fresh();
    let mut ground = Ground::new();
    let unix_at_start_us = 1_795_000_000_000_000u64; // spacecraft time when the first frame arrived
    sat.run(MINUTE, async |_, board| {
        let fpga = common::fpga_play(board, &log);
        let ground_side = async {
            Timer::after(Duration::from_millis(1234)).await;
            let now_us = Instant::now().as_micros();
            let ack = ground
                .transact(
                    board,
                    1,
                    Command::SetTime {
                        unix_us: unix_at_start_us + now_us,
                    },
                )
                .await;
            assert_eq!(ack.result, Ok(()));
        };
        embassy_futures::join::join(fpga, ground_side).await;
        Timer::after(Duration::from_millis(100)).await;
        ground.receive(board);
    });
    let log =
        host_test::formats::telemetry::TelemetryLog::decode(&ground.bytes, &BusConfig::DEFAULT);
    let mapped: Vec<(u64, u64)> = log
        .fused()
        .filter_map(|r| r.unix_us.map(|u| (r.t_us, u)))
        .collect();
    assert!(
        mapped.len() > 30,
        "{} reports on spacecraft time",
        mapped.len()
    );
    let worst_us = mapped
        .iter()
        .map(|&(t_us, unix_us)| (unix_us as i64 - (unix_at_start_us + t_us) as i64).abs())
        .max()
        .unwrap();
    eprintln!(
        "SetTime: {} reports mapped, worst error {worst_us} µs",
        mapped.len()
    );
    assert!(worst_us <= 10_000, "{worst_us} µs");
}

/// PPS (issue 15): a `SetTime` 40 ms wrong puts the reports 40 ms off; the edges of the following whole seconds
/// re-anchor the time on them, so that the reports mapped after the first edge are within a frame's read delay of
/// the truth; an edge in mid-second is refused and counted.
#[test]
fn pps_edges_put_the_reports_on_the_whole_second() {
    let log = frames(5 * 605);
    let mut sat = Sat::fresh();
    let mut ground = Ground::new();
    // Spacecraft time when the first frame arrived (virtual time 0), not on a whole second.
    let unix_at_start_us = 1_795_000_000_123_456u64;
    let (first_edge_s, edges) = (unix_at_start_us / 1_000_000 + 2, 3);
    let report = sat.run(MINUTE, async |app, board| {
        let fpga = common::fpga_play(board, &log);
        let ground_side = async {
            Timer::after(Duration::from_millis(1234)).await;
            let now_us = Instant::now().as_micros();
            let unix_us = unix_at_start_us + now_us + 40_000;
            let ack = ground
                .transact(board, 1, Command::SetTime { unix_us })
                .await;
            assert_eq!(ack.result, Ok(()));
        };
        let pps_side = async {
            for s in first_edge_s..first_edge_s + edges {
                Timer::at(Instant::from_micros(s * 1_000_000 - unix_at_start_us)).await;
                board.pps_edge();
            }
            // A glitch in mid-second.
            Timer::after(Duration::from_millis(500)).await;
            board.pps_edge();
        };
        embassy_futures::join::join3(fpga, ground_side, pps_side).await;
        Timer::after(Duration::from_millis(100)).await;
        ground.receive(board);
        app.pipeline.lock().await.pps_report()
    });
    assert_eq!((report.accepted, report.rejected), (edges as u32, 1));
    let log =
        host_test::formats::telemetry::TelemetryLog::decode(&ground.bytes, &BusConfig::DEFAULT);
    let error_us = |t_us: u64, unix_us: u64| unix_us as i64 - (unix_at_start_us + t_us) as i64;
    let first_edge_t_us = first_edge_s * 1_000_000 - unix_at_start_us;
    let (mut before, mut after) = (Vec::new(), Vec::new());
    for r in log.fused() {
        if let Some(u) = r.unix_us {
            // Reports whose interval starts after the first edge (by more than a read, ≈ 7 ms, so the edge was
            // handled before the report was made) carry the disciplined time.
            if r.t_us > first_edge_t_us + 20_000 {
                after.push(error_us(r.t_us, u));
            } else {
                before.push(error_us(r.t_us, u));
            }
        }
    }
    let worst = |v: &[i64]| v.iter().map(|e| e.abs()).max().unwrap_or(0);
    eprintln!(
        "PPS: {} reports after SetTime, worst {} µs; {} after the edges, worst {} µs",
        before.len(),
        worst(&before),
        after.len(),
        worst(&after)
    );
    assert!(
        before.iter().any(|e| e.abs() > 30_000),
        "SetTime's 40 ms error shows"
    );
    assert!(after.len() > 20, "{} reports after the edges", after.len());
    // In virtual time the link task reads a frame the instant it arrives (no read delay, which the pipeline test
    // covers), and the FPGA plays frames at their exact frame times: what remains is the µs rounding.
    assert!(worst(&after) <= 2, "{} µs after the edges", worst(&after));
}

/// A calibration store at a sagging rail (VDDA below `STORE_VDD_MIN_MV`, where x32 programming could leave weak
/// bits) is refused before anything is erased: the commit's ack says `Storage`, Housekeeping counts the refusal, the
/// table stays in force until the next reset, and that reset finds the flash as it was (the factory default).
#[test]
fn a_store_at_low_vdd_is_refused_and_nothing_is_erased() {
    use firmware::app::{Platform, STORE_VDD_MIN_MV};
    fn sagging() -> Option<(i16, u16)> {
        Some((2_500, STORE_VDD_MIN_MV - 150))
    }
    let mut sat = Sat::boot_on(
        simflash::erased(),
        Some(firmware::layout::BUS_BAUD),
        PipelineConfig::DEFAULT,
        Platform {
            mcu_sensors: Some(sagging),
            ..Platform::default()
        },
    );
    let mut ground = Ground::new();
    let table9 = table(9);
    let acks = sat.run(MINUTE, async |_, board| {
        let mut acks = Vec::new();
        for (tag, cmd) in upload_commands(&table9, shared::telemetry::CAL_CHUNK_MAX, 3) {
            acks.push(ground.transact(board, tag, cmd).await);
        }
        Timer::after(Duration::from_millis(1500)).await;
        ground.receive(board);
        acks
    });
    let commit = acks.last().unwrap();
    assert_eq!(commit.result, Err(Reject::Storage), "{acks:?}");
    assert!(acks[..acks.len() - 1].iter().all(|a| a.result.is_ok()));
    let hk = housekeeping(&ground.telemetry);
    let last = hk.last().unwrap();
    assert_eq!((last.stores_refused_low_vdd, last.cal_stores), (1, [0, 0]));
    assert_eq!(
        sat.app.pipeline.try_lock().unwrap().calibration(),
        &table9,
        "in force until the next reset"
    );
    let sat = Sat::boot(sat.into_flash(), None);
    let p = sat.app.pipeline.try_lock().unwrap();
    assert_eq!(
        p.calibration_source(),
        CalSource::Factory,
        "nothing was written"
    );
}
