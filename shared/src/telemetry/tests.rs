use super::*;
use crate::fuse::SensorFaults;
use proptest::prelude::*;

fn roundtrip<T: Serialize + DeserializeOwned + PartialEq + core::fmt::Debug>(msg: &T) -> usize {
    let mut buf = [0u8; 512];
    let bytes = encode(msg, &mut buf).unwrap();
    assert_eq!(bytes[0], PROTOCOL_VERSION);
    assert_eq!(decode::<T>(bytes).as_ref(), Ok(msg));
    bytes.len()
}

fn largest_telemetry() -> [Telemetry; 7] {
    let mask = SensorFaults {
        saturated: u32::MAX,
        stuck: u32::MAX,
        outlier: u32::MAX,
    };
    [
        Telemetry::Fused(FusedReport {
            seq: u32::MAX,
            t_us: u64::MAX,
            frames: u16::MAX,
            rate_udps: [i32::MIN; 3],
            accel_ug: [i32::MIN; 3],
            used: [u8::MAX; 6],
            health: HealthMask {
                gyro: mask,
                accel: mask,
            },
            temp_cdeg: Some(i16::MIN),
            unix_us: Some(u64::MAX),
        }),
        Telemetry::Allan(AllanReport {
            channel: u8::MAX,
            tau0_ps: u64::MAX,
            samples: u64::MAX,
            level: AllanLevel {
                level: 23,
                count: u32::MAX,
                sum_sq: u128::MAX,
            },
        }),
        Telemetry::Health(largest_health()),
        Telemetry::Housekeeping(largest_housekeeping()),
        Telemetry::Nav(NavReport {
            seq: u32::MAX,
            t_us: u64::MAX,
            dt_us: u32::MAX,
            dtheta_nrad: [i64::MIN; 3],
            dv_umps: [i64::MIN; 3],
            frames: u16::MAX,
            bridged: u16::MAX,
            clipped: u16::MAX,
        }),
        Telemetry::Resets(ResetHistory {
            boot_count: u32::MAX,
            short_runs: u8::MAX,
            safe_mode: true,
            dropped: u32::MAX,
            records: [Some(ResetRecord {
                boot: u32::MAX,
                uptime_ms: u32::MAX,
                reset_flags: u8::MAX,
                cause: ResetCause::HardFault(HardFaultInfo {
                    pc: u32::MAX,
                    lr: u32::MAX,
                    exc_return: u32::MAX,
                    sp: u32::MAX,
                    cfsr: u32::MAX,
                    hfsr: u32::MAX,
                    fault_addr: u32::MAX,
                }),
            }); RESET_HISTORY_LEN],
        }),
        Telemetry::Update(crate::update::UpdateStatus {
            running_version: u32::MAX,
            dfu_version: u32::MAX,
            dfu: crate::update::DfuState::Committed,
            received: u32::MAX,
            payload_len: u32::MAX,
            boot: crate::update::BootState::Unknown,
            last: crate::update::UpdateOutcome::Reverted(u32::MAX),
            counters: crate::update::UpdateCounters {
                requests: u32::MAX,
                refused: u32::MAX,
                crc_errors: u32::MAX,
                out_of_order: u32::MAX,
                duplicates: u32::MAX,
                erases: u32::MAX,
            },
        }),
    ]
}

/// The largest health report: every counter at its maximum.
fn largest_health() -> HealthReport {
    let faults = FaultCounts {
        saturated: u32::MAX,
        stuck: u32::MAX,
        outlier: u32::MAX,
    };
    HealthReport {
        uptime_ms: u64::MAX,
        link: LinkCounters {
            frames: u32::MAX,
            crc_errors: u32::MAX,
            resyncs: u32::MAX,
            bytes_skipped: u32::MAX,
            frames_dropped: u32::MAX,
            seq_restarts: u32::MAX,
            overruns: u32::MAX,
        },
        cal_id: u32::MAX,
        cal_source: CalSource::Uploaded,
        decimation: Some(u16::MAX),
        frames_per_output: u16::MAX,
        fusion: FusionMode::InverseVariance,
        robust: true,
        faults: [faults; 2],
        invalid_frames: u32::MAX,
        allan_samples: u64::MAX,
        telemetry_dropped: u32::MAX,
        commands: [u32::MAX; 2],
        temp: crate::calib::thermal::TempCounts {
            missing: u32::MAX,
            held: u32::MAX,
        },
        thermal_at_cdeg: Some(i16::MIN),
    }
}

