#![doc = include_str!("../README.md")]
// Lints: the workspace wall (Cargo.toml `[workspace.lints]`), plus docs on everything public.
#![warn(missing_docs)]
pub mod client;
pub mod codec;
pub mod error;
pub mod frame;

pub use client::{C863Config, LinkStats, Transport, C863};
pub use codec::{ClientCodec, Request, RequestBody, ServerCodec};
pub use error::error_message;
pub use frame::{Address, AxisQuery, AxisSetter, Command, ControlByte, RefMode, Reply};
