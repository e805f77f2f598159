//! The axis switch (X, Y, Z, W, V) and the multiplier switch (x1, x10, x100).
//!
//! Each switch position pulls one line low. The firmware samples the lines on a timer
//! through a [`SelectorInput`], which gives them as masks (bit `i` set = line `i` active):
//! on the board one read of the port the lines share, and [`SelectorLines`] over
//! `embedded-hal` input pins for any other wiring (and the host tests). A reading with no line or more than one line active is
//! not a position: for the axis switch it means "no axis" (the safe state: feed stops), for
//! the multiplier it keeps the previous factor, so a switch caught between positions never
//! changes the scale of motion. Either way a reading must be stable over consecutive samples
//! before it takes effect, which also rides out the break-before-make gap of a rotary switch
//! moving from one position to the next.

use embedded_hal::digital::InputPin;

/// A machine axis as the handwheel selects it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Axis {
    /// Switch position 1.
    X = 1,
    /// Switch position 2.
    Y = 2,
    /// Switch position 3.
    Z = 3,
    /// Switch position 4.
    W = 4,
    /// Switch position 5.
    V = 5,
}

impl Axis {
    /// All axes in switch order.
    pub const ALL: [Axis; 5] = [Axis::X, Axis::Y, Axis::Z, Axis::W, Axis::V];

    /// The value in object 0x2010 sub 1 and in the feed record (1..5).
    #[inline]
    pub const fn object_value(self) -> u8 {
        self as u8
    }

    /// From the object value 1..5.
    pub const fn from_object_value(value: u8) -> Option<Self> {
        match value {
            1 => Some(Self::X),
            2 => Some(Self::Y),
            3 => Some(Self::Z),
            4 => Some(Self::W),
            5 => Some(Self::V),
            _ => None,
        }
    }

    /// The paper's 3-bit axis field (X = 0 .. V = 4).
    #[inline]
    pub const fn paper_index(self) -> u8 {
        self as u8 - 1
    }

    /// The single active line of the 5 axis lines (bit 0 = X), or `None` for no line or more
    /// than one.
    pub const fn from_lines(active: u8) -> Option<Self> {
        match active & 0b1_1111 {
            0b0_0001 => Some(Self::X),
            0b0_0010 => Some(Self::Y),
            0b0_0100 => Some(Self::Z),
            0b0_1000 => Some(Self::W),
            0b1_0000 => Some(Self::V),
            _ => None,
        }
    }

    /// Object value of an optional axis: 0 for none.
    #[inline]
    pub const fn option_value(axis: Option<Axis>) -> u8 {
        match axis {
            Some(a) => a.object_value(),
            None => 0,
        }
    }
}

/// Units of feed per detent.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum Multiplier {
    /// One unit per detent.
    #[default]
    X1,
    /// Ten units per detent.
    X10,
    /// A hundred units per detent.
    X100,
}

impl Multiplier {
    /// The factor 1, 10 or 100 (object 0x2010 sub 2 and the feed record).
    #[inline]
    pub const fn factor(self) -> u8 {
        match self {
            Self::X1 => 1,
            Self::X10 => 10,
            Self::X100 => 100,
        }
    }

    /// From the factor 1, 10 or 100.
    pub const fn from_factor(factor: u8) -> Option<Self> {
        match factor {
            1 => Some(Self::X1),
            10 => Some(Self::X10),
            100 => Some(Self::X100),
            _ => None,
        }
    }

    /// The 2-bit code the feed record carries (0 = x1, 1 = x10, 2 = x100).
    #[inline]
    pub const fn code(self) -> u8 {
        match self {
            Self::X1 => 0,
            Self::X10 => 1,
            Self::X100 => 2,
        }
    }

    /// From the feed record's 2-bit code; `None` for 3 (never sent).
    pub const fn from_code(code: u8) -> Option<Self> {
        match code {
            0 => Some(Self::X1),
            1 => Some(Self::X10),
            2 => Some(Self::X100),
            _ => None,
        }
    }

    /// The single active line of the 3 multiplier lines (bit 0 = x1), or `None`.
    pub const fn from_lines(active: u8) -> Option<Self> {
        match active & 0b111 {
            0b001 => Some(Self::X1),
            0b010 => Some(Self::X10),
            0b100 => Some(Self::X100),
            _ => None,
        }
    }
}

