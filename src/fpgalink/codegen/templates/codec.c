/*
 * fpgalink_protocol.c: framing, the deframer, the message codec, the parameter table and
 * the wire CRC. Freestanding: no library call at all, so it links with -nostdlib.
 */
#include "fpgalink_protocol.h"

/* --- bytes, little-endian, one at a time ------------------------------------------------ */

static void fl_put_u8(uint8_t *at, uint8_t value) { at[0] = value; }

static void fl_put_u16(uint8_t *at, uint16_t value)
{
    at[0] = (uint8_t)(value & 0xFFu);
    at[1] = (uint8_t)(value >> 8);
}

static void fl_put_u32(uint8_t *at, uint32_t value)
{
    at[0] = (uint8_t)(value & 0xFFu);
    at[1] = (uint8_t)((value >> 8) & 0xFFu);
    at[2] = (uint8_t)((value >> 16) & 0xFFu);
    at[3] = (uint8_t)(value >> 24);
}

static void fl_put_u64(uint8_t *at, uint64_t value)
{
    fl_put_u32(at, (uint32_t)(value & 0xFFFFFFFFu));
    fl_put_u32(at + 4, (uint32_t)(value >> 32));
}

static void fl_put_i16(uint8_t *at, int16_t value) { fl_put_u16(at, (uint16_t)value); }
static void fl_put_i32(uint8_t *at, int32_t value) { fl_put_u32(at, (uint32_t)value); }
static void fl_put_value(uint8_t *at, fl_value value) { fl_put_u32(at, value.raw); }

static void fl_put_f32(uint8_t *at, float value)
{
    fl_value bits;
    bits.f = value;
    fl_put_u32(at, bits.raw);
}

static uint8_t fl_get_u8(const uint8_t *at) { return at[0]; }

static uint16_t fl_get_u16(const uint8_t *at)
{
    return (uint16_t)((uint16_t)at[0] | (uint16_t)((uint16_t)at[1] << 8));
}

static uint32_t fl_get_u32(const uint8_t *at)
{
    return (uint32_t)at[0] | ((uint32_t)at[1] << 8) | ((uint32_t)at[2] << 16)
           | ((uint32_t)at[3] << 24);
}

static uint64_t fl_get_u64(const uint8_t *at)
{
    return (uint64_t)fl_get_u32(at) | ((uint64_t)fl_get_u32(at + 4) << 32);
}

/* Two's complement without relying on an implementation-defined conversion. */
static int16_t fl_get_i16(const uint8_t *at)
{
    uint16_t raw = fl_get_u16(at);
    return raw < 0x8000u ? (int16_t)raw : (int16_t)(-(int32_t)(0xFFFFu - raw) - 1);
}

static int32_t fl_get_i32(const uint8_t *at)
{
    uint32_t raw = fl_get_u32(at);
    return raw < 0x80000000u ? (int32_t)raw : -(int32_t)(0xFFFFFFFFu - raw) - 1;
}

static fl_value fl_get_value(const uint8_t *at)
{
    fl_value value;
    value.raw = fl_get_u32(at);
    return value;
}

static float fl_get_f32(const uint8_t *at) { return fl_get_value(at).f; }

/* Finite: false for both infinities and NaN (x - x is NaN for those), without <math.h>. */
static bool fl_finite(float value)
{
    float zero = value - value;
    return zero == zero;
}

/* --- framing ----------------------------------------------------------------------------- */

const fl_framing fl_default_framing = { FL_START, FL_STOP, FL_SKIP, FL_MAX_CONTENT };

size_t fl_frame(const fl_framing *framing, const uint8_t *content, size_t length,
                uint8_t *wire, size_t capacity)
{
    size_t i, n = 0;
    if (length > framing->max_content || capacity < length + 2u)
        return 0u;
    wire[n++] = framing->start;
    for (i = 0u; i < length; i++) {
        uint8_t b = content[i];
        if (b == framing->start || b == framing->stop || b == framing->skip) {
            if (n + 2u >= capacity)
                return 0u;
            wire[n++] = framing->skip;
        } else if (n + 1u >= capacity) {
            return 0u;
        }
        wire[n++] = b;
    }
    wire[n++] = framing->stop;
    return n;
}

enum { FL_HUNT = 0, FL_IN_FRAME = 1, FL_ESCAPE = 2 };

