//! SDO server (CiA 301 7.2.4): expedited and segmented transfers, block download with its
//! CRC, abort codes.
//!
//! The server owns only the protocol state and its transfer buffers; object access goes
//! through `ObjectAccess`, implemented by the device, so the protocol code never sees the
//! object dictionary's internals.
//!
//! Block download needs a buffer of its own, `BLOCK` bytes (the server's const parameter):
//! a sub-block of `BLOCK / 7` segments (at most 127) is taken into RAM and handed to the
//! object only once it is complete, before its acknowledgement. So the object's slow work
//! (a flash page erased and programmed) falls where the client waits for the acknowledgement
//! and the bus is quiet, and no frame of a sub-block arrives while the CPU stalls on flash.
//! With `BLOCK` below 7 (the default, 0) block download is refused as before (0x05040001)
//! and costs neither RAM nor code. Block upload is not supported.

pub use crate::abort::SdoAbort;
use crate::crc::Crc16;
use crate::nmt::NmtState;
use crate::time::Instant;

/// Size of the segmented-transfer buffer: the longest object that can be uploaded or
/// downloaded segmented (device strings are short).
pub const SDO_BUFFER: usize = 32;

/// What the SDO server needs from the object dictionary. Every method checks existence and
/// access itself, so the server can report its abort code verbatim.
pub trait ObjectAccess {
    /// Reads an object for an upload into `buf`, returning the number of bytes.
    fn upload(&mut self, index: u16, sub: u8, buf: &mut [u8]) -> Result<usize, SdoAbort>;
    /// The object's size, for an expedited download that does not indicate one.
    fn size_of(&mut self, index: u16, sub: u8) -> Result<usize, SdoAbort>;
    /// Early checks of a segmented download (exists, writable, indicated size plausible).
    fn check_download(&mut self, index: u16, sub: u8, size: Option<u32>) -> Result<(), SdoAbort>;
    /// Fully checked write; must leave everything unchanged when it fails.
    fn download(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoAbort>;

    /// Whether a segmented download of `index:sub` goes to the object segment by segment
    /// ([`download_chunk`](Self::download_chunk)) instead of whole, from the server's
    /// [`SDO_BUFFER`]-byte buffer, to [`download`](Self::download): for a DOMAIN longer than
    /// any buffer (the loader's program data). The object then checks the indicated size
    /// itself (it had it in [`check_download`](Self::check_download)). An expedited
    /// download still goes to `download`. By default nothing streams, and a device whose
    /// objects keep the default compiles to the server without streaming.
    fn streams(&mut self, _index: u16, _sub: u8) -> bool {
        false
    }

    /// The data bytes (0..=7) of one segment of a streamed download of `index:sub`, in
    /// order; `last` on the final segment. An error aborts the transfer with that code. A
    /// transfer that ends otherwise (client abort, timeout, a new request replacing it,
    /// an NMT state change) does not call it again: the caller sees the server idle
    /// ([`SdoServer::deadline`] is `None`) with the object's stream unfinished.
    fn download_chunk(
        &mut self,
        _index: u16,
        _sub: u8,
        _data: &[u8],
        _last: bool,
    ) -> Result<(), SdoAbort> {
        Err(SdoAbort::UnsupportedAccess)
    }
}

/// Which transfer is running, named after the CiA 301 protocols.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Mode {
    Idle,
    SegmentedDownload,
    SegmentedUpload,
    /// Sub-blocks coming in.
    BlockDownload,
    /// The last segment taken: the end request (its CRC and the unused bytes) is next.
    BlockDownloadEnd,
}

