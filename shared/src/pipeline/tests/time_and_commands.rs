//! The pipeline's time line (arrival times, spacecraft time, PPS), its commands beyond the basics, navigation, thermal terms and fixed weights.

use super::*;

/// With arrival times, outages the 16-bit sequence counter cannot measure stay on the time line: an FPGA restart
/// (the counter starts again at 0) and a silence of more than 2¹⁶ frames (the counter wraps). Ordinary arrival
/// jitter and a buffered backlog within the slack change nothing.
#[test]
fn arrival_times_keep_outages_the_sequence_counter_cannot_see() {
    // Frame period at N = 15: 16 / 9676.8 Hz = 1653.44 µs; output interval 32 frames.
    let period_ns = 16.0e12 / FPGA_BASE_RATE_MILLIHZ as f64;
    let mut rng = Rng::new(9);
    let mut p = Pipeline::new_boxed(PipelineConfig::DEFAULT);
    let mut outputs = Vec::new();
    // Frame k (sequence `seq`) arrives at its true time plus a read delay, in reads of 4 frames.
    let push =
        |p: &mut HostPipeline, true_k: u64, seq: u16, outputs: &mut Vec<Output>, rng: &mut Rng| {
            let read_at_us = ((true_k / 4 * 4 + 4) as f64 * period_ns / 1000.0) as u64 + 300;
            p.set_arrival_us(read_at_us);
            let f = frame(seq, 15, [0.0; 3], [0.0, 0.0, -1.0], 20.0, rng);
            outputs.extend(run(p, &f.to_bytes()));
        };
    for k in 0..640u64 {
        push(&mut p, k, k as u16, &mut outputs, &mut rng);
    }
    assert_eq!(
        p.time_gaps(),
        0,
        "jitter of a 4-frame read is not an outage"
    );
    // A backlog: 20 frames read at once, 500 ms late (a flash erase stalled the CPU): late reads never add time.
    for k in 640..660u64 {
        p.set_arrival_us(((644 + 302) as f64 * period_ns / 1000.0) as u64 + 300);
        let f = frame(k as u16, 15, [0.0; 3], [0.0, 0.0, -1.0], 20.0, &mut rng);
        outputs.extend(run(&mut p, &f.to_bytes()));
    }
    for k in 660..704u64 {
        push(&mut p, k, k as u16, &mut outputs, &mut rng);
    }
    assert_eq!(
        p.time_gaps(),
        0,
        "a backlog within the slack is not an outage"
    );
    // FPGA restart after 10 s of silence: the counter starts at 0 again.
    let restart_k = 704 + (10.0e9 / period_ns) as u64;
    for j in 0..320u64 {
        push(&mut p, restart_k + j, j as u16, &mut outputs, &mut rng);
    }
    assert_eq!(p.time_gaps(), 1);
    // A silence of 70 000 frames (116 s) with the FPGA running: the counter wrapped and shows 70 000 − 65 536.
    let wrap_k = restart_k + 320 + 70_000;
    for j in 0..320u64 {
        push(
            &mut p,
            wrap_k + j,
            ((320 + 70_000 + j) % 65_536) as u16,
            &mut outputs,
            &mut rng,
        );
    }
    assert_eq!(p.time_gaps(), 2);
    // The last report starts at its first frame's true time, within the read granularity (4 frames) per bridged
    // outage.
    let last = *fused(&outputs).last().unwrap();
    let first_k_of_last = wrap_k + 320 - 32;
    let true_us = first_k_of_last as f64 * period_ns / 1000.0;
    let err_frames = (last.t_us as f64 - true_us).abs() / (period_ns / 1000.0);
    assert!(
        err_frames <= 8.0,
        "last report {} µs, true {true_us:.0} µs ({err_frames:.1} frames off)",
        last.t_us
    );
    // By the frames and the wrapped counter alone the stream spans ≈ 9.6 s (1 344 frames received, 4 464 seen
    // missing); with the two outages it spans ≈ 128 s.
    assert!(last.t_us > 125_000_000, "{}", last.t_us);
}

