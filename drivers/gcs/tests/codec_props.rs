//! Random and mutated input to the GCS parsers: no panic, no endless loop, bounded buffers,
//! and the same frames whichever way the bytes are split across reads.
use bytes::BytesMut;
use csmetro_gcs::{encode_reply, ReplyError, MAX_COMMAND_LEN, MAX_REPLY_LEN};
use csmetro_gcs::{ClientCodec, Command, Reply, RequestBody, ServerCodec};
use proptest::prelude::*;
use tokio_util::codec::Decoder;

/// Decodes `chunks` fed one after another, checking after every `None` that the decoder
/// keeps at most `max_kept` bytes, and that every frame consumed input (no endless loop).
fn feed<D: Decoder>(d: &mut D, chunks: &[Vec<u8>], max_kept: usize) -> Vec<D::Item>
where
    D::Error: std::fmt::Debug,
{
    let total: usize = chunks.iter().map(Vec::len).sum();
    let mut buf = BytesMut::new();
    let mut out = Vec::new();
    for c in chunks {
        buf.extend_from_slice(c);
        loop {
            let before = buf.len();
            match d.decode(&mut buf).expect("decoders never fail on bytes") {
                Some(item) => {
                    assert!(buf.len() < before, "a frame must consume input");
                    out.push(item);
                    assert!(out.len() <= total, "more frames than bytes");
                }
                None => {
                    assert!(
                        buf.len() <= max_kept,
                        "kept {} bytes waiting for more",
                        buf.len()
                    );
                    break;
                }
            }
        }
    }
    out
}

/// Splits `bytes` at the given cut points.
fn split(bytes: &[u8], cuts: &[usize]) -> Vec<Vec<u8>> {
    let mut cuts: Vec<usize> = cuts.iter().map(|c| c % (bytes.len() + 1)).collect();
    cuts.sort_unstable();
    let mut out = Vec::new();
    let mut at = 0;
    for c in cuts.into_iter().chain([bytes.len()]) {
        out.push(bytes[at..c].to_vec());
        at = c;
    }
    out
}

/// Bytes that look like GCS traffic: letters, digits, separators, LF, CR, control bytes,
/// 0xB0/0xB1 and anything else.
fn wire_byte() -> impl Strategy<Value = u8> {
    prop_oneof![
        6 => prop::sample::select(b"POSMVERFLT?*1 0x.=-\n".to_vec()),
        1 => prop::sample::select(vec![b'\r', 0x04, 0x05, 0x07, 0x08, 0x18, 0xB0, 0xB1, b' ']),
        1 => any::<u8>(),
    ]
}

/// Server frames with the free text of refused frames left out (it depends on where a read
/// ended, the code does not).
fn server_bodies(items: Vec<csmetro_gcs::Request>) -> Vec<(Option<(u8, u8)>, String)> {
    items
        .into_iter()
        .map(|r| {
            let a = r.address.map(|a| (a.target, a.sender));
            let b = match r.body {
                RequestBody::Control(c) => format!("#{}", c.byte()),
                RequestBody::Line(l) => format!("line {l}"),
                RequestBody::Invalid { code, .. } => format!("invalid {code}"),
            };
            (a, b)
        })
        .collect()
}

