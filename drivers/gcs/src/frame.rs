//! Typed GCS 2.0 frames: the commands a C-863 understands (as the client sends them and the
//! simulated controller parses them) and replies.
//!
//! Units on the wire are millimetres and seconds; this module does no unit conversion.
use std::fmt;

use crate::error::{
    E17_PARAM_OUT_OF_RANGE, E1_PARAM_SYNTAX, E25_INVALID_FLOAT, E2_UNKNOWN_COMMAND,
};

/// The single-byte commands, sent without LF (their replies do end with LF).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ControlByte {
    /// #4: status register (`0x9005`-style hex word).
    Status = 0x04,
    /// #5: motion status, hex bitmask of moving axes.
    MotionStatus = 0x05,
    /// #7: controller ready, 0xB1 ready / 0xB0 busy.
    Ready = 0x07,
    /// #8: is a macro running.
    MacroRunning = 0x08,
    /// #24: stop all axes (sets error 10).
    StopAll = 0x18,
}

impl ControlByte {
    /// The control command of a byte, `None` for bytes that are not one.
    pub fn from_byte(b: u8) -> Option<Self> {
        Some(match b {
            0x04 => Self::Status,
            0x05 => Self::MotionStatus,
            0x07 => Self::Ready,
            0x08 => Self::MacroRunning,
            0x18 => Self::StopAll,
            _ => return None,
        })
    }
    /// The byte sent on the wire.
    pub fn byte(self) -> u8 {
        self as u8
    }
}

/// `#7` reply byte: controller ready.
pub const READY: char = '\u{B1}';
/// `#7` reply byte: controller busy (e.g. referencing).
pub const BUSY: char = '\u{B0}';

/// Queries that take an optional list of axes and answer `axis=value` per axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum AxisQuery {
    /// `POS?`: current position, mm.
    Pos,
    /// `MOV?`: commanded target, mm.
    Mov,
    /// `ONT?`: on-target state (0|1).
    Ont,
    /// `SVO?`: servo state (0|1).
    Svo,
    /// `FRF?`: referenced state (0|1).
    Frf,
    /// `VEL?`: velocity, mm/s.
    Vel,
    /// `ACC?`: acceleration, mm/s².
    Acc,
    /// `DEC?`: deceleration, mm/s².
    Dec,
    /// `TMN?`: low end of travel, mm.
    Tmn,
    /// `TMX?`: high end of travel, mm.
    Tmx,
    /// `LIM?`: whether the axis has limit switches (0|1).
    Lim,
    /// `TRS?`: whether the axis has a reference switch (0|1).
    Trs,
    /// `RON?`: reference mode (0|1).
    Ron,
    /// `CST?`: stage name.
    Cst,
}

impl AxisQuery {
    /// Every query, in declaration order.
    pub const ALL: [AxisQuery; 14] = [
        Self::Pos,
        Self::Mov,
        Self::Ont,
        Self::Svo,
        Self::Frf,
        Self::Vel,
        Self::Acc,
        Self::Dec,
        Self::Tmn,
        Self::Tmx,
        Self::Lim,
        Self::Trs,
        Self::Ron,
        Self::Cst,
    ];
    /// The GCS mnemonic, with its `?`.
    pub fn mnemonic(self) -> &'static str {
        match self {
            Self::Pos => "POS?",
            Self::Mov => "MOV?",
            Self::Ont => "ONT?",
            Self::Svo => "SVO?",
            Self::Frf => "FRF?",
            Self::Vel => "VEL?",
            Self::Acc => "ACC?",
            Self::Dec => "DEC?",
            Self::Tmn => "TMN?",
            Self::Tmx => "TMX?",
            Self::Lim => "LIM?",
            Self::Trs => "TRS?",
            Self::Ron => "RON?",
            Self::Cst => "CST?",
        }
    }
}

/// Setters of the form `CMD axis value [axis value ...]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum AxisSetter {
    /// Servo on/off (0|1).
    Svo,
    /// Absolute move, mm.
    Mov,
    /// Relative move, mm.
    Mvr,
    /// Velocity, mm/s.
    Vel,
    /// Acceleration, mm/s².
    Acc,
    /// Deceleration, mm/s².
    Dec,
    /// Reference mode on/off (0|1).
    Ron,
    /// Set the current position (only with RON 0), mm.
    Pos,
}

