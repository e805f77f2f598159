//! `random-frames [--sequences N] [--seed S]`: runs N (default 1 000 000) random frame
//! sequences through the harness body the cargo-fuzz target runs, and prints how long they
//! took. A failing sequence is printed as hex with its seed and index, ready to be replayed
//! or put into the fuzzing corpus.

use std::panic;
use std::process::ExitCode;
use std::time::Instant;

use canopen_harness::{frames, random_input, Rng};

const USAGE: &str = "usage: random-frames [--sequences N] [--seed S]";

fn main() -> ExitCode {
    let mut sequences: u64 = 1_000_000;
    let mut seed: u64 = 0x00C0_FFEE;
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        let value = args.next().and_then(|v| v.replace('_', "").parse().ok());
        match (arg.as_str(), value) {
            ("--sequences", Some(n)) => sequences = n,
            ("--seed", Some(s)) => seed = s,
            _ => {
                eprintln!("{USAGE}");
                return ExitCode::from(2);
            }
        }
    }
    let started = Instant::now();
    let mut input = Vec::new();
    let mut total = (0u64, 0u64, 0u64);
    for index in 0..sequences {
        random_input(&mut Rng::for_sequence(seed, index), &mut input);
        match panic::catch_unwind(|| frames(&input)) {
            Ok(outcome) => {
                total.0 += u64::from(outcome.frames);
                total.1 += u64::from(outcome.operational);
                total.2 += u64::from(outcome.sent);
            }
            Err(_) => {
                let hex: String = input.iter().map(|b| format!("{b:02x}")).collect();
                eprintln!("random-frames: sequence {index} of seed {seed} failed; input: {hex}");
                return ExitCode::FAILURE;
            }
        }
    }
    let secs = started.elapsed().as_secs_f64();
    let (frames, operational, sent) = total;
    println!(
        "random-frames: {sequences} sequences (seed {seed}) passed in {secs:.1} s: \
         {frames} frames in, {operational} of them in Operational, {sent} frames out"
    );
    ExitCode::SUCCESS
}