/// A valid command line, then mutated.
fn command_text() -> impl Strategy<Value = String> {
    prop_oneof![
        "(MOV|MVR|SVO|VEL|ACC|DEC|RON|POS) 1 -?[0-9]{1,3}(\\.[0-9]{1,4})?",
        "(POS|ONT|MOV|FRF|TMN|TMX|CST)\\? ?1?",
        "SPA\\?( 1 (0x[0-9A-F]{1,2}|[0-9]{1,3})){0,3}",
        "SPA( 1 0x[0-9A-F]{1,2} [A-Za-z0-9.\\-]{1,6}){1,2}",
        "(FRF|FNL|FPL|HLT|STP|ERR\\?|CSV\\?|\\*IDN\\?|SAI\\?( ALL)?)( 1)?",
        "[ -~]{0,40}",
        "\\PC{0,20}",
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn server_codec_is_split_independent_and_bounded(
        bytes in prop::collection::vec(wire_byte(), 0..3000),
        cuts in prop::collection::vec(any::<usize>(), 0..8),
    ) {
        let one = std::slice::from_ref(&bytes);
        let whole = feed(&mut ServerCodec::default(), one, MAX_COMMAND_LEN);
        let parts = feed(&mut ServerCodec::default(), &split(&bytes, &cuts), MAX_COMMAND_LEN);
        prop_assert_eq!(server_bodies(whole), server_bodies(parts));
    }

    #[test]
    fn client_codec_is_split_independent_and_bounded(
        bytes in prop::collection::vec(wire_byte(), 0..3000),
        cuts in prop::collection::vec(any::<usize>(), 0..8),
        addressed in any::<bool>(),
    ) {
        let a = addressed.then_some(1);
        let one = std::slice::from_ref(&bytes);
        let whole = feed(&mut ClientCodec::new(a), one, MAX_REPLY_LEN);
        let parts = feed(&mut ClientCodec::new(a), &split(&bytes, &cuts), MAX_REPLY_LEN);
        prop_assert_eq!(whole, parts);
    }

    #[test]
    fn a_line_that_never_ends_does_not_grow_any_buffer(
        byte in wire_byte().prop_filter("not LF", |b| *b != b'\n'),
        chunk in 1000usize..9000,
    ) {
        // 160 KiB without LF, read by read: both ends stay within their line limits.
        let chunks = vec![vec![byte; chunk]; 160 * 1024 / chunk];
        let replies = feed(&mut ClientCodec::default(), &chunks, MAX_REPLY_LEN);
        prop_assert!(!replies.is_empty());
        prop_assert!(replies.iter().all(|r| *r == Err(ReplyError::TooLong)));
        let requests = feed(&mut ServerCodec::default(), &chunks, MAX_COMMAND_LEN);
        if csmetro_gcs::ControlByte::from_byte(byte).is_none() {
            prop_assert!(!requests.is_empty());
            let all_too_long = requests
                .iter()
                .all(|r| matches!(r.body, RequestBody::Invalid { code: 3, .. }));
            prop_assert!(all_too_long);
        }
    }

    #[test]
    fn parsed_commands_round_trip_through_their_bytes(text in command_text()) {
        if let Ok(c) = Command::parse(&text) {
            let bytes = c.to_bytes();
            prop_assert_eq!(bytes.last(), Some(&b'\n'));
            prop_assert_eq!(bytes.iter().filter(|&&b| b == b'\n').count(), 1);
            prop_assert_eq!(Command::parse(&c.to_string()), Ok(c));
        }
    }

    #[test]
    fn mutated_frames_never_panic_a_parser(
        text in command_text(),
        lines in prop::collection::vec("[ -~\\x{80}-\\x{ff}]{0,12}", 1..4),
        edits in prop::collection::vec((any::<usize>(), any::<u8>(), 0u8..3), 0..6),
    ) {
        let mut wire = BytesMut::new();
        encode_reply(&Reply::lines(lines), &mut wire);
        let mut bytes = [text.into_bytes(), b"\n".to_vec(), wire.to_vec()].concat();
        for (at, b, op) in edits {
            let at = at % (bytes.len() + 1);
            match op {
                0 => bytes.insert(at, b),
                1 if at < bytes.len() => { bytes.remove(at); }
                _ if at < bytes.len() => bytes[at] = b,
                _ => {}
            }
        }
        let one = std::slice::from_ref(&bytes);
        for r in feed(&mut ServerCodec::default(), one, MAX_COMMAND_LEN) {
            if let RequestBody::Line(l) = r.body {
                let _ = Command::parse(&l);
            }
        }
        let probe = Command::parse("SPA? 1 0x15 1 0xA").unwrap();
        for r in feed(&mut ClientCodec::new(Some(1)), &[bytes], MAX_REPLY_LEN)
            .into_iter()
            .flatten()
        {
            let _ = (r.axis_f64("1"), r.axis_bool("1"), r.single());
            let _ = probe.check_reply_shape(&r);
            let _ = Command::Err.check_reply_shape(&r);
        }
    }
}
