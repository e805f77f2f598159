//! The stimulus command line of the QEMU variant (USART2): the test harness turns the
//! simulated wheel and sets the simulated selector lines.
//!
//! Lines end with `\n` (a `\r` anywhere is ignored, so `\r\n` works). Words are separated by
//! spaces or tabs; keywords are case-insensitive.
//!
//! | command | meaning |
//! |---|---|
//! | `turn <n>` | `n` whole detents, signed (`+` optional), \|n\| <= [`TURN_LIMIT`]: emitted edge by edge as valid quadrature |
//! | `ab <0..3>` | set the A/B levels directly: bit 0 = A, bit 1 = B (chatter, illegal jumps) |
//! | `axis <off\|x\|y\|z\|w\|v>` | make that axis line active (only it), or none |
//! | `mult <1\|10\|100>` | make that multiplier line active (only it) |
//! | `stall <ms>` | hold the CAN-side task busy for `ms` (1..=[`STALL_LIMIT_MS`]) from its next round: the interrupts keep receiving, so a burst overruns the receive queue as on a board whose CAN side falls behind |
//!
//! The firmware answers every line with exactly one reply: [`OK`] once the command has been
//! applied, or `err <reason>` ([`render`]). Selector commands only set the simulated lines;
//! the firmware's own debouncing decides when the selection changes.

use crate::line::{Line, LineAssembler};

/// Longest command line accepted.
pub const MAX_LINE: usize = 32;

/// Largest `turn` magnitude: 10 000 detents are 40 000 edges, 100 turns of a 100-detent
/// wheel; enough for any test, and small enough that one command cannot keep the emulated
/// CPU busy for long.
pub const TURN_LIMIT: i32 = 10_000;

/// Longest `stall`: long enough to overrun the receive queue with any burst, short enough
/// to stay far from every timeout a test uses.
pub const STALL_LIMIT_MS: i32 = 2_000;

/// Reply to an applied command.
pub const OK: &[u8] = b"ok\n";

/// Longest reply line [`render`] produces.
pub const MAX_REPLY: usize = 32;

/// A position of the 5-line axis switch.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum AxisLine {
    /// No line active.
    Off,
    /// Line 0.
    X,
    /// Line 1.
    Y,
    /// Line 2.
    Z,
    /// Line 3.
    W,
    /// Line 4.
    V,
}

impl AxisLine {
    /// The mask of active lines in `handwheel-core`'s convention (bit 0 = X .. bit 4 = V).
    pub const fn active_mask(self) -> u8 {
        match self {
            Self::Off => 0,
            Self::X => 1 << 0,
            Self::Y => 1 << 1,
            Self::Z => 1 << 2,
            Self::W => 1 << 3,
            Self::V => 1 << 4,
        }
    }
}

/// A position of the 3-line multiplier switch.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum MultLine {
    /// x1, line 0.
    X1,
    /// x10, line 1.
    X10,
    /// x100, line 2.
    X100,
}

impl MultLine {
    /// The mask of active lines (bit 0 = x1, bit 1 = x10, bit 2 = x100).
    pub const fn active_mask(self) -> u8 {
        match self {
            Self::X1 => 1 << 0,
            Self::X10 => 1 << 1,
            Self::X100 => 1 << 2,
        }
    }
}

/// One stimulus command.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Command {
    /// `turn <n>`: `n` detents, positive forward.
    Turn(i32),
    /// `ab <0..3>`: A/B levels, bit 0 = A, bit 1 = B.
    Ab(u8),
    /// `axis ...`.
    Axis(AxisLine),
    /// `mult ...`.
    Mult(MultLine),
    /// `stall <ms>`: the CAN side stops for that long.
    Stall(u16),
}

/// Why a line was not applied; its [`StimError::reason`] is the text after `err `.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum StimError {
    /// Longer than [`MAX_LINE`].
    Overlong,
    /// Nothing but blanks.
    Empty,
    /// Not one of the four commands.
    UnknownCommand,
    /// The command needs an argument.
    MissingArgument,
    /// More words than the command takes.
    ExtraArgument,
    /// Not a decimal number.
    BadNumber,
    /// A number outside the command's range.
    OutOfRange,
    /// Not one of `off x y z w v`.
    BadAxis,
    /// Not one of `1 10 100`.
    BadMultiplier,
    /// For the firmware: the command could not be applied now.
    Busy,
}

