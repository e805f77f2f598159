//! A minimal, hand-written CANopen (CiA 301) device engine.
//!
//! `no_std`, no allocation, no HAL: frames go in through [`Device::on_frame`], time through
//! every call, and frames come out through a [`FrameSink`]. The object dictionary is a
//! static table ([`Od`]) declared by the application, whose own objects are reached
//! through the [`Application`] trait.
//!
//! Supported: NMT slave, SDO server (expedited and segmented) and a second one configured
//! through 0x1201, heartbeat producer and two consumers, SYNC consumer, two TPDOs (event-driven and synchronous) and one RPDO (acting at once or at the next SYNC, with deadline monitoring), with dynamic mapping,
//! EMCY producer with error history, store/restore of parameters, CiA 303-3 indicators, the
//! CAN controller's error states as EMCYs and LED codes ([`bus`]), the LSS slave of CiA 305
//! ([`lss`]: node-ID and bit timing over the bus, fastscan, unconfigured nodes), and helpers to drive the
//! engine from a 32-bit millisecond tick ([`WideClock`], [`sleep_ms`], [`Periodic`]).
//!
//! ```
//! use canopen_slave::*;
//!
//! const IDENTITY: Identity = Identity {
//!     device_type: 0x0002_0196,
//!     vendor_id: 0x123,
//!     product_code: 1,
//!     revision: 1,
//!     device_name: "Handwheel",
//!     hardware_version: "A",
//!     software_version: "0.1.0",
//! };
//! static STANDARD: [OdEntry; STANDARD_OBJECTS] =
//!     standard_objects(&IDENTITY, &CommDefaults::DEFAULT);
//! static OBJECTS: [OdEntry; 2] = [
//!     OdEntry::app(0x2000, 0, DataType::U8, Access::Rw).range(0, 1),
//!     OdEntry::app(0x6004, 0, DataType::I32, Access::Ro).mappable(),
//! ];
//! static OD: Od = Od::checked(&[&STANDARD, &OBJECTS]);
//!
//! struct App {
//!     flag: u8,
//!     position: i32,
//! }
//!
//! impl Application for App {
//!     fn read(&mut self, index: u16, _sub: u8, buf: &mut [u8]) -> Result<usize, SdoAbort> {
//!         let bytes = match index {
//!             0x2000 => &[self.flag][..],
//!             _ => &self.position.to_le_bytes()[..],
//!         };
//!         buf.get_mut(..bytes.len()).ok_or(SdoAbort::OutOfMemory)?.copy_from_slice(bytes);
//!         Ok(bytes.len())
//!     }
//!     fn write(&mut self, _index: u16, _sub: u8, data: &[u8]) -> Result<(), SdoAbort> {
//!         self.flag = data.first().copied().unwrap_or(0);
//!         Ok(())
//!     }
//! }
//!
//! let node = NodeId::new(5).unwrap();
//! let mut dev = Device::new(Config::new(node), OD, MemoryStorage::new());
//! let mut app = App { flag: 0, position: 0 };
//! let mut tx: heapless::Vec<Frame, 8> = heapless::Vec::new();
//! dev.start(Instant::ZERO, &mut app, &mut tx);
//! assert_eq!((tx[0].id(), tx[0].data()), (0x705, &[0x00][..])); // boot-up
//!
//! // An SDO upload of 0x1000 from the master.
//! let request = Frame::new(0x605, &[0x40, 0x00, 0x10, 0, 0, 0, 0, 0]).unwrap();
//! dev.on_frame(Instant::from_millis(1), &request, &mut app, &mut tx);
//! assert_eq!(tx[1].data(), &[0x43, 0x00, 0x10, 0x00, 0x96, 0x01, 0x02, 0x00]);
//!
//! // The firmware polls at the deadline the engine asks for: the first heartbeat.
//! assert_eq!(dev.next_deadline(), Some(Instant::from_millis(1000)));
//! dev.poll(Instant::from_millis(1000), &mut app, &mut tx);
//! assert_eq!(tx[2].data(), &[0x7F]);
//! ```
#![no_std]

#[macro_use]
mod log;

mod abort;
mod cob_id;
mod mapping;

pub mod bus;
pub mod crc;
pub mod device;
pub mod emcy;
pub mod filter;
pub mod frame;
pub mod heartbeat;
pub mod identity;
pub mod indicators;
pub mod lss;
pub mod nmt;
pub mod od;
pub mod rpdo;
pub mod sdo;
pub mod storage;
pub mod sync;
pub mod time;
pub mod tpdo;

pub use abort::SdoAbort;
pub use bus::{BusEvent, BusState};
pub use device::objects::params::blob::{APP_MAX, BLOB_MAX};
pub use device::objects::{
    comm_object, standard_objects, CommEntry, CommObject, ObjectName, STANDARD_OBJECTS,
};
pub use device::{Application, Config, Device, NoSuchPdo, Stats};
pub use emcy::EmcyError;
pub use filter::RxFilter;
pub use frame::{Frame, FrameError, FrameSink, InvalidNodeId, NodeId, SinkFull};
pub use identity::{CommDefaults, Identity, RpdoDefaults, TpdoDefaults};
pub use indicators::{indicators, ErrorIndication, Pattern};
pub use lss::{LssAddress, LssSlave, LssState};
pub use nmt::{NmtCommand, NmtState};
pub use od::{Access, DataType, ObjectCode, Od, OdEntry, OdError, Value};
pub use storage::{MemoryStorage, Storage, StorageError};
pub use time::{sleep_ms, Instant, Periodic, WideClock};
