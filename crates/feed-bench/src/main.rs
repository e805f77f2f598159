//! Prints the feed protocol comparison and writes its plot.
//!
//! Usage: `feed-bench [plot.svg]`; `cargo xtask bench` runs it with `docs/feed-protocols.svg`.

use feed_bench::{plot, run_all, scheme::Scheme, Row};

fn main() {
    let rows = run_all();
    println!("Feed protocols: the paper's scheme vs this project's, same traces");
    println!(
        "(paper: rising edge of B, one 1-byte frame per unit step, unbounded backlog, inhibit 0;"
    );
    println!(" compat: this project's unit-step mode, backlog bound 40, inhibit 2 ms;");
    println!(" record: this project's 8-byte feed record, inhibit 2 ms, event timer 100 ms)");
    println!();
    println!(
        "{:<14} {:>5} {:<7} {:>7} {:>7} {:>7} {:>10} {:>8} {:>8} {:>8}",
        "trace",
        "kbit",
        "scheme",
        "frames",
        "mean %",
        "peak %",
        "run-on ms",
        "err 0%",
        "err 1%",
        "err 10%"
    );
    for r in &rows {
        println!(
            "{:<14} {:>5} {:<7} {:>7} {:>7.1} {:>7.1} {:>10.1} {:>8} {:>8} {:>8}",
            r.trace,
            r.bitrate / 1000,
            r.scheme.name(),
            r.frames,
            r.mean_load,
            r.peak_load,
            r.run_on_ms,
            r.errors[0],
            r.errors[1],
            r.errors[2]
        );
    }
    println!();
    println!("Ratios paper / record (frames, peak load, run-on; run-on ratio vs 1 ms floor):");
    for r in rows.iter().filter(|r| r.scheme == Scheme::Paper) {
        let ours = find(&rows, r, Scheme::Record);
        println!(
            "{:<14} {:>5} kbit  frames x{:<9.1} peak load x{:<7.1} run-on x{:.1}",
            r.trace,
            r.bitrate / 1000,
            r.frames as f64 / ours.frames.max(1) as f64,
            r.peak_load / ours.peak_load.max(0.01),
            r.run_on_ms.max(1.0) / ours.run_on_ms.max(1.0)
        );
    }
    if let Some(path) = std::env::args().nth(1) {
        match std::fs::write(&path, plot::svg(&rows)) {
            Ok(()) => println!("\nplot written to {path}"),
            Err(e) => {
                eprintln!("cannot write {path}: {e}");
                std::process::exit(1);
            }
        }
    }
}

fn find<'a>(rows: &'a [Row], like: &Row, scheme: Scheme) -> &'a Row {
    rows.iter()
        .find(|r| r.trace == like.trace && r.bitrate == like.bitrate && r.scheme == scheme)
        .expect("every combination is measured")
}