/// The SDO server: one transfer at a time, replies built into 8-byte payloads.
///
/// A flat record rather than an enum with the transfer's fields in each variant: the fields
/// past `mode` only mean something while a transfer runs, and flat fields are much cheaper
/// to update in place.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct SdoServer<const BLOCK: usize = 0> {
    mode: Mode,
    /// Toggle bit the next segment must carry.
    toggle: bool,
    index: u16,
    sub: u8,
    /// Bytes in `buf`: received so far (download) or to send in total (upload).
    len: u8,
    /// Bytes of `buf` already sent (upload).
    sent: u8,
    /// Size the client indicated (download).
    size: Option<u32>,
    /// When the running transfer times out.
    deadline: Instant,
    timeout_us: u32,
    buf: [u8; SDO_BUFFER],
    /// Block download: the last segment of this sub-block taken in sequence (0: none yet).
    seq: u8,
    /// Block download: the segment with c = 1 was taken.
    last_taken: bool,
    /// Block download: whether the client asked for the CRC.
    crc_asked: bool,
    /// Block download: the CRC of the bytes handed to the object so far.
    crc: Crc16,
    /// Block download: bytes in `block` (a streamed object: of this sub-block, or the last
    /// segment held back for the end request; else of the whole transfer).
    block_len: u16,
    /// Block download: bytes taken in sequence in the whole transfer.
    taken: u32,
    block: [u8; BLOCK],
}

type Reply = Result<[u8; 8], SdoAbort>;

/// An initiate reply or abort: command byte, echoed multiplexer, 4 data bytes.
fn reply(cmd: u8, index: u16, sub: u8, data: u32) -> [u8; 8] {
    let [i0, i1] = index.to_le_bytes();
    let [d0, d1, d2, d3] = data.to_le_bytes();
    [cmd, i0, i1, sub, d0, d1, d2, d3]
}

pub(crate) fn abort_payload(index: u16, sub: u8, abort: SdoAbort) -> [u8; 8] {
    reply(0x80, index, sub, abort.code())
}

impl<const BLOCK: usize> SdoServer<BLOCK> {
    /// Segments per sub-block of a block download (0: block download refused).
    pub const BLOCK_SIZE: u8 = if BLOCK / 7 > 127 {
        127
    } else {
        (BLOCK / 7) as u8
    };

    /// An idle server whose transfers time out `timeout_ms` after the client's last request.
    pub const fn new(timeout_ms: u16) -> Self {
        Self {
            mode: Mode::Idle,
            toggle: false,
            index: 0,
            sub: 0,
            len: 0,
            sent: 0,
            size: None,
            deadline: Instant::ZERO,
            // u16 * 1000 always fits a u32.
            timeout_us: timeout_ms as u32 * 1000,
            buf: [0; SDO_BUFFER],
            seq: 0,
            last_taken: false,
            crc_asked: false,
            crc: Crc16::new(),
            block_len: 0,
            taken: 0,
            block: [0; BLOCK],
        }
    }

    /// Drops any transfer silently (client abort, NMT state change, reset).
    pub fn reset(&mut self) {
        self.mode = Mode::Idle;
    }

    /// NMT state change: a transfer does not survive leaving the communicating states.
    pub fn on_nmt_state(&mut self, next: NmtState) {
        if !next.communicating() {
            self.reset();
        }
    }

    /// Starts a segmented transfer of `index:sub`.
    fn begin(&mut self, mode: Mode, index: u16, sub: u8) {
        self.mode = mode;
        self.index = index;
        self.sub = sub;
        self.toggle = false;
        self.len = 0;
        self.sent = 0;
    }

    /// When the current transfer times out; `None` while no transfer runs.
    pub fn deadline(&self) -> Option<Instant> {
        (self.mode != Mode::Idle).then_some(self.deadline)
    }

    /// Aborts a transfer the client has left unfinished for too long.
    pub fn poll(&mut self, now: Instant) -> Option<[u8; 8]> {
        if self.mode == Mode::Idle || now < self.deadline {
            return None;
        }
        self.reset();
        warn!("SDO {=u16:#x}:{=u8} timed out", self.index, self.sub);
        Some(abort_payload(self.index, self.sub, SdoAbort::Timeout))
    }

