//! CAN over a serial line in the Lawicel ("SLCAN") ASCII protocol, the way python-can's
//! `slcan` interface speaks it.
//!
//! # What python-can sends and expects (python-can 4.6, `can/interfaces/slcan.py`)
//!
//! Every command is ASCII terminated by `\r`. On construction it sends, in this order:
//! - with `bitrate=`: `C\r`, `S0\r`..`S8\r` (its table maps 750 kbit/s to `S7`, Lawicel has
//!   800), then an *empty* command `\r` (the "no CAN FD data bit rate" code), then `O\r`;
//! - with `timing=` (a BTR pair): `C\r`, `sXXYY\r`, `O\r`;
//! - with neither (the handwheel tests): just `O\r` (or `L\r` for `listen_only=True`);
//! - on `shutdown()`: `C\r`.
//!
//! Frames go out as `tIIIL<data>\r` (11-bit), `TIIIIIIIIL<data>\r` (29-bit), `rIIIL\r` /
//! `RIIIIIIIIL\r` (remote), ids and data in upper-case hex, `L` a decimal digit. It never
//! sends `V`, `N`, `F`, `Z`, except `V`/`N` from `get_version()` / `get_serial_number()`,
//! which wait for a line starting with `V` / `N`.
//!
//! It never checks a reply to a command: its reader splits the input at `\r` (OK) or `\a`
//! (error) and only decodes lines that start with `t`, `T`, `r`, `R` (or the FD letters
//! `d D b B x`); anything else, such as `\r`, `\a`, or the `z\r` / `Z\r` that a Lawicel
//! adapter returns after a transmit, is read and dropped. Incoming frames are decoded as
//! `id = int(line[1:4], 16)`, `dlc = int(line[4])`, `data = fromhex(line[5:5 + 2 * dlc])`,
//! so trailing timestamp digits would be ignored.
//!
//! # What this port answers
//!
//! | command | state | reply |
//! |---|---|---|
//! | `O` / `L` (listen only) | any | `\r`; the channel is open (idempotent, where Lawicel says `\a` when already open) |
//! | `C` | any | `\r`; closed (idempotent) |
//! | `S0`..`S8`, `sXXYY`, `Z0` / `Z1` | closed | `\r` (bit rates have no effect in the emulator); `\a` while open |
//! | `V` / `N` | any | `V0101\r` / `NQEMU\r` |
//! | `F` | open | `F00\r` (no error flags); `\a` while closed |
//! | empty line | any | `\r` |
//! | `t` / `r` | open, not listen-only | `z\r`; a `t` data frame is forwarded to the device |
//! | `T` / `R` | open, not listen-only | `Z\r`; parsed, never forwarded (the handwheel uses 11-bit ids only) |
//! | anything else, malformed, or too long | any | `\a` |
//!
//! # Power-on state
//!
//! A Lawicel adapter powers up closed and forwards nothing until the host sends `O`;
//! [`SlcanPort::new`] behaves that way. The QEMU board uses [`SlcanPort::new_open`], which
//! powers up open, because there the `O` is often lost: QEMU starts the CPU when the host
//! connects, python-can writes `O` right after connecting, and QEMU's USART model drops every
//! byte that arrives before the firmware has enabled the USART. A port waiting for that `O`
//! would keep the boot-up frame (and everything after it) queued for good. Powered up open,
//! the device's frames go into the socket from boot on and the host reads them when it
//! listens. pyserial's `socket://` handler does discard what is already in the socket, once,
//! right after connecting, so the firmware must not send that early: QEMU setting up the
//! board and the firmware's `init` take only some 6 ms, a descheduled host can take longer,
//! and the QEMU board therefore holds the boot-up back a little longer
//! (`BOOT_UP_DELAY_MS` in the firmware's `qemu::board`).
//!
//! Otherwise the Lawicel states hold. After `C` the device's frames wait:
//! [`SlcanPort::encode`] returns `None` and the firmware keeps them queued, the way a CAN
//! controller keeps retrying a frame that no other node acknowledges, until `O` or `L`
//! opens the channel again. The host's frames are forwarded only while it is open (not
//! listen-only). So python-can's `bitrate=` sequence `C`, `Sn`, `O` works whether QEMU
//! dropped all of it, none of it, or its beginning (bytes are lost only before the USART
//! is enabled, so whatever arrives ends with the `O`).

use crate::line::{Line, LineAssembler};

/// Longest command line accepted: `T` + 8 id digits + DLC + 16 data digits is 26 bytes.
pub const MAX_LINE: usize = 32;

