//! Scenario tests of the firmware's own tasks (`firmware::app`), run on the host with the hardware modelled at the
//! edges (`firmware::sim`) in virtual time: the same loops the STM32 spawns, fed by a frame log and a ground station.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]
#![allow(clippy::arithmetic_side_effects)]

mod common;

use common::{Ground, Sat, frame_period, frames, healths, housekeeping, table, upload_commands};
use embassy_time::{Duration, Instant, Timer};
use embedded_io_async::Write as _;
use firmware::sim::clock::settle;
use firmware::sim::flash as simflash;
use firmware::sim::line::SimRxError;
use host_test::replay::{ReplayOptions, replay};
use shared::bus::BusConfig;
use shared::calib::CalibrationTable;
use shared::pipeline::{ALLAN_CHANNELS, PipelineConfig};
use shared::telemetry::TaskId;
use shared::telemetry::{Ack, CalSource, Command, PROTOCOL_VERSION, Reject, Telemetry, peek_tag};
use shared::wire::FpgaControl;
use shared::wire::frame::{FRAME_LEN, GROUPS};

#[path = "scenarios/modes_and_time.rs"]
mod modes_and_time;

const MINUTE: Duration = Duration::from_secs(60);

fn fused(t: &[Telemetry]) -> usize {
    t.iter()
        .filter(|t| matches!(t, Telemetry::Fused(_)))
        .count()
}

/// The last fused report received.
fn last_fused(t: &[Telemetry]) -> shared::telemetry::FusedReport {
    t.iter()
        .rev()
        .find_map(|t| match t {
            Telemetry::Fused(f) => Some(*f),
            _ => None,
        })
        .expect("a fused report")
}

/// A frame log through the tasks, then the ground's final dump (all Allan channels, detailed health), gives the
/// same bus bytes as `ground replay` of the log (`host_test::replay`, which drives `Pipeline` directly).
#[test]
fn replay_through_the_tasks_is_byte_identical_to_ground_replay() {
    let log = frames(5000);
    let expected = replay(
        &log,
        &ReplayOptions {
            config: PipelineConfig::DEFAULT,
            cal: CalibrationTable::factory(),
            bus: BusConfig::DEFAULT,
            final_dump: true,
            check: false,
        },
        |_| {},
    );
    let allan = expected
        .messages
        .iter()
        .filter(|m| matches!(m, Telemetry::Allan(_)))
        .count();
    assert!(
        allan > 1000 && fused(&expected.messages) > 100,
        "a stream and a dump worth comparing"
    );

    // The bus as fast as the tasks write: `ground replay` has no bus rate; the log as fast as the link takes it.
    let mut sat = Sat::boot(simflash::erased(), None);
    let ground = Ground::new();
    let bytes = sat.run(MINUTE, async |_, board| {
        board.fpga_rx.writer(None).write_all(&log).await.unwrap();
        settle().await;
        ground.send(
            board,
            1,
            Command::AllanRequest {
                first: 0,
                count: ALLAN_CHANNELS as u8,
            },
        );
        settle().await;
        ground.send(board, 2, Command::HealthRequest { detail: true });
        settle().await;
        // Nothing waited for time: every Health says uptime 0, as the replay's.
        assert_eq!(Instant::now().as_ticks(), 0);
        board.bus_tx.take_all()
    });
    let h = sat.app.health(&sat.app.pipeline.try_lock().unwrap());
    assert_eq!(h.link.frames, 5000);
    assert_eq!(h.telemetry_dropped, 0);
    assert_eq!(bytes.len(), expected.telemetry.len());
    assert!(
        bytes == expected.telemetry,
        "bus bytes differ from ground replay's"
    );
}

