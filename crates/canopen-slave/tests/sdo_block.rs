//! SDO block download (CiA 301 7.2.4.3.9-7.2.4.3.16) at the server: the exact frames, the
//! sub-block handed to a streamed object before its acknowledgement, the retransmission
//! after a lost segment, and every abort of the protocol. A client written here from the
//! specification drives it; a property test loses, repeats and corrupts segments at random
//! and checks that the object gets exactly the client's bytes or the transfer aborts.

use canopen_slave::crc::Crc16;
use canopen_slave::sdo::{ObjectAccess, SdoAbort, SdoServer};
use canopen_slave::Instant;
use proptest::prelude::*;

/// The loader's server: 127 segments of 7 bytes per sub-block.
type Server = SdoServer<889>;

const STREAM: (u16, u8) = (0x1F50, 1);
const WHOLE: (u16, u8) = (0x2000, 0);

/// A streamed DOMAIN (`STREAM`, as the loader's program data) and an object taken whole
/// (`WHOLE`, up to 64 bytes); each call in order.
#[derive(Default)]
struct Objects {
    streamed: Vec<u8>,
    /// Every chunk's length and whether it was the last.
    chunks: Vec<(usize, bool)>,
    whole: Option<Vec<u8>>,
    /// `download_chunk` fails once this many bytes have arrived.
    fail_after: Option<usize>,
}

impl ObjectAccess for Objects {
    fn upload(&mut self, _: u16, _: u8, _: &mut [u8]) -> Result<usize, SdoAbort> {
        Err(SdoAbort::WriteOnly)
    }
    fn size_of(&mut self, _: u16, _: u8) -> Result<usize, SdoAbort> {
        Ok(4)
    }
    fn check_download(&mut self, index: u16, sub: u8, size: Option<u32>) -> Result<(), SdoAbort> {
        match ((index, sub), size) {
            (WHOLE, Some(s)) if s > 64 => Err(SdoAbort::TooLong),
            (WHOLE | STREAM, _) => Ok(()),
            _ => Err(SdoAbort::NoObject),
        }
    }
    fn download(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoAbort> {
        // An expedited download goes here for either object.
        if (index, sub) == WHOLE {
            self.whole = Some(data.to_vec());
        }
        Ok(())
    }
    fn streams(&mut self, index: u16, sub: u8) -> bool {
        (index, sub) == STREAM
    }
    fn download_chunk(&mut self, _: u16, _: u8, data: &[u8], last: bool) -> Result<(), SdoAbort> {
        self.streamed.extend_from_slice(data);
        self.chunks.push((data.len(), last));
        if self.fail_after.is_some_and(|n| self.streamed.len() >= n) {
            return Err(SdoAbort::Hardware);
        }
        Ok(())
    }
}

fn initiate(cmd: u8, (index, sub): (u16, u8), size: u32) -> [u8; 8] {
    let [i0, i1] = index.to_le_bytes();
    let [s0, s1, s2, s3] = size.to_le_bytes();
    [cmd, i0, i1, sub, s0, s1, s2, s3]
}

fn segment(seqno: u8, last: bool, data: &[u8]) -> [u8; 8] {
    let mut f = [0u8; 8];
    f[0] = seqno | if last { 0x80 } else { 0 };
    f[1..1 + data.len()].copy_from_slice(data);
    f
}

fn end(unused: u8, crc: u16) -> [u8; 8] {
    let [c0, c1] = crc.to_le_bytes();
    [0xC1 | (unused << 2), c0, c1, 0, 0, 0, 0, 0]
}

fn abort_frame((index, sub): (u16, u8), code: SdoAbort) -> [u8; 8] {
    let [i0, i1] = index.to_le_bytes();
    let [c0, c1, c2, c3] = code.code().to_le_bytes();
    [0x80, i0, i1, sub, c0, c1, c2, c3]
}

fn crc(data: &[u8]) -> u16 {
    Crc16::new().update(data).finish()
}

struct Bench {
    server: Server,
    od: Objects,
    now: Instant,
}

impl Bench {
    fn new() -> Self {
        Self {
            server: Server::new(1000),
            od: Objects::default(),
            now: Instant::ZERO,
        }
    }

