//! Feed protocol benchmark: the same wheel traces through the paper's scheme and this
//! project's, over a CAN bus model, with lost frames. `cargo xtask bench` prints it.

pub mod bus;
pub mod plot;
pub mod scheme;
pub mod trace;

use scheme::Scheme;
use trace::{Rng, Trace};

/// Bit rates compared.
pub const BITRATES: [u32; 3] = [125_000, 500_000, 1_000_000];
/// Frame loss rates compared.
pub const DROP_RATES: [f64; 3] = [0.0, 0.01, 0.10];
/// Window of the peak bus load.
pub const PEAK_WINDOW_US: f64 = 10_000.0;

/// What one scheme did with one trace at one bit rate.
#[derive(Clone, Debug)]
pub struct Row {
    /// Trace name.
    pub trace: &'static str,
    /// Scheme.
    pub scheme: Scheme,
    /// Bit rate.
    pub bitrate: u32,
    /// Frames sent.
    pub frames: usize,
    /// Mean bus load over the trace and its run-on, percent.
    pub mean_load: f64,
    /// Peak bus load in any 10 ms window, percent.
    pub peak_load: f64,
    /// How long the host's position kept changing after the wheel stopped, ms.
    pub run_on_ms: f64,
    /// |true - host| final feed in units, at each of [`DROP_RATES`].
    pub errors: [i64; 3],
}

/// Runs one trace through one scheme at one bit rate.
pub fn measure(trace: &Trace, scheme: Scheme, bitrate: u32, seed: u64) -> Row {
    let (bus, frames) = scheme::run(scheme, trace, bitrate);
    let motion_end = trace.motion_end_us as f64;
    let mut errors = [0; 3];
    let mut run_on_ms = 0.0;
    for (i, drop) in DROP_RATES.into_iter().enumerate() {
        let mut rng = Rng::new(seed ^ (i as u64 + 1).wrapping_mul(0x9E37_79B9));
        let (position, last_change) = scheme::host(scheme, &frames, drop, &mut rng);
        errors[i] = (trace.true_units() - position).abs();
        if i == 0 {
            run_on_ms = ((last_change - motion_end) / 1000.0).max(0.0);
        }
    }
    let until = bus.free_at().max(motion_end);
    let (mean, peak) = bus.load(until, PEAK_WINDOW_US);
    Row {
        trace: trace.name,
        scheme,
        bitrate,
        frames: frames.len(),
        mean_load: mean * 100.0,
        peak_load: peak * 100.0,
        run_on_ms,
        errors,
    }
}

/// Every trace x scheme x bit rate.
pub fn run_all() -> Vec<Row> {
    let mut rows = Vec::new();
    for (i, trace) in trace::all().iter().enumerate() {
        for bitrate in BITRATES {
            for scheme in Scheme::ALL {
                rows.push(measure(trace, scheme, bitrate, 1000 + i as u64));
            }
        }
    }
    rows
}