/// At 115200 baud one report per frame (604.8 /s, ≈ 37 kB/s) cannot all be sent: the link task never waits for
/// the bus (every frame processed, no overrun of its ring), and every message is either sent or counted as dropped.
#[test]
fn slow_bus_drops_and_counts_telemetry_but_never_holds_up_the_link() {
    let frames_n = 1210; // 2 s
    let log = frames(frames_n);
    let mut sat = Sat::fresh();
    let mut ground = Ground::new();
    let sent_bytes = sat.run(MINUTE, async |app, board| {
        ground.send(board, 1, Command::SetOutputRate(1));
        settle().await;
        let t0 = Instant::now();
        for (k, f) in log.chunks(FRAME_LEN).enumerate() {
            Timer::at(t0 + frame_period() * k as u32).await;
            // The FPGA never waits: bytes the ring cannot take are lost and counted as overruns.
            board.fpga_rx.push(f);
        }
        let link_beat = app.last_beat_ms(TaskId::Link);
        Timer::after(Duration::from_millis(500)).await;
        assert!(
            app.last_beat_ms(TaskId::Link) > link_beat,
            "link task alive"
        );
        ground.receive(board);
        ground.bytes.len()
    });
    let h = sat.app.health(&sat.app.pipeline.try_lock().unwrap());
    let c = sat.app.counters();
    assert_eq!(h.link.frames, frames_n as u32);
    assert_eq!(h.link.overruns, 0);
    assert_eq!(h.link.crc_errors, 0);
    assert_eq!(
        ground.acks(),
        vec![Ack {
            tag: 1,
            result: Ok(())
        }]
    );
    // One Fused and one Nav report per frame, a Health every 19 outputs, Housekeeping and Update every second.
    let produced =
        2 * frames_n + frames_n / 19 + c.silent_health as usize + 2 * c.housekeeping as usize;
    let got = ground
        .telemetry
        .iter()
        .filter(|t| {
            matches!(
                t,
                Telemetry::Fused(_)
                    | Telemetry::Nav(_)
                    | Telemetry::Health(_)
                    | Telemetry::Housekeeping(_)
                    | Telemetry::Update(_)
            )
        })
        .count();
    eprintln!(
        "slow bus: {got} messages sent, {} dropped, {sent_bytes} bytes on the bus",
        h.telemetry_dropped
    );
    assert!(h.telemetry_dropped > 0);
    assert_eq!(
        got + h.telemetry_dropped as usize,
        produced,
        "sent + dropped = produced"
    );
    // The bus ran at its line rate while the frames came (2 s at 11 520 bytes/s), and never faster.
    let busy = frames_n as f64 / 604.8 * 11_520.0;
    assert!(
        sent_bytes as f64 > 0.97 * busy && (sent_bytes as f64) < busy + 0.5 * 11_520.0,
        "{sent_bytes}"
    );
    assert_eq!(ground.bad, 0);
}

/// Every command gets exactly one ack, with its tag, while frames stream: accepted, refused with a typed reason
/// (a decimation the 2 Mbaud link cannot carry, output rates out of range), malformed; the FPGA gets only accepted
/// control messages.
#[test]
fn every_command_is_answered_exactly_once() {
    let log = frames(1200);
    let mut sat = Sat::fresh();
    let mut ground = Ground::new();
    let commands: Vec<(u16, Command, Result<(), Reject>)> = vec![
        (1, Command::Ping, Ok(())),
        (2, Command::SetDecimation(31), Ok(())),
        (3, Command::SetDecimation(10), Err(Reject::BadArgument)),
        (4, Command::SetOutputRate(0), Err(Reject::BadArgument)),
        (5, Command::SetOutputRate(4097), Err(Reject::BadArgument)),
        (6, Command::SetOutputRate(64), Ok(())),
        (7, Command::HealthRequest { detail: false }, Ok(())),
        (8, Command::CalCommit, Err(Reject::CalNotStarted)),
        (
            9,
            Command::AllanRequest {
                first: 200,
                count: 1,
            },
            Err(Reject::BadArgument),
        ),
    ];
    let malformed = ground.packet(
        BusConfig::DEFAULT.command_port,
        &[PROTOCOL_VERSION, 0x34, 0x12, 0xFF, 0xFF],
    );
    let fpga = sat.run(MINUTE, async |_, board| {
        let t0 = Instant::now();
        let mut next = commands.iter();
        for (k, f) in log.chunks(FRAME_LEN).enumerate() {
            Timer::at(t0 + frame_period() * k as u32).await;
            board.fpga_rx.push(f);
            if k % 100 == 50 {
                match next.next() {
                    Some((tag, cmd, _)) => ground.send(board, *tag, cmd.clone()),
                    None if k == 950 => {
                        board.bus_rx.push(&malformed);
                    }
                    None => {}
                }
            }
        }
        Timer::after(Duration::from_millis(300)).await;
        ground.receive(board);
        board.fpga_tx.take_all()
    });
    let acks = ground.acks();
    assert_eq!(acks.len(), commands.len() + 1, "{acks:?}");
    for (tag, _, result) in &commands {
        let mine: Vec<_> = acks.iter().filter(|a| a.tag == *tag).collect();
        assert_eq!(mine.len(), 1, "tag {tag}: {acks:?}");
        assert_eq!(mine[0].result, *result, "tag {tag}");
    }
    let m = acks.last().unwrap();
    assert_eq!(
        (m.tag, m.result),
        (
            peek_tag(&[PROTOCOL_VERSION, 0x34, 0x12, 0xFF, 0xFF]),
            Err(Reject::Malformed)
        )
    );
    // Only the accepted decimation went to the FPGA.
    assert_eq!(fpga, FpgaControl::SetDecimation(31).to_bytes().to_vec());
    // The requested health came (tag 7), and the output rate in force is 64.
    assert!(
        healths(&ground.telemetry)
            .iter()
            .any(|h| h.frames_per_output == 64)
    );
    assert_eq!(
        sat.app
            .health(&sat.app.pipeline.try_lock().unwrap())
            .commands,
        [4, 6]
    );
}