impl AxisSetter {
    /// Every setter, in declaration order.
    pub const ALL: [AxisSetter; 8] = [
        Self::Svo,
        Self::Mov,
        Self::Mvr,
        Self::Vel,
        Self::Acc,
        Self::Dec,
        Self::Ron,
        Self::Pos,
    ];
    /// The GCS mnemonic.
    pub fn mnemonic(self) -> &'static str {
        match self {
            Self::Svo => "SVO",
            Self::Mov => "MOV",
            Self::Mvr => "MVR",
            Self::Vel => "VEL",
            Self::Acc => "ACC",
            Self::Dec => "DEC",
            Self::Ron => "RON",
            Self::Pos => "POS",
        }
    }
    /// Boolean setters accept only 0 or 1.
    pub fn is_boolean(self) -> bool {
        matches!(self, Self::Svo | Self::Ron)
    }
}

/// Reference move kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "UPPERCASE")]
pub enum RefMode {
    /// Reference switch.
    Frf,
    /// Negative limit switch.
    Fnl,
    /// Positive limit switch.
    Fpl,
}

impl RefMode {
    /// The GCS mnemonic.
    pub fn mnemonic(self) -> &'static str {
        match self {
            Self::Frf => "FRF",
            Self::Fnl => "FNL",
            Self::Fpl => "FPL",
        }
    }
}

/// One GCS command.
#[derive(Debug, Clone, PartialEq)]
pub enum Command {
    /// A single-byte control command (`#5`, `#7`, ...).
    Control(ControlByte),
    /// `*IDN?`
    Idn,
    /// `CSV?` (GCS syntax version)
    Csv,
    /// `SAI?` / `SAI? ALL`
    Sai {
        /// `true`: `SAI? ALL`; `false`: `SAI?`.
        all: bool,
    },
    /// `ERR?` (reading clears the error)
    Err,
    /// `HLP?` (multi-line reply)
    Hlp,
    /// `POS?`, `ONT? 1`, ... (empty axes = all axes)
    Query {
        /// Which query.
        query: AxisQuery,
        /// Axis identifiers; empty: all axes.
        axes: Vec<String>,
    },
    /// `MOV 1 7.5`, `SVO 1 1`, ...
    Set {
        /// Which setter.
        setter: AxisSetter,
        /// `(axis, value)` pairs, value in the setter's unit.
        args: Vec<(String, f64)>,
    },
    /// `FRF 1` / `FNL` / `FPL 1` (empty axes = all axes)
    Reference {
        /// Which reference move.
        mode: RefMode,
        /// Axis identifiers; empty: all axes.
        axes: Vec<String>,
    },
    /// `HLT` / `HLT 1`: stop smoothly
    Halt {
        /// Axis identifiers; empty: all axes.
        axes: Vec<String>,
    },
    /// `STP`: stop all abruptly
    Stop,
    /// `SPA 1 0x... value`
    SetParam {
        /// `(axis, parameter id, value as text)` triples.
        items: Vec<(String, u32, String)>,
    },
    /// `SPA? 1 0x...` (empty = all)
    QueryParam {
        /// `(axis, parameter id)` pairs.
        items: Vec<(String, u32)>,
    },
}

fn fmt_value(v: f64) -> String {
    // Shortest representation that round-trips; GCS accepts plain decimals.
    let s = format!("{v}");
    if s == "-0" {
        "0".into()
    } else {
        s
    }
}

impl Command {
    /// The bytes to send: a line with LF, or a lone control byte.
    pub fn to_bytes(&self) -> Vec<u8> {
        match self {
            Command::Control(c) => vec![c.byte()],
            other => {
                let mut v = other.to_string().into_bytes();
                v.push(b'\n');
                v
            }
        }
    }