    /// Handles one client request (DLC already checked to be 8); returns the reply, if any.
    pub fn on_request(
        &mut self,
        now: Instant,
        req: &[u8; 8],
        od: &mut impl ObjectAccess,
    ) -> Option<[u8; 8]> {
        let [cmd, i0, i1, sub, d0, d1, d2, d3] = *req;
        let index = u16::from_le_bytes([i0, i1]);
        let data = u32::from_le_bytes([d0, d1, d2, d3]);
        let ccs = cmd >> 5;
        // Segment requests carry no multiplexer: an abort then names the running transfer.
        // (`BLOCK_SIZE > 0` first: a server without block download compiles without it.)
        let block = Self::BLOCK_SIZE > 0
            && matches!(self.mode, Mode::BlockDownload | Mode::BlockDownloadEnd);
        let segment = ccs == 0 || ccs == 3 || block;
        let (abort_index, abort_sub) = if segment && self.mode != Mode::Idle {
            (self.index, self.sub)
        } else {
            (index, sub)
        };
        let result = match ccs {
            // An abort from the client ends the transfer without an answer (0x80 is never
            // a sub-block's segment: their sequence numbers start at 1).
            4 if cmd == 0x80 || !block => {
                self.reset();
                return None;
            }
            // Within a sub-block every frame is a segment, whatever its first byte.
            _ if block && self.mode == Mode::BlockDownload => match self.block_segment(req, od) {
                Ok(None) => {
                    self.deadline = now.after_us(self.timeout_us);
                    return None;
                }
                Ok(Some(ack)) => Ok(ack),
                Err(abort) => Err(abort),
            },
            _ if block => self.block_end(cmd, req, od),
            0 | 3 => self.segment(cmd, req, od),
            1 => self.initiate_download(cmd, index, sub, data, od),
            2 => self.initiate_upload(index, sub, od),
            6 if Self::BLOCK_SIZE > 0 && cmd & 0x01 == 0 => {
                self.initiate_block_download(cmd, index, sub, data, od)
            }
            // 5 is block upload, 6 with cs = 1 a block download's end outside one, 7 is
            // undefined.
            _ => Err(SdoAbort::UnknownCommand),
        };
        match result {
            Ok(payload) => {
                // A transfer that goes on has the full timeout again.
                self.deadline = now.after_us(self.timeout_us);
                Some(payload)
            }
            Err(abort) => {
                self.reset();
                warn!(
                    "SDO {=u16:#x}:{=u8} abort {=u32:#x}",
                    abort_index,
                    abort_sub,
                    abort.code()
                );
                Some(abort_payload(abort_index, abort_sub, abort))
            }
        }
    }

    fn initiate_download(
        &mut self,
        cmd: u8,
        index: u16,
        sub: u8,
        data: u32,
        od: &mut impl ObjectAccess,
    ) -> Reply {
        // A new initiate replaces whatever transfer was pending.
        self.reset();
        let expedited = cmd & 0x02 != 0;
        let size_indicated = cmd & 0x01 != 0;
        if expedited {
            let len = if size_indicated {
                4 - usize::from((cmd >> 2) & 0x03)
            } else {
                // 0x22: the client left the size to the object (strings: all 4 bytes).
                od.size_of(index, sub)?.min(4)
            };
            let bytes = data.to_le_bytes();
            od.download(index, sub, bytes.get(..len).unwrap_or(&bytes))?;
        } else {
            let size = size_indicated.then_some(data);
            od.check_download(index, sub, size)?;
            self.begin(Mode::SegmentedDownload, index, sub);
            self.size = size;
        }
        Ok(reply(0x60, index, sub, 0))
    }