/// The debounced state of both switches.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Hash)]
pub struct Selection {
    /// The selected axis, `None` when the switch shows no valid position.
    pub axis: Option<Axis>,
    /// The multiplier in force.
    pub multiplier: Multiplier,
}

/// Accepts a value once it has been read the same `threshold` times in a row.
#[derive(Clone, Copy, Debug, Hash)]
pub struct Debouncer<T> {
    stable: T,
    candidate: T,
    run: u8,
    threshold: u8,
}

impl<T: Copy + PartialEq> Debouncer<T> {
    /// Starts stable at `initial`. `threshold` is the number of equal consecutive samples a
    /// new value needs; 0 is rejected.
    pub const fn new(initial: T, threshold: u8) -> Option<Self> {
        if threshold == 0 {
            return None;
        }
        Some(Self {
            stable: initial,
            candidate: initial,
            run: 0,
            threshold,
        })
    }

    /// Takes one sample; returns the new stable value when it changes.
    #[must_use]
    pub fn sample(&mut self, raw: T) -> Option<T> {
        if raw != self.candidate {
            self.candidate = raw;
            self.run = 0;
        }
        if raw == self.stable {
            self.run = 0;
            return None;
        }
        self.run = self.run.saturating_add(1);
        if self.run >= self.threshold {
            self.stable = raw;
            self.run = 0;
            Some(raw)
        } else {
            None
        }
    }

    /// The accepted value.
    pub const fn stable(&self) -> T {
        self.stable
    }
}

/// Samples at the default 5 ms period that a new position must hold: 20 ms, longer than
/// contact bounce and the break-before-make gap of a hand-turned rotary switch, short enough
/// that the operator does not notice.
pub const DEFAULT_DEBOUNCE_SAMPLES: u8 = 4;

/// Debounces the two switches into a [`Selection`].
#[derive(Clone, Copy, Debug, Hash)]
pub struct Selector {
    axis: Debouncer<Option<Axis>>,
    multiplier: Debouncer<Option<Multiplier>>,
    selection: Selection,
}

impl Selector {
    /// Starts with no axis and x1 until the switches have been read stable.
    pub const fn new(threshold: u8) -> Option<Self> {
        let (Some(axis), Some(multiplier)) = (
            Debouncer::new(None, threshold),
            Debouncer::new(None, threshold),
        ) else {
            return None;
        };
        Some(Self {
            axis,
            multiplier,
            selection: Selection {
                axis: None,
                multiplier: Multiplier::X1,
            },
        })
    }

    /// Takes one sample of both switches (masks of active lines); returns the selection when
    /// it changes.
    #[must_use]
    pub fn sample(&mut self, axis_lines: u8, multiplier_lines: u8) -> Option<Selection> {
        let before = self.selection;
        if let Some(axis) = self.axis.sample(Axis::from_lines(axis_lines)) {
            self.selection.axis = axis;
        }
        if let Some(Some(multiplier)) = self
            .multiplier
            .sample(Multiplier::from_lines(multiplier_lines))
        {
            self.selection.multiplier = multiplier;
        }
        (self.selection != before).then_some(self.selection)
    }

    /// Samples both switches from `input`; returns the selection when it changes.
    #[must_use]
    pub fn sample_input(&mut self, input: &mut impl SelectorInput) -> Option<Selection> {
        let (axis, multiplier) = input.read_lines();
        self.sample(axis, multiplier)
    }

    /// The debounced selection.
    pub const fn selection(&self) -> Selection {
        self.selection
    }
}

/// Where the switch lines are read: the masks of active lines `(axis, multiplier)`.
pub trait SelectorInput {
    /// Reads all eight lines now.
    fn read_lines(&mut self) -> (u8, u8);
}

/// The eight switch inputs as `embedded-hal` pins, all active low (pull-ups, the switch
/// grounds the selected line).
pub struct SelectorLines<P> {
    /// Axis lines X, Y, Z, W, V.
    pub axis: [P; 5],
    /// Multiplier lines x1, x10, x100.
    pub multiplier: [P; 3],
}

impl<P: InputPin> SelectorLines<P> {
    /// Reads all lines; returns the masks of active lines `(axis, multiplier)`.
    pub fn read(&mut self) -> Result<(u8, u8), P::Error> {
        Ok((
            active_mask(&mut self.axis)?,
            active_mask(&mut self.multiplier)?,
        ))
    }
}