    /// Whether the controller answers this command (queries and control bytes except #24).
    pub fn expects_reply(&self) -> bool {
        match self {
            Command::Control(c) => *c != ControlByte::StopAll,
            Command::Idn
            | Command::Csv
            | Command::Sai { .. }
            | Command::Err
            | Command::Hlp
            | Command::Query { .. }
            | Command::QueryParam { .. } => true,
            _ => false,
        }
    }

    /// Whether `r` has the shape of this command's answer: no control characters, one
    /// `axis=value` line per asked axis (in order), one `axis id=value` line per asked
    /// parameter, an integer for `ERR?`, 0xB1/0xB0 for `#7`, hex for `#4`/`#5`, a number for
    /// `CSV?`, `vendor, model, serial, firmware` for `*IDN?`, axis names for `SAI?`. A reply of
    /// the wrong shape cannot be this command's, whatever else it is.
    pub fn check_reply_shape(&self, r: &Reply) -> Result<(), String> {
        let one = || r.single().map(str::trim);
        let fail = |what: &str| Err(format!("reply {:?} is not {what}", r.lines));
        if r.lines
            .iter()
            .any(|l| l.chars().any(|c| c.is_ascii_control()))
        {
            return fail("text (it holds control characters)");
        }
        match self {
            Command::Control(ControlByte::Ready) => match one()? {
                l if l == READY.to_string() || l == BUSY.to_string() => Ok(()),
                _ => fail("0xB1 or 0xB0 (#7)"),
            },
            Command::Control(ControlByte::Status | ControlByte::MotionStatus) => {
                let l = one()?;
                let h = l.strip_prefix("0x").unwrap_or(l);
                if !h.is_empty() && h.bytes().all(|b| b.is_ascii_hexdigit()) {
                    Ok(())
                } else {
                    fail("a hex word (#4, #5)")
                }
            }
            Command::Control(ControlByte::MacroRunning) | Command::Err => {
                match one()?.parse::<i64>() {
                    Ok(_) => Ok(()),
                    Err(_) => fail("an integer"),
                }
            }
            Command::Csv => match one()?.parse::<f64>() {
                Ok(v) if v.is_finite() => Ok(()),
                _ => fail("a syntax version"),
            },
            Command::Idn => match one()?.split(',').count() {
                n if n >= 3 => Ok(()),
                _ => fail("`vendor, model, serial, firmware`"),
            },
            Command::Sai { .. } => {
                let axis_name = |l: &String| {
                    let l = l.trim();
                    !l.is_empty() && l.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
                };
                if !r.lines.is_empty() && r.lines.iter().all(axis_name) {
                    Ok(())
                } else {
                    fail("axis names")
                }
            }
            Command::Query { axes, .. } if !axes.is_empty() => {
                if r.lines.len() != axes.len() {
                    return fail(&format!("{} `axis=value` lines", axes.len()));
                }
                for (l, a) in r.lines.iter().zip(axes) {
                    match l.split_once('=') {
                        Some((got, _)) if got.trim() == a => {}
                        _ => return fail(&format!("`{a}=value`")),
                    }
                }
                Ok(())
            }
            Command::QueryParam { items } if !items.is_empty() => {
                if r.lines.len() != items.len() {
                    return fail(&format!("{} `axis id=value` lines", items.len()));
                }
                for (l, (a, id)) in r.lines.iter().zip(items) {
                    let ok = l.split_once('=').is_some_and(|(head, _)| {
                        let mut t = head.split_ascii_whitespace();
                        t.next() == Some(a.as_str())
                            && t.next().map(parse_param_id) == Some(Ok(*id))
                            && t.next().is_none()
                    });
                    if !ok {
                        return fail(&format!("`{a} 0x{id:X}=value`"));
                    }
                }
                Ok(())
            }
            Command::Query { .. } | Command::QueryParam { .. } => {
                if !r.lines.is_empty() && r.lines.iter().all(|l| l.contains('=')) {
                    Ok(())
                } else {
                    fail("`key=value` lines")
                }
            }
            _ => Ok(()),
        }
    }

