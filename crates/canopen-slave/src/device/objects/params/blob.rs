//! The blob 0x1010 stores: magic, version, section flags, application length, the
//! communication section (the stored engine parameters of version 1, the first
//! [`STORED_V1_LEN`] of [`STORED`], each a little-endian U32), the application section, the
//! parameters added by version 2 (the rest of [`STORED`]: the RPDO's), CRC-16/CCITT of
//! everything before it. A blob that fails any check reads as empty.
//!
//! Version 2 appends, so that every byte of a version 1 blob keeps its offset: a blob stored
//! by firmware before the RPDO restores all it holds, the RPDO taking its defaults. It stays
//! a version 1 blob until the communication parameters are saved again (saving or removing
//! only the application section keeps the layout), and a save writes version 2 only when
//! an RPDO parameter differs from its default ([`Blob::set_comm`]).

use super::super::{STORED, STORED_LEN, STORED_V1_LEN};
use crate::storage::{crc16, MemoryStorage, Storage, StorageError};
use crate::time::Instant;

/// Largest application section (see `Application::save_application`).
pub const APP_MAX: usize = 32;

const MAGIC: u8 = 0xC0;
/// Bumped whenever [`STORED`] (the communication objects' `stored` sub-indices) or the
/// layout changes; a layout that only appends can still read the older blobs (see above),
/// others read them as empty.
const VERSION: u8 = 2;
/// The layout before the RPDO: no parameters after the application section.
const VERSION_1: u8 = 1;
/// Section flags.
pub(crate) const COMM: u8 = 1 << 0;
pub(crate) const APP: u8 = 1 << 1;
const HEADER: usize = 4;

const COMM_BYTES: usize = STORED_V1_LEN * 4;
const APP_OFFSET: usize = HEADER + COMM_BYTES;
/// The parameters version 2 added, after the application section.
const ADDED_BYTES: usize = (STORED_LEN - STORED_V1_LEN) * 4;
/// Largest blob the engine writes; a [`Storage`] must hold at least this much.
pub const BLOB_MAX: usize = APP_OFFSET + APP_MAX + ADDED_BYTES + 2;

// Every blob fits the RAM storage.
const _: () = assert!(BLOB_MAX <= MemoryStorage::CAPACITY);

/// A blob being read or edited in RAM.
pub(crate) struct Blob {
    buf: [u8; BLOB_MAX],
    sections: u8,
    app_len: usize,
    /// The parameters version 2 added; `None` in a version 1 blob.
    added: Option<[u8; ADDED_BYTES]>,
}

impl Blob {
    /// Loads and checks the stored blob; anything invalid reads as empty.
    pub(crate) fn load(storage: &mut (impl Storage + ?Sized)) -> Self {
        let mut blob = Self {
            buf: [0; BLOB_MAX],
            sections: 0,
            app_len: 0,
            added: None,
        };
        let n = storage.load(&mut blob.buf).min(BLOB_MAX);
        if !blob.validate(n) {
            blob.buf = [0; BLOB_MAX];
        }
        blob
    }

    fn validate(&mut self, n: usize) -> bool {
        let [magic, version, sections, app_len, ..] = self.buf;
        let app_len = usize::from(app_len);
        let added_len = match version {
            VERSION => ADDED_BYTES,
            VERSION_1 => 0,
            _ => return false,
        };
        let added_at = APP_OFFSET + app_len;
        let body = added_at + added_len;
        if magic != MAGIC || app_len > APP_MAX || n != body + 2 {
            return false;
        }
        let (Some(data), Some(&[c0, c1])) = (self.buf.get(..body), self.buf.get(body..n)) else {
            return false;
        };
        if crc16(data) != u16::from_le_bytes([c0, c1]) {
            return false;
        }
        self.sections = sections & (COMM | APP);
        self.app_len = app_len;
        if version == VERSION {
            let added = self.buf.get(added_at..body).and_then(|a| a.try_into().ok());
            self.added = Some(added.unwrap_or([0; ADDED_BYTES]));
        }
        true
    }

