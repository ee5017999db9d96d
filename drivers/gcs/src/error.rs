//! GCS 2.0 error codes (as `ERR?` reports them) and their meanings.

/// No error.
pub const E0_NONE: i32 = 0;
/// Parameter syntax error.
pub const E1_PARAM_SYNTAX: i32 = 1;
/// Unknown command.
pub const E2_UNKNOWN_COMMAND: i32 = 2;
/// Command too long.
pub const E3_COMMAND_TOO_LONG: i32 = 3;
/// Unallowable move attempted on unreferenced axis, or move while servo off.
pub const E5_INIT_NOT_DONE: i32 = 5;
/// Position out of limits.
pub const E7_POS_OUT_OF_LIMITS: i32 = 7;
/// Velocity out of limits.
pub const E8_VEL_OUT_OF_LIMITS: i32 = 8;
/// Controller was stopped by command (HLT, STP, #24).
pub const E10_STOPPED: i32 = 10;
/// Invalid axis identifier.
pub const E15_INVALID_AXIS: i32 = 15;
/// Parameter out of range.
pub const E17_PARAM_OUT_OF_RANGE: i32 = 17;
/// Illegal axis.
pub const E23_ILLEGAL_AXIS: i32 = 23;
/// Incorrect number of parameters.
pub const E24_WRONG_PARAM_COUNT: i32 = 24;
/// Invalid floating point number.
pub const E25_INVALID_FLOAT: i32 = 25;
/// Parameter missing.
pub const E26_MISSING_PARAM: i32 = 26;
/// Unknown parameter id (SPA).
pub const E54_UNKNOWN_PARAM: i32 = 54;
/// Command level too low.
pub const E60_LEVEL_TOO_LOW: i32 = 60;
/// Motor is off.
pub const E84_MOTOR_OFF: i32 = 84;
/// Timeout while receiving a command (partial line).
pub const E307_RECEIVE_TIMEOUT: i32 = 307;
/// Motion error: following error too large, servo switched off.
pub const E1024_MOTION_ERROR: i32 = 1024;

/// The meaning of a GCS error code, as the C-863 manual words it (shortened).
pub fn error_message(code: i32) -> &'static str {
    match code {
        0 => "no error",
        1 => "parameter syntax error",
        2 => "unknown command",
        3 => "command length out of limits or command buffer overrun",
        5 => "unallowable move attempted on unreferenced axis, or move attempted with servo off",
        7 => "position out of limits",
        8 => "velocity out of limits",
        10 => "controller was stopped by command",
        15 => "invalid axis identifier",
        17 => "parameter out of range",
        23 => "illegal axis",
        24 => "incorrect number of parameters",
        25 => "invalid floating point number",
        26 => "parameter missing",
        54 => "unknown parameter",
        60 => "command level too low for parameter access",
        84 => "motor is off",
        307 => "timeout while receiving command",
        1024 => "motion error: position error too large, servo switched off automatically",
        _ => "unknown error code",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_the_driver_reacts_to_have_meanings() {
        for code in [1, 2, 5, 7, 10, 15, 17, 25, 1024] {
            assert_ne!(error_message(code), "unknown error code", "code {code}");
        }
        assert_eq!(
            error_message(E1024_MOTION_ERROR).split(':').next(),
            Some("motion error")
        );
        assert_eq!(error_message(4242), "unknown error code");
    }
}
