//! Bytes ⇄ frames for GCS 2.0 over a byte stream (serial line, pty, TCP).
//!
//! - A command is a line ending in LF; the single-byte commands #4 #5 #7 #8 #24 come alone,
//!   without LF, and are recognised only at the start of a frame.
//! - A reply is one or more lines; every line but the last ends with a space before its LF.
//! - CR is never part of the protocol (PI's own client rejects replies with CR).
//! - An optional `<target> <sender> ` prefix addresses a frame on a daisy chain.
use bytes::{Buf, BufMut, BytesMut};
use tokio_util::codec::{Decoder, Encoder};

use crate::error::{E1_PARAM_SYNTAX, E3_COMMAND_TOO_LONG};
use crate::frame::{Address, Command, ControlByte, Reply};

/// Longest command line a controller accepts before error 3.
pub const MAX_COMMAND_LEN: usize = 1024;
/// How much of an overlong command line is kept (for logs).
const INVALID_TEXT_LEN: usize = 40;
/// Longest reply a client accepts (HLP? is the longest, a few KiB).
pub const MAX_REPLY_LEN: usize = 64 * 1024;

/// What a controller receives.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RequestBody {
    /// A single-byte control command.
    Control(ControlByte),
    /// A command line without LF and without address prefix.
    Line(String),
    /// A frame the controller refuses with this error code (CR in a line, line too long).
    Invalid {
        /// The GCS error code the controller sets.
        code: i32,
        /// The refused frame's text (a prefix of it when too long), for logs.
        text: String,
    },
}

#[derive(Debug, Clone, PartialEq, Eq)]
/// One received request: its daisy-chain prefix and body.
pub struct Request {
    /// Daisy-chain prefix, if the request had one.
    pub address: Option<Address>,
    /// What was requested.
    pub body: RequestBody,
}

fn latin1(bytes: &[u8]) -> String {
    bytes.iter().map(|&b| b as char).collect()
}

/// Splits `"<target> <sender> rest"` when the first two tokens are addresses. Commands never
/// start with a digit, so this is unambiguous for command lines.
fn split_address(line: &str) -> (Option<Address>, &str) {
    let mut it = line.splitn(3, ' ');
    if let (Some(t), Some(s), Some(rest)) = (it.next(), it.next(), it.next()) {
        if let (Ok(target), Ok(sender)) = (t.parse::<u8>(), s.parse::<u8>()) {
            if !rest.is_empty() {
                return (Some(Address { target, sender }), rest);
            }
        }
    }
    (None, line)
}

/// Controller side: decodes requests, encodes replies.
#[derive(Debug, Default)]
pub struct ServerCodec {
    /// Skipping the rest of an overlong line.
    discarding: bool,
}

impl Decoder for ServerCodec {
    type Item = Request;
    type Error = std::io::Error;

    fn decode(&mut self, buf: &mut BytesMut) -> Result<Option<Request>, Self::Error> {
        loop {
            if self.discarding {
                match buf.iter().position(|&b| b == b'\n') {
                    Some(i) => {
                        buf.advance(i + 1);
                        self.discarding = false;
                    }
                    None => {
                        buf.clear();
                        return Ok(None);
                    }
                }
            }
            let Some(&first) = buf.first() else {
                return Ok(None);
            };
            if let Some(c) = ControlByte::from_byte(first) {
                buf.advance(1);
                return Ok(Some(Request {
                    address: None,
                    body: RequestBody::Control(c),
                }));
            }
            let Some(i) = buf.iter().position(|&b| b == b'\n') else {
                if buf.len() > MAX_COMMAND_LEN {
                    self.discarding = true;
                    let text = latin1(&buf[..INVALID_TEXT_LEN]);
                    buf.clear();
                    return Ok(Some(Request {
                        address: None,
                        body: RequestBody::Invalid {
                            code: E3_COMMAND_TOO_LONG,
                            text,
                        },
                    }));
                }
                return Ok(None);
            };
            let raw = buf.split_to(i + 1);
            // Too long first: the verdict must not depend on whether the LF came in the
            // same read (a long line without LF yet is error 3 whatever it holds). Its text
            // is cut as in that case, so a refused frame never holds more than a prefix.
            if i > MAX_COMMAND_LEN {
                return Ok(Some(Request {
                    address: None,
                    body: RequestBody::Invalid {
                        code: E3_COMMAND_TOO_LONG,
                        text: latin1(&raw[..INVALID_TEXT_LEN]),
                    },
                }));
            }
            let text = latin1(&raw[..i]);
            if text.trim().is_empty() {
                continue; // blank lines are ignored
            }
            if text.contains('\r') {
                return Ok(Some(Request {
                    address: None,
                    body: RequestBody::Invalid {
                        code: E1_PARAM_SYNTAX,
                        text,
                    },
                }));
            }
            let (address, rest) = split_address(&text);
            return Ok(Some(Request {
                address,
                body: RequestBody::Line(rest.trim().to_string()),
            }));
        }
    }
}