    /// Parses one command line (without LF and address prefix), as a controller does.
    /// Errors are GCS error codes: 2 unknown command, 1 syntax, 25 invalid float, 17 out of range.
    /// Axis identifiers are not checked here (the controller knows its axes: error 15).
    pub fn parse(line: &str) -> Result<Command, i32> {
        let mut tokens = line.split_ascii_whitespace();
        let Some(head) = tokens.next() else {
            return Err(E2_UNKNOWN_COMMAND);
        };
        let args: Vec<&str> = tokens.collect();
        let head = head.to_ascii_uppercase();
        let no_args = |c: Command| {
            if args.is_empty() {
                Ok(c)
            } else {
                Err(E1_PARAM_SYNTAX)
            }
        };
        let axes = || args.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        match head.as_str() {
            "*IDN?" => no_args(Command::Idn),
            "CSV?" => no_args(Command::Csv),
            "ERR?" => no_args(Command::Err),
            "HLP?" => no_args(Command::Hlp),
            "STP" => no_args(Command::Stop),
            "SAI?" => match args.as_slice() {
                [] => Ok(Command::Sai { all: false }),
                [a] if a.eq_ignore_ascii_case("ALL") => Ok(Command::Sai { all: true }),
                _ => Err(E1_PARAM_SYNTAX),
            },
            "HLT" => Ok(Command::Halt { axes: axes() }),
            "FRF" | "FNL" | "FPL" => {
                let mode = match head.as_str() {
                    "FRF" => RefMode::Frf,
                    "FNL" => RefMode::Fnl,
                    _ => RefMode::Fpl,
                };
                Ok(Command::Reference { mode, axes: axes() })
            }
            "SPA" => {
                if args.is_empty() || !args.len().is_multiple_of(3) {
                    return Err(E1_PARAM_SYNTAX);
                }
                let items = args
                    .chunks(3)
                    .map(|c| Ok((c[0].to_string(), parse_param_id(c[1])?, c[2].to_string())))
                    .collect::<Result<Vec<_>, i32>>()?;
                Ok(Command::SetParam { items })
            }
            "SPA?" => {
                if !args.len().is_multiple_of(2) {
                    return Err(E1_PARAM_SYNTAX);
                }
                let items = args
                    .chunks(2)
                    .map(|c| Ok((c[0].to_string(), parse_param_id(c[1])?)))
                    .collect::<Result<Vec<_>, i32>>()?;
                Ok(Command::QueryParam { items })
            }
            h => {
                if let Some(q) = AxisQuery::ALL.iter().find(|q| q.mnemonic() == h) {
                    return Ok(Command::Query {
                        query: *q,
                        axes: axes(),
                    });
                }
                if let Some(s) = AxisSetter::ALL.iter().find(|s| s.mnemonic() == h) {
                    if args.is_empty() || !args.len().is_multiple_of(2) {
                        return Err(E1_PARAM_SYNTAX);
                    }
                    let mut pairs = Vec::new();
                    for c in args.chunks(2) {
                        let v = parse_float(c[1])?;
                        if s.is_boolean() && v != 0.0 && v != 1.0 {
                            return Err(E17_PARAM_OUT_OF_RANGE);
                        }
                        pairs.push((c[0].to_string(), v));
                    }
                    return Ok(Command::Set {
                        setter: *s,
                        args: pairs,
                    });
                }
                Err(E2_UNKNOWN_COMMAND)
            }
        }
    }
}

/// A float argument; GCS rejects NaN/inf and non-numbers with error 25.
pub fn parse_float(s: &str) -> Result<f64, i32> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(E25_INVALID_FLOAT),
    }
}

/// A parameter id, decimal (`60`) or hexadecimal (`0x3C`).
pub fn parse_param_id(s: &str) -> Result<u32, i32> {
    let r = match s.strip_prefix("0x").or_else(|| s.strip_prefix("0X")) {
        Some(h) => u32::from_str_radix(h, 16),
        None => s.parse::<u32>(),
    };
    r.map_err(|_| E1_PARAM_SYNTAX)
}

