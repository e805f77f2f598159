//! Runs the feed contract's checker over every setting of `bounds::ALL` and prints what it
//! explored; exits 1 with the shortest path to the first breach.

use std::process::ExitCode;
use std::time::Instant;

use feed_check::bounds;
use feed_check::model::FeedModel;
use stateright::{Checker, Model};

fn main() -> ExitCode {
    let mut failed = false;
    let started = Instant::now();
    let mut total = 0;
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    if let Some(i) = args.iter().position(|a| a == "--vectors") {
        let Some(path) = args.get(i + 1).cloned() else {
            eprintln!("usage: feed-check [--vectors FILE] [setting name parts]");
            return ExitCode::from(2);
        };
        args.drain(i..=i + 1);
        let mut out = String::new();
        for (n, b) in bounds::ALL.iter().enumerate() {
            if (b.rule.sequence_bits, b.rule.epoch_bits) == (16, 3) {
                feed_check::vectors::write(b, 400, 30, 0x5EED_0000 + n as u64, &mut out);
            }
        }
        feed_check::boundaries::write(&mut out);
        if let Err(e) = std::fs::write(&path, out) {
            eprintln!("feed-check: cannot write {path}: {e}");
            return ExitCode::FAILURE;
        }
        println!("feed-check: vectors for core.py in {path}");
    }
    let only = args;
    for bounds in bounds::ALL {
        if !only.is_empty() && !only.iter().any(|o| bounds.name.contains(o.as_str())) {
            continue;
        }
        let t = Instant::now();
        let checker = FeedModel { bounds: *bounds }
            .checker()
            .threads(2)
            .spawn_bfs()
            .join();
        let states = checker.unique_state_count();
        total += states;
        println!(
            "feed-check: {:<24} {:>9} states, depth {:>3}, {:.1} s",
            bounds.name,
            states,
            checker.max_depth(),
            t.elapsed().as_secs_f64()
        );
        for property in (FeedModel { bounds: *bounds }).properties() {
            if let Some(path) = checker.discovery(property.name) {
                failed = true;
                let last = path.last_state().violation.clone().unwrap_or_default();
                println!("  BREACH: {last}");
                println!("  after: {:?}", path.into_actions());
            }
        }
    }
    println!(
        "feed-check: {total} states in all, {:.1} s",
        started.elapsed().as_secs_f64()
    );
    if failed {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    }
}