/// Longest frame line [`encode_frame`] produces: `t` + 3 + 1 + 16 + 4 timestamp digits + CR.
pub const MAX_ENCODED: usize = 26;

/// Reply: command accepted.
pub const OK: &[u8] = b"\r";
/// Reply: error (BELL).
pub const ERROR: &[u8] = b"\x07";
/// Reply to a transmitted 11-bit frame.
pub const SENT_STANDARD: &[u8] = b"z\r";
/// Reply to a transmitted 29-bit frame.
pub const SENT_EXTENDED: &[u8] = b"Z\r";
/// Reply to `V`: hardware 01, software 01.
pub const VERSION: &[u8] = b"V0101\r";
/// Reply to `N`.
pub const SERIAL_NUMBER: &[u8] = b"NQEMU\r";
/// Reply to `F`: no error flags.
pub const STATUS_FLAGS: &[u8] = b"F00\r";

/// Timestamps (`Z1`) count milliseconds modulo this (Lawicel: 0x0000..0xEA5F).
pub const TIMESTAMP_MODULUS: u32 = 60_000;

/// An 11-bit data frame, in either direction.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct CanFrame {
    /// The 11-bit identifier.
    pub id: u16,
    /// Data length code, 0..=8.
    pub dlc: u8,
    /// Payload; bytes past `dlc` are zero.
    pub data: [u8; 8],
}

impl CanFrame {
    /// A frame with `data` (at most 8 bytes) on `id` (at most 0x7FF).
    pub fn new(id: u16, data: &[u8]) -> Option<Self> {
        if id > 0x7FF || data.len() > 8 {
            return None;
        }
        let mut frame = Self {
            id,
            dlc: data.len() as u8,
            data: [0; 8],
        };
        frame.data.get_mut(..data.len())?.copy_from_slice(data);
        Some(frame)
    }

    /// The payload, `dlc` bytes.
    pub fn payload(&self) -> &[u8] {
        self.data.get(..usize::from(self.dlc)).unwrap_or(&self.data)
    }
}

/// A 29-bit frame (`T` / `R`): understood, acknowledged, never forwarded to the handwheel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ExtendedFrame {
    /// The 29-bit identifier.
    pub id: u32,
    /// Data length code, 0..=8.
    pub dlc: u8,
    /// Payload of a data frame; zero for a remote frame.
    pub data: [u8; 8],
    /// `R`: a remote frame.
    pub remote: bool,
}

/// One Lawicel command.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Command {
    /// An empty line (python-can sends one as the "no data bit rate" code).
    Empty,
    /// `O`: open the channel.
    Open,
    /// `L`: open the channel listen-only (no transmission).
    ListenOnly,
    /// `C`: close the channel.
    Close,
    /// `Sn`: standard bit rate `n` (0..=8: 10, 20, 50, 100, 125, 250, 500, 800, 1000 kbit/s).
    Bitrate(u8),
    /// `sXXYY`: SJA1000 BTR0 / BTR1.
    BitTiming {
        /// BTR0.
        btr0: u8,
        /// BTR1.
        btr1: u8,
    },
    /// `V`: version.
    Version,
    /// `N`: serial number.
    SerialNumber,
    /// `F`: status flags.
    StatusFlags,
    /// `Z0` / `Z1`: time stamps on frames sent to the host.
    Timestamps(bool),
    /// `tIIIL..`: an 11-bit data frame to put on the bus.
    Frame(CanFrame),
    /// `rIIIL`: an 11-bit remote frame (acknowledged; the handwheel serves no RTR).
    RemoteFrame {
        /// The 11-bit identifier.
        id: u16,
        /// Requested length.
        dlc: u8,
    },
    /// `T` / `R`: a 29-bit frame.
    Extended(ExtendedFrame),
}

/// Why a line is not a command; every one is answered with [`ERROR`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ParseError {
    /// Longer than [`MAX_LINE`].
    Overlong,
    /// Unknown (or unsupported, e.g. CAN FD) command letter.
    UnknownCommand,
    /// Wrong length, a non-hex digit or trailing bytes.
    Malformed,
    /// An id above 0x7FF (11-bit) or 0x1FFF_FFFF (29-bit).
    IdOutOfRange,
    /// A DLC digit above 8.
    BadDlc,
    /// A bit-rate code above `S8` or a `Z` argument other than 0 / 1.
    BadArgument,
}