/// The periodic check of the calibration in RAM: intact after loading any table, broken by any single bit flip.
#[test]
fn a_bit_flip_in_the_calibration_in_ram_is_detected() {
    let mut p = Pipeline::new_boxed(PipelineConfig::DEFAULT);
    assert!(p.calibration_intact());
    // Before any load, the factory table in force is checked against its own CRC too.
    p.inject_calibration_bit_flip(2, 4);
    assert!(!p.calibration_intact());
    p.inject_calibration_bit_flip(2, 4);
    assert!(p.calibration_intact());
    let mut t = CalibrationTable::<GROUPS>::factory();
    t.cal_id = 3;
    p.load_calibration(&t, CalSource::Uploaded);
    assert!(p.calibration_intact());
    for bit in [0, 7, 31] {
        p.inject_calibration_bit_flip(5, bit);
        assert!(!p.calibration_intact(), "bit {bit}");
        p.inject_calibration_bit_flip(5, bit);
        assert!(p.calibration_intact());
    }
}

/// Bytes the platform dropped (`link_discarded`, after a flash stall lapped its DMA ring) leave no trace but the
/// frames' sequence gap: the partial frame before the drop is forgotten, so the next whole frame is accepted without
/// a CRC error, and the frames lost in between are counted. (The overrun is the platform's to count.)
#[test]
fn link_discarded_forgets_the_partial_frame_and_counts_the_gap() {
    let mut rng = Rng::new(3);
    let frames: Vec<FrameRepr> = (0..10u16)
        .map(|seq| frame(seq, 15, [0.0; 3], [0.0, 0.0, 1.0], 0.0, &mut rng))
        .collect();
    let bytes = stream(&frames);
    let len = crate::wire::frame::FRAME_LEN;
    let mut p = Pipeline::new_boxed(PipelineConfig::DEFAULT);
    // Frames 0–2, then half of frame 3; the ring is dropped; then frames 7–9.
    run(&mut p, &bytes[..3 * len + len / 2]);
    p.link_discarded();
    run(&mut p, &bytes[7 * len..]);
    let c = *p.link_counters();
    assert_eq!(c.frames, 6);
    assert_eq!(c.crc_errors, 0);
    assert_eq!(c.resyncs, 0);
    assert_eq!(c.overruns, 0);
    assert_eq!(c.frames_dropped, 4, "frames 3-6");
}

/// `ClearResets` is accepted only when it names the platform's boot counter (records from a boot the ground has
/// not seen are never cleared), and then asks the platform to clear; without a boot counter it is always refused.
#[test]
fn clear_resets_names_the_boot() {
    let mut p = Pipeline::new_boxed(PipelineConfig::DEFAULT);
    let out = command(&mut p, 1, Command::ClearResets { boot_count: 0 });
    assert_eq!(ack(&out).result, Err(Reject::BadArgument));
    assert_eq!(out.len(), 1);
    p.set_boot_count(7);
    let out = command(&mut p, 2, Command::ClearResets { boot_count: 6 });
    assert_eq!(ack(&out).result, Err(Reject::BadArgument));
    assert_eq!(out.len(), 1);
    let out = command(&mut p, 3, Command::ClearResets { boot_count: 7 });
    assert_eq!(ack(&out).result, Ok(()));
    assert_eq!(out[1], Output::ClearResets);
}

