//! 0x1010 (store parameters) and 0x1011 (restore default parameters): the parameter blob in
//! the firmware's [`Storage`], loaded at the next reset (`nmt`).
//!
//! Both write the medium, so both ask the application first
//! ([`Application::may_store`](super::Application::may_store)): refused, 0x08000022. A
//! storage that refuses for wear gives 0x08000020, one that fails 0x06060000.

use super::objects::{Comm, WriteCtx};
use crate::sdo::SdoAbort;
use crate::storage::{self, Blob, StorageError, LOAD_SIGNATURE, SAVE_SIGNATURE};

/// 0x1010: "save" stores communication (sub 2), application (sub 3) or both (sub 1).
pub(super) fn save(
    comm: &Comm,
    ctx: &mut WriteCtx<'_>,
    sub: u8,
    signature: u32,
) -> Result<(), SdoAbort> {
    let sections = check(ctx, sub, signature, SAVE_SIGNATURE)?;
    let mut blob = Blob::load(ctx.storage);
    if sections & storage::COMM != 0 {
        blob.set_comm(|index, sub| comm.read(index, sub).unwrap_or(0));
    }
    if sections & storage::APP != 0 {
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
        1 => storage::COMM | storage::APP,
        2 => storage::COMM,
        3 => storage::APP,
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