    /// The communication section as (index, sub, value) triples, if stored: all of
    /// [`STORED`], or its first [`STORED_V1_LEN`] from a version 1 blob.
    pub(crate) fn comm(&self) -> Option<impl Iterator<Item = (u16, u8, u32)> + '_> {
        let bytes = self.buf.get(HEADER..APP_OFFSET)?;
        let added = self.added.as_ref().map_or(&[][..], |a| &a[..]);
        (self.sections & COMM != 0).then(|| {
            STORED
                .iter()
                .zip(bytes.chunks_exact(4).chain(added.chunks_exact(4)))
                .map(|(&(i, s), v)| {
                    let raw = <[u8; 4]>::try_from(v).unwrap_or_default();
                    (i, s, u32::from_le_bytes(raw))
                })
        })
    }

    /// The application section, if stored.
    pub(crate) fn app(&self) -> Option<&[u8]> {
        let bytes = self.buf.get(APP_OFFSET..APP_OFFSET + self.app_len)?;
        (self.sections & APP != 0).then_some(bytes)
    }

    /// Replaces the communication section with the values `value` gives for [`STORED`].
    /// The parameters version 2 added are kept only when one differs from its `default`:
    /// a device that leaves them alone keeps version 1's layout and size (the handwheel's
    /// parameter page holds six such records per erase), and restores them as defaults all
    /// the same.
    pub(crate) fn set_comm(
        &mut self,
        mut value: impl FnMut(u16, u8) -> u32,
        mut default: impl FnMut(u16, u8) -> Option<u32>,
    ) {
        let mut added = [0; ADDED_BYTES];
        let mut changed = false;
        if let Some(bytes) = self.buf.get_mut(HEADER..APP_OFFSET) {
            let slots = bytes.chunks_exact_mut(4).chain(added.chunks_exact_mut(4));
            for (k, (&(i, s), dst)) in STORED.iter().zip(slots).enumerate() {
                let v = value(i, s);
                changed |= k >= STORED_V1_LEN && default(i, s) != Some(v);
                for (d, b) in dst.iter_mut().zip(v.to_le_bytes()) {
                    *d = b;
                }
            }
            self.sections |= COMM;
        }
        self.added = changed.then_some(added);
    }

    /// Replaces the application section with what `save` writes (it returns the length).
    pub(crate) fn set_app(&mut self, save: impl FnOnce(&mut [u8]) -> usize) {
        if let Some(bytes) = self.buf.get_mut(APP_OFFSET..APP_OFFSET + APP_MAX) {
            self.app_len = save(bytes).min(APP_MAX);
            self.sections |= APP;
        }
    }

    /// Forgets sections (restore defaults).
    pub(crate) fn remove(&mut self, sections: u8) {
        self.sections &= !sections;
        if self.sections & APP == 0 {
            self.app_len = 0;
        }
        if self.sections & COMM == 0 {
            self.added = None;
        }
    }

    /// Writes the blob back, or erases the storage when no section is left.
    pub(crate) fn store(
        &mut self,
        now: Instant,
        storage: &mut (impl Storage + ?Sized),
    ) -> Result<(), StorageError> {
        if self.sections == 0 {
            return storage.store(now, &[]);
        }
        let added_at = APP_OFFSET + self.app_len;
        let (version, body) = match &self.added {
            Some(added) => {
                if let Some(dst) = self.buf.get_mut(added_at..added_at + ADDED_BYTES) {
                    dst.copy_from_slice(added);
                }
                (VERSION, added_at + ADDED_BYTES)
            }
            None => (VERSION_1, added_at),
        };
        // app_len <= APP_MAX was enforced when it was set.
        let header = [MAGIC, version, self.sections, self.app_len as u8];
        if let Some(h) = self.buf.get_mut(..HEADER) {
            h.copy_from_slice(&header);
        }
        let crc = self.buf.get(..body).map(crc16).unwrap_or(0);
        let end = body + 2;
        let tail = self
            .buf
            .get_mut(body..end)
            .ok_or(StorageError::WriteFailed)?;
        tail.copy_from_slice(&crc.to_le_bytes());
        storage.store(now, self.buf.get(..end).unwrap_or(&[]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::storage::MemoryStorage;

    #[test]
    fn stored_list_covers_each_parameter_once() {
        for (i, a) in STORED.iter().enumerate() {
            assert!(STORED.iter().skip(i + 1).all(|b| b != a), "{a:?}");
        }
        // The layout of blob version 1, then what version 2 appends.
        let mut v1: heapless::Vec<(u16, u8), 64> = heapless::Vec::new();
        let head = [0x1005, 0x1014, 0x1015].map(|index| (index, 0));
        v1.extend(
            head.into_iter()
                .chain([(0x1016, 1), (0x1016, 2), (0x1017, 0)]),
        );
        for n in 0..2 {
            v1.extend([1, 2, 3, 5].map(|sub| (0x1800 + n, sub)));
            v1.extend((0..=8).map(|sub| (0x1A00 + n, sub)));
        }
        assert_eq!(STORED_V1_LEN, v1.len());
        v1.extend([1, 2, 5].map(|sub| (0x1400, sub)));
        v1.extend((0..=8).map(|sub| (0x1600, sub)));
        assert_eq!(STORED[..], v1[..], "a new layout needs a new VERSION");
    }

    #[test]
    fn blob_round_trip() {
        let mut storage = MemoryStorage::new();
        let mut blob = Blob::load(&mut storage);
        assert!(blob.comm().is_none() && blob.app().is_none());
        // All at their defaults: version 1's layout.
        blob.set_comm(|_, _| 7, |_, _| Some(7));
        blob.store(Instant::ZERO, &mut storage).unwrap();
        assert_eq!(storage.bytes().len(), APP_OFFSET + 2);
        assert_eq!(storage.bytes()[1], VERSION_1);
        let mut blob = Blob::load(&mut storage);
        assert_eq!(blob.comm().unwrap().count(), STORED_V1_LEN);
        blob.set_comm(
            |index, sub| u32::from(index) << 8 | u32::from(sub),
            |_, _| None,
        );
        blob.set_app(|buf| {
            buf[..3].copy_from_slice(b"abc");
            3
        });
        blob.store(Instant::ZERO, &mut storage).unwrap();
        assert_eq!(storage.bytes().len(), APP_OFFSET + 3 + ADDED_BYTES + 2);
        assert_eq!(storage.bytes()[1], VERSION);
        let blob = Blob::load(&mut storage);
        assert_eq!(blob.app(), Some(&b"abc"[..]));
        let comm: heapless::Vec<(u16, u8, u32), 64> = blob.comm().unwrap().collect();
        assert_eq!(comm.len(), STORED_LEN);
        assert!(comm
            .iter()
            .all(|&(i, s, v)| v == u32::from(i) << 8 | u32::from(s)));
        // An application claiming more than APP_MAX bytes is clamped.
        let mut blob = Blob::load(&mut storage);
        blob.set_app(|_| 1000);
        blob.store(Instant::ZERO, &mut storage).unwrap();
        assert_eq!(
            Blob::load(&mut storage).app().map(<[u8]>::len),
            Some(APP_MAX)
        );
    }
}
