//! The feed contract, checked by exhausting a bounded model that runs the real device code.
//!
//! # The property
//!
//! For every sequence of wheel turns, axis switch moves, feed enables and disables, NMT
//! commands (start, stop, pre-operational, reset node, reset communication), power cycles of
//! the device, time passing, bus holds of any length (frames wait in a transmit path of the
//! device's real size), frames lost, duplicated or replayed by the channel, and stalls of the
//! host: every motion the host credits to an axis is motion the device counted on that axis
//! while the feed was enabled, forward when it was turned forward, credited at most once, and
//! credited no later than a stated bound after it was turned (the model's `late_ms`; 500 ms,
//! the component's default master-loss timeout, for the shipped settings).
//!
//! # How it is checked
//!
//! [`model::FeedModel`] is a `stateright` model whose state holds the real
//! `HandwheelDevice` (engine, accumulator, outbox, TPDO1, NMT and reset handling), a transmit
//! path of bounded size in front of the bus, the channel, the host's rule ([`host`], what
//! `core.py` runs, with the sequence and epoch widths as parameters so that wrap-around comes
//! within a few steps) and the truth (every detent the device counted: its era, position,
//! axis and time). Every credit the host makes is judged against the truth; the checker
//! explores every interleaving of the actions within the budgets of each [`model::Bounds`]
//! breadth first and fails with the shortest path to a breach. [`bounds::ALL`] lists the
//! settings `cargo xtask test` runs; [`bounds::HOLES`] are weakened rules the checker must
//! find breaches in, so that a passing run means something.

pub mod boundaries;
pub mod bounds;
pub mod host;
pub mod model;
pub mod vectors;