impl<P: InputPin> SelectorInput for SelectorLines<P> {
    /// A pin that cannot be read counts as not active: for the axis switch that is "no axis"
    /// (feed stops), for the multiplier "between positions" (the factor stays).
    fn read_lines(&mut self) -> (u8, u8) {
        (
            active_mask(&mut self.axis).unwrap_or(0),
            active_mask(&mut self.multiplier).unwrap_or(0),
        )
    }
}

fn active_mask<P: InputPin>(pins: &mut [P]) -> Result<u8, P::Error> {
    let mut mask = 0;
    for (bit, pin) in pins.iter_mut().enumerate() {
        if pin.is_low()? {
            mask |= 1 << bit;
        }
    }
    Ok(mask)
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_hal_mock::eh1::digital::{Mock as PinMock, State, Transaction};

    const X: u8 = 0b0_0001;
    const Z: u8 = 0b0_0100;
    const M1: u8 = 0b001;
    const M10: u8 = 0b010;
    const M100: u8 = 0b100;

    fn selector() -> Selector {
        Selector::new(DEFAULT_DEBOUNCE_SAMPLES).unwrap()
    }

    /// Samples `n` times, returning the last change seen.
    fn hold(s: &mut Selector, axis: u8, mult: u8, n: usize) -> Option<Selection> {
        let mut last = None;
        for _ in 0..n {
            if let Some(sel) = s.sample(axis, mult) {
                assert!(last.is_none(), "selection changed twice in one hold");
                last = Some(sel);
            }
        }
        last
    }

    #[test]
    fn axis_lines_decode_only_single_active_line() {
        for mask in 0u8..32 {
            let expected = match mask.count_ones() {
                1 => Some(Axis::ALL[mask.trailing_zeros() as usize]),
                _ => None,
            };
            assert_eq!(Axis::from_lines(mask), expected, "{mask:05b}");
        }
    }

    #[test]
    fn multiplier_lines_decode_only_single_active_line() {
        assert_eq!(Multiplier::from_lines(M1), Some(Multiplier::X1));
        assert_eq!(Multiplier::from_lines(M10), Some(Multiplier::X10));
        assert_eq!(Multiplier::from_lines(M100), Some(Multiplier::X100));
        for mask in [0, 0b011, 0b101, 0b110, 0b111] {
            assert_eq!(Multiplier::from_lines(mask), None, "{mask:03b}");
        }
    }

    #[test]
    fn object_values_round_trip() {
        for axis in Axis::ALL {
            assert_eq!(Axis::from_object_value(axis.object_value()), Some(axis));
            assert_eq!(axis.paper_index(), axis.object_value() - 1);
        }
        assert_eq!(Axis::from_object_value(0), None);
        assert_eq!(Axis::from_object_value(6), None);
        for m in [Multiplier::X1, Multiplier::X10, Multiplier::X100] {
            assert_eq!(Multiplier::from_factor(m.factor()), Some(m));
        }
        assert_eq!(Multiplier::from_factor(2), None);
    }

    #[test]
    fn position_takes_effect_after_threshold_samples() {
        let mut s = selector();
        for _ in 0..DEFAULT_DEBOUNCE_SAMPLES - 1 {
            assert_eq!(s.sample(Z, M10), None);
        }
        assert_eq!(
            s.sample(Z, M10),
            Some(Selection {
                axis: Some(Axis::Z),
                multiplier: Multiplier::X10
            })
        );
        assert_eq!(hold(&mut s, Z, M10, 10), None);
    }

    #[test]
    fn bounce_restarts_the_count() {
        let mut s = selector();
        assert_eq!(hold(&mut s, X, M1, 3), None);
        assert_eq!(s.sample(0, M1), None);
        assert_eq!(hold(&mut s, X, M1, 3), None);
        assert_eq!(s.selection().axis, None);
        assert!(hold(&mut s, X, M1, 1).is_some());
        assert_eq!(s.selection().axis, Some(Axis::X));
    }

    #[test]
    fn stable_invalid_axis_means_no_axis() {
        let mut s = selector();
        hold(&mut s, X, M1, 4).unwrap();
        // Two lines active (a shorted or half-turned switch).
        let sel = hold(&mut s, X | Z, M1, 4).unwrap();
        assert_eq!(sel.axis, None);
        hold(&mut s, X, M1, 4).unwrap();
        let sel = hold(&mut s, 0, M1, 4).unwrap();
        assert_eq!(sel.axis, None);
    }

    #[test]
    fn short_gap_between_positions_goes_straight_to_the_new_axis() {
        let mut s = selector();
        hold(&mut s, X, M1, 4).unwrap();
        assert_eq!(hold(&mut s, 0, M1, 2), None);
        let sel = hold(&mut s, Z, M1, 4).unwrap();
        assert_eq!(sel.axis, Some(Axis::Z));
    }

    #[test]
    fn invalid_multiplier_keeps_the_previous_factor() {
        let mut s = selector();
        hold(&mut s, X, M100, 4).unwrap();
        assert_eq!(hold(&mut s, X, 0, 20), None);
        assert_eq!(hold(&mut s, X, M10 | M100, 20), None);
        assert_eq!(s.selection().multiplier, Multiplier::X100);
        let sel = hold(&mut s, X, M10, 4).unwrap();
        assert_eq!(sel.multiplier, Multiplier::X10);
    }

    #[test]
    fn invalid_then_same_multiplier_is_not_a_change() {
        let mut s = selector();
        hold(&mut s, X, M10, 4).unwrap();
        assert_eq!(hold(&mut s, X, 0, 8), None);
        assert_eq!(hold(&mut s, X, M10, 8), None);
    }

    #[test]
    fn zero_threshold_is_rejected() {
        assert!(Selector::new(0).is_none());
        assert!(Debouncer::new(0u8, 0).is_none());
    }

    fn pins(levels: [State; 8]) -> SelectorLines<PinMock> {
        let mk = |s: State| PinMock::new(&[Transaction::get(s)]);
        SelectorLines {
            axis: [
                mk(levels[0]),
                mk(levels[1]),
                mk(levels[2]),
                mk(levels[3]),
                mk(levels[4]),
            ],
            multiplier: [mk(levels[5]), mk(levels[6]), mk(levels[7])],
        }
    }

    fn done(lines: SelectorLines<PinMock>) {
        for mut p in lines.axis.into_iter().chain(lines.multiplier) {
            p.done();
        }
    }

    #[test]
    fn lines_are_active_low() {
        use State::{High as H, Low as L};
        // Y pulled low, x100 pulled low, everything else floating high on its pull-up.
        let mut lines = pins([H, L, H, H, H, H, H, L]);
        assert_eq!(lines.read(), Ok((0b0_0010, 0b100)));
        done(lines);
    }

    #[test]
    fn lines_report_two_active_as_a_mask_the_decoder_rejects() {
        use State::{High as H, Low as L};
        let mut lines = pins([L, H, H, H, L, H, H, H]);
        let (axis, mult) = lines.read().unwrap();
        assert_eq!((axis, mult), (0b1_0001, 0));
        assert_eq!(Axis::from_lines(axis), None);
        assert_eq!(Multiplier::from_lines(mult), None);
        done(lines);
    }

    #[test]
    fn read_lines_feed_the_selector() {
        use State::{High as H, Low as L};
        let mut s = selector();
        let mut change = None;
        for _ in 0..DEFAULT_DEBOUNCE_SAMPLES {
            let mut lines = pins([H, H, H, L, H, H, L, H]);
            change = s.sample_input(&mut lines).or(change);
            done(lines);
        }
        assert_eq!(
            change,
            Some(Selection {
                axis: Some(Axis::W),
                multiplier: Multiplier::X10
            })
        );
    }

    #[test]
    fn an_unreadable_axis_line_means_no_axis() {
        extern crate std;
        use embedded_hal_mock::eh1::MockError;
        use State::{High as H, Low as L};
        let mut s = selector();
        for _ in 0..DEFAULT_DEBOUNCE_SAMPLES {
            let mut lines = pins([L, H, H, H, H, L, H, H]);
            let _ = s.sample_input(&mut lines);
            done(lines);
        }
        assert_eq!(s.selection().axis, Some(Axis::X));
        let mut change = None;
        for _ in 0..DEFAULT_DEBOUNCE_SAMPLES {
            // X still pulled low, but the V line reports an error: the axis switch reads as
            // no position.
            let error = MockError::Io(std::io::ErrorKind::Other);
            let mut lines = pins([L, H, H, H, H, L, H, H]);
            let _ = lines.axis[4].is_high();
            lines.axis[4].done();
            lines.axis[4] = PinMock::new(&[Transaction::get(H).with_error(error)]);
            change = s.sample_input(&mut lines).or(change);
            done(lines);
        }
        assert_eq!(
            change,
            Some(Selection {
                axis: None,
                multiplier: Multiplier::X1
            })
        );
    }
}