void fl_deframer_init(fl_deframer *d, const fl_framing *framing)
{
    d->framing = *framing;
    if (d->framing.max_content > FL_MAX_CONTENT)
        d->framing.max_content = FL_MAX_CONTENT;
    d->state = FL_HUNT;
    d->length = 0u;
    d->wire = 0u;
    d->escapes = 0u;
    d->stats.frames = 0u;
    d->stats.frame_bytes = 0u;
    d->stats.escape_bytes = 0u;
    d->stats.dropped_bytes = 0u;
    d->stats.noise_bytes = 0u;
    d->stats.restarts = 0u;
    d->stats.overflows = 0u;
    d->stats.bytes_fed = 0u;
}

void fl_deframer_reset(fl_deframer *d)
{
    d->stats.dropped_bytes += d->wire;
    d->state = FL_HUNT;
    d->length = 0u;
    d->wire = 0u;
    d->escapes = 0u;
}

fl_deframe_event fl_deframe_byte(fl_deframer *d, uint8_t byte)
{
    d->stats.bytes_fed++;
    if (d->state == FL_HUNT) {
        if (byte == d->framing.start) {
            d->state = FL_IN_FRAME;
            d->length = 0u;
            d->wire = 1u;
            d->escapes = 0u;
        } else {
            d->stats.noise_bytes++;
            d->stats.dropped_bytes++;
        }
        return FL_DEFRAME_NOTHING;
    }
    d->wire++;
    if (d->state == FL_ESCAPE) {
        d->state = FL_IN_FRAME;
    } else if (byte == d->framing.skip) {
        d->state = FL_ESCAPE;
        d->escapes++;
        return FL_DEFRAME_NOTHING;
    } else if (byte == d->framing.start) {
        /* The partial frame is dropped; this START begins the next. */
        d->stats.restarts++;
        d->stats.dropped_bytes += (uint32_t)d->wire - 1u;
        d->wire = 1u;
        d->length = 0u;
        d->escapes = 0u;
        return FL_DEFRAME_RESTART;
    } else if (byte == d->framing.stop) {
        d->state = FL_HUNT;
        d->stats.frames++;
        d->stats.frame_bytes += (uint32_t)d->length + 2u;
        d->stats.escape_bytes += d->escapes;
        d->wire = 0u;
        return FL_DEFRAME_FRAME;
    }
    if (d->length >= d->framing.max_content) {
        /* The (limit + 1)th content byte: garbage; hunt from the next byte on. */
        d->stats.overflows++;
        d->stats.dropped_bytes += d->wire;
        d->state = FL_HUNT;
        d->wire = 0u;
        d->length = 0u;
        return FL_DEFRAME_OVERFLOW;
    }
    d->content[d->length++] = byte;
    return FL_DEFRAME_NOTHING;
}

/* --- messages ---------------------------------------------------------------------------- */

/* counter % 100000 by shifted subtraction, then its five digits by subtraction. */
static void fl_put_counter(uint8_t *at, uint32_t counter)
{
    static const uint32_t powers[5] = { 10000u, 1000u, 100u, 10u, 1u };
    int shift, i;
    for (shift = 15; shift >= 0; shift--) {
        uint32_t step = (uint32_t)FL_COUNTER_MODULUS << shift;
        if (counter >= step)
            counter -= step;
    }
    for (i = 0; i < 5; i++) {
        uint8_t digit = (uint8_t)'0';
        while (counter >= powers[i]) {
            counter -= powers[i];
            digit++;
        }
        at[i] = digit;
    }
}

static void fl_put_header(uint8_t *content, uint16_t id, uint32_t counter, uint8_t body_len)
{
    fl_put_u16(content, id);
    fl_put_counter(content + 2, counter);
    content[7] = FL_SECTION_OPEN;
    content[8] = body_len;
}

static bool fl_digits(const uint8_t *at)
{
    int i;
    for (i = 0; i < 5; i++)
        if (at[i] < (uint8_t)'0' || at[i] > (uint8_t)'9')
            return false;
    return true;
}

static uint32_t fl_get_counter(const uint8_t *content)
{
    uint32_t value = 0u;
    int i;
    for (i = 2; i < 7; i++)
        value = value * 10u + (uint32_t)(content[i] - (uint8_t)'0');
    return value;
}

