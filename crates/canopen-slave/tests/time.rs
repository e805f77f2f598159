//! Driving the engine from a 32-bit millisecond tick: extension, sleep time, periodic duties.
use canopen_slave::{sleep_ms, Instant, Periodic, WideClock};

#[test]
fn the_wide_clock_counts_across_the_wrap() {
    let mut clock = WideClock::new();
    assert_eq!(clock.now(0), Instant::ZERO);
    assert_eq!(
        clock.now(u32::MAX),
        Instant::from_millis(u64::from(u32::MAX))
    );
    // The count wrapped: one more millisecond, not 49.7 days back.
    assert_eq!(clock.now(0), Instant::from_millis(1 << 32));
    assert_eq!(clock.now(5), Instant::from_millis((1 << 32) + 5));
    // The same tick twice is the same instant.
    assert_eq!(clock.now(5), Instant::from_millis((1 << 32) + 5));
}

#[test]
fn sleep_rounds_up_and_is_capped() {
    let t = Instant::from_millis(1_000);
    assert_eq!(sleep_ms(t, t, 100), 0);
    assert_eq!(
        sleep_ms(t, Instant::from_micros(999_000), 100),
        0,
        "deadline passed"
    );
    assert_eq!(sleep_ms(t, Instant::from_micros(1_000_001), 100), 1);
    assert_eq!(sleep_ms(t, Instant::from_micros(1_040_000), 100), 40);
    assert_eq!(sleep_ms(t, Instant::from_micros(1_099_999), 100), 100);
    assert_eq!(sleep_ms(t, Instant::from_millis(1_000_000_000), 100), 100);
}

#[test]
fn a_periodic_duty_is_due_at_once_then_every_period() {
    let mut p = Periodic::new(10, 5);
    assert!(!p.is_due(9));
    assert!(p.is_due(10));
    assert_eq!(p.next_ms(), 15);
    assert!(!p.is_due(14));
    assert!(p.is_due(15));
    assert!(p.is_due(21), "a round one tick late");
    assert_eq!(p.next_ms(), 25, "keeps the grid");
}

#[test]
fn a_late_round_is_not_caught_up_in_a_burst() {
    let mut p = Periodic::new(0, 5);
    assert!(p.is_due(0));
    // 23 ms late: one round now, the next a full period away.
    assert!(p.is_due(28));
    assert_eq!(p.next_ms(), 33);
    assert!(!p.is_due(29));
}

#[test]
fn a_periodic_duty_runs_through_the_tick_wrap() {
    let mut p = Periodic::new(u32::MAX - 2, 5);
    assert!(p.is_due(u32::MAX - 2));
    assert_eq!(p.next_ms(), 2);
    assert!(!p.is_due(u32::MAX), "before the wrap, not yet due");
    assert!(!p.is_due(1));
    assert!(p.is_due(2));
}
