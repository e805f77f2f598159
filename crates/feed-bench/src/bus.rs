//! A CAN bus model: frame lengths with worst-case bit stuffing, one transmitter.

/// Bits on the wire for a classic base-format data frame with `data_len` bytes, worst-case
/// stuffing, plus the 3-bit intermission: 47 fixed bits (SOF, 11-bit id, RTR, IDE, r0, DLC,
/// 15-bit CRC, delimiters, ACK, EOF, IFS) + 8 per data byte, and one stuff bit per 4 bits of
/// the 34 + 8n bits that stuffing applies to (SOF through CRC).
pub const fn frame_bits(data_len: u32) -> u32 {
    47 + 8 * data_len + (34 + 8 * data_len - 1) / 4
}

/// One frame on the wire.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transmission {
    /// When the device handed the frame to the controller, µs.
    pub queued_us: f64,
    /// Start of arbitration, µs.
    pub start_us: f64,
    /// End of the frame (the host has it), µs.
    pub end_us: f64,
}

/// A bus with only this device transmitting (its own frames queue behind each other).
#[derive(Clone, Debug)]
pub struct Bus {
    bit_us: f64,
    free_at_us: f64,
    /// Every frame sent, in order.
    pub log: Vec<Transmission>,
}

impl Bus {
    /// A bus at `bits_per_second`.
    pub fn new(bits_per_second: u32) -> Self {
        Self {
            bit_us: 1e6 / f64::from(bits_per_second),
            free_at_us: 0.0,
            log: Vec::new(),
        }
    }

    /// When the bus is next free.
    pub fn free_at(&self) -> f64 {
        self.free_at_us
    }

    /// Transmits a frame queued at `at_us`; returns when it has been received.
    pub fn send(&mut self, at_us: f64, data_len: u32) -> Transmission {
        let start = at_us.max(self.free_at_us);
        let end = start + f64::from(frame_bits(data_len)) * self.bit_us;
        self.free_at_us = end;
        let t = Transmission {
            queued_us: at_us,
            start_us: start,
            end_us: end,
        };
        self.log.push(t);
        t
    }

    /// Mean load over `[0, until_us]` and the peak load over any `window_us` window, as
    /// fractions of the bus time.
    pub fn load(&self, until_us: f64, window_us: f64) -> (f64, f64) {
        let busy: f64 = self.log.iter().map(|t| t.end_us - t.start_us).sum();
        let mean = if until_us > 0.0 { busy / until_us } else { 0.0 };
        // The peak window starts at some frame's start: slide over those.
        let mut peak = 0.0f64;
        let mut j = 0;
        let mut in_window = 0.0;
        for i in 0..self.log.len() {
            let from = self.log[i].start_us;
            while j < self.log.len() && self.log[j].end_us <= from + window_us {
                in_window += self.log[j].end_us - self.log[j].start_us;
                j += 1;
            }
            // A frame straddling the window's end counts in part.
            let partial = self.log.get(j).map_or(0.0, |t| {
                (from + window_us - t.start_us).clamp(0.0, t.end_us - t.start_us)
            });
            peak = peak.max((in_window + partial) / window_us);
            if j > i {
                in_window -= self.log[i].end_us - self.log[i].start_us;
            } else {
                j = i + 1;
            }
        }
        (mean, peak.min(1.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_lengths_with_worst_case_stuffing() {
        // 0 bytes: 47 + 8 stuff bits; 1 byte: 47 + 8 + 10; 8 bytes: 47 + 64 + 24.
        assert_eq!(frame_bits(0), 55);
        assert_eq!(frame_bits(1), 65);
        assert_eq!(frame_bits(8), 135);
    }

    #[test]
    fn frames_queue_behind_each_other_and_load_adds_up() {
        let mut bus = Bus::new(1_000_000);
        let a = bus.send(0.0, 8);
        let b = bus.send(10.0, 8);
        assert_eq!(a.end_us, 135.0);
        assert_eq!(b.start_us, 135.0);
        assert_eq!(b.end_us, 270.0);
        let (mean, peak) = bus.load(1000.0, 500.0);
        assert!((mean - 0.27).abs() < 1e-9);
        assert!((peak - 0.54).abs() < 1e-9);
    }

    #[test]
    fn a_saturated_bus_peaks_at_one() {
        let mut bus = Bus::new(125_000);
        for _ in 0..100 {
            bus.send(0.0, 1);
        }
        let (_, peak) = bus.load(bus.free_at(), 10_000.0);
        assert!((peak - 1.0).abs() < 1e-9);
    }
}