/* A catalogued message's frame around its body: digits, '{' LEN, the closing '}'. */
static bool fl_typed_frame(const uint8_t *content, uint8_t body_len)
{
    return fl_digits(content + 2) && content[7] == FL_SECTION_OPEN && content[8] == body_len
           && content[FL_BODY_OFFSET + body_len] == FL_SECTION_CLOSE;
}

static fl_kind fl_counted(fl_message *message, fl_kind kind, uint16_t id,
                          const uint8_t *content)
{
    message->kind = kind;
    message->id = id;
    message->counter = fl_get_counter(content);
    return kind;
}

static bool fl_id_byte(uint8_t b)
{
    return (b >= (uint8_t)'A' && b <= (uint8_t)'Z') || (b >= (uint8_t)'0' && b <= (uint8_t)'9');
}

static fl_kind fl_malformed(fl_message *message, fl_malformed_reason reason)
{
    message->kind = FL_MSG_MALFORMED;
    message->malformed = reason;
    return FL_MSG_MALFORMED;
}

/*@DECODERS@*/

fl_kind fl_parse(const uint8_t *content, size_t length, fl_message *message)
{
    size_t i, j;
    bool catalogued = false;
    uint16_t id = length >= 2u ? fl_get_u16(content) : 0u;
    message->kind = FL_MSG_MALFORMED;
    message->malformed = FL_MALFORMED_NONE;
    message->id = 0u;
    message->counter = 0u;
    message->items = 0u;
    switch (id) {
/*@TYPED_CASES@*/
    default:
        break;
    }
    /* the direct commands, by exact content */
    if (length == 2u && id == FL_ID_RE)
        return message->kind = FL_MSG_RE;
    if (length == 2u && id == FL_ID_RD)
        return message->kind = FL_MSG_RD;
    if (length == 1u && content[0] == (uint8_t)'E')
        return message->kind = FL_MSG_E;
    /* the header */
    if (length < FL_HEADER_LEN)
        return fl_malformed(message, length == 0u ? FL_MALFORMED_EMPTY : FL_MALFORMED_TOO_SHORT);
    if (!fl_id_byte(content[0]) || !fl_id_byte(content[1]))
        return fl_malformed(message, FL_MALFORMED_BAD_ID);
    if (id == FL_ID_RE || id == FL_ID_RD || content[0] == (uint8_t)'E')
        return fl_malformed(message, FL_MALFORMED_RESERVED_ID);
    if (!fl_digits(content + 2))
        return fl_malformed(message, FL_MALFORMED_BAD_COUNTER);
    /* the body: text items and binary sections '{' LEN DATA '}' */
    message->counter = fl_get_counter(content);
    for (i = FL_HEADER_LEN; i < length;) {
        size_t open = length, data_end;
        uint8_t len;
        for (j = i; j < length; j++) {
            if (content[j] == FL_SECTION_CLOSE)
                return fl_malformed(message, FL_MALFORMED_STRAY_CLOSE);
            if (content[j] == FL_SECTION_OPEN) {
                open = j;
                break;
            }
        }
        if (open > i)
            message->items++; /* a text item */
        if (open == length)
            break;
        if (open + 1u >= length)
            return fl_malformed(message, FL_MALFORMED_TRUNCATED_SECTION);
        len = content[open + 1u];
        if (len == FL_LEN_RESERVED)
            return fl_malformed(message, FL_MALFORMED_RESERVED_LEN);
        data_end = open + 2u + len;
        if (data_end >= length)
            return fl_malformed(message, FL_MALFORMED_TRUNCATED_SECTION);
        if (content[data_end] != FL_SECTION_CLOSE)
            return fl_malformed(message, FL_MALFORMED_UNCLOSED_SECTION);
        message->items++;
        i = data_end + 1u;
    }
    if (catalogued)
        return fl_malformed(message, FL_MALFORMED_BAD_LAYOUT);
    message->kind = FL_MSG_COUNTED;
    message->id = id;
    return FL_MSG_COUNTED;
}

/*@ENCODERS@*/

/* --- parameters -------------------------------------------------------------------------- */

/*@PARAM_TABLE@*/

const fl_param_info *fl_param_find(uint8_t id)
{
    size_t i;
    for (i = 0u; i < FL_PARAM_COUNT; i++)
        if (fl_params[i].id == id)
            return &fl_params[i];
    return (const fl_param_info *)0;
}

int fl_param_slot(const fl_param_info *param, uint8_t channel)
{
    if (param->scope == FL_SCOPE_BOARD)
        return channel == FL_CHANNEL_BOARD ? (int)param->slot : -1;
    if (channel == FL_CHANNEL_A || channel == FL_CHANNEL_B)
        return (int)param->slot + (int)channel - 1;
    return -1;
}

