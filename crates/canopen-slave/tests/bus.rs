//! The CAN controller's error state: events, EMCYs and the ERR LED indication.
mod common;
use canopen_slave::bus::{
    transition, BusEvent, BusState, EMCY_BUS_OFF_RECOVERED, EMCY_CAN_ERROR_PASSIVE,
    EMCY_CAN_OVERRUN,
};
use canopen_slave::ErrorIndication;
use common::*;

#[test]
fn every_state_change_maps_to_its_event() {
    use BusEvent as E;
    use BusState::*;
    let states = [ErrorActive, Warning, ErrorPassive, BusOff];
    // Rows: from; columns: to (ErrorActive, Warning, ErrorPassive, BusOff).
    let expected = [
        [
            None,
            Some(E::WarningLimit),
            Some(E::ErrorPassive),
            Some(E::BusOff),
        ],
        [None, None, Some(E::ErrorPassive), Some(E::BusOff)],
        [
            Some(E::ErrorActiveAgain),
            Some(E::ErrorActiveAgain),
            None,
            Some(E::BusOff),
        ],
        [
            Some(E::BusOffRecovered),
            Some(E::BusOffRecovered),
            Some(E::BusOffRecovered),
            None,
        ],
    ];
    for (from, row) in states.iter().zip(expected) {
        for (to, event) in states.iter().zip(row) {
            assert_eq!(transition(*from, *to), event, "{from:?} -> {to:?}");
        }
    }
}

#[test]
fn the_err_led_shows_warning_and_bus_off() {
    assert_eq!(BusState::ErrorActive.indication(), ErrorIndication::NoError);
    assert_eq!(
        BusState::Warning.indication(),
        ErrorIndication::WarningLimit
    );
    assert_eq!(
        BusState::ErrorPassive.indication(),
        ErrorIndication::WarningLimit
    );
    assert_eq!(BusState::BusOff.indication(), ErrorIndication::BusOff);
}

fn emcy(code: u16, register: u8) -> canopen_slave::Frame {
    let [lo, hi] = code.to_le_bytes();
    frame(EMCY, &[lo, hi, register, 0, 0, 0, 0, 0])
}

#[test]
fn error_passive_is_a_condition_raised_then_cleared() {
    let mut b = Bench::new();
    b.dev.on_bus_event(BusEvent::ErrorPassive);
    b.poll_at(ms(1));
    assert_eq!(b.take(), vec![emcy(EMCY_CAN_ERROR_PASSIVE, 0x11)]);
    assert_eq!(b.dev.error_register(), 0x11);
    // A warning or bus-off sends nothing of its own.
    b.dev.on_bus_event(BusEvent::WarningLimit);
    b.dev.on_bus_event(BusEvent::BusOff);
    b.poll_at(ms(2));
    assert_eq!(b.take(), vec![]);
    b.dev.on_bus_event(BusEvent::ErrorActiveAgain);
    b.poll_at(ms(3));
    assert_eq!(b.take(), vec![emcy(0, 0)]);
    assert_eq!(b.dev.error_register(), 0);
}

#[test]
fn bus_off_recovery_ends_error_passive_and_reports_itself_as_an_event() {
    let mut b = Bench::new();
    b.dev.on_bus_event(BusEvent::ErrorPassive);
    b.poll_at(ms(1));
    b.take();
    b.dev.on_bus_event(BusEvent::BusOffRecovered);
    b.poll_at(ms(2));
    // 0x8140 goes out while 0x8120 is still active; the end of both is one error reset.
    assert_eq!(
        b.take(),
        vec![emcy(EMCY_BUS_OFF_RECOVERED, 0x11), emcy(0, 0)]
    );
    assert_eq!(b.dev.error_register(), 0);
    assert_eq!(b.upload_u32(0x1003, 0), 2);
    assert_eq!(b.upload_u32(0x1003, 1), u32::from(EMCY_BUS_OFF_RECOVERED));
}

#[test]
fn a_receive_overrun_is_an_event() {
    let mut b = Bench::new();
    b.dev.on_rx_overrun();
    b.poll_at(ms(1));
    assert_eq!(b.take(), vec![emcy(EMCY_CAN_OVERRUN, 0x11), emcy(0, 0)]);
    assert_eq!(b.upload_u32(0x1003, 1), u32::from(EMCY_CAN_OVERRUN));
}
