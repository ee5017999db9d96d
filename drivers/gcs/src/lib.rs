//! PI GCS 2.0 for the C-863 Mercury controller: typed frames, a byte codec and the error codes,
//! shared by the async driver ([`client`]) and the simulated controller in `csmetro-sim`.
pub mod client;
pub mod codec;
pub mod error;
pub mod frame;

pub use client::{C863Config, Transport, C863};
pub use codec::{ClientCodec, Request, RequestBody, ServerCodec};
pub use error::error_message;
pub use frame::{Address, AxisQuery, AxisSetter, Command, ControlByte, RefMode, Reply};