impl fmt::Display for Command {
    /// The command line without LF (control bytes as `#N`, for logs).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let join = |axes: &[String]| {
            if axes.is_empty() {
                String::new()
            } else {
                format!(" {}", axes.join(" "))
            }
        };
        match self {
            Command::Control(c) => write!(f, "#{}", c.byte()),
            Command::Idn => f.write_str("*IDN?"),
            Command::Csv => f.write_str("CSV?"),
            Command::Sai { all } => f.write_str(if *all { "SAI? ALL" } else { "SAI?" }),
            Command::Err => f.write_str("ERR?"),
            Command::Hlp => f.write_str("HLP?"),
            Command::Query { query, axes } => write!(f, "{}{}", query.mnemonic(), join(axes)),
            Command::Set { setter, args } => {
                f.write_str(setter.mnemonic())?;
                for (a, v) in args {
                    if setter.is_boolean() {
                        write!(f, " {a} {}", *v as i64)?;
                    } else {
                        write!(f, " {a} {}", fmt_value(*v))?;
                    }
                }
                Ok(())
            }
            Command::Reference { mode, axes } => write!(f, "{}{}", mode.mnemonic(), join(axes)),
            Command::Halt { axes } => write!(f, "HLT{}", join(axes)),
            Command::Stop => f.write_str("STP"),
            Command::SetParam { items } => {
                f.write_str("SPA")?;
                for (a, id, v) in items {
                    write!(f, " {a} 0x{id:X} {v}")?;
                }
                Ok(())
            }
            Command::QueryParam { items } => {
                f.write_str("SPA?")?;
                for (a, id) in items {
                    write!(f, " {a} 0x{id:X}")?;
                }
                Ok(())
            }
        }
    }
}

/// `<target> <sender>` prefix of daisy-chain frames (the PC is address 0).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Address {
    /// Address of the receiving controller.
    pub target: u8,
    /// Address of the sending device (0 for the PC).
    pub sender: u8,
}

/// One reply: one or more lines (without the continuation space and LF).
/// Bytes are mapped 1:1 to chars (Latin-1), so the #7 reply 0xB1 is `'\u{B1}'`.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Reply {
    /// Daisy-chain prefix, if the reply had one.
    pub address: Option<Address>,
    /// The reply's lines, in order.
    pub lines: Vec<String>,
}

