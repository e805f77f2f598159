//! Properties of both transports over arbitrary input: no panic, one reply per line, and
//! what the device encodes the host parses back unchanged.

use proptest::prelude::*;
use sim_io::slcan::{self, CanFrame, SlcanPort};
use sim_io::stimulus::{self, StimulusPort};

/// Bytes with the interesting ones (terminators, command letters, hex) over-represented.
fn stream() -> impl Strategy<Value = Vec<u8>> {
    let byte = prop_oneof![
        any::<u8>(),
        Just(b'\r'),
        Just(b'\n'),
        Just(b'\x07'),
        Just(b' '),
        prop::sample::select(b"tTrROLCSsVNFZ0123456789ABCDEFabcdef".to_vec()),
    ];
    prop::collection::vec(byte, 0..400)
}

fn frame() -> impl Strategy<Value = CanFrame> {
    (0u16..=0x7FF, prop::collection::vec(any::<u8>(), 0..=8))
        .prop_map(|(id, data)| CanFrame::new(id, &data).unwrap())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn slcan_answers_every_line_exactly_once(input in stream(), open_first in any::<bool>()) {
        let mut port = SlcanPort::new();
        if open_first {
            for &b in b"O\r" {
                port.push(b);
            }
        }
        let mut replies = 0;
        for &b in &input {
            if let Some(out) = port.push(b) {
                replies += 1;
                prop_assert!(!out.reply.is_empty());
                // A reply is a BELL or a CR-terminated line, so python-can's reader splits
                // the stream exactly at reply boundaries.
                prop_assert!(out.reply == slcan::ERROR || out.reply.ends_with(b"\r"));
                prop_assert_eq!(
                    out.reply.iter().filter(|&&c| c == b'\r' || c == b'\x07').count(),
                    1
                );
                if out.frame.is_some() {
                    prop_assert_eq!(out.reply, slcan::SENT_STANDARD);
                }
                if out.command.is_err() {
                    prop_assert_eq!(out.reply, slcan::ERROR);
                    prop_assert!(out.frame.is_none());
                }
            }
        }
        prop_assert_eq!(replies, input.iter().filter(|&&b| b == b'\r').count());
    }

    #[test]
    fn powered_open_is_the_same_as_new_then_open(input in stream()) {
        let mut powered = SlcanPort::new_open();
        let mut opened = SlcanPort::new();
        for &b in b"O\r" {
            opened.push(b);
        }
        let probe = CanFrame::new(0x710, &[0]).unwrap();
        for &b in &input {
            prop_assert_eq!(powered.push(b), opened.push(b));
            prop_assert_eq!(powered.channel(), opened.channel());
            prop_assert_eq!(powered.encode(&probe, 0), opened.encode(&probe, 0));
        }
    }

    #[test]
    fn stimulus_answers_every_line_exactly_once(input in stream()) {
        let mut port = StimulusPort::new();
        let mut replies = 0;
        for &b in &input {
            if let Some(result) = port.push(b) {
                replies += 1;
                let reply = stimulus::render(result.map(|_| ()));
                let bytes = reply.as_bytes();
                prop_assert!(bytes == stimulus::OK || bytes.starts_with(b"err "));
                prop_assert!(bytes.ends_with(b"\n"));
                prop_assert_eq!(bytes.iter().filter(|&&c| c == b'\n').count(), 1);
            }
        }
        prop_assert_eq!(replies, input.iter().filter(|&&b| b == b'\n').count());
    }

    #[test]
    fn device_frames_parse_back_as_host_frames(f in frame()) {
        let mut port = SlcanPort::new();
        for &b in b"O\r" {
            port.push(b);
        }
        let encoded = port.encode(&f, 0).unwrap();
        let line = encoded.as_bytes();
        prop_assert_eq!(line.len(), 6 + 2 * usize::from(f.dlc));
        let mut forwarded = None;
        for &b in line {
            if let Some(out) = port.push(b) {
                forwarded = out.frame;
            }
        }
        prop_assert_eq!(forwarded, Some(f));
    }

    #[test]
    fn python_can_send_format_is_accepted(f in frame()) {
        // python-can: f"t{id:03X}{dlc:d}" + data.hex().upper()
        let mut line = format!("t{:03X}{}", f.id, f.dlc);
        for b in f.payload() {
            line.push_str(&format!("{b:02X}"));
        }
        prop_assert_eq!(slcan::parse(line.as_bytes()), Ok(slcan::Command::Frame(f)));
        prop_assert_eq!(
            slcan::parse(line.to_lowercase().as_bytes()),
            Ok(slcan::Command::Frame(f))
        );
    }

    #[test]
    fn turn_round_trips(n in -stimulus::TURN_LIMIT..=stimulus::TURN_LIMIT) {
        let line = format!("turn {n}");
        prop_assert_eq!(stimulus::parse(line.as_bytes()), Ok(stimulus::Command::Turn(n)));
    }

    #[test]
    fn turn_beyond_the_limit_is_refused(n in any::<i64>()) {
        prop_assume!(n.abs() > i64::from(stimulus::TURN_LIMIT));
        let line = format!("turn {n}");
        prop_assert_eq!(
            stimulus::parse(line.as_bytes()),
            Err(stimulus::StimError::OutOfRange)
        );
    }
}