/// `SetMode` tells the FPGA to stop or start its stream; `ExcludeGroups` leaves groups out of the fusion by hand
/// (whether or not fault exclusion is on), keeps them out across a new calibration, and refuses groups the board
/// does not have.
#[test]
fn mode_and_groups_excluded_by_hand() {
    let mut p = Pipeline::new_boxed(PipelineConfig::DEFAULT);
    let out = command(&mut p, 1, Command::SetMode(crate::telemetry::Mode::Idle));
    assert_eq!(ack(&out).result, Ok(()));
    assert_eq!(out[1], Output::Fpga(FpgaControl::SetStreaming(false)));
    assert_eq!(p.mode(), crate::telemetry::Mode::Idle);
    let out = command(&mut p, 2, Command::SetMode(crate::telemetry::Mode::Stream));
    assert_eq!(out[1], Output::Fpga(FpgaControl::SetStreaming(true)));

    let bad = command(
        &mut p,
        3,
        Command::ExcludeGroups {
            gyro: 1 << GROUPS,
            accel: 0,
        },
    );
    assert_eq!(ack(&bad).result, Err(Reject::BadArgument));
    let out = command(
        &mut p,
        4,
        Command::ExcludeGroups {
            gyro: 0b101,
            accel: 1 << 15,
        },
    );
    assert_eq!(ack(&out).result, Ok(()));
    p.load_calibration(&CalibrationTable::factory(), CalSource::Uploaded);
    assert_eq!(
        p.fusion().config().excluded,
        [0b101, 1 << 15],
        "kept across a new table"
    );

    // One group's gyro x reads 5 °/s off: excluded by hand, the fused rate ignores it; put back, it counts.
    let mut rng = Rng::new(3);
    let frames: Vec<FrameRepr> = (0..64)
        .map(|i| {
            let mut f = frame(i, 15, [0.0; 3], [0.0, 0.0, -1.0], 20.0, &mut rng);
            let off = frame(
                i,
                15,
                [5.0, 0.0, 0.0],
                [0.0, 0.0, -1.0],
                20.0,
                &mut Rng::new(3),
            );
            f.raw[2] = off.raw[2];
            f
        })
        .collect();
    for robust in [false, true] {
        let mut p = Pipeline::new_boxed(PipelineConfig {
            frames_per_output: 32,
            fusion: FusionConfig {
                mode: crate::fuse::FusionMode::Equal,
                robust,
                ..FusionConfig::DEFAULT
            },
            ..PipelineConfig::DEFAULT
        });
        command(
            &mut p,
            5,
            Command::ExcludeGroups {
                gyro: 1 << 2,
                accel: 0,
            },
        );
        let r = fused(&run(&mut p, &stream(&frames)));
        assert!(
            r.iter().all(|r| r.rate_udps[0].abs() < 20_000),
            "{:?}",
            r[0].rate_udps
        );
        assert!(r.iter().all(|r| r.used[0] == GROUPS as u8 - 1));
        if !robust {
            command(&mut p, 6, Command::ExcludeGroups { gyro: 0, accel: 0 });
            let r = fused(&run(&mut p, &stream(&frames)));
            // 5 °/s / 16 = 312 500 µ°/s in the equal-weight mean.
            assert!(
                r.iter().all(|r| (r.rate_udps[0] - 312_500).abs() < 20_000),
                "{:?}",
                r[0].rate_udps
            );
        }
    }
}

/// `SetTime` correlates frame time with spacecraft time: a `Time` report right after the ack and with every
/// periodic Health, both naming the last frame's time on the two scales; `Fused` reports carry no spacecraft time
/// before, and their first frame's after.
#[test]
fn set_time_correlates_frame_time_with_spacecraft_time() {
    let mut rng = Rng::new(4);
    let frames: Vec<FrameRepr> = (0..100)
        .map(|i| frame(i, 15, [0.0; 3], [0.0, 0.0, -1.0], 20.0, &mut rng))
        .collect();
    let mut p = Pipeline::new_boxed(PipelineConfig {
        frames_per_output: 10,
        health_every: 3,
        ..PipelineConfig::DEFAULT
    });
    assert_eq!(p.time_report(), None);
    let before = run(&mut p, &stream(&frames[..50]));
    assert_eq!(fused(&before).len(), 5);
    assert!(fused(&before).iter().all(|r| r.unix_us.is_none()));
    // Frame 49 is at 49 · 16 / 9676.8 Hz = 81 018.518… µs.
    let unix_us = 1_795_000_000_000_000u64;
    let out = command(&mut p, 1, Command::SetTime { unix_us });
    assert_eq!(ack(&out).result, Ok(()));
    let t49 = 49 * 16 * 1_000_000_000 / FPGA_BASE_RATE_MILLIHZ;
    let expected = TimeReport { t_us: t49, unix_us };
    assert_eq!(out[1], Output::Telemetry(Telemetry::Time(expected)));
    let out = run(&mut p, &stream(&frames[50..]));
    let times: Vec<TimeReport> = out
        .iter()
        .filter_map(|o| match o {
            Output::Telemetry(Telemetry::Time(t)) => Some(*t),
            _ => None,
        })
        .collect();
    let healths = out
        .iter()
        .filter(|o| matches!(o, Output::Telemetry(Telemetry::Health(_))))
        .count();
    assert_eq!(times.len(), healths, "one Time with each periodic Health");
    assert!(!times.is_empty());
    for t in times {
        assert_eq!(t.unix_us - t.t_us, unix_us - t49, "one epoch");
    }
    let after = fused(&out);
    assert_eq!(after.len(), 5);
    for r in after {
        // Frame k of the interval starting at frame 10·j is at 10·j · 16 / 9676.8 Hz.
        let first = u64::from(r.seq) * 10 * 16 * 1_000_000_000 / FPGA_BASE_RATE_MILLIHZ;
        assert_eq!(r.t_us, first);
        assert_eq!(r.unix_us, Some(unix_us - t49 + first), "report {}", r.seq);
    }
}

