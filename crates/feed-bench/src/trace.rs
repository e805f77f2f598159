//! Wheel traces: what the EXTI task would see, edge by edge, with the ground truth.

use handwheel_core::{AbLevels, Multiplier};

/// Detents per revolution of the modelled wheel (a typical MPG).
pub const DETENTS_PER_REV: f64 = 100.0;
/// Quadrature counts per detent (one full cycle).
pub const COUNTS_PER_DETENT: i64 = 4;

/// One edge: the levels read after it, and when.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Edge {
    /// Time in microseconds.
    pub t_us: u64,
    /// A/B levels after the edge.
    pub levels: AbLevels,
}

/// A wheel trace with its ground truth.
#[derive(Clone, Debug)]
pub struct Trace {
    /// Short name for tables.
    pub name: &'static str,
    /// The multiplier the operator selected.
    pub multiplier: Multiplier,
    /// Edges in time order.
    pub edges: Vec<Edge>,
    /// Net detents the wheel really moved.
    pub true_detents: i64,
    /// When the wheel last really moved (chatter is not motion), microseconds.
    pub motion_end_us: u64,
}

impl Trace {
    /// The true final feed in multiplied units.
    pub fn true_units(&self) -> i64 {
        self.true_detents * i64::from(self.multiplier.factor())
    }
}

/// A deterministic xorshift generator: the same traces and drops on every run.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// Seeded generator (seed 0 is replaced).
    pub fn new(seed: u64) -> Self {
        Self(seed.max(1))
    }

    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        self.0 = x;
        x
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Builds edges from a velocity profile in revolutions per second, sampled every 10 µs.
fn from_velocity(duration_s: f64, rev_per_s: impl Fn(f64) -> f64) -> (Vec<Edge>, i64, u64) {
    const STEP_S: f64 = 10e-6;
    let counts_per_rev = DETENTS_PER_REV * COUNTS_PER_DETENT as f64;
    let mut edges = Vec::new();
    let mut levels = AbLevels::from_bits(0);
    let mut position = 0.0f64; // counts
    let mut count: i64 = 0;
    let mut last_motion = 0;
    let steps = (duration_s / STEP_S).round() as u64;
    for i in 0..steps {
        let t = i as f64 * STEP_S;
        position += rev_per_s(t) * counts_per_rev * STEP_S;
        // A hair of slack so that a profile meant to end on a whole count does.
        let whole = (position + 1e-6).floor() as i64;
        while whole > count {
            count += 1;
            levels = levels.next_forward();
            edges.push(Edge {
                t_us: i * 10,
                levels,
            });
            last_motion = i * 10;
        }
        while whole < count {
            count -= 1;
            levels = levels.next_reverse();
            edges.push(Edge {
                t_us: i * 10,
                levels,
            });
            last_motion = i * 10;
        }
    }
    (edges, count, last_motion)
}

fn trace(
    name: &'static str,
    multiplier: Multiplier,
    (edges, counts, end): (Vec<Edge>, i64, u64),
) -> Trace {
    Trace {
        name,
        multiplier,
        edges,
        // Whole detents the decoder can report; a partial detent at the end is not feed.
        true_detents: counts / COUNTS_PER_DETENT,
        motion_end_us: end,
    }
}

/// 1 rev/s for 2 s at x1: 200 detents.
pub fn slow_jog() -> Trace {
    trace("slow jog", Multiplier::X1, from_velocity(2.0, |_| 1.0))
}

/// 10 rev/s for 1 s at x100: 1000 detents, 100 000 units.
pub fn fast_spin() -> Trace {
    trace("fast spin", Multiplier::X100, from_velocity(1.0, |_| 10.0))
}

/// 5 rev/s forward for 0.5 s, then 5 rev/s back for 0.5 s, at x10.
pub fn reversal() -> Trace {
    trace(
        "reversal",
        Multiplier::X10,
        from_velocity(1.0, |t| if t < 0.5 { 5.0 } else { -5.0 }),
    )
}

/// Twenty detents, then the wheel rests on a B edge that chatters at 500 Hz for 1 s (x10).
pub fn dither() -> Trace {
    let (mut edges, counts, end) = from_velocity(0.2, |_| 1.0);
    // Bring the wheel to a state where B is about to rise (A high): the paper's decoder
    // counts every such rise as motion.
    let mut levels = edges.last().map_or(AbLevels::from_bits(0), |e| e.levels);
    let mut t = end + 1000;
    let mut counts = counts;
    // Until A is high and B low, i.e. the next forward edge is B rising.
    while !levels.a() || levels.b() {
        levels = levels.next_forward();
        counts += 1;
        edges.push(Edge { t_us: t, levels });
        t += 1000;
    }
    let motion_end = t - 1000;
    let rest = levels;
    let bounce = rest.next_forward(); // B rises
    for i in 0..500u64 {
        let at = t + i * 2000;
        edges.push(Edge {
            t_us: at,
            levels: bounce,
        });
        edges.push(Edge {
            t_us: at + 1000,
            levels: rest,
        });
    }
    trace("dither", Multiplier::X10, (edges, counts, motion_end))
}

/// A random operator: speed changes every 50 ms between -6 and +6 rev/s, random
/// multiplier-free pauses, 3 s, at x10.
pub fn operator_walk(seed: u64) -> Trace {
    let mut rng = Rng::new(seed);
    let speeds: Vec<f64> = (0..60)
        .map(|_| {
            if rng.unit() < 0.3 {
                0.0
            } else {
                (rng.unit() - 0.5) * 12.0
            }
        })
        .collect();
    trace(
        "operator walk",
        Multiplier::X10,
        from_velocity(3.0, |t| speeds[((t / 0.05) as usize).min(59)]),
    )
}

/// The five traces of the benchmark.
pub fn all() -> Vec<Trace> {
    vec![
        slow_jog(),
        fast_spin(),
        dither(),
        reversal(),
        operator_walk(7),
    ]
}