/// An uploaded calibration is committed through the tasks, stored, and in force after a restart on the same flash.
#[test]
fn uploaded_calibration_survives_a_restart() {
    let mut sat = Sat::fresh();
    assert_eq!(
        sat.app.pipeline.try_lock().unwrap().calibration_source(),
        CalSource::Factory
    );
    let new = table(77);
    let mut ground = Ground::new();
    sat.run(MINUTE, async |app, board| {
        for (tag, cmd) in upload_commands(&new, 40, 5) {
            ground.transact(board, tag, cmd).await;
        }
        while app.counters().cal_stores == 0 {
            Timer::after(Duration::from_millis(10)).await;
        }
    });
    assert!(
        ground.acks().iter().all(|a| a.result == Ok(())),
        "{:?}",
        ground.acks()
    );
    assert_eq!(sat.app.counters().cal_store_errors, 0);

    let sat = Sat::boot(sat.into_flash(), None);
    let p = sat.app.pipeline.try_lock().unwrap();
    assert_eq!(*p.calibration(), new);
    assert_eq!(p.calibration_source(), CalSource::Stored);
}

/// A power cut at every flash operation of a commit made through the tasks: the next boot has the old table or the
/// new one, never the factory default; and the commit's ack says `Ok` only when the new one survives.
#[test]
fn power_cut_at_every_flash_step_of_a_commit_keeps_old_or_new() {
    let (old, new) = (table(1), table(2));
    // The commit's ack (the flash model fails every operation after the cut, so the tasks live on to answer).
    let upload = |sat: &mut Sat, t: &CalibrationTable<GROUPS>| {
        let mut ground = Ground::new();
        let cmds = upload_commands(t, 48, 9);
        sat.run(MINUTE, async |_app, board| {
            let mut last = None;
            for (tag, cmd) in cmds {
                let commit = cmd == Command::CalCommit;
                let ack = ground.transact(board, tag, cmd).await;
                if commit {
                    last = Some(ack.result);
                } else {
                    assert_eq!(ack.result, Ok(()));
                }
            }
            last.expect("a commit")
        })
    };
    let mut sat = Sat::fresh();
    assert_eq!(upload(&mut sat, &old), Ok(()));
    let base = sat.into_flash();
    let start = base.ops;

    // One complete commit, to learn how many operations it takes.
    let mut sat = Sat::boot(base.clone(), None);
    assert_eq!(upload(&mut sat, &new), Ok(()));
    let steps = sat.into_flash().ops - start;
    assert!(steps > 2, "an erase and some writes: {steps}");

    let mut outcomes = [0usize; 2];
    for cut in 0..=steps {
        let mut flash = base.clone();
        flash.budget = Some(start + cut);
        let mut sat = Sat::boot(flash, None);
        let acked = upload(&mut sat, &new);
        let mut flash = sat.into_flash();
        flash.budget = None;
        let sat = Sat::boot(flash, None);
        let p = sat.app.pipeline.try_lock().unwrap();
        assert_eq!(
            p.calibration_source(),
            CalSource::Stored,
            "cut after {cut} of {steps}"
        );
        let id = p.calibration().cal_id;
        assert!(id == 1 || id == 2, "cut after {cut}: table {id}");
        assert!(
            acked == Ok(()) && id == 2 || acked == Err(Reject::Storage),
            "cut after {cut}: ack {acked:?}, table {id} after the reboot"
        );
        outcomes[(id - 1) as usize] += 1;
    }
    // Both outcomes occur: the cut lands before and after the new record is complete.
    eprintln!(
        "power cuts: {steps} flash operations per commit; boots with the old table {}, the new {}",
        outcomes[0], outcomes[1]
    );
    assert!(outcomes[0] > 0 && outcomes[1] > 0, "{outcomes:?}");
}