/// Navigation increments through the pipeline: a board turning at 12.5 °/s about x under 1 g along −z gives
/// ΔΘ = ω·dt and ΔV = f·dt per interval (f = −g along z; rotation about x turns it a little into y); lost frames
/// are bridged and counted, and dt comes from the frame clock, lost frames included.
#[test]
fn nav_increments_of_a_steady_turn_with_lost_frames() {
    let mut rng = Rng::new(8);
    let keep = |i: u16| !(40..43).contains(&i); // frames 40, 41, 42 are lost
    let frames: Vec<FrameRepr> = (0..96u16)
        .filter(|&i| keep(i))
        // One count of ADC noise: without any, every channel would look stuck after 64 frames.
        .map(|i| frame(i, 15, [12.5, 0.0, 0.0], [0.0, 0.0, -1.0], 1.0, &mut rng))
        .collect();
    let mut p = Pipeline::new_boxed(PipelineConfig::DEFAULT);
    let out = run(&mut p, &stream(&frames));
    let nav: Vec<NavReport> = out
        .iter()
        .filter_map(|o| match o {
            Output::Telemetry(Telemetry::Nav(n)) => Some(*n),
            _ => None,
        })
        .collect();
    let fused = fused(&out);
    assert_eq!(nav.len(), fused.len());
    let period_s = 16.0e3 / FPGA_BASE_RATE_MILLIHZ as f64;
    for (k, n) in nav.iter().enumerate() {
        assert_eq!(n.seq, fused[k].seq);
        let lost = if k == 1 { 3 } else { 0 };
        // 32 frames received per report; the interval also spans the lost ones.
        assert_eq!(
            (n.frames, n.bridged, n.clipped),
            (32 + lost, lost, 0),
            "interval {k}"
        );
        // Its frame periods, exactly (rounded to µs): the interval ends where the next begins.
        let dt_s = f64::from(n.dt_us) * 1e-6;
        assert!(
            (dt_s - f64::from(n.frames) * period_s).abs() < 2e-6,
            "{k}: {dt_s}"
        );
        if k > 0 {
            assert_eq!(n.t_us, nav[k - 1].t_us + u64::from(nav[k - 1].dt_us));
        }
        let w = 12.5f64.to_radians();
        let dth = n.dtheta_nrad.map(|x| x as f64 * 1e-9);
        // Noise: 1 count = 1/160 °/s per sample and group, ≈ 5e-7 rad over an interval of the cluster mean.
        assert!((dth[0] - w * dt_s).abs() < 3e-6, "{k}: {dth:?}");
        assert!(dth[1].abs() < 3e-6 && dth[2].abs() < 3e-6, "{k}: {dth:?}");
        // ΔV in the body frame at the interval's start: ∫ R_x(ωt)·(0, 0, −g) dt ≈ (0, g ω dt²/2, −g dt).
        let g = 9.80665;
        let dv = n.dv_umps.map(|x| x as f64 * 1e-6);
        assert!((dv[2] + g * dt_s).abs() < 3e-5, "{k}: {dv:?}");
        assert!(
            (dv[1] - g * w * dt_s * dt_s / 2.0).abs() < 3e-5,
            "{k}: {dv:?}"
        );
        assert!(dv[0].abs() < 3e-5, "{k}: {dv:?}");
    }
}