/// Lawicel bit rate of `Sn` in kbit/s (`None` above `S8`).
pub const fn bitrate_kbit(code: u8) -> Option<u16> {
    match code {
        0 => Some(10),
        1 => Some(20),
        2 => Some(50),
        3 => Some(100),
        4 => Some(125),
        5 => Some(250),
        6 => Some(500),
        7 => Some(800),
        8 => Some(1000),
        _ => None,
    }
}

const fn hex_digit(b: u8) -> Option<u8> {
    match b {
        b'0'..=b'9' => Some(b - b'0'),
        b'A'..=b'F' => Some(b - b'A' + 10),
        b'a'..=b'f' => Some(b - b'a' + 10),
        _ => None,
    }
}

/// Value of a run of hex digits (at most 8 of them, so it fits).
fn hex_value(digits: &[u8]) -> Result<u32, ParseError> {
    if digits.is_empty() || digits.len() > 8 {
        return Err(ParseError::Malformed);
    }
    digits.iter().try_fold(0u32, |acc, &b| {
        hex_digit(b)
            .map(|d| acc << 4 | u32::from(d))
            .ok_or(ParseError::Malformed)
    })
}

/// `digits` (exactly 2 per byte) into `out`.
fn hex_bytes(digits: &[u8], out: &mut [u8]) -> Result<(), ParseError> {
    if digits.len() != out.len() * 2 {
        return Err(ParseError::Malformed);
    }
    for (byte, pair) in out.iter_mut().zip(digits.chunks_exact(2)) {
        *byte = hex_value(pair)? as u8;
    }
    Ok(())
}

/// A frame body after the command letter: `id_len` id digits, a DLC digit, then (for data
/// frames) `2 * dlc` data digits and nothing else.
fn parse_frame(
    body: &[u8],
    id_len: usize,
    max_id: u32,
    remote: bool,
) -> Result<(u32, u8, [u8; 8]), ParseError> {
    let (id_digits, rest) = body.split_at_checked(id_len).ok_or(ParseError::Malformed)?;
    let id = hex_value(id_digits)?;
    let (&dlc_digit, data_digits) = rest.split_first().ok_or(ParseError::Malformed)?;
    if !dlc_digit.is_ascii_digit() {
        return Err(ParseError::Malformed);
    }
    let dlc = dlc_digit - b'0';
    if dlc > 8 {
        return Err(ParseError::BadDlc);
    }
    if id > max_id {
        return Err(ParseError::IdOutOfRange);
    }
    let mut data = [0u8; 8];
    if remote {
        if !data_digits.is_empty() {
            return Err(ParseError::Malformed);
        }
    } else {
        let dst = data.get_mut(..usize::from(dlc)).ok_or(ParseError::BadDlc)?;
        hex_bytes(data_digits, dst)?;
    }
    Ok((id, dlc, data))
}

/// One command line (without its `\r`).
pub fn parse(line: &[u8]) -> Result<Command, ParseError> {
    let Some((&letter, args)) = line.split_first() else {
        return Ok(Command::Empty);
    };
    let no_args = |cmd| {
        if args.is_empty() {
            Ok(cmd)
        } else {
            Err(ParseError::Malformed)
        }
    };
    match letter {
        b'O' => no_args(Command::Open),
        b'L' => no_args(Command::ListenOnly),
        b'C' => no_args(Command::Close),
        b'V' => no_args(Command::Version),
        b'N' => no_args(Command::SerialNumber),
        b'F' => no_args(Command::StatusFlags),
        b'S' => match args {
            [d] if d.is_ascii_digit() => match bitrate_kbit(d - b'0') {
                Some(_) => Ok(Command::Bitrate(d - b'0')),
                None => Err(ParseError::BadArgument),
            },
            _ => Err(ParseError::Malformed),
        },
        b's' => {
            if args.len() != 4 {
                return Err(ParseError::Malformed);
            }
            let mut btr = [0u8; 2];
            hex_bytes(args, &mut btr)?;
            Ok(Command::BitTiming {
                btr0: btr[0],
                btr1: btr[1],
            })
        }
        b'Z' => match args {
            b"0" => Ok(Command::Timestamps(false)),
            b"1" => Ok(Command::Timestamps(true)),
            [_] => Err(ParseError::BadArgument),
            _ => Err(ParseError::Malformed),
        },
        b't' | b'r' => {
            let remote = letter == b'r';
            let (id, dlc, data) = parse_frame(args, 3, 0x7FF, remote)?;
            let id = id as u16;
            Ok(if remote {
                Command::RemoteFrame { id, dlc }
            } else {
                Command::Frame(CanFrame { id, dlc, data })
            })
        }
        b'T' | b'R' => {
            let remote = letter == b'R';
            let (id, dlc, data) = parse_frame(args, 8, 0x1FFF_FFFF, remote)?;
            Ok(Command::Extended(ExtendedFrame {
                id,
                dlc,
                data,
                remote,
            }))
        }
        _ => Err(ParseError::UnknownCommand),
    }
}