impl StimError {
    /// The reason, as it appears after `err `.
    pub const fn reason(self) -> &'static str {
        match self {
            Self::Overlong => "line too long",
            Self::Empty => "empty line",
            Self::UnknownCommand => "unknown command",
            Self::MissingArgument => "missing argument",
            Self::ExtraArgument => "extra argument",
            Self::BadNumber => "bad number",
            Self::OutOfRange => "out of range",
            Self::BadAxis => "bad axis",
            Self::BadMultiplier => "bad multiplier",
            Self::Busy => "busy",
        }
    }
}

/// A reply line, `ok\n` or `err <reason>\n`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Reply {
    buf: [u8; MAX_REPLY],
    len: u8,
}

impl Reply {
    /// The bytes to write to the USART.
    pub fn as_bytes(&self) -> &[u8] {
        self.buf.get(..usize::from(self.len)).unwrap_or(&self.buf)
    }
}

/// The reply to a line: [`OK`] for `Ok`, `err <reason>\n` for an error.
pub fn render(result: Result<(), StimError>) -> Reply {
    let mut reply = Reply {
        buf: [0; MAX_REPLY],
        len: 0,
    };
    let parts: [&[u8]; 3] = match result {
        Ok(()) => [OK, b"", b""],
        Err(e) => [b"err ", e.reason().as_bytes(), b"\n"],
    };
    for &b in parts.iter().flat_map(|p| p.iter()) {
        if let Some(slot) = reply.buf.get_mut(usize::from(reply.len)) {
            *slot = b;
            reply.len += 1;
        }
    }
    reply
}

fn is_blank(b: &u8) -> bool {
    matches!(b, b' ' | b'\t')
}

/// Words of a line, split at runs of blanks.
fn words(line: &[u8]) -> impl Iterator<Item = &[u8]> {
    line.split(is_blank).filter(|w| !w.is_empty())
}

/// A signed decimal within +-`limit`; digits beyond the limit are `OutOfRange`, not an
/// overflow.
fn number(word: &[u8], limit: i32) -> Result<i32, StimError> {
    let (negative, digits) = match word {
        [b'-', rest @ ..] => (true, rest),
        [b'+', rest @ ..] => (false, rest),
        _ => (false, word),
    };
    if digits.is_empty() || !digits.iter().all(u8::is_ascii_digit) {
        return Err(StimError::BadNumber);
    }
    let mut value: i32 = 0;
    for &d in digits {
        value = value * 10 + i32::from(d - b'0');
        if value > limit {
            return Err(StimError::OutOfRange);
        }
    }
    Ok(if negative { -value } else { value })
}

/// One command line (without its `\n`).
pub fn parse(line: &[u8]) -> Result<Command, StimError> {
    let mut words = words(line);
    let keyword = words.next().ok_or(StimError::Empty)?;
    let is = |name: &[u8]| keyword.eq_ignore_ascii_case(name);
    let known = is(b"turn") || is(b"ab") || is(b"axis") || is(b"mult") || is(b"stall");
    if !known {
        return Err(StimError::UnknownCommand);
    }
    let arg = words.next().ok_or(StimError::MissingArgument)?;
    if words.next().is_some() {
        return Err(StimError::ExtraArgument);
    }
    let arg_is = |name: &[u8]| arg.eq_ignore_ascii_case(name);
    if is(b"turn") {
        number(arg, TURN_LIMIT).map(Command::Turn)
    } else if is(b"ab") {
        let levels = number(arg, 3)?;
        u8::try_from(levels)
            .map(Command::Ab)
            .map_err(|_| StimError::OutOfRange)
    } else if is(b"stall") {
        let ms = number(arg, STALL_LIMIT_MS)?;
        u16::try_from(ms)
            .ok()
            .filter(|&ms| ms > 0)
            .map(Command::Stall)
            .ok_or(StimError::OutOfRange)
    } else if is(b"axis") {
        let axis = [
            (&b"off"[..], AxisLine::Off),
            (b"x", AxisLine::X),
            (b"y", AxisLine::Y),
            (b"z", AxisLine::Z),
            (b"w", AxisLine::W),
            (b"v", AxisLine::V),
        ]
        .into_iter()
        .find(|(name, _)| arg_is(name))
        .map(|(_, axis)| axis)
        .ok_or(StimError::BadAxis)?;
        Ok(Command::Axis(axis))
    } else {
        match arg {
            b"1" => Ok(Command::Mult(MultLine::X1)),
            b"10" => Ok(Command::Mult(MultLine::X10)),
            b"100" => Ok(Command::Mult(MultLine::X100)),
            _ => Err(StimError::BadMultiplier),
        }
    }
}

