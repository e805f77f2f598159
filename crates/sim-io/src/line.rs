//! A byte-at-a-time line assembler with a fixed buffer.

/// What the assembler hands back when a line ends.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Line<'a> {
    /// A complete line without its terminator (and without the ignored byte).
    Complete(&'a [u8]),
    /// The line was longer than the buffer: its bytes were discarded up to and including
    /// the terminator. It still deserves exactly one (error) reply.
    Overlong,
}

/// Collects bytes into lines of at most `N` bytes.
///
/// Every terminator byte completes exactly one line (possibly empty, possibly
/// [`Line::Overlong`]), so a caller that answers each returned line once answers each line
/// of the input once. The `ignored` byte is dropped wherever it appears (e.g. the `\n` of a
/// `\r\n` pair on a CR-terminated protocol), so it neither counts towards the length nor
/// ends a line.
#[derive(Clone, Debug)]
pub struct LineAssembler<const N: usize> {
    buf: [u8; N],
    len: usize,
    overlong: bool,
    terminator: u8,
    ignored: Option<u8>,
}

impl<const N: usize> LineAssembler<N> {
    /// An empty assembler ending lines at `terminator` and dropping `ignored`.
    pub const fn new(terminator: u8, ignored: Option<u8>) -> Self {
        Self {
            buf: [0; N],
            len: 0,
            overlong: false,
            terminator,
            ignored,
        }
    }

    /// Takes one byte; returns the line it completed, if it was the terminator.
    ///
    /// The returned slice borrows the assembler's buffer: handle it before the next byte.
    pub fn push(&mut self, byte: u8) -> Option<Line<'_>> {
        if byte == self.terminator {
            let len = core::mem::take(&mut self.len);
            if core::mem::take(&mut self.overlong) {
                return Some(Line::Overlong);
            }
            return Some(Line::Complete(self.buf.get(..len).unwrap_or(&[])));
        }
        if Some(byte) == self.ignored || self.overlong {
            return None;
        }
        match self.buf.get_mut(self.len) {
            Some(slot) => {
                *slot = byte;
                self.len += 1;
            }
            None => {
                self.overlong = true;
                self.len = 0;
            }
        }
        None
    }

    /// Forgets a partial line (e.g. when the host reconnects).
    pub fn clear(&mut self) {
        self.len = 0;
        self.overlong = false;
    }

    /// Bytes of the line being collected so far (0 while discarding an overlong line).
    pub const fn pending(&self) -> usize {
        self.len
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    extern crate std;
    use std::vec::Vec;

    /// The last line the bytes completed, copied out (`None` inside for overlong).
    fn feed<const N: usize>(a: &mut LineAssembler<N>, bytes: &[u8]) -> Option<Option<Vec<u8>>> {
        let mut last = None;
        for &b in bytes {
            if let Some(line) = a.push(b) {
                last = Some(match line {
                    Line::Overlong => None,
                    Line::Complete(l) => Some(l.to_vec()),
                });
            }
        }
        last
    }

    #[test]
    fn assembles_lines_and_drops_the_ignored_byte() {
        let mut a = LineAssembler::<4>::new(b'\r', Some(b'\n'));
        assert_eq!(a.push(b'a'), None);
        assert_eq!(a.push(b'\n'), None);
        assert_eq!(a.push(b'b'), None);
        assert_eq!(a.push(b'c'), None);
        assert_eq!(a.pending(), 3);
        assert_eq!(a.push(b'\r'), Some(Line::Complete(b"abc")));
        assert_eq!(a.push(b'\r'), Some(Line::Complete(b"")));
    }

    #[test]
    fn exactly_full_is_fine_one_more_is_overlong() {
        let mut a = LineAssembler::<4>::new(b'\r', None);
        assert_eq!(feed(&mut a, b"abcd\r"), Some(Some(b"abcd".to_vec())));
        assert_eq!(feed(&mut a, b"abcde\r"), Some(None));
        // Long garbage is one overlong line, and the next line is clean.
        assert_eq!(feed(&mut a, b"0123456789abcdef\r"), Some(None));
        assert_eq!(feed(&mut a, b"x\r"), Some(Some(b"x".to_vec())));
    }

    #[test]
    fn clear_forgets_a_partial_line() {
        let mut a = LineAssembler::<4>::new(b'\n', Some(b'\r'));
        feed(&mut a, b"zzzzzz");
        a.clear();
        assert_eq!(feed(&mut a, b"abc\r\n"), Some(Some(b"abc".to_vec())));
    }

    #[test]
    fn zero_sized_buffer_never_panics() {
        let mut a = LineAssembler::<0>::new(b'\n', None);
        assert_eq!(a.push(b'\n'), Some(Line::Complete(b"")));
        assert_eq!(a.push(b'a'), None);
        assert_eq!(a.push(b'\n'), Some(Line::Overlong));
    }
}
