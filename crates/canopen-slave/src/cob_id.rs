//! The COB-ID rules of the objects that name an identifier (SYNC, EMCY, PDOs, the second
//! SDO server): the bits this device supports and the identifiers CiA 301 reserves.

use crate::abort::SdoAbort;
use crate::frame::MAX_STANDARD_ID;

/// COB-ID bit 31: the object (PDO, EMCY) does not exist / is not valid.
pub(crate) const COB_INVALID: u32 = 1 << 31;
/// COB-ID bit 29: 29-bit identifier (CAN 2.0B), which this device does not support.
pub(crate) const COB_EXTENDED: u32 = 1 << 29;

/// COB-IDs that CiA 301 reserves for NMT, SYNC/EMCY of others, SDO, heartbeat and LSS;
/// configuring a PDO or EMCY onto one of them would break the network.
pub(crate) const fn is_restricted(can_id: u32) -> bool {
    matches!(
        can_id,
        0x000..=0x07F | 0x101..=0x180 | 0x581..=0x5FF | 0x601..=0x67F | 0x6E0..=0x6FF | 0x701..=0x7FF
    )
}

/// Validation of a write to a PDO, EMCY or SDO server COB-ID (CiA 301 7.5.2.35 / 7.5.2.36,
/// and the SDO server parameter's; bit 30 of an SDO COB-ID, "dynamic", is kept as
/// written).
pub(crate) fn check_cob_id_write(old: u32, new: u32) -> Result<(), SdoAbort> {
    // Bits 28..11 belong to 29-bit identifiers only.
    if new & COB_EXTENDED != 0 || new & 0x1FFF_F800 != 0 {
        return Err(SdoAbort::InvalidValue);
    }
    let valid = |v: u32| v & COB_INVALID == 0;
    let can_id = |v: u32| v & u32::from(MAX_STANDARD_ID);
    // The CAN-ID may only change while the object is invalid: a master must first destroy it.
    if valid(old) && valid(new) && can_id(old) != can_id(new) {
        return Err(SdoAbort::InvalidValue);
    }
    if valid(new) && is_restricted(can_id(new)) {
        return Err(SdoAbort::InvalidValue);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cob_id_rules() {
        assert_eq!(check_cob_id_write(0x185, 0x185), Ok(()));
        assert_eq!(
            check_cob_id_write(0x185, 0x186),
            Err(SdoAbort::InvalidValue)
        );
        assert_eq!(check_cob_id_write(0x8000_0185, 0x186), Ok(()));
        assert_eq!(check_cob_id_write(0x185, 0x8000_0186), Ok(()));
        assert_eq!(
            check_cob_id_write(0x8000_0185, 0x2000_0185),
            Err(SdoAbort::InvalidValue)
        );
        assert_eq!(
            check_cob_id_write(0x8000_0185, 0x0000_0800),
            Err(SdoAbort::InvalidValue)
        );
        for restricted in [
            0x000, 0x07F, 0x101, 0x180, 0x581, 0x601, 0x6E0, 0x701, 0x7FF,
        ] {
            assert_eq!(
                check_cob_id_write(COB_INVALID, restricted),
                Err(SdoAbort::InvalidValue),
                "{restricted:#x}"
            );
        }
        assert_eq!(check_cob_id_write(COB_INVALID, 0x181), Ok(()));
    }
}