/// The largest housekeeping report: every counter at its maximum, every option present.
fn largest_housekeeping() -> HousekeepingReport {
    HousekeepingReport {
        uptime_ms: u64::MAX,
        fw_commit: u32::MAX,
        fw_dirty: true,
        reset_flags: u8::MAX,
        boot_count: u32::MAX,
        safe_mode: true,
        clock_source: Some(ClockSource::HsiAfterClockFailure),
        hsi_trim: u8::MAX,
        hsi_error_ppm: Some(i32::MIN),
        bor_level: Some(u8::MAX),
        stores_refused_low_vdd: u32::MAX,
        core_load_permille: Some(u16::MAX),
        core_cycles_per_frame: Some(u32::MAX),
        mcu_temp_cdeg: Some(i16::MIN),
        vdda_mv: Some(u16::MAX),
        link_rx_errors: RxErrorCounts {
            overrun: u32::MAX,
            line: u32::MAX,
            other: u32::MAX,
        },
        bus_rx_errors: RxErrorCounts {
            overrun: u32::MAX,
            line: u32::MAX,
            other: u32::MAX,
        },
        bus_tx_errors: u32::MAX,
        bus: BusCounters {
            packets: u32::MAX,
            kiss_errors: u32::MAX,
            csp_errors: u32::MAX,
            ignored: u32::MAX,
        },
        fpga_ctrl_dropped: u32::MAX,
        time_gaps: u32::MAX,
        cal_stores: [u32::MAX; 2],
        last_store: StoreOutcome::Stored(u32::MAX),
        cal_ram_repairs: u32::MAX,
        mode: Mode::Idle,
        excluded: [u32::MAX; 2],
        core_clock_hz: Some(u32::MAX),
    }
}

#[test]
fn every_message_round_trips_and_fits_the_mtu() {
    for msg in largest_telemetry() {
        let n = roundtrip(&msg);
        assert!(n <= MAX_MESSAGE_LEN, "{n} bytes: {msg:?}");
    }
    roundtrip(&Telemetry::Ack(Ack {
        tag: 7,
        result: Err(Reject::Cal(CalError::Crc)),
    }));
    let data = heapless::Vec::from_slice(&[0xAB; CAL_CHUNK_MAX]).unwrap();
    let chunk = CommandEnvelope {
        tag: u16::MAX,
        cmd: Command::CalChunk {
            offset: u16::MAX,
            data,
        },
    };
    assert!(roundtrip(&chunk) <= MAX_MESSAGE_LEN);
    roundtrip(&CommandEnvelope {
        tag: 1,
        cmd: Command::SetFusion {
            mode: FusionMode::Equal,
            robust: false,
        },
    });
}

#[test]
fn known_encoding() {
    // version 4, tag 300 = varint AC 02, variant 1 (SetDecimation), 15.
    let mut buf = [0u8; 16];
    let bytes = encode(
        &CommandEnvelope {
            tag: 300,
            cmd: Command::SetDecimation(15),
        },
        &mut buf,
    )
    .unwrap();
    assert_eq!(bytes, [4, 0xAC, 0x02, 1, 15]);
    assert_eq!(peek_tag(bytes), 300);
}

#[test]
fn typed_errors() {
    assert_eq!(decode::<CommandEnvelope>(&[]), Err(DecodeError::Empty));
    assert_eq!(
        decode::<CommandEnvelope>(&[3, 0, 0]),
        Err(DecodeError::Version(3))
    ); // the previous version
    assert_eq!(
        decode::<CommandEnvelope>(&[4, 0, 0, 0]),
        Err(DecodeError::Malformed)
    ); // trailing byte
    assert_eq!(
        decode::<CommandEnvelope>(&[4, 0, 99]),
        Err(DecodeError::Malformed)
    ); // no such command
    let mut long = [0u8; 8];
    long[..4].copy_from_slice(&[4, 0, 5, 200]); // CalChunk with a 200-byte vector announced
    assert_eq!(
        decode::<CommandEnvelope>(&long),
        Err(DecodeError::Malformed)
    );
    assert_eq!(encode(&Command::Ping, &mut []), Err(BufferTooSmall));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(5000))]
    #[test]
    fn arbitrary_bytes_never_panic(mut bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
        let _ = decode::<Telemetry>(&bytes);
        if let Some(b) = bytes.first_mut() { *b = PROTOCOL_VERSION; }
        let _ = decode::<CommandEnvelope>(&bytes);
        let _ = decode::<Telemetry>(&bytes);
        let _ = peek_tag(&bytes);
    }
}