/// State of the SLCAN channel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Channel {
    /// After [`SlcanPort::new`] and `C`: no frames either way; configuration commands
    /// accepted.
    Closed,
    /// After [`SlcanPort::new_open`] and `O`: frames both ways.
    Open,
    /// After `L`: frames to the host only; the host's frames are refused.
    ListenOnly,
}

/// What one completed line produced.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Outcome {
    /// The bytes to send back to the host (never empty).
    pub reply: &'static [u8],
    /// A data frame to hand to the CAN-RX path, as if received from the bus.
    pub frame: Option<CanFrame>,
    /// The command, for logging; `Err` for a line that was answered with [`ERROR`].
    pub command: Result<Command, ParseError>,
}

/// An encoded frame line for the host, `tIIIL<data>[TTTT]\r`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Encoded {
    buf: [u8; MAX_ENCODED],
    len: u8,
}

impl Encoded {
    /// The bytes to write to the USART.
    pub fn as_bytes(&self) -> &[u8] {
        self.buf.get(..usize::from(self.len)).unwrap_or(&self.buf)
    }
}

const HEX: &[u8; 16] = b"0123456789ABCDEF";

fn hex_char(nibble: u32) -> u8 {
    HEX.get((nibble & 0xF) as usize).copied().unwrap_or(b'0')
}

/// Renders an 11-bit data frame as `tIIIL<data>\r`, upper-case hex, with a 4-digit
/// millisecond time stamp before the `\r` when `timestamp` is given. A DLC above 8 is
/// clamped to 8 and the id is masked to 11 bits: the output is always well-formed.
pub fn encode_frame(frame: &CanFrame, timestamp: Option<u16>) -> Encoded {
    let mut out = Encoded {
        buf: [0; MAX_ENCODED],
        len: 0,
    };
    let mut put = |b: u8| {
        if let Some(slot) = out.buf.get_mut(usize::from(out.len)) {
            *slot = b;
            out.len += 1;
        }
    };
    let id = u32::from(frame.id & 0x7FF);
    let dlc = frame.dlc.min(8);
    put(b't');
    for shift in [8, 4, 0] {
        put(hex_char(id >> shift));
    }
    put(b'0' + dlc);
    for &byte in frame.data.iter().take(usize::from(dlc)) {
        put(hex_char(u32::from(byte) >> 4));
        put(hex_char(u32::from(byte)));
    }
    if let Some(ts) = timestamp {
        for shift in [12, 8, 4, 0] {
            put(hex_char(u32::from(ts) >> shift));
        }
    }
    put(b'\r');
    out
}

/// The SLCAN side of USART1: feed it every received byte, write back each [`Outcome`]'s
/// reply, forward its frame; render the device's frames with [`SlcanPort::encode`].
#[derive(Clone, Debug)]
pub struct SlcanPort {
    lines: LineAssembler<MAX_LINE>,
    channel: Channel,
    timestamps: bool,
}

impl Default for SlcanPort {
    fn default() -> Self {
        Self::new()
    }
}

impl SlcanPort {
    /// A closed channel without time stamps, as a Lawicel adapter powers up: nothing is
    /// forwarded either way until the host sends `O` (or `L`). A `\n` after the `\r` (a
    /// terminal's `\r\n`) is ignored.
    pub const fn new() -> Self {
        Self {
            lines: LineAssembler::new(b'\r', Some(b'\n')),
            channel: Channel::Closed,
            timestamps: false,
        }
    }

    /// An open channel without time stamps: like [`SlcanPort::new`] followed by `O`. For a
    /// link whose host may lose its opening `O` (QEMU's USART before the firmware enables
    /// it; see the module documentation).
    pub const fn new_open() -> Self {
        Self {
            channel: Channel::Open,
            ..Self::new()
        }
    }

    /// One byte from the host; `Some` when it completed a line.
    pub fn push(&mut self, byte: u8) -> Option<Outcome> {
        let parsed = match self.lines.push(byte)? {
            Line::Complete(line) => parse(line),
            Line::Overlong => Err(ParseError::Overlong),
        };
        Some(self.apply(parsed))
    }

