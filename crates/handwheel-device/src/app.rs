//! The handwheel's application objects (0x2000 and up, 0x6004) over the shared wheel.

use canopen_slave::{Application, NmtState, SdoAbort};
use handwheel_core::{
    Axis, CounterStride, CountsPerDetent, DecoderConfig, FeedRecord, FeedStatus, Handwheel,
    StopReason, UnitStep, UnitStepEncoder, WheelAccess, DEFAULT_STEP_BACKLOG,
};

use crate::od::{
    ENCODER, FEED_DIAGNOSTICS, FEED_ENABLE, FEED_FORMAT, FEED_SEQUENCE, FEED_STATUS,
    POSITION_VALUE, SELECTION, UNIT_STEP,
};

/// Application parameters that 0x1010 stores: everything the integrator configures about
/// the wheel, never the feed enable (a handwheel must not power up live).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WheelParameters {
    /// 0x2001: unit-step (paper) format instead of the feed record.
    pub unit_steps: bool,
    /// 0x2020:3 and :4.
    pub decoder: DecoderConfig,
    /// 0x2040:3.
    pub backlog_bound: u16,
}

impl WheelParameters {
    /// Factory settings.
    pub const DEFAULT: Self = Self {
        unit_steps: false,
        decoder: DecoderConfig {
            counts_per_detent: CountsPerDetent::Four,
            invert: false,
        },
        backlog_bound: DEFAULT_STEP_BACKLOG,
    };

    const BLOB_VERSION: u8 = 1;
    const BLOB_LEN: usize = 6;

    fn to_blob(self) -> [u8; Self::BLOB_LEN] {
        let bound = self.backlog_bound.to_le_bytes();
        [
            Self::BLOB_VERSION,
            self.unit_steps as u8,
            self.decoder.counts_per_detent.get(),
            self.decoder.invert as u8,
            bound[0],
            bound[1],
        ]
    }

    /// `None` for a blob of another version or with any field out of range.
    #[cfg(test)]
    fn from_blob(blob: &[u8]) -> Option<Self> {
        Self::check_blob(blob).ok()
    }

    /// The parameters of a stored blob, or the first object whose value is out of the range
    /// its SDO write takes (0x1010:3, the application's section, for a blob of another
    /// version or length).
    fn check_blob(blob: &[u8]) -> Result<Self, (u16, u8)> {
        let &[version, unit_steps, cpd, invert, b0, b1] = blob else {
            return Err((0x1010, 3));
        };
        let bound = u16::from_le_bytes([b0, b1]);
        let checks = [
            (version == Self::BLOB_VERSION, (0x1010, 3)),
            (unit_steps <= 1, (0x2001, 0)),
            (CountsPerDetent::from_u8(cpd).is_some(), (0x2020, 3)),
            (invert <= 1, (0x2020, 4)),
            (
                (1..=crate::od::MAX_BACKLOG_BOUND).contains(&bound),
                (0x2040, 3),
            ),
        ];
        if let Some(&(_, object)) = checks.iter().find(|(ok, _)| !ok) {
            return Err(object);
        }
        Ok(Self {
            unit_steps: unit_steps == 1,
            decoder: DecoderConfig {
                counts_per_detent: CountsPerDetent::from_u8(cpd).ok_or((0x2020, 3))?,
                invert: invert == 1,
            },
            backlog_bound: bound,
        })
    }

    /// Pushes the parameters into the wheel.
    pub(crate) fn apply(self, wheel: &mut Handwheel) {
        wheel.decoder.configure(self.decoder);
        // The bound was validated on its way in; a rejected bound keeps the previous one.
        let _ = wheel.feed.set_backlog_bound(self.backlog_bound);
        let _ = wheel.feed.set_unit_step_mode(self.unit_steps);
    }
}

