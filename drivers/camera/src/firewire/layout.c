/* Sizes, field offsets and enum values of the installed libdc1394 headers, for the test that
   checks the Rust declarations in ffi.rs against them. */
#include <stddef.h>
#include <stdint.h>
#include <dc1394/dc1394.h>

size_t csmetro_dc1394_layout(uint64_t *out, size_t n) {
    const uint64_t v[] = {
        sizeof(dc1394camera_t),
        offsetof(dc1394camera_t, guid),
        offsetof(dc1394camera_t, vendor),
        offsetof(dc1394camera_t, model),
        offsetof(dc1394camera_t, bmode_capable),
        offsetof(dc1394camera_t, one_shot_capable),
        sizeof(dc1394camera_id_t),
        offsetof(dc1394camera_id_t, guid),
        sizeof(dc1394camera_list_t),
        offsetof(dc1394camera_list_t, ids),
        sizeof(dc1394video_frame_t),
        offsetof(dc1394video_frame_t, size),
        offsetof(dc1394video_frame_t, position),
        offsetof(dc1394video_frame_t, color_coding),
        offsetof(dc1394video_frame_t, stride),
        offsetof(dc1394video_frame_t, image_bytes),
        offsetof(dc1394video_frame_t, timestamp),
        offsetof(dc1394video_frame_t, little_endian),
        sizeof(dc1394video_modes_t),
        sizeof(dc1394color_codings_t),
        sizeof(dc1394trigger_sources_t),
        DC1394_VIDEO_MODE_FORMAT7_0,
        DC1394_COLOR_CODING_MONO8,
        DC1394_COLOR_CODING_MONO16,
        DC1394_FEATURE_SHUTTER,
        DC1394_FEATURE_GAIN,
        DC1394_TRIGGER_MODE_0,
        DC1394_TRIGGER_SOURCE_0,
        DC1394_TRIGGER_SOURCE_SOFTWARE,
        DC1394_TRIGGER_ACTIVE_HIGH,
        DC1394_FEATURE_MODE_MANUAL,
        DC1394_CAPTURE_POLICY_POLL,
        DC1394_OPERATION_MODE_LEGACY,
        DC1394_OPERATION_MODE_1394B,
        DC1394_ISO_SPEED_400,
        DC1394_ISO_SPEED_800,
        DC1394_CAPTURE_FLAGS_DEFAULT,
        (uint64_t)(int64_t)DC1394_USE_RECOMMENDED,
    };
    size_t k = sizeof(v) / sizeof(v[0]);
    for (size_t i = 0; i < k && i < n; i++) out[i] = v[i];
    return k;
}
