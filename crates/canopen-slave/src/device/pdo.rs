//! The PDO services. RPDO: reception in Operational, the length check, the checked writes
//! of the mapped objects (at once, or at the next SYNC), deadline monitoring, and their
//! EMCYs. TPDO: application requests, SYNC, event timers and inhibit times, and the building
//! of a PDO from its mapping.

use super::{Application, Device, Inner, NoSuchPdo};
use crate::abort::SdoAbort;
use crate::emcy::{code, register};
use crate::frame::{Frame, FrameSink};
use crate::nmt::NmtState;
use crate::od::{Od, OdEntry};
use crate::rpdo::{check_rpdo_mapping, RPDOS};
use crate::storage::Storage;
use crate::time::Instant;
use crate::tpdo::{self, Tpdo, TPDOS};

/// Why an RPDO frame was not (wholly) processed: an EMCY code and its manufacturer bytes.
type RpdoFault = (u16, [u8; 5]);

/// Calls `each` with every object RPDO data `data` writes and its bytes, in mapping order
/// (dummy entries skipped). A mapping that no longer checks (a default naming an object the
/// dictionary lacks: stored and SDO-written mappings were checked) refuses the frame.
fn each_mapped(
    od: &Od,
    mapping: &[u32],
    data: &[u8; 8],
    mut each: impl FnMut(&'static OdEntry, &[u8]) -> Result<(), SdoAbort>,
) -> Result<(), (u32, SdoAbort)> {
    let mut at = 0;
    for &entry in mapping {
        let (target, size) = check_rpdo_mapping(od, entry).map_err(|a| (entry, a))?;
        let bytes = data
            .get(at..at + size)
            .ok_or((entry, SdoAbort::PdoTooLong))?;
        if let Some(e) = target {
            each(e, bytes).map_err(|a| (entry, a))?;
        }
        at += size;
    }
    Ok(())
}

/// The bytes an RPDO's mapping takes; `None` if an entry no longer checks.
fn mapped_len(od: &Od, mapping: &[u32]) -> Option<usize> {
    mapping
        .iter()
        .try_fold(0, |len, &e| Some(len + check_rpdo_mapping(od, e).ok()?.1))
}

impl<S: Storage> Device<S> {
    /// Mapped data of TPDO `pdo` (1-based) changed: an event-driven PDO goes out at the next
    /// `poll` the inhibit time allows, a type-0 PDO at the next SYNC. Ignored outside
    /// Operational and for cyclic types.
    pub fn request_tpdo(&mut self, pdo: u8) -> Result<(), NoSuchPdo> {
        let comm = &mut self.inner.comm;
        let operational = comm.state == NmtState::Operational;
        let t = usize::from(pdo)
            .checked_sub(1)
            .and_then(|i| comm.tpdos.get_mut(i))
            .ok_or(NoSuchPdo)?;
        if operational {
            t.request();
        }
        Ok(())
    }
}

impl<S: Storage> Inner<S> {
    /// The RPDO (0-based) received on `id`, if any.
    pub(super) fn rpdo_on(&self, id: u16) -> Option<usize> {
        self.comm
            .rpdos
            .iter()
            .position(|r| r.active() && r.can_id() == id)
    }

    /// A data frame on RPDO `i`'s identifier. Ignored outside Operational (CiA 301). Shorter
    /// than the mapping: not processed, EMCY 0x8210. Otherwise it restarts deadline
    /// monitoring; longer: processed, EMCY 0x8220. Its data is written at once, or held for
    /// the next SYNC (types 0..=240). The EMCYs are conditions, as CANopenNode raises them:
    /// raised by the first bad frame, cleared by the next good one, so that a stream of
    /// bad frames is one EMCY, not one per frame.
    pub(super) fn on_rpdo(
        &mut self,
        now: Instant,
        i: usize,
        frame: &Frame,
        app: &mut dyn Application,
    ) {
        if self.comm.state != NmtState::Operational {
            return;
        }
        let od = self.comm.od;
        let Some(r) = self.comm.rpdos.get_mut(i) else {
            return;
        };
        // A mapping that does not check is refused with its entry when written.
        let expected = mapped_len(&od, r.mapping()).unwrap_or(0);
        let dlc = frame.dlc();
        // i < RPDOS, so the PDO number fits a u8; the length is at most 8 (the mapping's
        // check).
        let pdo = i as u8 + 1;
        let length = [pdo, expected as u8, dlc, 0, 0];
        if usize::from(dlc) < expected {
            self.rpdo_errors = self.rpdo_errors.saturating_add(1);
            self.set_rpdo_fault(i, Some((code::RPDO_SHORT, length)));
            return;
        }
        r.received(now);
        let timed_out = core::mem::take(&mut r.timed_out);
        let long = (usize::from(dlc) > expected).then_some((code::RPDO_LONG, length));
        if r.synchronous() {
            r.held = Some(*frame.raw_data());
            // A refusal stands until the SYNC has written this frame.
            if long.is_some() || r.fault != Some(code::RPDO_REFUSED) {
                self.set_rpdo_fault(i, long);
            }
        } else {
            let fault = self.write_rpdo(i, frame.raw_data(), app).or(long);
            self.set_rpdo_fault(i, fault);
        }
        if timed_out {
            let transmit = self.comm.state.communicating();
            self.comm.emcy.clear(code::RPDO_TIMEOUT, transmit);
        }
    }

    /// Writes RPDO `i`'s data to its mapped objects: every value checked first (the table's
    /// type and range, as an SDO write, then the application's `check_write`), then all
    /// written, so that a frame is taken whole or not at all. A refused frame is counted;
    /// the refusal is returned as EMCY 0x8200 with the PDO number and the refused object's
    /// index and sub-index.
    fn write_rpdo(
        &mut self,
        i: usize,
        data: &[u8; 8],
        app: &mut dyn Application,
    ) -> Option<RpdoFault> {
        let od = self.comm.od;
        let mapping = self.comm.rpdos.get(i)?.mapping();
        let checked = each_mapped(&od, mapping, data, |e, bytes| {
            e.check_write(bytes)?;
            app.check_write(e.index(), e.sub(), bytes)
        });
        let written = checked.and_then(|()| {
            each_mapped(&od, mapping, data, |e, bytes| {
                app.write(e.index(), e.sub(), bytes)
            })
        });
        // i < RPDOS, so the PDO number fits a u8.
        let pdo = i as u8 + 1;
        match written {
            Ok(()) => {
                app.on_rpdo(pdo);
                None
            }
            Err((entry, abort)) => {
                debug!("RPDO{=u8} refused: {=u32:#x}", pdo, abort.code());
                self.rpdo_errors = self.rpdo_errors.saturating_add(1);
                let [_, sub, lo, hi] = entry.to_le_bytes();
                Some((code::RPDO_REFUSED, [pdo, lo, hi, sub, 0]))
            }
        }
    }

    /// RPDO `i`'s reception error becomes `fault`: the EMCY of the one before is cleared,
    /// the new one raised (nothing when it stays the same).
    fn set_rpdo_fault(&mut self, i: usize, fault: Option<RpdoFault>) {
        let Some(r) = self.comm.rpdos.get_mut(i) else {
            return;
        };
        let new = fault.map(|(code, _)| code);
        if r.fault == new {
            return;
        }
        let old = core::mem::replace(&mut r.fault, new);
        let transmit = self.comm.state.communicating();
        if let Some((code, info)) = fault {
            // A full error list still counts the frame in `Stats::rpdo_errors`.
            let _ = self
                .comm
                .emcy
                .raise(code, register::COMMUNICATION, info, transmit);
        }
        if let Some(old) = old {
            self.comm.emcy.clear(old, transmit);
        }
    }

    /// Deadline monitoring: an RPDO whose event timer passed without a frame since the last
    /// one raises EMCY 0x8250 (cleared by its next frame) and tells the application, once.
    pub(super) fn check_rpdo_deadlines(&mut self, now: Instant, app: &mut dyn Application) {
        if self.comm.state != NmtState::Operational {
            return;
        }
        for i in 0..RPDOS {
            let Some(r) = self.comm.rpdos.get_mut(i) else {
                continue;
            };
            if r.deadline.is_none_or(|t| now < t) {
                continue;
            }
            r.deadline = None;
            r.timed_out = true;
            // i < RPDOS, so the PDO number fits a u8.
            let pdo = i as u8 + 1;
            warn!("RPDO{=u8} timed out", pdo);
            let _ = self.comm.emcy.raise(
                code::RPDO_TIMEOUT,
                register::COMMUNICATION,
                [pdo, 0, 0, 0, 0],
                true,
            );
            app.on_rpdo_timeout(pdo);
        }
    }

    /// Ends the RPDOs' error conditions (a reset of communication sets them up anew).
    pub(super) fn clear_rpdo_faults(&mut self) {
        for i in 0..RPDOS {
            self.set_rpdo_fault(i, None);
            if let Some(r) = self.comm.rpdos.get_mut(i) {
                if core::mem::take(&mut r.timed_out) {
                    self.comm.emcy.clear(code::RPDO_TIMEOUT, false);
                }
            }
        }
    }

    /// A SYNC: the synchronous RPDOs' held data is written, then the synchronous TPDOs
    /// whose turn it is go out (so that a TPDO answering an RPDO carries its effect).
    pub(super) fn on_sync(
        &mut self,
        now: Instant,
        app: &mut dyn Application,
        tx: &mut dyn FrameSink,
    ) {
        if self.comm.state == NmtState::Operational {
            for i in 0..RPDOS {
                let held = self.comm.rpdos.get_mut(i).and_then(|r| r.held.take());
                if let Some(data) = held {
                    let fault = self.write_rpdo(i, &data, app);
                    // A refusal replaces a length error; a frame written keeps the
                    // reception's verdict (none, or "length exceeded").
                    if fault.is_some() {
                        self.set_rpdo_fault(i, fault);
                    } else if self
                        .comm
                        .rpdos
                        .get(i)
                        .is_some_and(|r| r.fault == Some(code::RPDO_REFUSED))
                    {
                        self.set_rpdo_fault(i, None);
                    }
                }
            }
        }
        self.send_due(now, app, tx, Tpdo::on_sync);
    }

    /// The event-driven PDOs that are due (requested or event timer) and allowed (inhibit
    /// time) go out.
    pub(super) fn service_tpdos(
        &mut self,
        now: Instant,
        app: &mut dyn Application,
        tx: &mut dyn FrameSink,
    ) {
        self.send_due(now, app, tx, |t| t.event_due(now));
    }

    /// Sends each PDO `due` says is due, in Operational only.
    fn send_due(
        &mut self,
        now: Instant,
        app: &mut dyn Application,
        tx: &mut dyn FrameSink,
        mut due: impl FnMut(&mut Tpdo) -> bool,
    ) {
        if self.comm.state != NmtState::Operational {
            return;
        }
        for i in 0..TPDOS {
            if self.comm.tpdos.get_mut(i).is_some_and(&mut due) {
                self.send_tpdo(i, now, app, tx);
            }
        }
    }

    fn send_tpdo(
        &mut self,
        i: usize,
        now: Instant,
        app: &mut dyn Application,
        tx: &mut dyn FrameSink,
    ) {
        // i < TPDOS, so the PDO number fits a u8.
        let pdo = i as u8 + 1;
        if !app.tpdo_ready(pdo) {
            if let Some(t) = self.comm.tpdos.get_mut(i) {
                t.withdrawn(now);
            }
            return;
        }
        let built = self.build_tpdo(i, app);
        let sent = match built {
            Ok(frame) => Some(self.emit(tx, frame)),
            Err(abort) => {
                // Repeats at the event timer's rate while the fault lasts: debug only, the
                // count is in `Stats::tpdo_errors`.
                debug!("TPDO{=u8} not built: {=u32:#x}", pdo, abort.code());
                self.tpdo_errors = self.tpdo_errors.saturating_add(1);
                None
            }
        };
        let Some(t) = self.comm.tpdos.get_mut(i) else {
            return;
        };
        match sent {
            Some(false) => t.retry_later(now),
            Some(true) => {
                t.sent(now);
                app.on_tpdo_sent(pdo);
            }
            // Give this event up rather than retrying a mapping that cannot be read.
            None => t.sent(now),
        }
    }

    fn build_tpdo(&self, i: usize, app: &mut dyn Application) -> Result<Frame, SdoAbort> {
        let comm = &self.comm;
        let t = comm.tpdos.get(i).ok_or(SdoAbort::NoObject)?;
        let mut data = [0u8; 8];
        let mut len = 0;
        for &entry in t.mapping() {
            // Stored or default mappings never went through the SDO checks: re-check here.
            let (e, size) = tpdo::check_mapping(&comm.od, entry)?;
            let dst = data.get_mut(len..len + size).ok_or(SdoAbort::PdoTooLong)?;
            comm.read_value(e, dst, app, Some(i as u8 + 1))?;
            len += size;
        }
        // len <= 8, checked by the slice above.
        Ok(Frame::from_parts(t.can_id(), data, len as u8))
    }
}