/// PPS discipline: frames stamped on arrival (reads of 4 frames, each read up to 4 frame periods after its first
/// frame), a `SetTime` 37 ms wrong, then edges at the spacecraft's whole seconds: the first edge corrects the
/// time to the true second within the least read delay, later ones hold it there while the frame clock runs 40 ppm
/// fast; edges before `SetTime`, off the second or doubled are refused and counted.
#[test]
fn pps_edges_anchor_spacecraft_time_on_the_whole_second() {
    // True scales: spacecraft = frame + EPOCH (µs); arrival clock = frame + ARRIVAL_OFFSET + read delay. The FPGA
    // clock runs 40 ppm fast against the spacecraft's (frame time advances 1.00004 µs per spacecraft µs).
    const EPOCH: u64 = 1_795_000_000_123_456;
    const ARRIVAL_OFFSET: u64 = 7_000_000;
    let period_us = 16.0e9 / FPGA_BASE_RATE_MILLIHZ as f64;
    let frame_us = |k: u64| (k as f64 * period_us) as u64;
    let spacecraft_of_frame = |t: u64| EPOCH + (t as f64 / 1.000_04) as u64;
    let mut rng = Rng::new(21);
    let mut p = Pipeline::new_boxed(PipelineConfig {
        health_every: 1,
        ..PipelineConfig::DEFAULT
    });
    let mut k = 0u64;
    // Frames up to spacecraft time `until`, read 4 at a time: the read happens 1.2 frame periods after its last
    // frame, so the least delay is 1.2 periods (≈ 2 ms).
    let feed_until = |p: &mut HostPipeline, until: u64, k: &mut u64, rng: &mut Rng| {
        while spacecraft_of_frame(frame_us(*k + 4)) < until {
            p.set_arrival_us(frame_us(*k + 3) + ARRIVAL_OFFSET + (1.2 * period_us) as u64);
            let fs: Vec<FrameRepr> = (*k..*k + 4)
                .map(|i| frame(i as u16, 15, [0.0; 3], [0.0, 0.0, -1.0], 20.0, rng))
                .collect();
            run(p, &stream(&fs));
            *k += 4;
        }
    };
    // The edge of spacecraft second `s`, on the arrival clock.
    let edge = |s: u64| {
        let t = ((s - EPOCH) as f64 * 1.000_04) as u64;
        t + ARRIVAL_OFFSET
    };
    let first = EPOCH / 1_000_000 + 1;
    feed_until(&mut p, first * 1_000_000 - 300_000, &mut k, &mut rng);
    assert_eq!(p.pps(edge(first * 1_000_000)), None, "no time yet");
    // SetTime, 37 ms late.
    let t_last = frame_us(k - 1);
    let wrong = spacecraft_of_frame(t_last) + 37_000;
    command(&mut p, 1, Command::SetTime { unix_us: wrong });
    for s in first + 1..first + 6 {
        feed_until(&mut p, s * 1_000_000, &mut k, &mut rng);
        let correction = p.pps(edge(s * 1_000_000)).expect("an edge on the second");
        if s == first + 1 {
            // The 37 ms error, less the least read delay (≈ 2 ms) the estimate keeps.
            assert!((-37_000..=-34_000).contains(&correction), "{correction}");
        } else {
            // 40 ppm of drift per second, and the read delay's scatter.
            assert!(correction.abs() <= 200, "{correction}");
        }
        let r = p.time_report().unwrap();
        let error = r.unix_us as i64 - spacecraft_of_frame(r.t_us) as i64;
        // The least read delay (1.2 frame periods, 2 ms) makes the frame time at the edge look earlier than it is:
        // the anchored time runs late by that delay at most, never early.
        assert!(
            (0..=2_100).contains(&error),
            "second {s}: time off by {error} µs"
        );
    }
    let accepted = p.pps_report().accepted;
    assert_eq!(accepted, 5);
    // A doubled edge 0.3 s later, and one 0.4 s off the second, are refused.
    let s = first + 6;
    feed_until(&mut p, s * 1_000_000, &mut k, &mut rng);
    assert!(p.pps(edge(s * 1_000_000)).is_some());
    assert_eq!(p.pps(edge(s * 1_000_000 + 300_000)), None);
    feed_until(&mut p, s * 1_000_000 + 700_000, &mut k, &mut rng);
    assert_eq!(p.pps(edge(s * 1_000_000 + 600_000)), None);
    let report = p.pps_report();
    assert_eq!((report.accepted, report.rejected), (6, 3));
    // On the bus with every periodic Health, after the Time report.
    let fs: Vec<FrameRepr> = (k..k + 32)
        .map(|i| frame(i as u16, 15, [0.0; 3], [0.0, 0.0, -1.0], 20.0, &mut rng))
        .collect();
    let out = run(&mut p, &stream(&fs));
    let at = out
        .iter()
        .position(|o| matches!(o, Output::Telemetry(Telemetry::Pps(_))))
        .expect("a PPS report");
    assert!(matches!(out[at - 1], Output::Telemetry(Telemetry::Time(_))));
    assert_eq!(out[at], Output::Telemetry(Telemetry::Pps(report)));
}

