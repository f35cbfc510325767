//! Telemetry, command and calibration-table decoding (`shared::telemetry::{decode, encode}`,
//! `shared::calib::CalibrationTable::{decode, encode}`).
//!
//! Input: first byte selects the message type, the rest is the encoded message.
//! Properties: decoding never panics; when bytes decode, encode → decode gives the same message back, and
//! encoding that again gives the same bytes (decode → encode → decode is a fixed point). Telemetry and commands
//! always fit `MAX_MESSAGE_LEN`; tables fit `encoded_len_max`. `peek_tag` of a decoded command is its tag.
#![no_main]

use core::fmt::Debug;
use libfuzzer_sys::fuzz_target;
use shared::calib::{CalibrationTable, encoded_len_max};
use shared::telemetry::{self, Command, CommandEnvelope, MAX_MESSAGE_LEN, Telemetry};
use shared::wire::frame::GROUPS;

fn round_trip<T>(bytes: &[u8])
where
    T: serde::Serialize + serde::de::DeserializeOwned + PartialEq + Debug,
{
    if let Ok(msg) = telemetry::decode::<T>(bytes) {
        let mut buf = [0u8; MAX_MESSAGE_LEN];
        let enc = telemetry::encode(&msg, &mut buf)
            .expect("a decoded message does not fit MAX_MESSAGE_LEN")
            .to_vec();
        let again: T = telemetry::decode(&enc).expect("re-encoded message does not decode");
        assert_eq!(again, msg);
        let mut buf2 = [0u8; MAX_MESSAGE_LEN];
        assert_eq!(telemetry::encode(&again, &mut buf2).unwrap(), &enc[..]);
    }
}

fuzz_target!(|data: &[u8]| {
    let Some((&kind, body)) = data.split_first() else {
        return;
    };
    match kind % 4 {
        0 => round_trip::<Telemetry>(body),
        1 => {
            round_trip::<CommandEnvelope>(body);
            if let Ok(env) = telemetry::decode::<CommandEnvelope>(body) {
                assert_eq!(telemetry::peek_tag(body), env.tag);
            }
        }
        2 => round_trip::<Command>(body),
        _ => {
            if let Ok(t) = CalibrationTable::<GROUPS>::decode(body) {
                let mut buf = [0u8; encoded_len_max(GROUPS)];
                let enc = t
                    .encode(&mut buf)
                    .expect("a decoded table does not fit encoded_len_max")
                    .to_vec();
                let again = CalibrationTable::<GROUPS>::decode(&enc).expect("re-encoded table");
                assert_eq!(again, t);
                let mut buf2 = [0u8; encoded_len_max(GROUPS)];
                assert_eq!(again.encode(&mut buf2).unwrap(), &enc[..]);
            }
            // Other group counts must be refused, never mis-read.
            let _ = CalibrationTable::<1>::decode(body);
        }
    }
});
