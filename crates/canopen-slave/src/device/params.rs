//! 0x1010 (store parameters) and 0x1011 (restore default parameters): the parameter blob in
//! the firmware's [`Storage`], loaded at the next reset (`nmt`).

use super::objects::{Comm, WriteCtx};
use crate::sdo::SdoAbort;
use crate::storage::{self, Blob, Storage, LOAD_SIGNATURE, SAVE_SIGNATURE};

/// 0x1010: "save" stores communication (sub 2), application (sub 3) or both (sub 1).
pub(super) fn save(
    comm: &Comm,
    ctx: &mut WriteCtx<'_>,
    sub: u8,
    signature: u32,
) -> Result<(), SdoAbort> {
    if signature != SAVE_SIGNATURE {
        return Err(SdoAbort::CannotStore);
    }
    let sections = sections(sub)?;
    let mut blob = Blob::load(ctx.storage);
    if sections & storage::COMM != 0 {
        blob.set_comm(|index, sub| comm.read(index, sub).unwrap_or(0));
    }
    if sections & storage::APP != 0 {
        blob.set_app(|buf| ctx.app.save_application(buf));
    }
    blob.store(ctx.storage).map_err(|_| SdoAbort::Hardware)
}

/// 0x1011: "load" forgets stored values, so the next reset loads the defaults.
pub(super) fn forget(storage: &mut dyn Storage, sub: u8, signature: u32) -> Result<(), SdoAbort> {
    if signature != LOAD_SIGNATURE {
        return Err(SdoAbort::CannotStore);
    }
    let sections = sections(sub)?;
    let mut blob = Blob::load(storage);
    blob.remove(sections);
    blob.store(storage).map_err(|_| SdoAbort::Hardware)
}

/// Blob sections selected by sub-index 1 (all), 2 (communication), 3 (application).
fn sections(sub: u8) -> Result<u8, SdoAbort> {
    match sub {
        1 => Ok(storage::COMM | storage::APP),
        2 => Ok(storage::COMM),
        3 => Ok(storage::APP),
        _ => Err(SdoAbort::NoSubIndex),
    }
}
