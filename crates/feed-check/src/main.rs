//! Runs the feed contract's checker over every setting of `bounds::ALL` and then of
//! `bounds::COPIES_AND_POWER_CYCLES` (or those whose names contain one of the arguments, in
//! `bounds::ALL`, `bounds::COPIES_AND_POWER_CYCLES` and `bounds::UNFILED`) and prints what it
//! explored; exits 1 with the shortest path to the first breach.
//!
//! A setting stops at its first breach. `--through`: explore on past breaches, to the end (to
//! measure a setting that breaches today as it will be once it passes). `--mutant NAME`: run the device bug NAME
//! (`nmt-stop`, `reset`, `snapshot`, `stall-completions`; the mutation tests' bugs) instead of the real code.
//! `--vectors FILE`: write the test vectors for `core.py` first. Each setting is capped
//! (`run::Caps::RUN`, printed first; `--max-states N`, `--max-seconds S` for others): one
//! that reaches a cap stops there and fails the run.

use std::process::ExitCode;
use std::time::Instant;

use feed_check::bounds;
use feed_check::model::Bounds;
use feed_check::run::{explore, Caps};
use handwheel_device::mutant::Mutant;

const USAGE: &str =
    "usage: feed-check [--vectors FILE] [--through] [--mutant nmt-stop|reset|snapshot|stall-completions|enable-intake] [--max-states N] [--max-seconds S] [setting name parts]";

fn main() -> ExitCode {
    let mut failed = false;
    let started = Instant::now();
    let mut total = 0;
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let mut value = |flag: &str| -> Result<Option<String>, ExitCode> {
        let Some(i) = args.iter().position(|a| a == flag) else {
            return Ok(None);
        };
        let Some(v) = args.get(i + 1).cloned() else {
            eprintln!("{USAGE}");
            return Err(ExitCode::from(2));
        };
        args.drain(i..=i + 1);
        Ok(Some(v))
    };
    let vectors = match value("--vectors") {
        Ok(v) => v,
        Err(code) => return code,
    };
    let mutant = match value("--mutant").map(|m| m.as_deref().map(mutant_named)) {
        Ok(None) => None,
        Ok(Some(Some(m))) => Some(m),
        Ok(Some(None)) | Err(_) => {
            eprintln!("{USAGE}");
            return ExitCode::from(2);
        }
    };
    let mut flag = |name: &str| {
        let at = args.iter().position(|a| a == name);
        at.map(|i| args.remove(i)).is_some()
    };
    let through = flag("--through");
    let mut caps = Caps::RUN;
    for (name, slot) in [("--max-states", 0), ("--max-seconds", 1)] {
        let Some(i) = args.iter().position(|a| a == name) else {
            continue;
        };
        let parsed = args.get(i + 1).and_then(|v| v.parse::<f64>().ok());
        let Some(v) = parsed.filter(|v| *v > 0.0) else {
            eprintln!("{USAGE}");
            return ExitCode::from(2);
        };
        args.drain(i..=i + 1);
        if slot == 0 {
            caps.states = v as usize;
        } else {
            caps.seconds = v;
        }
    }
    if through {
        feed_check::model::THROUGH_BREACHES.store(true, std::sync::atomic::Ordering::Relaxed);
    }
    if let Some(path) = vectors {
        let mut out = String::new();
        for (n, b) in bounds::ALL.iter().enumerate() {
            if (b.rule.sequence_bits, b.rule.epoch_bits) == (16, 3) {
                feed_check::vectors::write(b, 400, 30, 0x5EED_0000 + n as u64, &mut out);
            }
        }
        // The narrowed settings' walks (power cycles, copies, reconfigurations, the host's
        // tokens used up) at the shipped widths, which `core.py` runs.
        let narrowed = bounds::ALL
            .iter()
            .chain(bounds::COPIES_AND_POWER_CYCLES)
            .filter(|b| {
                b.rule != bounds::at_shipped_widths(b).rule
                    || b.pace != handwheel_core::SequencePace::SHIPPED
            });
        for (n, b) in narrowed.enumerate() {
            let name = format!("{} at the shipped widths", b.name);
            let shipped = Bounds {
                name: Box::leak(name.into_boxed_str()),
                ..bounds::at_shipped_widths(b)
            };
            feed_check::vectors::write(&shipped, 50, 30, 0x5EED_1000 + n as u64, &mut out);
        }
        if let Some(b) = bounds::ALL.iter().find(|b| b.name == "gateway hold") {
            feed_check::vectors::write_paths(b, feed_check::vectors::DATING_PATHS, &mut out);
        }
        feed_check::boundaries::write(&mut out);
        if let Err(e) = std::fs::write(&path, out) {
            eprintln!("feed-check: cannot write {path}: {e}");
            return ExitCode::FAILURE;
        }
        println!("feed-check: vectors for core.py in {path}");
    }
    let only = args;
    let chosen: Vec<Bounds> = if only.is_empty() {
        bounds::ALL
            .iter()
            .chain(bounds::COPIES_AND_POWER_CYCLES)
            .copied()
            .collect()
    } else {
        bounds::ALL
            .iter()
            .chain(bounds::COPIES_AND_POWER_CYCLES)
            .chain(bounds::UNFILED)
            .filter(|b| only.iter().any(|o| b.name.contains(o.as_str())))
            .copied()
            .collect()
    };
    println!(
        "feed-check: caps per setting: {} states, {} s",
        caps.states, caps.seconds
    );
    for mut bounds in chosen {
        bounds.mutant = mutant.or(bounds.mutant);
        let run = explore(bounds, caps, 2, through);
        total += run.states;
        println!(
            "feed-check: {:<24} {:>9} states, depth {:>3}, {:.1} s",
            bounds.name, run.states, run.depth, run.seconds
        );
        if let Some(over) = &run.over {
            failed = true;
            println!("  OVER: {over}, unfinished (narrow the setting or raise the cap)");
        }
        if let Some((found, warmup, path)) = run.breach {
            failed = true;
            println!("  BREACH: {found}");
            if let Some(warmup) = bounds.warmups.get(warmup) {
                println!("  from the warm-up {warmup:?}");
            }
            println!("  after: {path:?}");
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

fn mutant_named(name: &str) -> Option<Mutant> {
    match name {
        "nmt-stop" => Some(Mutant::NmtStopKeepsHeld),
        "reset" => Some(Mutant::ResetKeepsPending),
        "snapshot" => Some(Mutant::TpdoReadAtSend),
        "stall-completions" => Some(Mutant::StallCompletions),
        "enable-intake" => Some(Mutant::EnableWithoutIntake),
        _ => None,
    }
}