/// What the application keeps between engine calls.
#[derive(Clone, Debug)]
pub struct FeedApp {
    pub(crate) parameters: WheelParameters,
    pub(crate) nmt: NmtState,
    pub(crate) encoder: UnitStepEncoder,
    /// The unit step waiting for TPDO2; its byte is in 0x2032 until it is sent.
    pub(crate) step_in_flight: Option<UnitStep>,
    /// 0x2032: the last unit-step byte handed to TPDO2.
    pub(crate) step_byte: u8,
    /// A consumed heartbeat is in timeout: feed may not be enabled until the engine reports
    /// every monitored node back.
    pub(crate) master_lost: bool,
    /// The feed record TPDO1 is being built from: one snapshot, taken when the engine asks
    /// whether TPDO1 is ready, so that every mapped object reads the same record however the
    /// edge task moves the wheel meanwhile.
    pub(crate) record: Option<FeedRecord>,
}

impl FeedApp {
    pub(crate) const fn new() -> Self {
        Self {
            parameters: WheelParameters::DEFAULT,
            nmt: NmtState::Initialising,
            encoder: UnitStepEncoder::new(CounterStride::One),
            step_in_flight: None,
            step_byte: 0,
            master_lost: false,
            record: None,
        }
    }
}

/// The application as the engine sees it during one call: the kept state plus access to
/// the shared wheel.
pub(crate) struct AppContext<'a, W: WheelAccess> {
    pub app: &'a mut FeedApp,
    pub wheel: &'a mut W,
}

fn put(buf: &mut [u8], bytes: &[u8]) -> Result<usize, SdoAbort> {
    let dst = buf.get_mut(..bytes.len()).ok_or(SdoAbort::OutOfMemory)?;
    dst.copy_from_slice(bytes);
    Ok(bytes.len())
}

