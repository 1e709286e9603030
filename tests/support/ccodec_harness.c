/* See ccodec_harness.h. */
#include "ccodec_harness.h"

static void put32(uint8_t *at, uint32_t v)
{
    at[0] = (uint8_t)v;
    at[1] = (uint8_t)(v >> 8);
    at[2] = (uint8_t)(v >> 16);
    at[3] = (uint8_t)(v >> 24);
}

static uint8_t round_trip(const fl_message *m, const uint8_t *content, size_t length)
{
    uint8_t again[FL_MAX_CONTENT];
    size_t n, i;
    switch (m->kind) {
    case FL_MSG_PS: n = fl_encode_ps(again, m->counter, &m->body.ps); break;
    case FL_MSG_PA: n = fl_encode_pa(again, m->counter, &m->body.pa); break;
    case FL_MSG_PG: n = fl_encode_pg(again, m->counter, &m->body.pg); break;
    case FL_MSG_PN: n = fl_encode_pn(again, m->counter, &m->body.pn); break;
    case FL_MSG_TM: n = fl_encode_tm(again, m->counter, &m->body.tm); break;
    case FL_MSG_IQ: n = fl_encode_iq(again, m->counter, &m->body.iq); break;
    case FL_MSG_IA: n = fl_encode_ia(again, m->counter, &m->body.ia); break;
    case FL_MSG_RV:
        n = fl_encode_rv(again, m->counter, &m->body.rv);
        if (n == 0u)
            return 2u; /* a non-finite reference: the encoder refuses it */
        break;
    default: return 0u;
    }
    if (n != length)
        return 3u;
    for (i = 0u; i < n; i++)
        if (again[i] != content[i])
            return 3u;
    return 1u;
}

size_t harness_streams(const uint8_t *data, const uint32_t *ends, uint32_t count, uint8_t *out,
                       size_t capacity)
{
    static fl_deframer d;
    size_t at = 0u;
    uint32_t k, i, start = 0u;
    for (k = 0u; k < count; k++) {
        fl_deframer_init(&d, &fl_default_framing);
        for (i = start; i < ends[k]; i++) {
            if (fl_deframe_byte(&d, data[i]) == FL_DEFRAME_FRAME) {
                fl_message m;
                if (at + HARNESS_FRAME_RECORD > capacity)
                    return 0u;
                fl_parse(d.content, d.length, &m);
                out[at] = (uint8_t)'F';
                out[at + 1] = (uint8_t)m.kind;
                out[at + 2] = (uint8_t)m.malformed;
                put32(out + at + 3, m.kind == FL_MSG_MALFORMED ? 0u : m.counter);
                out[at + 7] = m.kind == FL_MSG_COUNTED ? m.items : 0u;
                out[at + 8] = (uint8_t)(m.kind == FL_MSG_COUNTED ? m.id : 0u);
                out[at + 9] = (uint8_t)(m.kind == FL_MSG_COUNTED ? m.id >> 8 : 0u);
                out[at + 10] = (uint8_t)d.length;
                out[at + 11] = round_trip(&m, d.content, d.length);
                at += HARNESS_FRAME_RECORD;
            }
        }
        if (at + HARNESS_STREAM_RECORD > capacity)
            return 0u;
        out[at] = (uint8_t)'S';
        put32(out + at + 1, d.stats.frames);
        put32(out + at + 5, d.stats.frame_bytes);
        put32(out + at + 9, d.stats.escape_bytes);
        put32(out + at + 13, d.stats.dropped_bytes);
        put32(out + at + 17, d.stats.noise_bytes);
        put32(out + at + 21, d.stats.restarts);
        put32(out + at + 25, d.stats.overflows);
        put32(out + at + 29, d.stats.bytes_fed);
        put32(out + at + 33, d.wire);
        at += HARNESS_STREAM_RECORD;
        start = ends[k];
    }
    return at;
}

uint8_t harness_check_set(uint8_t id, uint8_t channel, uint8_t value_type, uint32_t raw)
{
    fl_value value;
    value.raw = raw;
    return fl_param_check_set(id, channel, value_type, value);
}
