//! The benchmark's schemes against facts that follow from their definitions.

use feed_bench::measure;
use feed_bench::scheme::{self, Scheme};
use feed_bench::trace::{self, Rng};

#[test]
fn clean_slow_jog_is_exact_for_every_scheme() {
    let t = trace::slow_jog();
    assert_eq!(t.true_detents, 200);
    for s in Scheme::ALL {
        let row = measure(&t, s, 1_000_000, 1);
        assert_eq!(row.errors[0], 0, "{s:?}");
    }
}

#[test]
fn record_recovers_from_lost_frames_and_steps_do_not() {
    for t in trace::all() {
        let row = measure(&t, Scheme::Record, 500_000, 3);
        assert_eq!(row.errors, [0, 0, 0], "{}", t.name);
    }
    let t = trace::slow_jog();
    let (_, frames) = scheme::run(Scheme::Paper, &t, 500_000);
    let (position, _) = scheme::host(Scheme::Paper, &frames, 0.10, &mut Rng::new(9));
    assert!(position < 200, "lost step frames are lost motion");
}

#[test]
fn paper_counts_chatter_as_motion_and_ours_does_not() {
    let t = trace::dither();
    // 500 rises of B with A high, each one x10 unit steps of phantom motion.
    let paper = measure(&t, Scheme::Paper, 1_000_000, 1);
    assert_eq!(paper.errors[0], 5000);
    let record = measure(&t, Scheme::Record, 1_000_000, 1);
    assert_eq!(record.errors[0], 0);
}

#[test]
fn paper_backlog_at_x100_saturates_the_bus_and_runs_on_for_seconds() {
    let t = trace::fast_spin();
    let (bus, frames) = scheme::run(Scheme::Paper, &t, 1_000_000);
    assert_eq!(frames.len(), 100_000);
    // 100 000 one-byte frames of 65 bits at 1 Mbit/s: 6.5 s of bus time.
    assert!((bus.free_at() - 6.5e6).abs() < 2e3, "{}", bus.free_at());
    let row = measure(&t, Scheme::Paper, 1_000_000, 1);
    assert!(row.run_on_ms > 5_000.0);
    let record = measure(&t, Scheme::Record, 1_000_000, 1);
    assert!(record.run_on_ms <= 2.0, "{}", record.run_on_ms);
}

#[test]
fn compat_run_on_stays_within_its_bound() {
    let t = trace::fast_spin();
    let row = measure(&t, Scheme::Compat, 1_000_000, 1);
    // 40 steps at 2 ms, plus the frame time.
    assert!(row.run_on_ms <= 81.0, "{}", row.run_on_ms);
}
