/* The C codec's test harness (tests/fpgalink/codegen): many streams in one call. */
#include "fpgalink_protocol.h"

/* Record sizes, per delivered frame and per stream end. */
#define HARNESS_FRAME_RECORD 12u
#define HARNESS_STREAM_RECORD 37u

/* Stream k is data[ends[k-1] .. ends[k]) (ends[-1] = 0), each through a fresh deframer,
 * each frame parsed. Per frame: 'F', kind, malformed reason, counter (u32), items, ID (u16),
 * length, whether re-encoding a catalogued message gives its content back. Per stream:
 * 'S' and nine u32: frames, frame_bytes, escape_bytes, dropped_bytes, noise_bytes,
 * restarts, overflows, bytes_fed, pending wire bytes. Returns the bytes written, 0 when
 * `capacity` is too small. */
size_t harness_streams(const uint8_t *data, const uint32_t *ends, uint32_t count, uint8_t *out,
                       size_t capacity);

/* fl_param_check_set with the value as its raw bits. */
uint8_t harness_check_set(uint8_t id, uint8_t channel, uint8_t value_type, uint32_t raw);