/// A board whose every gyro zero level moves by +8 counts/°C (0.05 (°/s)/°C): the uncompensated fused rate follows
/// the temperature; with the table's thermal terms it stays at the true rate, a frame without temperature is
/// calibrated at the last valid one, and health counts both.
#[test]
fn thermal_terms_follow_the_frame_temperature() {
    let mut rng = Rng::new(3);
    let make = |temp: Option<i16>, seq: u16, rng: &mut Rng| {
        let mut f = frame(seq, 15, [1.0, 0.0, 0.0], [0.0, 0.0, -1.0], 0.0, rng);
        // The zero level at 20 °C + 8 counts/°C: codes moved by 8 · (T − 20) counts (whole counts: T in whole °C).
        let shift = temp.map_or(0, |t| 8 * (i32::from(t) - 2000) / 100);
        for g in f.raw.iter_mut() {
            for c in &mut g[..4] {
                *c = (i32::from(*c) + shift) as u16;
            }
        }
        f.temp_cdeg = temp;
        f
    };
    // 32 frames at 30 °C, then 32 without a valid temperature (the board still at 30 °C).
    let frames: Vec<FrameRepr> = (0..64)
        .map(|i| make(if i < 32 { Some(3000) } else { None }, i, &mut rng))
        .collect();
    let config = PipelineConfig {
        health_every: 0,
        nav: false,
        ..PipelineConfig::DEFAULT
    };
    // Without compensation, +80 counts on every gyro channel = +0.5 °/s on x and y and z.
    let mut p = Pipeline::new_boxed(config);
    let plain = fused(&run(&mut p, &stream(&frames[..32])));
    assert_eq!(plain[0].rate_udps, [1_500_000, 500_000, 500_000]);

    let mut table = CalibrationTable::<GROUPS>::factory();
    table.t_ref_cdeg = 2000;
    for th in table.thermal.iter_mut() {
        th.gyro_lin_q28 = [(0.08 * 2f64.powi(28)).round() as i32; 4];
    }
    let mut p = Pipeline::new_boxed(config);
    p.load_calibration(&table, CalSource::Uploaded);
    let reports = fused(&run(&mut p, &stream(&frames)));
    assert_eq!(reports[0].rate_udps, [1_000_000, 0, 0]);
    // Held at 30 °C: the codes (shift 0 without a temperature in `make`) are the zero level at 20 °C, so the held
    // compensation subtracts 80 counts that are not there: exactly −0.5 °/s, which shows it was held, not dropped.
    assert_eq!(reports[1].rate_udps, [500_000, -500_000, -500_000]);
    let h = p.health();
    assert_eq!(
        h.temp,
        crate::calib::thermal::TempCounts {
            missing: 32,
            held: 32
        }
    );
    assert_eq!(h.thermal_at_cdeg, Some(3000));
    // A new pipeline (a restart) has no temperature to hold: the reference biases, counted as missing only.
    let mut p = Pipeline::new_boxed(config);
    p.load_calibration(&table, CalSource::Stored);
    let reports = fused(&run(&mut p, &stream(&frames[32..])));
    assert_eq!(reports[0].rate_udps, [1_000_000, 0, 0]);
    assert_eq!(
        p.health().temp,
        crate::calib::thermal::TempCounts {
            missing: 32,
            held: 0
        }
    );
    assert_eq!(p.health().thermal_at_cdeg, None);
}

/// Fixed weights arrive with a table and are in force at once; `SetFusion` can leave and resume them, and is
/// refused for a table without them.
#[test]
fn fixed_weights_come_with_the_table() {
    let mut p = Pipeline::new_boxed(PipelineConfig::DEFAULT);
    let fixed = Command::SetFusion {
        mode: FusionMode::Fixed,
        robust: true,
    };
    assert_eq!(
        ack(&command(&mut p, 1, fixed.clone())).result,
        Err(Reject::BadArgument)
    );
    let mut table = CalibrationTable::<GROUPS>::factory();
    for w in table.weights_q16.iter_mut() {
        *w = [1 << 12; 6];
    }
    p.load_calibration(&table, CalSource::Uploaded);
    assert_eq!(p.fusion().config().mode, FusionMode::Fixed);
    let iv = Command::SetFusion {
        mode: FusionMode::InverseVariance,
        robust: true,
    };
    assert_eq!(ack(&command(&mut p, 2, iv)).result, Ok(()));
    assert_eq!(ack(&command(&mut p, 3, fixed)).result, Ok(()));
    assert_eq!(p.health().fusion, FusionMode::Fixed);
    // A table without weights ends their use.
    p.load_calibration(&CalibrationTable::factory(), CalSource::Uploaded);
    assert_eq!(p.fusion().config().mode, FusionConfig::DEFAULT.mode);
}