/// A bus line that stops taking bytes no longer stalls the transmitter: each frame that cannot leave within
/// `BUS_TX_TIMEOUT` is dropped and counted, every task keeps its heartbeat, and the watchdog keeps feeding.
#[test]
fn a_stuck_bus_line_costs_frames_not_the_watchdog() {
    // The ground drains the line for 2 s, then stops and asks for a detailed health report (17 messages, more than
    // the 256-byte line holds).
    let mut sat = Sat::fresh();
    sat.board.bus_tx = firmware::sim::line::Line::new(256);
    let ground = Ground::new();
    let (fed_before, fed_after) = sat.run(MINUTE, async |_, board| {
        for _ in 0..200 {
            Timer::after(Duration::from_millis(10)).await;
            board.bus_tx.take_all();
        }
        let before = board.feeds();
        ground.send(board, 1, Command::HealthRequest { detail: true });
        Timer::after(Duration::from_secs(4)).await;
        (before, board.feeds() - before)
    });
    // 250 ms period: about 8 feeds in 2 s, 16 in 4 s.
    assert!(fed_before >= 6, "{fed_before}");
    assert!(
        fed_after >= 14,
        "fed {fed_after} times in the 4 s after the line stuck"
    );
    let c = sat.app.counters();
    assert!(c.bus_tx_errors >= 4, "{c:?}");
}

/// A task that hangs (awaits something that never comes) misses its deadline: the watchdog stops feeding within
/// that deadline (the IWDG then resets the MCU), and names the task; while all beat, it feeds every period.
#[test]
fn a_hung_task_stops_the_watchdog_feed_within_its_deadline() {
    let deadline_ms = firmware::app::DEADLINES_MS[6];
    let mut sat = Sat::fresh();
    let (fed_before, last_feed_after_ms, late) = sat.run(MINUTE, async |app, board| {
        Timer::after(Duration::from_secs(2)).await;
        let before = board.feeds();
        let hang_at = Instant::now();
        app.inject_hang(TaskId::Housekeeping);
        // Watch the feeds for the deadline, a period (the task's next beat) and 2 s more.
        let mut last_feed = 0;
        let mut seen = board.feeds();
        for _ in 0..(u64::from(deadline_ms) + 3000) / 50 {
            Timer::after(Duration::from_millis(50)).await;
            if board.feeds() != seen {
                seen = board.feeds();
                last_feed = hang_at.elapsed().as_millis();
            }
        }
        (
            before,
            last_feed,
            app.late_task(Instant::now().as_millis() as u32),
        )
    });
    assert!(fed_before >= 6, "{fed_before}");
    // The last beat is at most one housekeeping period (1 s) before the hang; the feed stops at most one watchdog
    // period (250 ms) after the deadline.
    assert!(
        last_feed_after_ms <= u64::from(deadline_ms) + 250,
        "fed {last_feed_after_ms} ms after the hang"
    );
    assert!(last_feed_after_ms >= u64::from(deadline_ms) - 1000 - 250);
    assert_eq!(late, Some(TaskId::Housekeeping));
}

/// Injected UART errors on the FPGA link: each is counted by kind, and costs only the frames whose bytes it
/// destroyed; the frames before and after are all processed.
#[test]
fn uart_errors_are_counted_and_cost_only_the_frames_they_touch() {
    let log = frames(100);
    let mut sat = Sat::fresh();
    sat.run(MINUTE, async |_, board| {
        let t0 = Instant::now();
        for (k, f) in log.chunks(FRAME_LEN).enumerate() {
            Timer::at(t0 + frame_period() * k as u32).await;
            match k {
                // A framing error destroys 3 bytes in the middle of frame 20.
                20 => {
                    board.fpga_rx.push(&f[..100]);
                    board.fpga_rx.inject(SimRxError::Framing, 3);
                    board.fpga_rx.push(&f[100..]);
                }
                // Noise at a frame boundary, nothing destroyed: costs nothing.
                40 => {
                    board.fpga_rx.inject(SimRxError::Noise, 0);
                    board.fpga_rx.push(f);
                }
                // An overrun: the DMA ring lost the second half of frame 60.
                60 => {
                    board.fpga_rx.push(&f[..120]);
                    board.fpga_rx.inject(SimRxError::Overrun, 120);
                    board.fpga_rx.push(&f[120..]);
                }
                _ => {
                    board.fpga_rx.push(f);
                }
            }
        }
        Timer::after(Duration::from_millis(200)).await;
    });
    let h = sat.app.health(&sat.app.pipeline.try_lock().unwrap());
    let c = sat.app.counters();
    assert_eq!(c.link_line_errors, 2);
    assert_eq!(h.link.overruns, 1);
    assert_eq!(h.link.frames, 98, "{:?}", h.link);
    assert_eq!(
        h.link.frames_dropped, 2,
        "the sequence counter shows the two lost frames: {:?}",
        h.link
    );
}
