//! A PDO's mapping parameter (0x1600+n, 0x1A00+n): up to eight entries
//! `index << 16 | sub << 8 | bits` and their count, with CiA 301's re-mapping procedure.
//! Shared by both directions; what may be mapped is the direction's own check.

use crate::abort::SdoAbort;
use crate::od::Od;

/// Most objects one PDO maps.
pub const MAX_MAPPED: usize = 8;

/// A mapping entry split into (index, sub-index, length in bits).
pub(crate) const fn split_mapping(entry: u32) -> (u16, u8, u8) {
    ((entry >> 16) as u16, (entry >> 8) as u8, entry as u8)
}

/// Checks that an entry may be mapped in the PDO's direction; returns its size in bytes.
pub(crate) type CheckEntry = fn(&Od, u32) -> Result<usize, SdoAbort>;

/// The mapping of one PDO.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub(crate) struct PdoMapping {
    mapped: u8,
    entries: [u32; MAX_MAPPED],
}

impl PdoMapping {
    pub(crate) const fn new() -> Self {
        Self {
            mapped: 0,
            entries: [0; MAX_MAPPED],
        }
    }

    /// The active entries.
    pub(crate) fn entries(&self) -> &[u32] {
        self.entries
            .get(..usize::from(self.mapped))
            .unwrap_or(&self.entries)
    }

    /// Whether anything is mapped.
    pub(crate) fn any(&self) -> bool {
        self.mapped != 0
    }

    /// Reads sub-index `sub`: the count, or an entry.
    pub(crate) fn read(&self, sub: u8) -> Result<u32, SdoAbort> {
        if sub == 0 {
            return Ok(self.mapped.into());
        }
        usize::from(sub)
            .checked_sub(1)
            .and_then(|i| self.entries.get(i))
            .copied()
            .ok_or(SdoAbort::NoSubIndex)
    }

    /// Checked write, enforcing the CiA 301 re-mapping procedure: PDO invalid (`valid`
    /// false), sub 0 = 0, entries, sub 0 = n. Sub 0 = n checks the first n entries with
    /// `check` and their total against the 8 bytes of a frame. Refusals answer as
    /// CANopenNode does (and the CiA conformance test accepts): any sub-index while the PDO
    /// is valid, or an entry while sub 0 is not 0, 0x06010000; a count above the entries
    /// or whose entries exceed 64 bits, 0x06040042.
    pub(crate) fn write(
        &mut self,
        sub: u8,
        v: u32,
        valid: bool,
        od: &Od,
        check: CheckEntry,
    ) -> Result<(), SdoAbort> {
        if valid {
            return Err(SdoAbort::UnsupportedAccess);
        }
        if sub == 0 {
            let n = usize::try_from(v).map_err(|_| SdoAbort::PdoTooLong)?;
            let entries = self.entries.get(..n).ok_or(SdoAbort::PdoTooLong)?;
            let mut bytes = 0;
            for &entry in entries {
                bytes += check(od, entry)?;
            }
            if bytes > 8 {
                return Err(SdoAbort::PdoTooLong);
            }
        } else {
            if self.mapped != 0 {
                return Err(SdoAbort::UnsupportedAccess);
            }
            if usize::from(sub) > MAX_MAPPED {
                return Err(SdoAbort::NoSubIndex);
            }
            // 0 clears an entry; anything else must name a mappable object.
            if v != 0 {
                check(od, v)?;
            }
        }
        self.set(sub, v);
        Ok(())
    }

    /// Unchecked write (defaults, stored parameters).
    pub(crate) fn set(&mut self, sub: u8, v: u32) {
        if sub == 0 {
            // Clamped so that a corrupt stored value can never index past the array.
            self.mapped = (v.min(MAX_MAPPED as u32)) as u8;
        } else if let Some(m) = usize::from(sub)
            .checked_sub(1)
            .and_then(|i| self.entries.get_mut(i))
        {
            *m = v;
        }
    }
}