    fn send(&mut self, frame: [u8; 8]) -> Option<[u8; 8]> {
        self.now = self.now.add_micros(100);
        self.server.on_request(self.now, &frame, &mut self.od)
    }
}

/// The whole download of `data` as a CiA 301 client sends it when nothing is lost: every
/// answer checked.
fn download(b: &mut Bench, object: (u16, u8), data: &[u8]) -> [u8; 8] {
    let [i0, i1] = object.0.to_le_bytes();
    assert_eq!(
        b.send(initiate(0xC6, object, data.len() as u32)),
        Some([0xA4, i0, i1, object.1, 127, 0, 0, 0])
    );
    let chunks: Vec<&[u8]> = data.chunks(7).collect();
    for (block_no, block) in chunks.chunks(127).enumerate() {
        for (i, chunk) in block.iter().enumerate() {
            let seqno = i as u8 + 1;
            let last = block_no * 127 + i + 1 == chunks.len();
            let answer = b.send(segment(seqno, last, chunk));
            if seqno == 127 || last {
                assert_eq!(answer, Some([0xA2, seqno, 127, 0, 0, 0, 0, 0]));
            } else {
                assert_eq!(answer, None, "segment {seqno} is not answered");
            }
        }
    }
    let unused = (7 - data.len() % 7) % 7;
    b.send(end(unused as u8, crc(data)))
        .expect("an answer to the end")
}

fn pattern(len: usize) -> Vec<u8> {
    (0..len).map(|i| (i * 31 + 7) as u8).collect()
}

#[test]
fn a_streamed_download_arrives_whole_each_sub_block_before_its_acknowledgement() {
    let data = pattern(2000); // 286 segments: two full sub-blocks and one of 32
    let mut b = Bench::new();
    assert_eq!(download(&mut b, STREAM, &data), [0xA1, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(b.od.streamed, data);
    // 127 * 7 = 889 bytes per full sub-block; the last segment (5 data bytes) waits for the
    // end request, which says how many of its 7 bytes are data.
    assert_eq!(
        b.od.chunks,
        vec![(889, false), (889, false), (31 * 7, false), (5, true)]
    );
    assert_eq!(b.server.deadline(), None, "idle after the end");
}

#[test]
fn a_download_of_whole_segments_holds_back_the_last_one_for_the_end() {
    let data = pattern(889 * 2); // exactly two sub-blocks, the last segment full
    let mut b = Bench::new();
    assert_eq!(download(&mut b, STREAM, &data), [0xA1, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(b.od.streamed, data);
    assert_eq!(b.od.chunks, vec![(889, false), (882, false), (7, true)]);
}

#[test]
fn an_object_taken_whole_gets_one_download_after_the_crc() {
    let data = pattern(40);
    let mut b = Bench::new();
    assert_eq!(download(&mut b, WHOLE, &data), [0xA1, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(b.od.whole.as_deref(), Some(&data[..]));
    assert!(b.od.chunks.is_empty());
}

#[test]
fn a_lost_segment_is_sent_again_from_the_acknowledged_one() {
    let data = pattern(70); // 10 segments
    let mut b = Bench::new();
    b.send(initiate(0xC6, STREAM, 70)).unwrap();
    let chunks: Vec<&[u8]> = data.chunks(7).collect();
    // Segment 4 lost: 5..10 come out of sequence and are ignored; the last one (c = 1)
    // ends the sub-block, acknowledged up to 3.
    for (i, chunk) in chunks.iter().enumerate() {
        if i == 3 {
            continue;
        }
        let last = i + 1 == chunks.len();
        let answer = b.send(segment(i as u8 + 1, last, chunk));
        assert_eq!(answer, last.then_some([0xA2, 3, 127, 0, 0, 0, 0, 0]));
    }
    assert_eq!(
        b.od.streamed,
        data[..21],
        "what came in sequence, before the ack"
    );
    // The client goes on from segment 4, numbered from 1 in a new sub-block.
    for (i, chunk) in chunks[3..].iter().enumerate() {
        let last = i + 4 == chunks.len();
        let answer = b.send(segment(i as u8 + 1, last, chunk));
        assert_eq!(answer, last.then_some([0xA2, 7, 127, 0, 0, 0, 0, 0]));
    }
    assert_eq!(
        b.send(end(0, crc(&data))),
        Some([0xA1, 0, 0, 0, 0, 0, 0, 0])
    );
    assert_eq!(b.od.streamed, data);
}

#[test]
fn a_repeated_segment_is_ignored() {
    let data = pattern(21);
    let mut b = Bench::new();
    b.send(initiate(0xC6, STREAM, 21)).unwrap();
    let chunks: Vec<&[u8]> = data.chunks(7).collect();
    assert_eq!(b.send(segment(1, false, chunks[0])), None);
    assert_eq!(b.send(segment(1, false, chunks[0])), None); // a gateway's duplicate
    assert_eq!(b.send(segment(2, false, chunks[1])), None);
    assert_eq!(
        b.send(segment(3, true, chunks[2])),
        Some([0xA2, 3, 127, 0, 0, 0, 0, 0])
    );
    assert_eq!(
        b.send(end(0, crc(&data))),
        Some([0xA1, 0, 0, 0, 0, 0, 0, 0])
    );
    assert_eq!(b.od.streamed, data);
}

#[test]
fn a_wrong_crc_aborts_before_the_object_gets_the_end() {
    let data = pattern(30);
    let mut b = Bench::new();
    b.send(initiate(0xC6, STREAM, 30)).unwrap();
    for (i, chunk) in data.chunks(7).enumerate() {
        b.send(segment(i as u8 + 1, i == 4, chunk));
    }
    assert_eq!(
        b.send(end(5, crc(&data) ^ 1)),
        Some(abort_frame(STREAM, SdoAbort::CrcError))
    );
    assert!(b.od.chunks.iter().all(|&(_, last)| !last), "never finished");
    assert_eq!(b.server.deadline(), None);
}

#[test]
fn without_the_clients_crc_the_crc_field_is_not_checked() {
    let data = pattern(14);
    let mut b = Bench::new();
    // cc = 0: the client computes no CRC.
    b.send(initiate(0xC2, STREAM, 14)).unwrap();
    b.send(segment(1, false, &data[..7]));
    assert!(b.send(segment(2, true, &data[7..])).is_some());
    assert_eq!(b.send(end(0, 0)), Some([0xA1, 0, 0, 0, 0, 0, 0, 0]));
    assert_eq!(b.od.streamed, data);
}

#[test]
fn a_length_other_than_the_indicated_size_aborts() {
    let data = pattern(14);
    let mut b = Bench::new();
    b.send(initiate(0xC6, STREAM, 15)).unwrap();
    b.send(segment(1, false, &data[..7]));
    b.send(segment(2, true, &data[7..]));
    assert_eq!(
        b.send(end(0, crc(&data))),
        Some(abort_frame(STREAM, SdoAbort::LengthMismatch))
    );
}

#[test]
fn sequence_numbers_outside_the_block_abort() {
    for bad in [0u8, 128 & 0x7F, 0x7F] {
        let mut b = Bench::new();
        b.send(initiate(0xC6, STREAM, 700)).unwrap();
        let answer = b.send([bad, 1, 2, 3, 4, 5, 6, 7]);
        if bad == 0x7F {
            // 127 is the sub-block's last: out of sequence, acknowledged with none taken.
            assert_eq!(answer, Some([0xA2, 0, 127, 0, 0, 0, 0, 0]));
        } else {
            assert_eq!(answer, Some(abort_frame(STREAM, SdoAbort::InvalidSequence)));
        }
    }
}

#[test]
fn a_client_abort_ends_the_transfer_silently_and_an_end_outside_one_is_refused() {
    let mut b = Bench::new();
    b.send(initiate(0xC6, STREAM, 700)).unwrap();
    b.send(segment(1, false, &[1; 7]));
    assert_eq!(b.send(abort_frame(STREAM, SdoAbort::General)), None);
    assert_eq!(b.server.deadline(), None);
    assert_eq!(
        b.send(end(0, 0)),
        Some([0x80, 0, 0, 0, 0x01, 0x00, 0x04, 0x05])
    );
}

#[test]
fn a_transfer_left_waiting_times_out() {
    let mut b = Bench::new();
    b.send(initiate(0xC6, STREAM, 700)).unwrap();
    b.send(segment(1, false, &[1; 7]));
    let deadline = b.server.deadline().expect("a transfer runs");
    assert_eq!(b.server.poll(deadline).map(|f| f[0]), Some(0x80));
    assert_eq!(b.server.deadline(), None);
}

#[test]
fn the_objects_refusal_aborts_with_its_code() {
    let mut b = Bench::new();
    // Too long for the object, at the initiate.
    assert_eq!(
        b.send(initiate(0xC6, WHOLE, 65)),
        Some(abort_frame(WHOLE, SdoAbort::TooLong))
    );
    // A flash failure in the middle of a sub-block's hand-over, in place of its ack.
    b.od.fail_after = Some(100);
    let data = pattern(900);
    b.send(initiate(0xC6, STREAM, 900)).unwrap();
    let mut answer = None;
    for (i, chunk) in data.chunks(7).take(127).enumerate() {
        answer = b.send(segment(i as u8 + 1, false, chunk));
    }
    assert_eq!(answer, Some(abort_frame(STREAM, SdoAbort::Hardware)));
    assert_eq!(b.server.deadline(), None);
}

#[test]
fn a_server_without_a_block_buffer_refuses_block_download() {
    let mut server: SdoServer = SdoServer::new(1000);
    let mut od = Objects::default();
    let answer = server.on_request(Instant::ZERO, &initiate(0xC6, STREAM, 7), &mut od);
    assert_eq!(answer, Some(abort_frame(STREAM, SdoAbort::UnknownCommand)));
    assert_eq!(SdoServer::<0>::BLOCK_SIZE, 0);
    assert_eq!(SdoServer::<7>::BLOCK_SIZE, 1);
    assert_eq!(SdoServer::<2000>::BLOCK_SIZE, 127);
}

#[test]
fn a_repeated_closing_segment_ends_in_an_abort_not_in_wrong_data() {
    // A gateway repeats the closing segment of the first sub-block: the server acknowledges
    // it again with none taken; a client that reads that answer as its second sub-block's
    // sends the second sub-block again, which the server, waiting for the end, refuses.
    let data = pattern(889 + 14);
    let mut b = Bench::new();
    b.send(initiate(0xC6, STREAM, data.len() as u32)).unwrap();
    let chunks: Vec<&[u8]> = data.chunks(7).collect();
    for (i, chunk) in chunks[..127].iter().enumerate() {
        b.send(segment(i as u8 + 1, false, chunk));
    }
    assert_eq!(
        b.send(segment(127, false, chunks[126])),
        Some([0xA2, 0, 127, 0, 0, 0, 0, 0])
    );
    assert_eq!(b.send(segment(1, false, chunks[127])), None);
    assert_eq!(
        b.send(segment(2, true, chunks[128])),
        Some([0xA2, 2, 127, 0, 0, 0, 0, 0])
    );
    assert_eq!(
        b.send(segment(1, false, chunks[127])),
        Some(abort_frame(STREAM, SdoAbort::UnknownCommand))
    );
    assert!(b.od.chunks.iter().all(|&(_, last)| !last), "never finished");
    assert_eq!(b.server.deadline(), None);
}

#[derive(Clone, Copy, Debug)]
enum Fault {
    None,
    Lose,
    Repeat,
}

fn fault() -> impl Strategy<Value = Fault> {
    prop_oneof![
        8 => Just(Fault::None),
        1 => Just(Fault::Lose),
        1 => Just(Fault::Repeat),
    ]
}

proptest! {
    /// A client that follows CiA 301 (it sends each sub-block, then goes on from the
    /// acknowledged segment) over a channel that loses and repeats segments at random: the
    /// streamed object gets exactly the client's bytes, in chunks of whole segments, and
    /// the end is accepted.
    #[test]
    fn lost_and_repeated_segments_never_change_what_the_object_gets(
        data in proptest::collection::vec(any::<u8>(), 1..1500),
        faults in proptest::collection::vec(fault(), 400),
    ) {
        let mut b = Bench::new();
        let answer = b.send(initiate(0xC6, STREAM, data.len() as u32)).unwrap();
        let blksize = usize::from(answer[4]);
        let chunks: Vec<&[u8]> = data.chunks(7).collect();
        let mut faults = faults.into_iter().chain(core::iter::repeat(Fault::None));
        let mut next = 0; // the first segment not yet acknowledged
        while next < chunks.len() {
            let block: Vec<usize> = (next..chunks.len()).take(blksize).collect();
            let mut ack = None;
            for (i, &n) in block.iter().enumerate() {
                let last = n + 1 == chunks.len();
                let frame = segment(i as u8 + 1, last, chunks[n]);
                // The sub-block's closing segment is neither lost nor repeated here: its
                // loss leaves the client waiting until the transfer times out, and its
                // repeat is acknowledged again (with none taken), which a client reads
                // as the next sub-block's answer: the transfer then aborts
                // (`a_repeated_closing_segment_ends_in_an_abort_not_in_wrong_data`).
                let closing = i + 1 == block.len();
                let copies = match faults.next().unwrap() {
                    Fault::Lose if !closing => 0,
                    Fault::Repeat if !closing => 2,
                    _ => 1,
                };
                for _ in 0..copies {
                    if let Some(a) = b.send(frame) {
                        ack = Some(a);
                    }
                }
            }
            let ack = ack.expect("the sub-block's end is acknowledged");
            prop_assert_eq!(ack[0], 0xA2);
            prop_assert!(usize::from(ack[1]) <= block.len());
            next += usize::from(ack[1]);
            prop_assert!(data.starts_with(&b.od.streamed));
        }
        let unused = (7 - data.len() % 7) % 7;
        prop_assert_eq!(b.send(end(unused as u8, crc(&data))), Some([0xA1, 0, 0, 0, 0, 0, 0, 0]));
        prop_assert_eq!(&b.od.streamed, &data);
        prop_assert!(b.od.chunks.iter().all(|&(len, last)| last || len % 7 == 0));
        prop_assert_eq!(b.od.chunks.last().map(|c| c.1), Some(true));
    }
}

/// A frame a hostile or broken client may send: a block initiate to either object, a
/// segment with any first byte, an end request with any n and CRC, an abort, or 8 random
/// bytes.
fn hostile_frame() -> impl Strategy<Value = [u8; 8]> {
    prop_oneof![
        (any::<bool>(), 0u32..2000, any::<u8>()).prop_map(|(whole, size, flags)| initiate(
            0xC0 | (flags & 0x06),
            if whole { WHOLE } else { STREAM },
            size
        )),
        (any::<u8>(), any::<[u8; 7]>()).prop_map(|(b0, data)| {
            let mut f = [b0; 8];
            f[1..].copy_from_slice(&data);
            f
        }),
        (0u8..8, any::<u16>()).prop_map(|(n, crc)| end(n, crc)),
        Just(abort_frame(STREAM, SdoAbort::General)),
        any::<[u8; 8]>(),
    ]
}

proptest! {
    /// Whatever arrives, in any order: no panic; every answer is a block or SDO answer the
    /// protocol has (an initiate, acknowledgement or end confirmation of a block download,
    /// an expedited or segment answer, or an abort); a streamed object gets only whole
    /// segments but in a last chunk, never more than one sub-block at once.
    #[test]
    fn any_frames_get_a_defined_answer(frames in proptest::collection::vec(hostile_frame(), 1..300)) {
        let mut b = Bench::new();
        for frame in frames {
            if let Some(answer) = b.send(frame) {
                let cmd = answer[0];
                prop_assert!(
                    matches!(cmd, 0xA4 | 0xA2 | 0xA1 | 0x80 | 0x60)
                        || cmd & 0xE0 == 0x20
                        || cmd & 0xE0 == 0x40,
                    "answer {answer:02X?} to {frame:02X?}"
                );
            }
        }
        for &(len, last) in &b.od.chunks {
            prop_assert!(last || len % 7 == 0, "a chunk of {len} bytes before the last");
            prop_assert!(len <= 889);
        }
    }
}