/// Writes a reply: continuation lines end with " \n", the last with "\n".
pub fn encode_reply(reply: &Reply, dst: &mut BytesMut) {
    let n = reply.lines.len().max(1);
    for i in 0..n {
        if i == 0 {
            if let Some(a) = reply.address {
                dst.put_slice(format!("{} {} ", a.target, a.sender).as_bytes());
            }
        }
        if let Some(line) = reply.lines.get(i) {
            dst.extend(line.chars().map(|c| u32::from(c).min(0xFF) as u8));
        }
        if i + 1 < n {
            dst.put_u8(b' ');
        }
        dst.put_u8(b'\n');
    }
}

impl Encoder<Reply> for ServerCodec {
    type Error = std::io::Error;
    fn encode(&mut self, item: Reply, dst: &mut BytesMut) -> Result<(), Self::Error> {
        encode_reply(&item, dst);
        Ok(())
    }
}

/// Why a received reply is not a valid GCS reply. The bytes are consumed; the stream goes on.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ReplyError {
    #[error("reply contains CR: {0:?}")]
    /// The reply contains a CR.
    CarriageReturn(String),
    #[error("reply longer than {MAX_REPLY_LEN} bytes")]
    /// The reply exceeds the maximum reply length.
    TooLong,
}

/// Client side: encodes commands (with an optional address prefix), decodes replies.
#[derive(Debug, Default, Clone)]
pub struct ClientCodec {
    /// Controller address on a daisy chain; `None` = unaddressed (a single controller).
    pub address: Option<u8>,
    /// Bytes of the current reply already scanned for its end.
    scanned: usize,
}

impl ClientCodec {
    /// A codec for the controller at `address` (`None`: unaddressed).
    pub fn new(address: Option<u8>) -> Self {
        Self {
            address,
            scanned: 0,
        }
    }
    /// Forgets the partial reply scanned so far (call when the read buffer is cleared).
    pub fn reset(&mut self) {
        self.scanned = 0;
    }
}

impl Encoder<&Command> for ClientCodec {
    type Error = std::io::Error;
    fn encode(&mut self, cmd: &Command, dst: &mut BytesMut) -> Result<(), Self::Error> {
        if let (Some(a), false) = (self.address, matches!(cmd, Command::Control(_))) {
            dst.put_slice(format!("{a} 0 ").as_bytes());
        }
        dst.put_slice(&cmd.to_bytes());
        Ok(())
    }
}

impl Decoder for ClientCodec {
    /// A reply, or a reply that breaks the protocol (already consumed).
    type Item = Result<Reply, ReplyError>;
    type Error = std::io::Error;

