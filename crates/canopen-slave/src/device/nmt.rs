//! NMT: initialisation (power-on, reset node, reset communication) and the one place where
//! the NMT state changes. Each service's reaction to a new state is its own
//! (`on_nmt_state` of the SDO server, EMCY, heartbeat, RPDOs and TPDOs); this module only calls
//! them in order.

use super::objects::params::blob::Blob;
use super::{Application, Device};
use crate::frame::{cob, Frame, FrameSink};
use crate::nmt::{NmtCommand, NmtState};
use crate::storage::Storage;
use crate::time::Instant;
use crate::{rpdo, tpdo};

/// Why the device (re)initialises.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub(super) enum Boot {
    PowerOn,
    ResetNode,
    ResetCommunication,
}

impl<S: Storage> Device<S> {
    pub(super) fn on_nmt(
        &mut self,
        now: Instant,
        cmd: NmtCommand,
        app: &mut dyn Application,
        tx: &mut dyn FrameSink,
    ) {
        match cmd {
            NmtCommand::StartRemoteNode => self.set_state(now, NmtState::Operational, app, tx),
            NmtCommand::StopRemoteNode => self.set_state(now, NmtState::Stopped, app, tx),
            NmtCommand::EnterPreOperational => {
                self.set_state(now, NmtState::PreOperational, app, tx)
            }
            NmtCommand::ResetNode => self.boot(now, Boot::ResetNode, app, tx),
            NmtCommand::ResetCommunication => self.boot(now, Boot::ResetCommunication, app, tx),
        }
    }

    /// The one place where the NMT state changes: logs the transition, then lets every
    /// service react, the application last.
    fn set_state(
        &mut self,
        now: Instant,
        next: NmtState,
        app: &mut dyn Application,
        tx: &mut dyn FrameSink,
    ) {
        let comm = &mut self.inner.comm;
        let prev = comm.state;
        if prev == next {
            return;
        }
        info!("NMT {} -> {}", prev, next);
        comm.state = next;
        for server in &mut self.sdo {
            server.on_nmt_state(next);
        }
        comm.emcy.on_nmt_state(next);
        rpdo::on_nmt_state(&mut comm.rpdos, next);
        tpdo::on_nmt_state(&mut comm.tpdos, next, now);
        app.on_nmt_state(next);
        if comm.heartbeat.on_nmt_state(prev, next, now) {
            self.inner.send_heartbeat(tx);
        }
        // Entry to Operational sends TPDO1.
        self.inner.service_tpdos(now, app, tx);
    }

    /// Initialisation (power-on, reset node, reset communication) up to Pre-operational.
    pub(super) fn boot(
        &mut self,
        now: Instant,
        kind: Boot,
        app: &mut dyn Application,
        tx: &mut dyn FrameSink,
    ) {
        self.set_state(now, NmtState::Initialising, app, tx);
        // The RPDOs start over with their stored parameters: their errors end here.
        self.inner.clear_rpdo_faults();
        // Also at power-on, when the state was Initialising already.
        for server in &mut self.sdo {
            server.reset();
        }
        // Every initialisation activates the LSS node-ID (at power-on, the configured one).
        self.inner.comm.node = self.lss.pending_node_id();
        let Some(node) = self.inner.comm.node else {
            info!("unconfigured (node-ID 0xFF): LSS only");
            return;
        };
        let blob = Blob::load(&mut self.inner.storage);
        if kind == Boot::ResetNode {
            self.inner.comm.emcy.reset();
            app.on_reset_application();
        }
        let mut app_refused = None;
        if kind != Boot::ResetCommunication {
            if let Some(data) = blob.app() {
                app_refused = app.restore_application(data).err();
            }
        }
        self.inner.comm.load_defaults(now);
        let refused = blob
            .comm()
            .and_then(|params| self.inner.restore_stored(now, params, app));
        if kind != Boot::PowerOn {
            // CiA 301's reset of communication: nothing said before it goes out after it,
            // and the boot-up is the first frame (a full queue would refuse it).
            tx.discard_pending();
        }
        let bootup = Frame::from_parts(node.cob_id(cob::HEARTBEAT), [0; 8], 1);
        self.inner.emit(tx, bootup);
        self.inner.comm.heartbeat.restart(now);
        // The consumers start over (waiting for a first heartbeat): no loss is pending.
        self.inner.settle_heartbeat(app);
        self.set_state(now, NmtState::PreOperational, app, tx);
        self.report_refused_stored(refused, app_refused);
    }
}
