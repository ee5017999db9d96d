//! The handful of libdc1394 2.x declarations the FireWire backend calls (headers of
//! libdc1394-dev 2.2.6); `tests::layout_matches_the_installed_headers` compares every size,
//! offset and constant here with a C probe compiled against the installed headers.
#![allow(non_camel_case_types, dead_code)]

use std::ffi::{c_char, c_int};

pub(crate) type dc1394error_t = c_int;
pub(crate) type dc1394bool_t = u32;
pub(crate) type dc1394switch_t = u32;

pub(crate) const DC1394_SUCCESS: dc1394error_t = 0;
pub(crate) const DC1394_FALSE: dc1394bool_t = 0;
pub(crate) const DC1394_TRUE: dc1394bool_t = 1;
pub(crate) const DC1394_OFF: dc1394switch_t = 0;
pub(crate) const DC1394_ON: dc1394switch_t = 1;

pub(crate) const DC1394_FEATURE_SHUTTER: u32 = 423;
pub(crate) const DC1394_FEATURE_GAIN: u32 = 424;
pub(crate) const DC1394_TRIGGER_MODE_0: u32 = 384;
pub(crate) const DC1394_TRIGGER_ACTIVE_HIGH: u32 = 705;
pub(crate) const DC1394_FEATURE_MODE_MANUAL: u32 = 736;
pub(crate) const DC1394_CAPTURE_POLICY_POLL: u32 = 673;
pub(crate) const DC1394_OPERATION_MODE_LEGACY: u32 = 480;
pub(crate) const DC1394_OPERATION_MODE_1394B: u32 = 481;
pub(crate) const DC1394_ISO_SPEED_400: u32 = 2;
pub(crate) const DC1394_ISO_SPEED_800: u32 = 3;
pub(crate) const DC1394_CAPTURE_FLAGS_DEFAULT: u32 = 4;
pub(crate) const DC1394_USE_RECOMMENDED: i32 = -3;
const DC1394_VIDEO_MODE_NUM: usize = 32;
const DC1394_COLOR_CODING_NUM: usize = 11;
const DC1394_TRIGGER_SOURCE_NUM: usize = 5;
const DC1394_VIDEO_MODE_FORMAT7_NUM: usize = 8;

/// Opaque library context.
#[repr(C)]
pub(crate) struct dc1394_t {
    _private: [u8; 0],
}

#[repr(C)]
pub(crate) struct dc1394camera_t {
    pub(crate) guid: u64,
    pub(crate) unit: c_int,
    pub(crate) unit_spec_id: u32,
    pub(crate) unit_sw_version: u32,
    pub(crate) unit_sub_sw_version: u32,
    pub(crate) command_registers_base: u32,
    pub(crate) unit_directory: u32,
    pub(crate) unit_dependent_directory: u32,
    pub(crate) advanced_features_csr: u64,
    pub(crate) pio_control_csr: u64,
    pub(crate) sio_control_csr: u64,
    pub(crate) strobe_control_csr: u64,
    pub(crate) format7_csr: [u64; DC1394_VIDEO_MODE_FORMAT7_NUM],
    pub(crate) iidc_version: u32,
    pub(crate) vendor: *mut c_char,
    pub(crate) model: *mut c_char,
    pub(crate) vendor_id: u32,
    pub(crate) model_id: u32,
    pub(crate) bmode_capable: dc1394bool_t,
    pub(crate) one_shot_capable: dc1394bool_t,
    pub(crate) multi_shot_capable: dc1394bool_t,
    pub(crate) can_switch_on_off: dc1394bool_t,
    pub(crate) has_vmode_error_status: dc1394bool_t,
    pub(crate) has_feature_error_status: dc1394bool_t,
    pub(crate) max_mem_channel: c_int,
    pub(crate) flags: u32,
}

#[repr(C)]
pub(crate) struct dc1394camera_id_t {
    pub(crate) unit: u16,
    pub(crate) guid: u64,
}

#[repr(C)]
pub(crate) struct dc1394camera_list_t {
    pub(crate) num: u32,
    pub(crate) ids: *mut dc1394camera_id_t,
}

#[repr(C)]
pub(crate) struct dc1394video_frame_t {
    pub(crate) image: *mut u8,
    pub(crate) size: [u32; 2],
    pub(crate) position: [u32; 2],
    pub(crate) color_coding: u32,
    pub(crate) color_filter: u32,
    pub(crate) yuv_byte_order: u32,
    pub(crate) data_depth: u32,
    pub(crate) stride: u32,
    pub(crate) video_mode: u32,
    pub(crate) total_bytes: u64,
    pub(crate) image_bytes: u32,
    pub(crate) padding_bytes: u32,
    pub(crate) packet_size: u32,
    pub(crate) packets_per_frame: u32,
    pub(crate) timestamp: u64,
    pub(crate) frames_behind: u32,
    pub(crate) camera: *mut dc1394camera_t,
    pub(crate) id: u32,
    pub(crate) allocated_image_bytes: u64,
    pub(crate) little_endian: dc1394bool_t,
    pub(crate) data_in_padding: dc1394bool_t,
}

