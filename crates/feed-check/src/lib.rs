//! The feed contract, checked by exhausting a bounded model that runs the real device code.
//!
//! # The property
//!
//! For every sequence of wheel turns (forward and back, at x1, x10 and x100, between two
//! rounds of the device or inside one), axis and multiplier switch moves, feed enables and
//! disables, NMT commands from any node (start, stop, pre-operational, reset node, reset
//! communication), power cycles of the device (their boot-up seen or lost), time passing,
//! bus holds of any length (frames wait in a transmit path of the device's real kind: a FIFO
//! queue feeding mailboxes that the bus empties by identifier), frames lost or duplicated,
//! exact copies of any earlier feed record up to the contract's age, a path between the bus
//! and the host (a gateway) holding the device's frames and releasing them at once, the host
//! opening sessions (its configurations, a token in 0x2002 last) and, where its rule dates
//! records, probing the device's sequence (0x2033), stalls of the host and the master's
//! heartbeat coming or not:
//! - every motion the host credits to an axis is motion the operator turned on that axis
//!   while the feed was enabled, with its sign and multiplier, credited at most once, and
//!   no later than a stated bound after it was turned (the model's `late_ms`; 500 ms, the
//!   component's default master-loss timeout, for the shipped settings);
//! - exactly that when no record is missing: a detent turned while the host is in step
//!   (nothing happened since its last record after which a record may be missing) is
//!   credited within the bound;
//! - the device keeps the promises the host's rule builds on: the feed is enabled only by a
//!   0x2000 write it accepted in Operational with the master present and a transmit path
//!   that drained since it was last blocked, and stops when it leaves Operational, loses the
//!   master's heartbeat, changes or ends its session (a new token, a write of anything the
//!   session stands for, a reset, its pace) or has frames waiting 100 ms without the path
//!   running empty; its session is the token written last; nothing it made before a reset
//!   reaches the bus after it.
//!
//! # How it is checked
//!
//! [`model::FeedModel`] is a `stateright` model whose state holds the real node (the step
//! function `Node::poll` over `HandwheelDevice`: engine, accumulator, outbox, TPDO1, NMT and
//! reset handling), its wheel, the transmit path, the channel with the feed records it
//! delivered, the host's rule ([`host`], what `core.py` runs, with the sequence and epoch
//! widths and the device's pace as parameters, so that wrap-around comes within about a
//! hundred records), the model's
//! own view of what the device must do ([`model::Spec`]) and the truth ([`truth`]: the
//! detents the stimulus turned on each axis while the device had the feed enabled, never the
//! device's position). Every credit the host makes is judged against the truth; the checker
//! explores every interleaving of the actions within the budgets of each [`model::Bounds`]
//! breadth first and fails with the shortest path to a breach. [`bounds::ALL`] lists the
//! settings `cargo xtask test` runs; [`bounds::COPIES_AND_POWER_CYCLES`] the settings that
//! reached what old copies and power cycles broke on the code before feed record v2, which
//! pass now (the binary runs them after [`bounds::ALL`]);
//! [`bounds::UNFILED`] breaches found on today's code that no issue names yet
//! (`tests/unfiled.rs`). `tests/holes.rs` weakens the host's rule or lets copies be older
//! than the contract, and `tests/mutants.rs` runs plausible device bugs
//! (`handwheel_device::mutant`): the checker must find a breach in each, so that a passing run
//! means something; it also changes the host's dating (`host::HostMutant`). [`run`] explores
//! one setting within caps on its states and time.

pub mod boundaries;
pub mod bounds;
pub mod host;
pub mod model;
pub mod run;
pub mod truth;
pub mod vectors;