    /// Carries out a parsed line: the state change, the reply and the frame to forward.
    pub fn apply(&mut self, command: Result<Command, ParseError>) -> Outcome {
        let mut frame = None;
        let reply = match command {
            Err(_) => ERROR,
            Ok(cmd) => match cmd {
                Command::Empty => OK,
                Command::Open => {
                    self.channel = Channel::Open;
                    OK
                }
                Command::ListenOnly => {
                    self.channel = Channel::ListenOnly;
                    OK
                }
                Command::Close => {
                    self.channel = Channel::Closed;
                    OK
                }
                Command::Bitrate(_) | Command::BitTiming { .. } if self.is_open() => ERROR,
                Command::Bitrate(_) | Command::BitTiming { .. } => OK,
                Command::Timestamps(_) if self.is_open() => ERROR,
                Command::Timestamps(on) => {
                    self.timestamps = on;
                    OK
                }
                Command::Version => VERSION,
                Command::SerialNumber => SERIAL_NUMBER,
                Command::StatusFlags if self.is_open() => STATUS_FLAGS,
                Command::StatusFlags => ERROR,
                Command::Frame(_) | Command::RemoteFrame { .. } | Command::Extended(_)
                    if self.channel != Channel::Open =>
                {
                    ERROR
                }
                Command::Frame(f) => {
                    frame = Some(f);
                    SENT_STANDARD
                }
                Command::RemoteFrame { .. } => SENT_STANDARD,
                Command::Extended(_) => SENT_EXTENDED,
            },
        };
        Outcome {
            reply,
            frame,
            command,
        }
    }

    /// The channel state.
    pub const fn channel(&self) -> Channel {
        self.channel
    }

    /// Open or listen-only: the host is listening.
    pub const fn is_open(&self) -> bool {
        !matches!(self.channel, Channel::Closed)
    }

    /// Whether `Z1` is in force.
    pub const fn timestamps(&self) -> bool {
        self.timestamps
    }

    /// A device frame for the host, or `None` while the channel is closed (keep the frame
    /// queued and try again later). `now_ms` is any free-running millisecond count; it is
    /// used, modulo [`TIMESTAMP_MODULUS`], only after `Z1`.
    pub fn encode(&self, frame: &CanFrame, now_ms: u32) -> Option<Encoded> {
        if !self.is_open() {
            return None;
        }
        let ts = self
            .timestamps
            .then_some((now_ms % TIMESTAMP_MODULUS) as u16);
        Some(encode_frame(frame, ts))
    }

