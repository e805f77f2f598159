//! The blob 0x1010 stores: magic, version, section flags, application length, the
//! communication section (every stored engine parameter, [`STORED`], as a little-endian U32),
//! the application section, CRC-16/CCITT of everything before it. A blob that fails any
//! check reads as empty.

use super::super::{STORED, STORED_LEN};
use crate::storage::{crc16, MemoryStorage, Storage, StorageError};
use crate::time::Instant;

/// Largest application section (see `Application::save_application`).
pub const APP_MAX: usize = 32;

const MAGIC: u8 = 0xC0;
/// Bumped whenever [`STORED`] (the communication objects' `stored` sub-indices) or the
/// layout changes, so that old blobs read as empty.
const VERSION: u8 = 1;
/// Section flags.
pub(crate) const COMM: u8 = 1 << 0;
pub(crate) const APP: u8 = 1 << 1;
const HEADER: usize = 4;

const COMM_BYTES: usize = STORED_LEN * 4;
const APP_OFFSET: usize = HEADER + COMM_BYTES;
/// Largest blob the engine writes; a [`Storage`] must hold at least this much.
pub const BLOB_MAX: usize = APP_OFFSET + APP_MAX + 2;

// Every blob fits the RAM storage.
const _: () = assert!(BLOB_MAX <= MemoryStorage::CAPACITY);

/// A blob being read or edited in RAM.
pub(crate) struct Blob {
    buf: [u8; BLOB_MAX],
    sections: u8,
    app_len: usize,
}

impl Blob {
    /// Loads and checks the stored blob; anything invalid reads as empty.
    pub(crate) fn load(storage: &mut (impl Storage + ?Sized)) -> Self {
        let mut blob = Self {
            buf: [0; BLOB_MAX],
            sections: 0,
            app_len: 0,
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
        let body = APP_OFFSET + app_len;
        if magic != MAGIC || version != VERSION || app_len > APP_MAX || n != body + 2 {
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
        true
    }

    /// The communication section as (index, sub, value) triples, if stored.
    pub(crate) fn comm(&self) -> Option<impl Iterator<Item = (u16, u8, u32)> + '_> {
        let bytes = self.buf.get(HEADER..APP_OFFSET)?;
        (self.sections & COMM != 0).then(|| {
            STORED
                .iter()
                .zip(bytes.chunks_exact(4))
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
    pub(crate) fn set_comm(&mut self, mut value: impl FnMut(u16, u8) -> u32) {
        if let Some(bytes) = self.buf.get_mut(HEADER..APP_OFFSET) {
            for (&(i, s), dst) in STORED.iter().zip(bytes.chunks_exact_mut(4)) {
                for (d, b) in dst.iter_mut().zip(value(i, s).to_le_bytes()) {
                    *d = b;
                }
            }
            self.sections |= COMM;
        }
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
        let body = APP_OFFSET + self.app_len;
        // app_len <= APP_MAX was enforced when it was set.
        let header = [MAGIC, VERSION, self.sections, self.app_len as u8];
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
        // The layout of blob VERSION 1.
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
        assert_eq!(STORED[..], v1[..], "a new layout needs a new VERSION");
    }

    #[test]
    fn blob_round_trip() {
        let mut storage = MemoryStorage::new();
        let mut blob = Blob::load(&mut storage);
        assert!(blob.comm().is_none() && blob.app().is_none());
        blob.set_comm(|index, sub| u32::from(index) << 8 | u32::from(sub));
        blob.set_app(|buf| {
            buf[..3].copy_from_slice(b"abc");
            3
        });
        blob.store(Instant::ZERO, &mut storage).unwrap();
        assert_eq!(storage.bytes().len(), APP_OFFSET + 3 + 2);
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