    fn decode(&mut self, buf: &mut BytesMut) -> Result<Option<Self::Item>, Self::Error> {
        // The reply ends at the first LF not preceded by a space.
        let mut end = None;
        // A buffer emptied behind the codec's back restarts the scan.
        if self.scanned > buf.len() {
            self.scanned = 0;
        }
        for i in self.scanned..buf.len() {
            if buf[i] == b'\n' && (i == 0 || buf[i - 1] != b' ') {
                end = Some(i);
                break;
            }
        }
        let Some(end) = end else {
            if buf.len() > MAX_REPLY_LEN {
                buf.clear();
                self.scanned = 0;
                return Ok(Some(Err(ReplyError::TooLong)));
            }
            self.scanned = buf.len();
            return Ok(None);
        };
        self.scanned = 0;
        let raw = buf.split_to(end + 1);
        let text = latin1(&raw[..end]);
        if text.contains('\r') {
            return Ok(Some(Err(ReplyError::CarriageReturn(text))));
        }
        let mut lines: Vec<String> = text.split(" \n").map(str::to_string).collect();
        let mut address = None;
        if self.address.is_some() {
            let (a, rest) = split_address(&lines[0]);
            address = a;
            lines[0] = rest.to_string();
        }
        Ok(Some(Ok(Reply { address, lines })))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode_all(codec: &mut ServerCodec, bytes: &[u8]) -> Vec<Request> {
        let mut buf = BytesMut::from(bytes);
        let mut out = Vec::new();
        while let Some(r) = codec.decode(&mut buf).unwrap() {
            out.push(r);
        }
        out
    }

    fn line(s: &str) -> Request {
        Request {
            address: None,
            body: RequestBody::Line(s.into()),
        }
    }

    #[test]
    fn several_commands_and_control_bytes_in_one_read() {
        let got = decode_all(
            &mut ServerCodec::default(),
            b"SVO 1 1\nERR?\n\x05\x07MOV 1 2\n\x18",
        );
        assert_eq!(
            got,
            vec![
                line("SVO 1 1"),
                line("ERR?"),
                Request {
                    address: None,
                    body: RequestBody::Control(ControlByte::MotionStatus)
                },
                Request {
                    address: None,
                    body: RequestBody::Control(ControlByte::Ready)
                },
                line("MOV 1 2"),
                Request {
                    address: None,
                    body: RequestBody::Control(ControlByte::StopAll)
                },
            ]
        );
    }

    #[test]
    fn lone_control_byte_is_a_whole_command_but_a_partial_line_waits() {
        let mut c = ServerCodec::default();
        let mut buf = BytesMut::from(&b"\x04"[..]);
        assert_eq!(
            c.decode(&mut buf).unwrap(),
            Some(Request {
                address: None,
                body: RequestBody::Control(ControlByte::Status)
            })
        );
        buf.extend_from_slice(b"POS");
        assert_eq!(c.decode(&mut buf).unwrap(), None);
        buf.extend_from_slice(b"? 1\n");
        assert_eq!(c.decode(&mut buf).unwrap(), Some(line("POS? 1")));
    }

    #[test]
    fn addressed_frames_are_split_and_answered_with_swapped_address() {
        let got = decode_all(&mut ServerCodec::default(), b"1 0 POS? 1\n");
        assert_eq!(
            got,
            vec![Request {
                address: Some(Address {
                    target: 1,
                    sender: 0
                }),
                body: RequestBody::Line("POS? 1".into())
            }]
        );
        let mut client = ClientCodec::new(Some(1));
        let mut out = BytesMut::new();
        client.encode(&Command::Idn, &mut out).unwrap();
        assert_eq!(&out[..], b"1 0 *IDN?\n");
        let mut buf = BytesMut::from(&b"0 1 1=2.5\n"[..]);
        let r = client.decode(&mut buf).unwrap().unwrap().unwrap();
        assert_eq!(
            r.address,
            Some(Address {
                target: 0,
                sender: 1
            })
        );
        assert_eq!(r.axis_f64("1"), Ok(2.5));
    }

    #[test]
    fn carriage_return_is_rejected_both_ways() {
        let got = decode_all(&mut ServerCodec::default(), b"POS?\r\nERR?\n");
        assert!(
            matches!(got[0].body, RequestBody::Invalid { code: 1, .. }),
            "{got:?}"
        );
        assert_eq!(got[1], line("ERR?"), "the next command is still understood");
        let mut c = ClientCodec::default();
        let mut buf = BytesMut::from(&b"1=2\r\n0\n"[..]);
        assert!(matches!(
            c.decode(&mut buf).unwrap(),
            Some(Err(ReplyError::CarriageReturn(_)))
        ));
        assert_eq!(c.decode(&mut buf).unwrap(), Some(Ok(Reply::line("0"))));
    }

    #[test]
    fn multi_line_reply_ends_at_lf_without_space_even_split_across_reads() {
        let reply = Reply::lines(vec!["a".into(), "b c".into(), "d".into()]);
        let mut wire = BytesMut::new();
        encode_reply(&reply, &mut wire);
        assert_eq!(&wire[..], b"a \nb c \nd\n");
        let mut c = ClientCodec::default();
        let mut buf = BytesMut::new();
        for (i, b) in wire.iter().enumerate() {
            buf.put_u8(*b);
            let got = c.decode(&mut buf).unwrap();
            if i + 1 < wire.len() {
                assert_eq!(got, None, "complete too early at byte {i}");
            } else {
                assert_eq!(got, Some(Ok(reply.clone())));
            }
        }
    }

    #[test]
    fn ready_byte_survives_the_round_trip() {
        let mut wire = BytesMut::new();
        encode_reply(&Reply::line(crate::frame::READY.to_string()), &mut wire);
        assert_eq!(&wire[..], &[0xB1, b'\n']);
        let r = ClientCodec::default()
            .decode(&mut wire)
            .unwrap()
            .unwrap()
            .unwrap();
        assert_eq!(r.single(), Ok("\u{B1}"));
    }

    #[test]
    fn overlong_line_gives_error_3_and_the_stream_recovers() {
        let mut bytes = vec![b'A'; MAX_COMMAND_LEN + 10];
        bytes.extend_from_slice(b"AAA\nERR?\n");
        let mut c = ServerCodec::default();
        let mut buf = BytesMut::from(&bytes[..MAX_COMMAND_LEN + 5]);
        let first = c.decode(&mut buf).unwrap().unwrap();
        assert!(matches!(first.body, RequestBody::Invalid { code: 3, .. }));
        buf.extend_from_slice(&bytes[MAX_COMMAND_LEN + 5..]);
        assert_eq!(c.decode(&mut buf).unwrap(), Some(line("ERR?")));
    }
}
