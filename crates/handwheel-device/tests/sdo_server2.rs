//! The second SDO server (0x1201) on the handwheel: a master's reads on it beside another
//! master's transfers on the default server, and its writes ending the session like any
//! configuration write (README "Communication objects").

mod common;

use common::*;
use handwheel_core::{Axis, Multiplier};

const SDO2_RX: u16 = 0x690;
const SDO2_TX: u16 = 0x6A0;

/// One request to the second server and its one reply.
fn second(b: &mut Bench, request: [u8; 8]) -> Vec<u8> {
    b.receive(SDO2_RX, &request);
    let replies = b.take_id(SDO2_TX);
    assert_eq!(replies.len(), 1, "one reply on 0x1201:2");
    replies[0].data.clone()
}

fn upload(index: u16, sub: u8) -> [u8; 8] {
    [0x40, index as u8, (index >> 8) as u8, sub, 0, 0, 0, 0]
}

#[test]
fn writes_of_0x1201_end_the_session_and_reads_on_it_keep_it() {
    let mut b = Bench::new();
    b.select(Some(Axis::X), Multiplier::X1);
    b.open_session(4);
    b.sdo_write(0x1201, 1, &u32::from(SDO2_RX).to_le_bytes())
        .unwrap();
    assert_eq!(
        b.read_u32(0x2002, 0),
        0,
        "a write of 0x1201:1 ends the session"
    );
    b.sdo_write(0x1201, 2, &u32::from(SDO2_TX).to_le_bytes())
        .unwrap();
    // The session opened again, the feed enabled.
    b.open_session(5);
    b.nmt(0x01);
    b.sdo_write(0x2000, 0, &[1]).unwrap();
    b.take();
    // A segmented upload on the default server, with the second master's reads between
    // its segments.
    b.receive(SDO_RX, &upload(0x1008, 0));
    assert_eq!(b.take_id(SDO_TX)[0].data[0], 0x41);
    for toggle in [0x00, 0x10] {
        let session = second(&mut b, upload(0x2002, 0));
        assert_eq!(session, [0x4F, 0x02, 0x20, 0x00, 5, 0, 0, 0]);
        let enabled = second(&mut b, upload(0x2000, 0));
        assert_eq!(enabled, [0x4F, 0x00, 0x20, 0x00, 1, 0, 0, 0]);
        b.receive(SDO_RX, &[0x60 | toggle, 0, 0, 0, 0, 0, 0, 0]);
        let segment = b.take_id(SDO_TX);
        assert_eq!(segment.len(), 1);
        assert_eq!(segment[0].data[0] & 0x10, toggle);
    }
    assert_eq!(b.read_u32(0x2002, 0), 5, "reads keep the session");
    // A write over the second server itself ends it as well.
    let written = second(&mut b, [0x2F, 0x01, 0x12, 0x03, 1, 0, 0, 0]);
    assert_eq!(written, [0x60, 0x01, 0x12, 0x03, 0, 0, 0, 0]);
    assert_eq!(
        b.read_u32(0x2002, 0),
        0,
        "a write of 0x1201:3 ends the session"
    );
    assert_eq!(b.read_u32(0x2000, 0), 0, "and stops the feed");
}