impl<W: WheelAccess> Application for AppContext<'_, W> {
    fn read(&mut self, index: u16, sub: u8, buf: &mut [u8]) -> Result<usize, SdoAbort> {
        self.read_object(index, sub, buf, false)
    }

    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoAbort> {
        // The engine checked length and the table's range: `byte` is the whole value of the
        // U8 objects, `word` of the U16 one.
        let byte = data.first().copied().unwrap_or(0);
        let word = u16::from_le_bytes([byte, data.get(1).copied().unwrap_or(0)]);
        let mut parameters = self.app.parameters;
        match (index, sub) {
            (FEED_ENABLE, 0) => {
                // Feed only runs while PDOs flow: enabling in Pre-operational would let the
                // position move unseen and jump at the next start.
                // Nor while a master we monitor is silent: a wheel enabled by a write that
                // arrives while the master is lost would move an axis nobody supervises.
                if byte == 1 && (self.app.nmt != NmtState::Operational || self.app.master_lost) {
                    return Err(SdoAbort::DeviceState);
                }
                self.wheel
                    .with_wheel(|w| w.record_due |= w.feed.set_enabled(byte == 1));
                return Ok(());
            }
            (FEED_FORMAT, 0) => parameters.unit_steps = byte == 1,
            (ENCODER, 3) => {
                parameters.decoder.counts_per_detent =
                    CountsPerDetent::from_u8(byte).ok_or(SdoAbort::InvalidValue)?;
            }
            (ENCODER, 4) => parameters.decoder.invert = byte == 1,
            (FEED_DIAGNOSTICS, 3) => parameters.backlog_bound = word,
            _ => return Err(SdoAbort::ReadOnly),
        }
        self.set_parameters(parameters);
        Ok(())
    }

    fn on_nmt_state(&mut self, state: NmtState) {
        self.app.nmt = state;
        if state == NmtState::Operational {
            self.wheel.with_wheel(|w| w.feed.start_records());
        } else {
            self.stop(StopReason::NotOperational);
            // PDOs stop here: what was not reported by now (the stopped epoch's final state
            // among it) would reach the host only at the next start, as stale motion. It is
            // dropped, and the sequence gap makes the host start afresh.
            self.wheel.with_wheel(|w| w.feed.stop_records());
        }
    }

    fn on_heartbeat_lost(&mut self, _node_id: u8) {
        self.app.master_lost = true;
        self.stop(StopReason::MasterLost);
    }

    fn on_heartbeat_restored(&mut self) {
        // Feed stays off (status bit 3 stays set) until the master enables it again.
        self.app.master_lost = false;
    }

    fn on_reset_application(&mut self) {
        let (nmt, master_lost) = (self.app.nmt, self.app.master_lost);
        *self.app = FeedApp::new();
        // Engine state, not application state: the engine ends the loss itself.
        self.app.nmt = nmt;
        self.app.master_lost = master_lost;
        self.wheel.with_wheel(|w| {
            w.decoder.reset(WheelParameters::DEFAULT.decoder);
            w.feed.reset();
        });
    }

    fn tpdo_ready(&mut self, pdo: u8) -> bool {
        if pdo == 1 {
            self.app.record = Some(self.wheel.with_wheel(|w| w.feed.record()));
        }
        // TPDO2 carries unit steps, i.e. motion: it may only go out with a step in flight.
        // A step withdrawn by a stop or an axis change, an event timer or a SYNC an
        // integrator configured, must never repeat the last byte.
        pdo != 2 || self.app.step_in_flight.is_some()
    }

    fn read_for_tpdo(
        &mut self,
        pdo: u8,
        index: u16,
        sub: u8,
        buf: &mut [u8],
    ) -> Result<usize, SdoAbort> {
        self.read_object(index, sub, buf, pdo == 1)
    }

    fn on_tpdo_sent(&mut self, pdo: u8) {
        if pdo == 1 {
            let record = self.app.record.take();
            self.wheel.with_wheel(|w| {
                let sent = record.map_or_else(|| w.feed.record_to_send(), |r| r.state);
                w.record_due |= w.feed.record_sent(sent);
            });
        } else if pdo == 2 && self.app.step_in_flight.take().is_some() {
            // `tpdo_ready` let TPDO2 go only with a step in flight: that step is on the bus.
            self.app.encoder.advance();
        }
    }

    fn save_application(&self, buf: &mut [u8]) -> usize {
        let blob = self.app.parameters.to_blob();
        match buf.get_mut(..blob.len()) {
            Some(dst) => {
                dst.copy_from_slice(&blob);
                blob.len()
            }
            None => 0,
        }
    }

    fn restore_application(&mut self, data: &[u8]) -> Result<(), (u16, u8)> {
        let parameters = WheelParameters::check_blob(data)?;
        self.set_parameters(parameters);
        Ok(())
    }

    fn may_store(&mut self) -> bool {
        // Writing flash stalls the CPU, edge interrupt included (a page erase takes 20-40 ms
        // on the F103): edges in that window would be lost. Store only with the feed off.
        !self.wheel.with_wheel(|w| w.feed.enabled())
    }
}

