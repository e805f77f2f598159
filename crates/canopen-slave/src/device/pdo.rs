//! The TPDO service: application requests, SYNC, event timers and inhibit times, and the
//! building of a PDO from its mapping.

use super::{Application, Device, Inner, NoSuchPdo};
use crate::abort::SdoAbort;
use crate::frame::{Frame, FrameSink};
use crate::nmt::NmtState;
use crate::storage::Storage;
use crate::time::Instant;
use crate::tpdo::{self, Tpdo, TPDOS};

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
    /// A SYNC: the synchronous PDOs whose turn it is go out.
    pub(super) fn on_sync(
        &mut self,
        now: Instant,
        app: &mut dyn Application,
        tx: &mut dyn FrameSink,
    ) {
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