    /// A download or upload segment (client command specifier 0 or 3).
    fn segment(&mut self, cmd: u8, req: &[u8; 8], od: &mut impl ObjectAccess) -> Reply {
        let upload = cmd & 0x60 != 0;
        let mode = if upload {
            Mode::SegmentedUpload
        } else {
            Mode::SegmentedDownload
        };
        if self.mode != mode {
            return Err(SdoAbort::UnknownCommand);
        }
        let toggle = cmd & 0x10;
        if (toggle != 0) != self.toggle {
            return Err(SdoAbort::ToggleBit);
        }
        self.toggle = !self.toggle;
        if upload {
            return Ok(self.upload_segment(toggle));
        }
        // Bytes 1..8 carry 7 - n data bytes.
        let used = 7 - usize::from((cmd >> 1) & 0x07);
        let last = cmd & 0x01 != 0;
        if od.streams(self.index, self.sub) {
            let data = req.get(1..1 + used).unwrap_or(&[]);
            od.download_chunk(self.index, self.sub, data, last)?;
            if last {
                self.reset();
            }
            return Ok([0x20 | toggle, 0, 0, 0, 0, 0, 0, 0]);
        }
        let start = usize::from(self.len);
        let end = start + used;
        if end > SDO_BUFFER {
            return Err(SdoAbort::TooLong);
        }
        for (dst, src) in self.buf.iter_mut().skip(start).zip(&req[1..]).take(used) {
            *dst = *src;
        }
        // end <= SDO_BUFFER, checked above.
        self.len = end as u8;
        if last {
            if self.size.is_some_and(|s| s != end as u32) {
                return Err(SdoAbort::LengthMismatch);
            }
            od.download(self.index, self.sub, self.buf.get(..end).unwrap_or(&[]))?;
            self.reset();
        }
        Ok([0x20 | toggle, 0, 0, 0, 0, 0, 0, 0])
    }

    /// A block download's initiate (client command specifier 6, cs = 0): `cmd` bit 2 the
    /// client's CRC support, bit 1 the size in `data`.
    fn initiate_block_download(
        &mut self,
        cmd: u8,
        index: u16,
        sub: u8,
        data: u32,
        od: &mut impl ObjectAccess,
    ) -> Reply {
        self.reset();
        if Self::BLOCK_SIZE == 0 {
            return Err(SdoAbort::UnknownCommand);
        }
        let size = (cmd & 0x02 != 0).then_some(data);
        od.check_download(index, sub, size)?;
        if !od.streams(index, sub) && size.is_some_and(|s| s as usize > BLOCK) {
            // Taken whole into the block buffer: it cannot hold more.
            return Err(SdoAbort::TooLong);
        }
        self.begin(Mode::BlockDownload, index, sub);
        self.size = size;
        self.seq = 0;
        self.last_taken = false;
        self.crc_asked = cmd & 0x04 != 0;
        self.crc = Crc16::new();
        self.block_len = 0;
        self.taken = 0;
        // scs = 5, sc = 1 (the server checks the CRC), ss = 0; byte 4 the sub-block size.
        Ok(reply(0xA4, index, sub, u32::from(Self::BLOCK_SIZE)))
    }

    /// One segment of a sub-block: byte 0 is c (bit 7, the last of the transfer) and the
    /// sequence number (1..=`BLOCK_SIZE`), bytes 1-7 the data. Segments out of sequence
    /// (one before them lost, or a repeat) are ignored; the sub-block ends with the segment
    /// numbered `BLOCK_SIZE` or one with c = 1, and its acknowledgement names the last one
    /// taken in sequence, from which the client sends again. What was taken goes to a
    /// streamed object before the acknowledgement.
    fn block_segment(
        &mut self,
        req: &[u8; 8],
        od: &mut impl ObjectAccess,
    ) -> Result<Option<[u8; 8]>, SdoAbort> {
        let seqno = req[0] & 0x7F;
        let last = req[0] & 0x80 != 0;
        if seqno == 0 || seqno > Self::BLOCK_SIZE {
            return Err(SdoAbort::InvalidSequence);
        }
        if seqno == self.seq + 1 && !self.last_taken {
            let start = usize::from(self.block_len);
            let dst = self
                .block
                .get_mut(start..start + 7)
                .ok_or(SdoAbort::TooLong)?;
            dst.copy_from_slice(&req[1..]);
            // start + 7 <= BLOCK <= u16::MAX here (checked by the slice above and the
            // block size); the transfer's length is checked against its size at the end.
            self.block_len += 7;
            self.taken = self.taken.wrapping_add(7);
            self.seq = seqno;
            self.last_taken = last;
        }
        if seqno < Self::BLOCK_SIZE && !last {
            return Ok(None);
        }
        if od.streams(self.index, self.sub) {
            // The last segment waits for the end request, which says how much of it is data.
            let held = if self.last_taken { 7 } else { 0 };
            let len = usize::from(self.block_len) - held;
            let data = self.block.get(..len).unwrap_or(&[]);
            if !data.is_empty() {
                self.crc = self.crc.update(data);
                od.download_chunk(self.index, self.sub, data, false)?;
            }
            // The held segment to the front, where the next sub-block would start (byte by
            // byte: `copy_within` would bring in a general `memmove`).
            for i in 0..held {
                let byte = self.block.get(len + i).copied().unwrap_or(0);
                if let Some(dst) = self.block.get_mut(i) {
                    *dst = byte;
                }
            }
            self.block_len = held as u16;
        }
        let ackseq = self.seq;
        self.seq = 0;
        if self.last_taken {
            self.mode = Mode::BlockDownloadEnd;
        }
        Ok(Some([0xA2, ackseq, Self::BLOCK_SIZE, 0, 0, 0, 0, 0]))
    }

