//! The object dictionary as the SDO server sees it, and the local reads and writes that go
//! through the same checks.

use super::{Application, Device, Inner};
use crate::abort::SdoAbort;
use crate::frame::{Frame, FrameSink};
use crate::sdo::ObjectAccess;
use crate::storage::Storage;
use crate::time::Instant;

impl<S: Storage> Device<S> {
    /// An SDO request to server `channel` (8 bytes, in a communicating state): the server
    /// runs over the objects, and its reply goes out on the channel's reply identifier as
    /// it was when the request came (a write of 0x1201 may change it).
    pub(super) fn on_sdo_request(
        &mut self,
        now: Instant,
        channel: usize,
        frame: &Frame,
        app: &mut dyn Application,
        tx: &mut dyn FrameSink,
    ) {
        let (Some((_, reply_id)), Some(server)) =
            (self.inner.comm.sdo_ids(channel), self.sdo.get_mut(channel))
        else {
            return;
        };
        let mut objects = Objects {
            inner: &mut self.inner,
            app,
            now,
        };
        if let Some(reply) = server.on_request(now, frame.raw_data(), &mut objects) {
            self.inner.emit(tx, Frame::from_parts(reply_id, reply, 8));
        }
        self.settle_sdo();
    }

    /// The second server holds no transfer while 0x1201 does not make it valid: a write
    /// that invalidates it ends its transfer silently.
    fn settle_sdo(&mut self) {
        if self.inner.comm.sdo_ids(1).is_none() {
            self.sdo[1].reset();
        }
    }

    /// Local read of any object, with the same checks as an SDO upload.
    pub fn read(
        &mut self,
        index: u16,
        sub: u8,
        buf: &mut [u8],
        app: &mut dyn Application,
    ) -> Result<usize, SdoAbort> {
        Objects {
            inner: &mut self.inner,
            app,
            now: Instant::ZERO,
        }
        .upload(index, sub, buf)
    }

    /// Local write of any object, with the same checks as an SDO download (e.g. for an
    /// application object that mirrors a communication parameter).
    pub fn write(
        &mut self,
        now: Instant,
        index: u16,
        sub: u8,
        data: &[u8],
        app: &mut dyn Application,
    ) -> Result<(), SdoAbort> {
        let inner = &mut self.inner;
        let written = inner
            .comm
            .write_object(now, index, sub, data, app, &mut inner.storage);
        self.inner.settle_heartbeat(app);
        self.settle_sdo();
        written
    }
}

/// The object dictionary as the SDO server sees it.
struct Objects<'a, S> {
    inner: &'a mut Inner<S>,
    app: &'a mut dyn Application,
    now: Instant,
}

impl<S: Storage> ObjectAccess for Objects<'_, S> {
    fn upload(&mut self, index: u16, sub: u8, buf: &mut [u8]) -> Result<usize, SdoAbort> {
        debug!("SDO upload {=u16:#x}:{=u8}", index, sub);
        let comm = &self.inner.comm;
        let e = comm.od.find(index, sub)?;
        if !e.access().readable() {
            return Err(SdoAbort::WriteOnly);
        }
        comm.read_value(e, buf, self.app, None)
    }

    fn size_of(&mut self, index: u16, sub: u8) -> Result<usize, SdoAbort> {
        let e = self.inner.comm.od.find(index, sub)?;
        Ok(e.data_type().size().unwrap_or(4))
    }

    fn check_download(&mut self, index: u16, sub: u8, size: Option<u32>) -> Result<(), SdoAbort> {
        let e = self.inner.comm.od.find(index, sub)?;
        if !e.access().writable() {
            return Err(SdoAbort::ReadOnly);
        }
        let Some(size) = size.map(|s| usize::try_from(s).unwrap_or(usize::MAX)) else {
            return Ok(());
        };
        e.data_type().check_len(size)
    }

    fn download(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoAbort> {
        let inner = &mut *self.inner;
        inner
            .comm
            .write_object(self.now, index, sub, data, self.app, &mut inner.storage)?;
        // Refused writes are logged with their abort code by the SDO server.
        info!("SDO write {=u16:#x}:{=u8}", index, sub);
        self.app.on_written(index, sub);
        Ok(())
    }
}