static bool fl_param_in_range(const fl_param_info *p, fl_value value)
{
    if (p->type == FL_TYPE_INT) {
        int32_t v = value.i;
        if (p->range & FL_RANGE_ALLOWED) {
            uint8_t k;
            for (k = 0u; k < p->allowed_count; k++)
                if (p->allowed[k] == v)
                    return true;
            return false;
        }
        if (!(p->range & FL_RANGE_NO_MAX) && v > p->maximum.i)
            return false;
        if (p->range & FL_RANGE_NO_MIN)
            return true;
        return (p->range & FL_RANGE_MIN_EXCLUSIVE) ? v > p->minimum.i : v >= p->minimum.i;
    }
    if (!fl_finite(value.f))
        return false;
    if (!(p->range & FL_RANGE_NO_MAX) && (double)value.f > (double)p->maximum.f)
        return false;
    if (p->range & FL_RANGE_NO_MIN)
        return true;
    return (p->range & FL_RANGE_MIN_EXCLUSIVE) ? (double)value.f > (double)p->minimum.f
                                               : (double)value.f >= (double)p->minimum.f;
}

uint8_t fl_param_check_set(uint8_t id, uint8_t channel, uint8_t value_type, fl_value value)
{
    const fl_param_info *p = fl_param_find(id);
    if (!p)
        return FL_NACK_UNKNOWN_ID;
    if (fl_param_slot(p, channel) < 0)
        return FL_NACK_BAD_CHANNEL;
    if (value_type != p->type)
        return FL_NACK_WRONG_TYPE;
    if (!fl_param_in_range(p, value))
        return FL_NACK_OUT_OF_RANGE;
    return 0u;
}

uint8_t fl_param_check_get(uint8_t id, uint8_t channel)
{
    const fl_param_info *p = fl_param_find(id);
    if (!p)
        return FL_NACK_UNKNOWN_ID;
    if (fl_param_slot(p, channel) < 0)
        return FL_NACK_BAD_CHANNEL;
    return 0u;
}

/* --- the wire CRC ------------------------------------------------------------------------ */

/*@CRC_TABLE@*/

uint16_t fl_crc16(const uint8_t *data, size_t length)
{
    uint16_t crc = FL_CRC_INIT;
    size_t i;
    for (i = 0u; i < length; i++)
        crc = (uint16_t)((uint16_t)(crc << 8) ^ fl_crc_table[(uint8_t)((crc >> 8) ^ data[i])]);
    return (uint16_t)(crc ^ FL_CRC_XOROUT);
}

size_t fl_crc_append(uint8_t *content, size_t length)
{
    fl_put_u16(content + length, fl_crc16(content, length));
    return length + FL_CRC_BYTES;
}

bool fl_crc_good(const uint8_t *content, size_t length)
{
    return length > FL_CRC_BYTES
           && fl_crc16(content, length - FL_CRC_BYTES) == fl_get_u16(content + length - FL_CRC_BYTES);
}

bool fl_crc_handshake(const uint8_t *content, size_t length)
{
    uint16_t id;
    if (length == FL_PS_CONTENT_LEN)
        id = FL_ID_PS;
    else if (length == FL_PG_CONTENT_LEN)
        id = FL_ID_PG;
    else
        return false;
    return fl_get_u16(content) == id && fl_digits(content + 2) && content[7] == FL_SECTION_OPEN
           && content[8] == (uint8_t)(length - 10u) && content[length - 1u] == FL_SECTION_CLOSE
           && content[FL_BODY_OFFSET] == FL_WIRE_CRC_PARAM;
}

int fl_crc_board_receive(bool crc_on, const uint8_t *content, size_t length)
{
    if (crc_on) {
        if (fl_crc_good(content, length))
            return (int)(length - FL_CRC_BYTES);
        if (fl_crc_handshake(content, length))
            return (int)length;
        return -1;
    }
    if ((length == FL_PS_CONTENT_LEN + FL_CRC_BYTES || length == FL_PG_CONTENT_LEN + FL_CRC_BYTES)
        && fl_crc_good(content, length) && fl_crc_handshake(content, length - FL_CRC_BYTES))
        return (int)(length - FL_CRC_BYTES);
    return (int)length;
}
