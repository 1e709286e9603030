/*
 * fpgalink_protocol.h: the wire protocol of the FPGA motor-controller board (SPEC §3-§5, and
 * the optional wire CRC of docs/protocol.md §7), for the board's C.
 *
 * Freestanding C99: <stdint.h>, <stddef.h> and <stdbool.h> only; no allocation, no stdio,
 * no floating-point formatting, fixed buffers. Every multi-byte field is written and read
 * a byte at a time, little-endian, whatever the processor's byte order: nothing depends on
 * how a compiler packs a struct. Division-free (a MicroBlaze without a hardware divider
 * needs no libgcc helper).
 */
#ifndef FPGALINK_PROTOCOL_H
#define FPGALINK_PROTOCOL_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#define FL_DECLARATIONS_DIGEST "/*@DIGEST@*/"
/* The same as the 64-bit number a board answers IQ with (IA's declarations field). */
#define FL_DECLARATIONS_HASH UINT64_C(0x/*@DIGEST@*/)

/* --- framing (SPEC §3) --- */
/*@FRAMING@*/
#define FL_MAX_WIRE (2u * FL_MAX_CONTENT + 2u)  /* every content byte escaped */

typedef struct {
    uint8_t start;
    uint8_t stop;
    uint8_t skip;
    uint8_t max_content;  /* at most FL_MAX_CONTENT */
} fl_framing;

extern const fl_framing fl_default_framing;

/* START, content with a SKIP before every START, STOP or SKIP byte, STOP. Returns the wire
 * length, or 0 when the content is over the limit or the wire buffer too small. */
size_t fl_frame(const fl_framing *framing, const uint8_t *content, size_t length,
                uint8_t *wire, size_t capacity);

/* The streaming decoder, one byte at a time, exactly as the uartcommand logic steps. */
typedef enum {
    FL_DEFRAME_NOTHING = 0,  /* the byte was stored, or dropped as noise */
    FL_DEFRAME_FRAME,        /* a frame ended: content[0 .. length) */
    FL_DEFRAME_RESTART,      /* an unescaped START dropped the partial frame; a new one began */
    FL_DEFRAME_OVERFLOW      /* the content passed the limit: dropped, hunting again */
} fl_deframe_event;

/* Running totals. Every byte fed is exactly one of: in a delivered frame (frame_bytes:
 * START, content and STOP), an escape in a delivered frame (escape_bytes), dropped
 * (dropped_bytes: noise, restarted and overflowed frames), or pending in an unfinished
 * frame (fl_deframer.wire). */
typedef struct {
    uint32_t frames;
    uint32_t frame_bytes;
    uint32_t escape_bytes;
    uint32_t dropped_bytes;
    uint32_t noise_bytes;
    uint32_t restarts;
    uint32_t overflows;
    uint32_t bytes_fed;
} fl_deframer_stats;

typedef struct {
    fl_framing framing;
    uint8_t state;      /* hunting, in a frame, after a SKIP */
    uint16_t length;    /* content bytes so far */
    uint16_t wire;      /* wire bytes of the unfinished frame, START included (0: hunting) */
    uint16_t escapes;   /* SKIPs in the unfinished frame */
    fl_deframer_stats stats;
    uint8_t content[FL_MAX_CONTENT];
} fl_deframer;

void fl_deframer_init(fl_deframer *deframer, const fl_framing *framing);
/* Forget an unfinished frame (its bytes counted as dropped), as the hardware's reset. */
void fl_deframer_reset(fl_deframer *deframer);
fl_deframe_event fl_deframe_byte(fl_deframer *deframer, uint8_t byte);

/* --- messages (SPEC §4) --- */
/*@MESSAGES@*/
#define FL_HEADER_LEN 7u   /* ID and counter */
#define FL_BODY_OFFSET 9u  /* ID, counter, '{', LEN */

typedef union {
/*@UNION@*/
} fl_body_union;

/* One frame's content, parsed. */
typedef struct {
    fl_kind kind;
    fl_malformed_reason malformed;  /* FL_MSG_MALFORMED: why */
    uint16_t id;                    /* counted messages: FL_ID of the ID */
    uint32_t counter;               /* counted messages: 0..99999 */
    uint8_t items;                  /* FL_MSG_COUNTED: text items and binary sections */
    fl_body_union body;             /* the catalogued kinds: their body */
} fl_message;

/* Never fails on any input: bad content is FL_MSG_MALFORMED with a reason. The same rules,
 * in the same order, as fpgalink.protocol.parse_content. */
fl_kind fl_parse(const uint8_t *content, size_t length, fl_message *message);

/* Each writes the message's whole content (FL_<ID>_CONTENT_LEN bytes) with the counter
 * taken modulo FL_COUNTER_MODULUS, and returns its length; fl_encode_rv returns 0 for a
 * reference that is not a finite number (it is never sent). */
/*@ENCODERS@*/

/*@PARAMS@*/
/* The table entry, or NULL for an unknown id. */
const fl_param_info *fl_param_find(uint8_t id);
/* The store slot of (parameter, channel), or -1 when the channel is not the parameter's. */
int fl_param_slot(const fl_param_info *param, uint8_t channel);
/* The PN code a PS would get (0: acceptable), checks in SPEC order: unknown id, channel,
 * type code, range (NaN and infinities out of range). */
uint8_t fl_param_check_set(uint8_t id, uint8_t channel, uint8_t value_type, fl_value value);
/* The PN code a PG would get (0: acceptable). */
uint8_t fl_param_check_get(uint8_t id, uint8_t channel);

/* --- the optional wire CRC (docs/protocol.md §7) --- */
/*@CRC@*/

uint16_t fl_crc16(const uint8_t *data, size_t length);
/* Appends the CRC of content[0 .. length) at content[length], little-endian; returns
 * length + FL_CRC_BYTES (content must have room). */
size_t fl_crc_append(uint8_t *content, size_t length);
/* Whether content ends in the CRC of what precedes it (and holds more than the CRC). */
bool fl_crc_good(const uint8_t *content, size_t length);
/* Whether plain content is a PS or PG naming WireCrc: the handshake, understood in either
 * form whatever the mode. */
bool fl_crc_handshake(const uint8_t *content, size_t length);
/* The board's rule for a received frame: the length of the content to parse (the CRC
 * stripped when there was one), or -1 for a frame to drop and count. */
int fl_crc_board_receive(bool crc_on, const uint8_t *content, size_t length);

#endif /* FPGALINK_PROTOCOL_H */