    /// The end request (ccs = 6, cs = 1): `n`, the bytes of the last segment that carry no
    /// data, in bits 2-4, the CRC in bytes 1-2. The length and the CRC are checked before
    /// the object gets the rest.
    fn block_end(&mut self, cmd: u8, req: &[u8; 8], od: &mut impl ObjectAccess) -> Reply {
        if cmd & 0xE3 != 0xC1 {
            return Err(SdoAbort::UnknownCommand);
        }
        let unused = (cmd >> 2) & 0x07;
        let len = usize::from(self.block_len)
            .checked_sub(usize::from(unused))
            .ok_or(SdoAbort::LengthMismatch)?;
        let total = self.taken.wrapping_sub(u32::from(unused));
        if self.size.is_some_and(|s| s != total) {
            return Err(SdoAbort::LengthMismatch);
        }
        let data = self.block.get(..len).unwrap_or(&[]);
        let crc = self.crc.update(data).finish();
        if self.crc_asked && crc != u16::from_le_bytes([req[1], req[2]]) {
            return Err(SdoAbort::CrcError);
        }
        if od.streams(self.index, self.sub) {
            od.download_chunk(self.index, self.sub, data, true)?;
        } else {
            od.download(self.index, self.sub, data)?;
        }
        self.reset();
        Ok([0xA1, 0, 0, 0, 0, 0, 0, 0])
    }

    fn initiate_upload(&mut self, index: u16, sub: u8, od: &mut impl ObjectAccess) -> Reply {
        self.reset();
        let len = od.upload(index, sub, &mut self.buf)?.min(SDO_BUFFER);
        if (1..=4).contains(&len) {
            // Only the value's bytes: the rest of the buffer may hold an older transfer.
            let [b0, b1, b2, b3, ..] = self.buf;
            let data = u32::from_le_bytes([b0, b1, b2, b3]) & (u32::MAX >> (32 - 8 * len));
            // e = 1, s = 1, n = number of unused bytes.
            let cmd = 0x43 | (((4 - len) as u8) << 2);
            return Ok(reply(cmd, index, sub, data));
        }
        // Longer (or empty) values go segmented with the size indicated.
        self.begin(Mode::SegmentedUpload, index, sub);
        self.len = len as u8;
        Ok(reply(0x41, index, sub, len as u32))
    }

    /// The next upload segment; `toggle` is the (checked) toggle bit of the request.
    fn upload_segment(&mut self, toggle: u8) -> [u8; 8] {
        let sent = usize::from(self.sent);
        let rest = usize::from(self.len).saturating_sub(sent);
        let n = rest.min(7);
        let last = rest <= 7;
        let mut out = [0u8; 8];
        for (dst, src) in out
            .iter_mut()
            .skip(1)
            .zip(self.buf.iter().skip(sent))
            .take(n)
        {
            *dst = *src;
        }
        out[0] = toggle | (((7 - n) as u8) << 1) | u8::from(last);
        // n <= 7 and sent + n <= len <= SDO_BUFFER: no overflow.
        self.sent += n as u8;
        if last {
            self.reset();
        }
        out
    }
}
