//! 0x1010 (store parameters) and 0x1011 (restore default parameters): the parameter blob in
//! the firmware's [`Storage`], loaded at the next reset (`nmt`).
//!
//! Both write the medium, so both ask the application first
//! ([`Application::may_store`](crate::Application::may_store)): refused, 0x08000022. A
//! storage that refuses for wear gives 0x08000020, one that fails 0x06060000.

pub(crate) mod blob;

use super::{Comm, Refused, WriteCtx, STORED, STORED_LEN};
use crate::abort::SdoAbort;
use crate::device::{Application, Device, Inner};
use crate::emcy;
use crate::storage::{Storage, StorageError, LOAD_SIGNATURE, SAVE_SIGNATURE};
use crate::time::Instant;
use blob::{Blob, APP, COMM};

/// EMCY "data set" (CiA 301 error code 0x63xx): a stored parameter was not restored.
pub const EMCY_STORED_REFUSED: u16 = 0x6300;

impl<S: Storage> Inner<S> {
    /// The stored communication parameters over the defaults, checked as SDO writes
    /// ([`Comm::restore_stored`]); the first refusal and the count of refused objects.
    pub(in crate::device) fn restore_stored(
        &mut self,
        now: Instant,
        params: impl Iterator<Item = (u16, u8, u32)>,
        app: &mut dyn Application,
    ) -> Option<(Refused, u8)> {
        // A blob of an older layout holds a prefix of `STORED`: the parameters added since
        // restore as their defaults.
        let mut values = [0; STORED_LEN];
        for (dst, &(index, sub)) in values.iter_mut().zip(&STORED) {
            *dst = self.comm.default_value(index, sub).unwrap_or(0);
        }
        for (dst, (_, _, value)) in values.iter_mut().zip(params) {
            *dst = value;
        }
        let mut ctx = WriteCtx {
            now,
            app,
            storage: &mut self.storage,
        };
        self.comm.restore_stored(&mut ctx, &values)
    }
}

impl<S: Storage> Device<S> {
    /// Stored values refused at the restore (communication parameters: the first and how
    /// many objects; the application's: the object it named): EMCY 0x6300 as an event
    /// (raised and cleared at once), manufacturer bytes: the first refused object's index
    /// (little-endian) and sub-index, and how many objects were refused.
    pub(in crate::device) fn report_refused_stored(
        &mut self,
        comm: Option<(Refused, u8)>,
        app: Option<(u16, u8)>,
    ) {
        if let Some((index, sub)) = app {
            warn!(
                "stored application {=u16:#06x}:{=u8} out of range: application defaults kept",
                index, sub
            );
        }
        let first = comm.map(|(r, _)| (r.index, r.sub)).or(app);
        let Some((index, sub)) = first else {
            return;
        };
        let count = comm
            .map_or(0, |(_, n)| n)
            .saturating_add(u8::from(app.is_some()));
        let [lo, hi] = index.to_le_bytes();
        let info = [lo, hi, sub, count, 0];
        if self
            .raise_error(EMCY_STORED_REFUSED, emcy::register::GENERIC, info)
            .is_ok()
        {
            self.clear_error(EMCY_STORED_REFUSED);
        }
    }
}

/// 0x1010: "save" stores communication (sub 2), application (sub 3) or both (sub 1).
pub(super) fn save(
    comm: &Comm,
    ctx: &mut WriteCtx<'_>,
    sub: u8,
    signature: u32,
) -> Result<(), SdoAbort> {
    let sections = check(ctx, sub, signature, SAVE_SIGNATURE)?;
    let mut blob = Blob::load(ctx.storage);
    if sections & COMM != 0 {
        blob.set_comm(
            |index, sub| comm.read(index, sub).unwrap_or(0),
            |index, sub| comm.default_value(index, sub),
        );
    }
    if sections & APP != 0 {
        blob.set_app(|buf| ctx.app.save_application(buf));
    }
    blob.store(ctx.now, ctx.storage).map_err(abort)
}

/// 0x1011: "load" forgets stored values, so the next reset loads the defaults.
pub(super) fn forget(ctx: &mut WriteCtx<'_>, sub: u8, signature: u32) -> Result<(), SdoAbort> {
    let sections = check(ctx, sub, signature, LOAD_SIGNATURE)?;
    let mut blob = Blob::load(ctx.storage);
    blob.remove(sections);
    blob.store(ctx.now, ctx.storage).map_err(abort)
}

/// The signature, the sub-index (its sections: 1 all, 2 communication, 3 application), then
/// the application's consent, in CiA 301's order of abort codes.
fn check(ctx: &mut WriteCtx<'_>, sub: u8, signature: u32, want: u32) -> Result<u8, SdoAbort> {
    if signature != want {
        return Err(SdoAbort::CannotStore);
    }
    let sections = match sub {
        1 => COMM | APP,
        2 => COMM,
        3 => APP,
        _ => return Err(SdoAbort::NoSubIndex),
    };
    if !ctx.app.may_store() {
        return Err(SdoAbort::DeviceState);
    }
    Ok(sections)
}

/// The SDO answer to a store the medium did not take.
fn abort(error: StorageError) -> SdoAbort {
    match error {
        StorageError::WearLimit => SdoAbort::CannotStore,
        StorageError::DeviceState => SdoAbort::DeviceState,
        StorageError::WriteFailed | StorageError::Unsupported => SdoAbort::Hardware,
    }
}