#[repr(C)]
pub(crate) struct dc1394video_modes_t {
    pub(crate) num: u32,
    pub(crate) modes: [u32; DC1394_VIDEO_MODE_NUM],
}

#[repr(C)]
pub(crate) struct dc1394color_codings_t {
    pub(crate) num: u32,
    pub(crate) codings: [u32; DC1394_COLOR_CODING_NUM],
}

#[repr(C)]
pub(crate) struct dc1394trigger_sources_t {
    pub(crate) num: u32,
    pub(crate) sources: [u32; DC1394_TRIGGER_SOURCE_NUM],
}

#[link(name = "dc1394")]
extern "C" {
    pub(crate) fn dc1394_new() -> *mut dc1394_t;
    pub(crate) fn dc1394_free(d: *mut dc1394_t);
    pub(crate) fn dc1394_camera_enumerate(
        d: *mut dc1394_t,
        list: *mut *mut dc1394camera_list_t,
    ) -> dc1394error_t;
    pub(crate) fn dc1394_camera_free_list(list: *mut dc1394camera_list_t);
    pub(crate) fn dc1394_camera_new_unit(
        d: *mut dc1394_t,
        guid: u64,
        unit: c_int,
    ) -> *mut dc1394camera_t;
    pub(crate) fn dc1394_camera_free(c: *mut dc1394camera_t);
    pub(crate) fn dc1394_error_get_string(e: dc1394error_t) -> *const c_char;

    pub(crate) fn dc1394_video_get_supported_modes(
        c: *mut dc1394camera_t,
        modes: *mut dc1394video_modes_t,
    ) -> dc1394error_t;
    pub(crate) fn dc1394_video_set_mode(c: *mut dc1394camera_t, mode: u32) -> dc1394error_t;
    pub(crate) fn dc1394_video_set_operation_mode(
        c: *mut dc1394camera_t,
        mode: u32,
    ) -> dc1394error_t;
    pub(crate) fn dc1394_video_set_iso_speed(c: *mut dc1394camera_t, speed: u32) -> dc1394error_t;
    pub(crate) fn dc1394_video_set_transmission(
        c: *mut dc1394camera_t,
        pwr: dc1394switch_t,
    ) -> dc1394error_t;
    pub(crate) fn dc1394_video_set_one_shot(
        c: *mut dc1394camera_t,
        pwr: dc1394switch_t,
    ) -> dc1394error_t;

    pub(crate) fn dc1394_format7_get_max_image_size(
        c: *mut dc1394camera_t,
        mode: u32,
        h: *mut u32,
        v: *mut u32,
    ) -> dc1394error_t;
    pub(crate) fn dc1394_format7_get_unit_size(
        c: *mut dc1394camera_t,
        mode: u32,
        h: *mut u32,
        v: *mut u32,
    ) -> dc1394error_t;
    pub(crate) fn dc1394_format7_get_unit_position(
        c: *mut dc1394camera_t,
        mode: u32,
        h: *mut u32,
        v: *mut u32,
    ) -> dc1394error_t;
    pub(crate) fn dc1394_format7_get_color_codings(
        c: *mut dc1394camera_t,
        mode: u32,
        codings: *mut dc1394color_codings_t,
    ) -> dc1394error_t;
    pub(crate) fn dc1394_format7_set_roi(
        c: *mut dc1394camera_t,
        mode: u32,
        coding: u32,
        packet_size: i32,
        left: i32,
        top: i32,
        width: i32,
        height: i32,
    ) -> dc1394error_t;
    pub(crate) fn dc1394_format7_get_roi(
        c: *mut dc1394camera_t,
        mode: u32,
        coding: *mut u32,
        packet_size: *mut u32,
        left: *mut u32,
        top: *mut u32,
        width: *mut u32,
        height: *mut u32,
    ) -> dc1394error_t;

    pub(crate) fn dc1394_feature_set_mode(
        c: *mut dc1394camera_t,
        feature: u32,
        mode: u32,
    ) -> dc1394error_t;
    pub(crate) fn dc1394_feature_has_absolute_control(
        c: *mut dc1394camera_t,
        feature: u32,
        value: *mut dc1394bool_t,
    ) -> dc1394error_t;
    pub(crate) fn dc1394_feature_set_absolute_control(
        c: *mut dc1394camera_t,
        feature: u32,
        pwr: dc1394switch_t,
    ) -> dc1394error_t;
    pub(crate) fn dc1394_feature_get_absolute_boundaries(
        c: *mut dc1394camera_t,
        feature: u32,
        min: *mut f32,
        max: *mut f32,
    ) -> dc1394error_t;
    pub(crate) fn dc1394_feature_get_absolute_value(
        c: *mut dc1394camera_t,
        feature: u32,
        value: *mut f32,
    ) -> dc1394error_t;
    pub(crate) fn dc1394_feature_set_absolute_value(
        c: *mut dc1394camera_t,
        feature: u32,
        value: f32,
    ) -> dc1394error_t;

    pub(crate) fn dc1394_external_trigger_set_power(
        c: *mut dc1394camera_t,
        pwr: dc1394switch_t,
    ) -> dc1394error_t;
    pub(crate) fn dc1394_external_trigger_set_mode(
        c: *mut dc1394camera_t,
        mode: u32,
    ) -> dc1394error_t;
    pub(crate) fn dc1394_external_trigger_set_source(
        c: *mut dc1394camera_t,
        source: u32,
    ) -> dc1394error_t;
    pub(crate) fn dc1394_external_trigger_get_supported_sources(
        c: *mut dc1394camera_t,
        sources: *mut dc1394trigger_sources_t,
    ) -> dc1394error_t;
    pub(crate) fn dc1394_external_trigger_has_polarity(
        c: *mut dc1394camera_t,
        capable: *mut dc1394bool_t,
    ) -> dc1394error_t;
    pub(crate) fn dc1394_external_trigger_set_polarity(
        c: *mut dc1394camera_t,
        polarity: u32,
    ) -> dc1394error_t;
    pub(crate) fn dc1394_software_trigger_set_power(
        c: *mut dc1394camera_t,
        pwr: dc1394switch_t,
    ) -> dc1394error_t;

    pub(crate) fn dc1394_capture_setup(
        c: *mut dc1394camera_t,
        num_dma_buffers: u32,
        flags: u32,
    ) -> dc1394error_t;
    pub(crate) fn dc1394_capture_stop(c: *mut dc1394camera_t) -> dc1394error_t;
    pub(crate) fn dc1394_capture_dequeue(
        c: *mut dc1394camera_t,
        policy: u32,
        frame: *mut *mut dc1394video_frame_t,
    ) -> dc1394error_t;
    pub(crate) fn dc1394_capture_enqueue(
        c: *mut dc1394camera_t,
        frame: *mut dc1394video_frame_t,
    ) -> dc1394error_t;
    pub(crate) fn dc1394_capture_is_frame_corrupt(
        c: *mut dc1394camera_t,
        frame: *mut dc1394video_frame_t,
    ) -> dc1394bool_t;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::iidc;
    use std::mem::{offset_of, size_of};

    extern "C" {
        fn csmetro_dc1394_layout(out: *mut u64, n: usize) -> usize;
    }

    #[test]
    fn layout_matches_the_installed_headers() {
        let mut c = [0u64; 64];
        // SAFETY: the probe writes at most `n` = c.len() values into `c`.
        let n = unsafe { csmetro_dc1394_layout(c.as_mut_ptr(), c.len()) };
        let rust: Vec<u64> = [
            size_of::<dc1394camera_t>(),
            offset_of!(dc1394camera_t, guid),
            offset_of!(dc1394camera_t, vendor),
            offset_of!(dc1394camera_t, model),
            offset_of!(dc1394camera_t, bmode_capable),
            offset_of!(dc1394camera_t, one_shot_capable),
            size_of::<dc1394camera_id_t>(),
            offset_of!(dc1394camera_id_t, guid),
            size_of::<dc1394camera_list_t>(),
            offset_of!(dc1394camera_list_t, ids),
            size_of::<dc1394video_frame_t>(),
            offset_of!(dc1394video_frame_t, size),
            offset_of!(dc1394video_frame_t, position),
            offset_of!(dc1394video_frame_t, color_coding),
            offset_of!(dc1394video_frame_t, stride),
            offset_of!(dc1394video_frame_t, image_bytes),
            offset_of!(dc1394video_frame_t, timestamp),
            offset_of!(dc1394video_frame_t, little_endian),
            size_of::<dc1394video_modes_t>(),
            size_of::<dc1394color_codings_t>(),
            size_of::<dc1394trigger_sources_t>(),
        ]
        .into_iter()
        .map(|v| v as u64)
        .chain(
            [
                iidc::VIDEO_MODE_FORMAT7_0,
                iidc::COLOR_CODING_MONO8,
                iidc::COLOR_CODING_MONO16,
                DC1394_FEATURE_SHUTTER,
                DC1394_FEATURE_GAIN,
                DC1394_TRIGGER_MODE_0,
                iidc::TRIGGER_SOURCE_0,
                iidc::TRIGGER_SOURCE_SOFTWARE,
                DC1394_TRIGGER_ACTIVE_HIGH,
                DC1394_FEATURE_MODE_MANUAL,
                DC1394_CAPTURE_POLICY_POLL,
                DC1394_OPERATION_MODE_LEGACY,
                DC1394_OPERATION_MODE_1394B,
                DC1394_ISO_SPEED_400,
                DC1394_ISO_SPEED_800,
                DC1394_CAPTURE_FLAGS_DEFAULT,
            ]
            .into_iter()
            .map(u64::from),
        )
        .chain([DC1394_USE_RECOMMENDED as i64 as u64])
        .collect();
        assert_eq!(n, rust.len(), "probe and declarations list different items");
        for (i, (r, c)) in rust.iter().zip(&c[..n]).enumerate() {
            assert_eq!(
                r, c,
                "item {i} of the layout list differs from the C headers"
            );
        }
    }
}