/// The stimulus side of USART2: feed it every received byte; each completed line gives one
/// parsed command (apply it, then send [`OK`]) or one error (send [`render`] of it).
#[derive(Clone, Debug)]
pub struct StimulusPort {
    lines: LineAssembler<MAX_LINE>,
}

impl Default for StimulusPort {
    fn default() -> Self {
        Self::new()
    }
}

impl StimulusPort {
    /// Lines end at `\n`; `\r` is ignored.
    pub const fn new() -> Self {
        Self {
            lines: LineAssembler::new(b'\n', Some(b'\r')),
        }
    }

    /// One byte from the harness; `Some` when it completed a line.
    pub fn push(&mut self, byte: u8) -> Option<Result<Command, StimError>> {
        Some(match self.lines.push(byte)? {
            Line::Complete(line) => parse(line),
            Line::Overlong => Err(StimError::Overlong),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    extern crate std;
    use std::vec;
    use std::vec::Vec;

    fn run(input: &[u8]) -> Vec<Result<Command, StimError>> {
        let mut port = StimulusPort::new();
        input.iter().filter_map(|&b| port.push(b)).collect()
    }

    #[test]
    fn turn() {
        for (line, n) in [
            (&b"turn 3"[..], 3),
            (b"turn -1", -1),
            (b"turn +7", 7),
            (b"turn 0", 0),
            (b"turn -0", 0),
            (b"turn 10000", 10_000),
            (b"turn -10000", -10_000),
            (b"turn 0000000000000000000012", 12),
            (b"TURN\t 5  ", 5),
        ] {
            assert_eq!(parse(line), Ok(Command::Turn(n)), "{line:?}");
        }
        for (line, err) in [
            (&b"turn"[..], StimError::MissingArgument),
            (b"turn ", StimError::MissingArgument),
            (b"turn 1 2", StimError::ExtraArgument),
            (b"turn x", StimError::BadNumber),
            (b"turn -", StimError::BadNumber),
            (b"turn +-1", StimError::BadNumber),
            (b"turn 1.5", StimError::BadNumber),
            (b"turn 0x10", StimError::BadNumber),
            (b"turn 10001", StimError::OutOfRange),
            (b"turn -10001", StimError::OutOfRange),
            (b"turn 99999999999999999999999", StimError::OutOfRange),
            (b"turn3", StimError::UnknownCommand),
        ] {
            assert_eq!(parse(line), Err(err), "{line:?}");
        }
    }

    #[test]
    fn ab() {
        for v in 0..=3u8 {
            let line = [b'a', b'b', b' ', b'0' + v];
            assert_eq!(parse(&line), Ok(Command::Ab(v)));
        }
        assert_eq!(parse(b"ab 4"), Err(StimError::OutOfRange));
        assert_eq!(parse(b"ab -1"), Err(StimError::OutOfRange));
        assert_eq!(parse(b"ab b"), Err(StimError::BadNumber));
        assert_eq!(parse(b"ab"), Err(StimError::MissingArgument));
        assert_eq!(parse(b"ab 1 1"), Err(StimError::ExtraArgument));
    }

    #[test]
    fn stall() {
        assert_eq!(parse(b"stall 1"), Ok(Command::Stall(1)));
        assert_eq!(parse(b"STALL 500"), Ok(Command::Stall(500)));
        assert_eq!(parse(b"stall 2000"), Ok(Command::Stall(2000)));
        for (line, err) in [
            (&b"stall 0"[..], StimError::OutOfRange),
            (b"stall -5", StimError::OutOfRange),
            (b"stall 2001", StimError::OutOfRange),
            (b"stall", StimError::MissingArgument),
            (b"stall 1 2", StimError::ExtraArgument),
            (b"stall ms", StimError::BadNumber),
        ] {
            assert_eq!(parse(line), Err(err), "{line:?}");
        }
    }

    #[test]
    fn axis() {
        for (arg, axis, mask) in [
            (&b"off"[..], AxisLine::Off, 0),
            (b"x", AxisLine::X, 0b00001),
            (b"y", AxisLine::Y, 0b00010),
            (b"z", AxisLine::Z, 0b00100),
            (b"w", AxisLine::W, 0b01000),
            (b"V", AxisLine::V, 0b10000),
        ] {
            let mut line = b"axis ".to_vec();
            line.extend_from_slice(arg);
            assert_eq!(parse(&line), Ok(Command::Axis(axis)));
            assert_eq!(axis.active_mask(), mask);
        }
        assert_eq!(parse(b"axis a"), Err(StimError::BadAxis));
        assert_eq!(parse(b"axis xy"), Err(StimError::BadAxis));
        assert_eq!(parse(b"axis 1"), Err(StimError::BadAxis));
        assert_eq!(parse(b"axis"), Err(StimError::MissingArgument));
    }

    #[test]
    fn mult() {
        assert_eq!(parse(b"mult 1"), Ok(Command::Mult(MultLine::X1)));
        assert_eq!(parse(b"mult 10"), Ok(Command::Mult(MultLine::X10)));
        assert_eq!(parse(b"Mult 100"), Ok(Command::Mult(MultLine::X100)));
        assert_eq!(
            [MultLine::X1, MultLine::X10, MultLine::X100].map(MultLine::active_mask),
            [1, 2, 4]
        );
        for bad in [
            &b"mult 2"[..],
            b"mult 1000",
            b"mult x10",
            b"mult 010",
            b"mult -1",
        ] {
            assert_eq!(parse(bad), Err(StimError::BadMultiplier), "{bad:?}");
        }
        assert_eq!(parse(b"mult"), Err(StimError::MissingArgument));
    }

    #[test]
    fn unknown_and_empty() {
        assert_eq!(parse(b""), Err(StimError::Empty));
        assert_eq!(parse(b" \t "), Err(StimError::Empty));
        assert_eq!(parse(b"jog 1"), Err(StimError::UnknownCommand));
        assert_eq!(parse(b"\xff\x00"), Err(StimError::UnknownCommand));
    }

    #[test]
    fn port_splits_lines_and_reports_overlong_once() {
        let mut input = b"turn 2\r\naxis x\n\nmult 10".to_vec();
        input.extend_from_slice(&[b'9'; 40]);
        input.extend_from_slice(b"\nab 3\n");
        assert_eq!(
            run(&input),
            vec![
                Ok(Command::Turn(2)),
                Ok(Command::Axis(AxisLine::X)),
                Err(StimError::Empty),
                Err(StimError::Overlong),
                Ok(Command::Ab(3)),
            ]
        );
    }

    #[test]
    fn replies() {
        assert_eq!(render(Ok(())).as_bytes(), b"ok\n");
        assert_eq!(
            render(Err(StimError::UnknownCommand)).as_bytes(),
            b"err unknown command\n"
        );
        for e in [
            StimError::Overlong,
            StimError::Empty,
            StimError::UnknownCommand,
            StimError::MissingArgument,
            StimError::ExtraArgument,
            StimError::BadNumber,
            StimError::OutOfRange,
            StimError::BadAxis,
            StimError::BadMultiplier,
            StimError::Busy,
        ] {
            let r = render(Err(e));
            let mut want = b"err ".to_vec();
            want.extend_from_slice(e.reason().as_bytes());
            want.push(b'\n');
            assert_eq!(r.as_bytes(), &want[..], "{e:?}");
        }
    }
}