impl<W: WheelAccess> AppContext<'_, W> {
    /// Reads an application object. `record`: for the feed record (TPDO1), whose state
    /// objects carry what the outbox sends next (a closed epoch's final state while one is
    /// held) rather than the present state, whatever the master mapped.
    fn read_object(
        &mut self,
        index: u16,
        sub: u8,
        buf: &mut [u8],
        record: bool,
    ) -> Result<usize, SdoAbort> {
        // Every application object is an integer of 1, 2 or 4 bytes: pick the value and its
        // size, then copy once (one copy instead of one per object keeps the image small).
        let app = &*self.app;
        if let Some(bytes) = app.record.filter(|_| record).map(|r| r.to_bytes()) {
            // The record's own encoding (`handwheel-core`), object by object.
            let field = match (index, sub) {
                (POSITION_VALUE, 0) => Some(&bytes[0..4]),
                (SELECTION, 1) => Some(&bytes[4..5]),
                (SELECTION, 2) => Some(&bytes[5..6]),
                (FEED_STATUS, 0) => Some(&bytes[6..7]),
                (FEED_SEQUENCE, 0) => Some(&bytes[7..8]),
                _ => None,
            };
            if let Some(field) = field {
                return put(buf, field);
            }
        }
        let (value, size): (u32, usize) = match (index, sub) {
            (FEED_FORMAT, 0) => (app.parameters.unit_steps.into(), 1),
            (ENCODER, 3) => (app.parameters.decoder.counts_per_detent.get().into(), 1),
            (ENCODER, 4) => (app.parameters.decoder.invert.into(), 1),
            (UNIT_STEP, 0) => (app.step_byte.into(), 1),
            (FEED_DIAGNOSTICS, 3) => (app.parameters.backlog_bound.into(), 2),
            _ => self.wheel.with_wheel(|w| {
                let feed = &w.feed;
                let state = match app.record.filter(|_| record) {
                    Some(r) => r.state,
                    None if record => feed.record_to_send(),
                    None => feed.state(),
                };
                Ok(match (index, sub) {
                    (FEED_ENABLE, 0) => (state.status.contains(FeedStatus::ENABLED).into(), 1),
                    (SELECTION, 1) => (Axis::option_value(state.axis).into(), 1),
                    (SELECTION, 2) => (state.multiplier.factor().into(), 1),
                    (SELECTION, 3) => (state.epoch.into(), 1),
                    // Two's complement bytes of the signed objects, as CiA 301 sends them.
                    (ENCODER, 1) => (w.decoder.count() as u32, 4),
                    (ENCODER, 2) => (w.decoder.illegal_transitions(), 4),
                    (FEED_STATUS, 0) => (state.status_byte().into(), 1),
                    (FEED_SEQUENCE, 0) => (feed.record_sequence().into(), 1),
                    (FEED_DIAGNOSTICS, 1) => (feed.ignored_detents(), 4),
                    (FEED_DIAGNOSTICS, 2) => (feed.dropped_steps(), 4),
                    (POSITION_VALUE, 0) => (state.position as u32, 4),
                    _ => return Err(SdoAbort::NoObject),
                })
            })?,
        };
        let bytes = value.to_le_bytes();
        put(buf, &bytes[..size])
    }

    fn set_parameters(&mut self, parameters: WheelParameters) {
        self.app.parameters = parameters;
        self.app.step_in_flight = None;
        self.wheel.with_wheel(|w| {
            parameters.apply(w);
            w.record_due = true;
        });
    }

    fn stop(&mut self, reason: StopReason) {
        // A step that has not reached the bus is withdrawn with the rest of the backlog.
        self.app.step_in_flight = None;
        self.wheel
            .with_wheel(|w| w.record_due |= w.feed.stop(reason));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parameter_blob_round_trips() {
        let p = WheelParameters {
            unit_steps: true,
            decoder: DecoderConfig {
                counts_per_detent: CountsPerDetent::Two,
                invert: true,
            },
            backlog_bound: 300,
        };
        assert_eq!(p.to_blob(), [1, 1, 2, 1, 0x2C, 0x01]);
        assert_eq!(WheelParameters::from_blob(&p.to_blob()), Some(p));
    }

    #[test]
    fn bad_blobs_are_refused() {
        let good = WheelParameters::DEFAULT.to_blob();
        assert!(WheelParameters::from_blob(&good).is_some());
        for (i, bad) in [(0, 2), (1, 2), (2, 3), (3, 7), (4, 0)] {
            let mut blob = good;
            blob[i] = bad;
            if i == 4 {
                blob[5] = 0;
            }
            assert_eq!(WheelParameters::from_blob(&blob), None, "byte {i} = {bad}");
        }
        assert_eq!(WheelParameters::from_blob(&good[..5]), None);
        assert_eq!(WheelParameters::from_blob(&[]), None);
    }
}
