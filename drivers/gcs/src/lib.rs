#![doc = include_str!("../README.md")]
// Lints: the workspace wall (Cargo.toml `[workspace.lints]`), plus docs on everything public.
#![warn(missing_docs)]
// Modules are private; the curated list below is the crate's API. `error` stays a public
// namespace: its `E*` constants are the controller's error codes, read as `error::E7_...`.
mod client;
mod codec;
pub mod error;
mod frame;

pub use client::{C863Config, LinkStats, Transport, C863};
pub use codec::{
    encode_reply, ClientCodec, ReplyError, Request, RequestBody, ServerCodec, MAX_COMMAND_LEN,
    MAX_REPLY_LEN,
};
pub use error::error_message;
pub use frame::{
    parse_float, parse_param_id, Address, AxisQuery, AxisSetter, Command, ControlByte, RefMode,
    Reply, BUSY, READY,
};