    /// Closed, no time stamps, no partial line, as [`SlcanPort::new`] starts: for a host
    /// that disconnected. Closed even after [`SlcanPort::new_open`]: the USART is running
    /// by then, so the next host's `O` arrives, and until it does the device's frames wait
    /// instead of going into a socket whose new client may discard them on connecting.
    pub fn reset(&mut self) {
        *self = Self::new();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    extern crate std;
    use std::vec;
    use std::vec::Vec;

    /// Replies to a byte stream, concatenated, and the frames forwarded.
    fn run(port: &mut SlcanPort, input: &[u8]) -> (Vec<u8>, Vec<CanFrame>) {
        let mut replies = Vec::new();
        let mut frames = Vec::new();
        for &b in input {
            if let Some(out) = port.push(b) {
                replies.extend_from_slice(out.reply);
                frames.extend(out.frame);
            }
        }
        (replies, frames)
    }

    fn frame(id: u16, data: &[u8]) -> CanFrame {
        CanFrame::new(id, data).unwrap()
    }

    #[test]
    fn python_can_default_open_then_frames_both_ways() {
        let mut p = SlcanPort::new();
        assert_eq!(p.encode(&frame(0x710, &[0]), 0), None, "closed: keep it");
        assert_eq!(run(&mut p, b"O\r"), (b"\r".to_vec(), vec![]));
        assert_eq!(p.channel(), Channel::Open);
        // An NMT start to all nodes and an SDO upload request, as python-can writes them.
        let (replies, frames) = run(&mut p, b"t00020100\rt61084000100000000000\r");
        assert_eq!(replies, b"z\rz\r");
        assert_eq!(
            frames,
            vec![
                frame(0x000, &[0x01, 0x00]),
                frame(0x610, &[0x40, 0x00, 0x10, 0, 0, 0, 0, 0])
            ]
        );
        let enc = p.encode(&frame(0x710, &[0x00]), 1234).unwrap();
        assert_eq!(enc.as_bytes(), b"t710100\r");
        assert_eq!(run(&mut p, b"C\r"), (b"\r".to_vec(), vec![]));
        assert!(!p.is_open());
    }

    #[test]
    fn powered_open_port_sends_the_boot_up_before_any_command() {
        let mut p = SlcanPort::new_open();
        assert_eq!(p.channel(), Channel::Open);
        assert!(!p.timestamps());
        // The boot-up frame goes out although the host has not said a word.
        let enc = p.encode(&frame(0x710, &[0x00]), 0).unwrap();
        assert_eq!(enc.as_bytes(), b"t710100\r");
        // The host's frames are forwarded without an `O` as well.
        assert_eq!(
            run(&mut p, b"t00020110\r"),
            (b"z\r".to_vec(), vec![frame(0x000, &[0x01, 0x10])])
        );
        // An `O` that did get through changes nothing.
        assert_eq!(run(&mut p, b"O\r").0, b"\r");
        assert_eq!(p.channel(), Channel::Open);
    }

    #[test]
    fn powered_open_port_holds_frames_after_close_until_reopened() {
        let mut p = SlcanPort::new_open();
        let boot_up = frame(0x710, &[0x00]);
        assert_eq!(run(&mut p, b"C\r"), (b"\r".to_vec(), vec![]));
        assert_eq!(p.encode(&boot_up, 0), None, "closed: keep it queued");
        assert_eq!(
            run(&mut p, b"t0000\r").0,
            b"\x07",
            "host frames refused too"
        );
        assert_eq!(run(&mut p, b"O\r").0, b"\r");
        assert_eq!(p.encode(&boot_up, 0).unwrap().as_bytes(), b"t710100\r");
        // Listen-only reopens for the device's frames, not for the host's.
        run(&mut p, b"C\rL\r");
        assert_eq!(p.encode(&boot_up, 0).unwrap().as_bytes(), b"t710100\r");
        assert_eq!(run(&mut p, b"t0000\r").0, b"\x07");
    }

    #[test]
    fn powered_open_port_keeps_lawicel_configuration_rules() {
        let mut p = SlcanPort::new_open();
        // Bit rate, BTR and time stamps are refused while open, as after `O`.
        assert_eq!(run(&mut p, b"S6\rs0014\rZ1\r").0, b"\x07\x07\x07");
        assert_eq!(run(&mut p, b"F\r").0, b"F00\r");
        assert_eq!(run(&mut p, b"C\rZ1\rO\r").0, b"\r\r\r");
        assert!(p.timestamps() && p.is_open());
        // `reset` is for a host that disconnected: closed, so the next host's `O` decides.
        p.reset();
        assert_eq!((p.channel(), p.timestamps()), (Channel::Closed, false));
    }

    #[test]
    fn python_can_bitrate_sequence_from_the_open_state_with_any_prefix_lost() {
        // bitrate=500000: `C`, `S6`, the empty FD data rate code, `O`. QEMU loses the bytes
        // that arrive before the firmware enables the USART, so the port sees a suffix of
        // this; from the open power-on state every suffix leaves the channel open.
        let sequence = b"C\rS6\r\rO\r";
        let mut p = SlcanPort::new_open();
        assert_eq!(run(&mut p, sequence), (b"\r\r\r\r".to_vec(), vec![]));
        assert_eq!(p.channel(), Channel::Open);
        for lost in 0..=sequence.len() {
            let mut p = SlcanPort::new_open();
            let (replies, frames) = run(&mut p, &sequence[lost..]);
            assert_eq!(p.channel(), Channel::Open, "first {lost} bytes lost");
            assert!(frames.is_empty());
            assert!(
                p.encode(&frame(0x710, &[0x00]), 0).is_some(),
                "first {lost} bytes lost: {replies:?}"
            );
        }
    }

    #[test]
    fn python_can_bitrate_and_btr_sequences() {
        let mut p = SlcanPort::new();
        // bitrate=500000: close, S6, the empty FD data rate code, open.
        assert_eq!(run(&mut p, b"C\rS6\r\rO\r").0, b"\r\r\r\r");
        assert!(p.is_open());
        let mut p = SlcanPort::new();
        assert_eq!(run(&mut p, b"C\rs031C\rO\r").0, b"\r\r\r");
        assert_eq!(
            parse(b"s031C"),
            Ok(Command::BitTiming {
                btr0: 3,
                btr1: 0x1C
            })
        );
    }

    #[test]
    fn every_bitrate_code() {
        for (code, kbit) in [
            (0, 10),
            (1, 20),
            (2, 50),
            (3, 100),
            (4, 125),
            (5, 250),
            (6, 500),
            (7, 800),
            (8, 1000),
        ] {
            let line = [b'S', b'0' + code];
            assert_eq!(parse(&line), Ok(Command::Bitrate(code)));
            assert_eq!(bitrate_kbit(code), Some(kbit));
        }
        assert_eq!(parse(b"S9"), Err(ParseError::BadArgument));
        assert_eq!(parse(b"S"), Err(ParseError::Malformed));
        assert_eq!(parse(b"S10"), Err(ParseError::Malformed));
        assert_eq!(parse(b"Sx"), Err(ParseError::Malformed));
        assert_eq!(parse(b"s03"), Err(ParseError::Malformed));
        assert_eq!(parse(b"s031G"), Err(ParseError::Malformed));
    }

    #[test]
    fn configuration_only_while_closed() {
        let mut p = SlcanPort::new();
        run(&mut p, b"O\r");
        assert_eq!(run(&mut p, b"S6\rs0014\rZ1\r").0, b"\x07\x07\x07");
        assert!(!p.timestamps());
        run(&mut p, b"C\r");
        assert_eq!(run(&mut p, b"S8\rZ1\r").0, b"\r\r");
        assert!(p.timestamps());
    }

    #[test]
    fn info_commands() {
        let mut p = SlcanPort::new();
        assert_eq!(run(&mut p, b"V\rN\rF\r").0, b"V0101\rNQEMU\r\x07");
        run(&mut p, b"O\r");
        assert_eq!(run(&mut p, b"F\r").0, b"F00\r");
        assert_eq!(run(&mut p, b"V1\rNx\rF0\rOO\rC1\rL2\r").0, [0x07; 6]);
    }

    #[test]
    fn open_and_close_are_idempotent() {
        let mut p = SlcanPort::new();
        assert_eq!(run(&mut p, b"C\rC\rO\rO\r").0, b"\r\r\r\r");
        assert_eq!(p.channel(), Channel::Open);
        assert_eq!(run(&mut p, b"L\r").0, b"\r");
        assert_eq!(p.channel(), Channel::ListenOnly);
    }

    #[test]
    fn frames_are_refused_while_closed_or_listening() {
        let mut p = SlcanPort::new();
        assert_eq!(run(&mut p, b"t0000\r"), (b"\x07".to_vec(), vec![]));
        run(&mut p, b"L\r");
        assert_eq!(run(&mut p, b"t0000\r"), (b"\x07".to_vec(), vec![]));
        assert!(
            p.encode(&frame(1, &[]), 0).is_some(),
            "listening host gets frames"
        );
        run(&mut p, b"O\r");
        assert_eq!(
            run(&mut p, b"t0000\r"),
            (b"z\r".to_vec(), vec![frame(0, &[])])
        );
    }

    #[test]
    fn standard_frames_of_every_length_and_case() {
        let mut p = SlcanPort::new();
        run(&mut p, b"O\r");
        let (r, f) = run(&mut p, b"t7FF80102030405060708\rt1a3200ff\rt0001AB\r");
        assert_eq!(r, b"z\rz\rz\r");
        assert_eq!(
            f,
            vec![
                frame(0x7FF, &[1, 2, 3, 4, 5, 6, 7, 8]),
                frame(0x1A3, &[0x00, 0xFF]),
                frame(0x000, &[0xAB]),
            ]
        );
        assert_eq!(f[1].payload(), &[0x00, 0xFF]);
    }

    #[test]
    fn malformed_frames() {
        for (line, err) in [
            (&b"t"[..], ParseError::Malformed),
            (b"t12", ParseError::Malformed),
            (b"t123", ParseError::Malformed),
            (b"t8000", ParseError::IdOutOfRange),
            (b"tFFF0", ParseError::IdOutOfRange),
            (b"t1239", ParseError::BadDlc),
            (b"t123A", ParseError::Malformed),
            (b"t1231", ParseError::Malformed),
            (b"t12310", ParseError::Malformed),
            (b"t123100F", ParseError::Malformed),
            (b"t1231G0", ParseError::Malformed),
            (b"t12G0", ParseError::Malformed),
            (b"t-120", ParseError::Malformed),
            (b"t1230 ", ParseError::Malformed),
            (b"r1232AA", ParseError::Malformed),
            (b"T123", ParseError::Malformed),
            (b"T200000000", ParseError::IdOutOfRange),
            (b"T1FFFFFFF9", ParseError::BadDlc),
            (b"x", ParseError::UnknownCommand),
            (b"d1230", ParseError::UnknownCommand),
            (b"\x00", ParseError::UnknownCommand),
            (b"Z2", ParseError::BadArgument),
            (b"Z", ParseError::Malformed),
            (b"Z10", ParseError::Malformed),
        ] {
            assert_eq!(parse(line), Err(err), "{line:?}");
        }
    }

    #[test]
    fn remote_and_extended_frames_are_acknowledged_not_forwarded() {
        let mut p = SlcanPort::new();
        run(&mut p, b"O\r");
        assert_eq!(
            parse(b"r7FF8"),
            Ok(Command::RemoteFrame { id: 0x7FF, dlc: 8 })
        );
        assert_eq!(
            parse(b"T1FFFFFFF20102"),
            Ok(Command::Extended(ExtendedFrame {
                id: 0x1FFF_FFFF,
                dlc: 2,
                data: [1, 2, 0, 0, 0, 0, 0, 0],
                remote: false,
            }))
        );
        assert_eq!(
            parse(b"R000006104"),
            Ok(Command::Extended(ExtendedFrame {
                id: 0x610,
                dlc: 4,
                data: [0; 8],
                remote: true,
            }))
        );
        let (r, f) = run(&mut p, b"r6100\rT1FFFFFFF20102\rR000006104\r");
        assert_eq!(r, b"z\rZ\rZ\r");
        assert!(
            f.is_empty(),
            "29-bit and remote frames never reach the device"
        );
    }

    #[test]
    fn overlong_and_garbage_lines_get_one_bell_each() {
        let mut p = SlcanPort::new();
        run(&mut p, b"O\r");
        let long = [b'7'; 100];
        let (r, f) = run(&mut p, &long);
        assert!(r.is_empty() && f.is_empty());
        assert_eq!(run(&mut p, b"\r"), (b"\x07".to_vec(), vec![]));
        // The next line is clean; a `\n` after `\r` is ignored.
        assert_eq!(run(&mut p, b"t0000\r\n").0, b"z\r");
        assert_eq!(run(&mut p, b"\xff\xfe\r?\r").0, b"\x07\x07");
    }

    #[test]
    fn encoding_exact_bytes() {
        let enc = |id, data: &[u8], ts| encode_frame(&frame(id, data), ts).as_bytes().to_vec();
        assert_eq!(enc(0x710, &[0x00], None), b"t710100\r");
        assert_eq!(
            enc(0x090, &[0x30, 0x81, 0x11, 1, 0, 0, 0, 0], None),
            b"t09083081110100000000\r"
        );
        assert_eq!(enc(0x7FF, &[], None), b"t7FF0\r");
        assert_eq!(
            enc(0x190, &[0xAB; 8], Some(0xEA5F)),
            b"t1908ABABABABABABABABEA5F\r"
        );
        assert_eq!(enc(0x190, &[0xAB; 8], Some(0xEA5F)).len(), MAX_ENCODED);
        // Out-of-range fields cannot produce a malformed line.
        let odd = CanFrame {
            id: 0xFFFF,
            dlc: 15,
            data: [0x5A; 8],
        };
        assert_eq!(
            encode_frame(&odd, None).as_bytes(),
            b"t7FF85A5A5A5A5A5A5A5A\r"
        );
    }

    #[test]
    fn timestamps_after_z1_wrap_at_60_s() {
        let mut p = SlcanPort::new();
        run(&mut p, b"Z1\rO\r");
        let f = frame(0x190, &[1]);
        assert_eq!(
            p.encode(&f, 0x1234).unwrap().as_bytes(),
            b"t190101"
                .iter()
                .chain(b"1234\r")
                .copied()
                .collect::<Vec<u8>>()
        );
        assert_eq!(p.encode(&f, 60_001).unwrap().as_bytes(), b"t1901010001\r");
        p.reset();
        assert!(!p.timestamps() && !p.is_open());
    }

    #[test]
    fn frame_constructor_checks_bounds() {
        assert_eq!(CanFrame::new(0x800, &[]), None);
        assert_eq!(CanFrame::new(0x7FF, &[0; 9]), None);
        let f = CanFrame::new(0x123, &[9, 8]).unwrap();
        assert_eq!((f.id, f.dlc, f.payload()), (0x123, 2, &[9u8, 8][..]));
    }
}
