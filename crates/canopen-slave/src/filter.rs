//! The identifiers the device listens to, for the CAN controller's acceptance filter.
//!
//! Which frames the engine wants depends on configuration a master can change (0x1005 moves
//! SYNC, 0x1201 opens a second SDO server, 0x1400 moves or disables RPDO1) and on the node-ID,
//! so the filter is derived from the engine, not written into the
//! driver: the firmware compares [`Device::rx_filter`](crate::Device::rx_filter) after each
//! round and reprograms the controller when it changed.

use crate::frame::{cob, NodeId, MAX_STANDARD_ID};
use crate::lss::LSS_REQUEST;

/// The set of identifiers the engine handles; every other frame may be dropped in hardware.
///
/// NMT (0x000), SYNC (0x1005, 0x080 by default), this node's SDO requests (0x600 + node-ID,
/// and 0x1201:1 while the second SDO server is valid), RPDO1 (0x1400:1 while it is valid
/// and maps something), every heartbeat 0x700..=0x77F (the
/// consumer picks its producers itself, so a change of 0x1016 needs no new filter) and LSS
/// requests (0x7E5). An unconfigured node ([`RxFilter::unconfigured`]) has no SYNC and no
/// SDO: NMT, heartbeats and LSS only.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RxFilter {
    sync: u16,
    sdo_request: u16,
    second_sdo_request: u16,
    rpdo: u16,
}

impl RxFilter {
    /// The filter of a node at its defaults: SYNC on 0x080.
    pub const fn new(node: NodeId) -> Self {
        Self::with_sync(node, cob::SYNC)
    }

    /// The filter of an unconfigured node (CiA 305 node-ID 0xFF). Its [`RxFilter::sync`],
    /// [`RxFilter::sdo_request`] and [`RxFilter::rpdo`] repeat identifiers that are in the filter anyway (NMT and
    /// LSS), so that a port can program the same four list entries in every case.
    pub const fn unconfigured() -> Self {
        Self {
            sync: cob::NMT,
            sdo_request: LSS_REQUEST,
            second_sdo_request: LSS_REQUEST,
            rpdo: LSS_REQUEST,
        }
    }

    /// The filter of a node whose SYNC is on `sync` (11 bits; higher bits are ignored).
    pub const fn with_sync(node: NodeId, sync: u16) -> Self {
        let sdo_request = node.cob_id(cob::SDO_RX);
        Self {
            sync: sync & MAX_STANDARD_ID,
            sdo_request,
            second_sdo_request: sdo_request,
            rpdo: sdo_request,
        }
    }

    /// This filter with the second SDO server's request identifier (0x1201:1, 11 bits;
    /// higher bits are ignored), or without one (`None`: the server is not valid).
    pub const fn with_second_sdo(self, request: Option<u16>) -> Self {
        Self {
            second_sdo_request: match request {
                Some(id) => id & MAX_STANDARD_ID,
                None => self.sdo_request,
            },
            ..self
        }
    }

    /// This filter with RPDO1's identifier (0x1400:1, 11 bits; higher bits are ignored), or
    /// without (`None`: the RPDO is not received).
    pub const fn with_rpdo(self, rpdo: Option<u16>) -> Self {
        Self {
            rpdo: match rpdo {
                Some(id) => id & MAX_STANDARD_ID,
                None => self.sdo_request,
            },
            ..self
        }
    }

    /// RPDO1's identifier while it is received; otherwise a repeat of
    /// [`RxFilter::sdo_request`], so that a port can program the same list entries in every
    /// case.
    pub const fn rpdo(&self) -> u16 {
        self.rpdo
    }

    /// The SYNC identifier.
    pub const fn sync(&self) -> u16 {
        self.sync
    }

    /// This node's SDO request identifier.
    pub const fn sdo_request(&self) -> u16 {
        self.sdo_request
    }

    /// The second SDO server's request identifier (0x1201:1) while that server is valid;
    /// otherwise a repeat of [`RxFilter::sdo_request`], so that a port can program the same
    /// list entries in every case.
    pub const fn second_sdo_request(&self) -> u16 {
        self.second_sdo_request
    }

    /// The NMT identifier (always 0x000).
    pub const fn nmt(&self) -> u16 {
        cob::NMT
    }

    /// The LSS request identifier (always 0x7E5).
    pub const fn lss(&self) -> u16 {
        LSS_REQUEST
    }

    /// Base and mask of the heartbeat range: `id & mask == base` for 0x700..=0x77F.
    pub const fn heartbeats(&self) -> (u16, u16) {
        (cob::HEARTBEAT, 0x780)
    }

    /// Whether a data frame with identifier `id` is one the engine handles.
    pub const fn accepts(&self, id: u16) -> bool {
        let (base, mask) = self.heartbeats();
        id == self.nmt()
            || id == self.sync
            || id == self.sdo_request
            || id == self.second_sdo_request
            || id == self.rpdo
            || id == LSS_REQUEST
            || id & mask == base
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_filter_is_the_predefined_connection_set() {
        let f = RxFilter::new(NodeId::new(16).unwrap());
        for id in 0..=MAX_STANDARD_ID {
            let expected = matches!(id, 0x000 | 0x080 | 0x610 | 0x700..=0x77F | 0x7E5);
            assert_eq!(f.accepts(id), expected, "{id:#05x}");
        }
    }

    #[test]
    fn moved_sync_replaces_the_default() {
        let f = RxFilter::with_sync(NodeId::new(1).unwrap(), 0x081);
        assert!(f.accepts(0x081));
        assert!(!f.accepts(0x080));
        assert_eq!((f.sync(), f.sdo_request()), (0x081, 0x601));
    }

    #[test]
    fn a_second_sdo_server_adds_its_request_identifier() {
        let node = NodeId::new(16).unwrap();
        let f = RxFilter::new(node).with_second_sdo(Some(0x690));
        for id in 0..=MAX_STANDARD_ID {
            let expected = matches!(id, 0x000 | 0x080 | 0x610 | 0x690 | 0x700..=0x77F | 0x7E5);
            assert_eq!(f.accepts(id), expected, "{id:#05x}");
        }
        assert_eq!(f.second_sdo_request(), 0x690);
        let none = f.with_second_sdo(None);
        assert_eq!(none, RxFilter::new(node));
        assert_eq!(none.second_sdo_request(), 0x610);
    }

    #[test]
    fn a_received_rpdo_adds_its_identifier() {
        let node = NodeId::new(16).unwrap();
        let f = RxFilter::new(node).with_rpdo(Some(0x210));
        for id in 0..=MAX_STANDARD_ID {
            let expected = matches!(id, 0x000 | 0x080 | 0x210 | 0x610 | 0x700..=0x77F | 0x7E5);
            assert_eq!(f.accepts(id), expected, "{id:#05x}");
        }
        assert_eq!(f.rpdo(), 0x210);
        let none = f.with_rpdo(None);
        assert_eq!(none, RxFilter::new(node));
        assert_eq!(none.rpdo(), 0x610);
    }

    #[test]
    fn unconfigured_node_hears_nmt_heartbeats_and_lss_only() {
        let f = RxFilter::unconfigured();
        for id in 0..=MAX_STANDARD_ID {
            let expected = matches!(id, 0x000 | 0x700..=0x77F | 0x7E5);
            assert_eq!(f.accepts(id), expected, "{id:#05x}");
        }
    }
}