impl Reply {
    /// A one-line reply without an address.
    pub fn line(s: impl Into<String>) -> Self {
        Self {
            address: None,
            lines: vec![s.into()],
        }
    }
    /// A multi-line reply without an address.
    pub fn lines(lines: Vec<String>) -> Self {
        Self {
            address: None,
            lines,
        }
    }
    /// The single line of a one-line reply, else a protocol complaint.
    pub fn single(&self) -> Result<&str, String> {
        match self.lines.as_slice() {
            [l] => Ok(l.as_str()),
            _ => Err(format!("expected one reply line, got {}", self.lines.len())),
        }
    }
    /// `axis=value` of a one-axis reply; the value as text.
    pub fn axis_value(&self, axis: &str) -> Result<&str, String> {
        let l = self.single()?;
        let (a, v) = l
            .split_once('=')
            .ok_or_else(|| format!("no `axis=value` in reply {l:?}"))?;
        if a.trim() != axis {
            return Err(format!(
                "reply {l:?} is for axis {:?}, not {axis:?}",
                a.trim()
            ));
        }
        Ok(v.trim())
    }
    /// `axis=value` of a one-axis reply as a finite number.
    pub fn axis_f64(&self, axis: &str) -> Result<f64, String> {
        let v = self.axis_value(axis)?;
        parse_float(v).map_err(|_| format!("not a number in reply: {v:?}"))
    }
    /// `axis=value` of a one-axis reply as a 0|1 boolean.
    pub fn axis_bool(&self, axis: &str) -> Result<bool, String> {
        match self.axis_value(axis)? {
            "0" => Ok(false),
            "1" => Ok(true),
            v => Err(format!("expected 0 or 1, got {v:?}")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn commands_round_trip_through_their_text() {
        let cmds = [
            Command::Idn,
            Command::Sai { all: true },
            Command::Query {
                query: AxisQuery::Pos,
                axes: vec!["1".into()],
            },
            Command::Set {
                setter: AxisSetter::Mov,
                args: vec![("1".into(), 7.5)],
            },
            Command::Set {
                setter: AxisSetter::Svo,
                args: vec![("1".into(), 1.0)],
            },
            Command::Reference {
                mode: RefMode::Fnl,
                axes: vec!["1".into()],
            },
            Command::Halt { axes: vec![] },
            Command::SetParam {
                items: vec![("1".into(), 0x3C, "M-111.1DG".into())],
            },
            Command::QueryParam {
                items: vec![("1".into(), 0x15)],
            },
        ];
        for c in cmds {
            assert_eq!(Command::parse(&c.to_string()), Ok(c.clone()), "{c}");
        }
        assert_eq!(
            Command::Set {
                setter: AxisSetter::Mov,
                args: vec![("1".into(), 0.1234567)]
            }
            .to_string(),
            "MOV 1 0.1234567"
        );
    }

    #[test]
    fn parse_reports_the_gcs_error_codes() {
        assert_eq!(Command::parse("FOO 1"), Err(2));
        assert_eq!(Command::parse("MOV 1"), Err(1));
        assert_eq!(Command::parse("MOV 1 abc"), Err(25));
        assert_eq!(Command::parse("MOV 1 nan"), Err(25));
        assert_eq!(Command::parse("SVO 1 2"), Err(17));
        assert_eq!(Command::parse("SPA 1 0xZZ 3"), Err(1));
        assert_eq!(
            Command::parse("mov 1 2"),
            Command::parse("MOV 1 2"),
            "mnemonics are case-insensitive"
        );
        assert_eq!(
            Command::parse("SPA? 1 60"),
            Ok(Command::QueryParam {
                items: vec![("1".into(), 0x3C)]
            }),
            "decimal and 0x ids are the same parameter"
        );
    }

    #[test]
    fn reply_shape_tells_apart_the_answers_of_different_commands() {
        let pos = Command::Query {
            query: AxisQuery::Pos,
            axes: vec!["1".into()],
        };
        assert_eq!(pos.check_reply_shape(&Reply::line("1=7.5")), Ok(()));
        for wrong in ["\u{B1}", "0", "2.0", "2=7.5", "\u{fe}#~garbled\u{1}@"] {
            assert!(
                pos.check_reply_shape(&Reply::line(wrong)).is_err(),
                "{wrong:?}"
            );
        }
        let ready = Command::Control(ControlByte::Ready);
        assert_eq!(ready.check_reply_shape(&Reply::line("\u{B0}")), Ok(()));
        assert!(ready.check_reply_shape(&Reply::line("1=1")).is_err());
        assert!(Command::Err.check_reply_shape(&Reply::line("1=0")).is_err());
        assert_eq!(Command::Err.check_reply_shape(&Reply::line("1024")), Ok(()));
        let spa = Command::QueryParam {
            items: vec![("1".into(), 0x15), ("1".into(), 0x0A)],
        };
        let two = |a: &str, b: &str| Reply::lines(vec![a.into(), b.into()]);
        assert_eq!(spa.check_reply_shape(&two("1 0x15=15", "1 10=1.5")), Ok(()));
        assert!(spa
            .check_reply_shape(&two("1 0x0A=1.5", "1 0x15=15"))
            .is_err());
        assert!(spa.check_reply_shape(&Reply::line("1 0x15=15")).is_err());
        let garbage = Reply::line("\u{fe}#~garbled\u{1}@");
        for c in [
            Command::Csv,
            Command::Idn,
            Command::Sai { all: false },
            Command::Hlp,
        ] {
            assert!(c.check_reply_shape(&garbage).is_err(), "{c}");
        }
        assert_eq!(Command::Csv.check_reply_shape(&Reply::line("2.0")), Ok(()));
        assert_eq!(
            Command::Sai { all: true }.check_reply_shape(&Reply::line("1")),
            Ok(())
        );
    }

    #[test]
    fn reply_accessors_check_axis_and_shape() {
        let r = Reply::line("1=7.5000");
        assert_eq!(r.axis_f64("1"), Ok(7.5));
        assert!(r.axis_f64("2").is_err());
        assert!(Reply::line("garbage").axis_f64("1").is_err());
        assert!(Reply::lines(vec!["1=1".into(), "1=0".into()])
            .axis_bool("1")
            .is_err());
    }
}
