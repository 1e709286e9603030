/*
 * fl_selftest.c: the C codec against golden vectors the Python codec produced when this was
 * generated (a hosted program: it prints). `make check` builds and runs it; exit 0 when
 * every vector matches.
 */
#include <stdio.h>

#include "fpgalink_protocol.h"

static int same(const uint8_t *a, size_t na, const uint8_t *b, size_t nb)
{
    size_t i;
    if (na != nb)
        return 0;
    for (i = 0; i < na; i++)
        if (a[i] != b[i])
            return 0;
    return 1;
}

static uint8_t content[FL_MAX_CONTENT];
static uint8_t wire[FL_MAX_WIRE];

static int check_message(const char *what, fl_kind kind, uint32_t counter, size_t length,
                         const uint8_t *want, size_t want_length, const uint8_t *want_wire,
                         size_t want_wire_length, const uint8_t *want_checked,
                         size_t want_checked_length)
{
    fl_message parsed;
    fl_deframer deframer;
    size_t n, i, delivered = 0;
    int failures = 0;
    if (!same(content, length, want, want_length)) {
        printf("FAIL %s: encoded content differs\n", what);
        failures++;
    }
    if (fl_parse(want, want_length, &parsed) != kind || parsed.counter != counter) {
        printf("FAIL %s: parsed as kind %d counter %lu\n", what, (int)parsed.kind,
               (unsigned long)parsed.counter);
        failures++;
    }
    n = fl_frame(&fl_default_framing, want, want_length, wire, sizeof wire);
    if (!same(wire, n, want_wire, want_wire_length)) {
        printf("FAIL %s: framed wire differs\n", what);
        failures++;
    }
    fl_deframer_init(&deframer, &fl_default_framing);
    for (i = 0; i < want_wire_length; i++)
        if (fl_deframe_byte(&deframer, want_wire[i]) == FL_DEFRAME_FRAME)
            delivered = deframer.length;
    if (!same(deframer.content, delivered, want, want_length)) {
        printf("FAIL %s: deframed content differs\n", what);
        failures++;
    }
    for (i = 0; i < want_length; i++)
        content[i] = want[i];
    n = fl_crc_append(content, want_length);
    n = fl_frame(&fl_default_framing, content, n, wire, sizeof wire);
    if (!same(wire, n, want_checked, want_checked_length)) {
        printf("FAIL %s: with the wire CRC, the wire differs\n", what);
        failures++;
    }
    if (fl_crc_board_receive(true, content, want_length + FL_CRC_BYTES) != (int)want_length) {
        printf("FAIL %s: the CRC does not check\n", what);
        failures++;
    }
    if (!failures)
        printf("ok   %s\n", what);
    return failures;
}

int main(void)
{
    int failures = 0;
    static const uint8_t check[] = "123456789";
    if (fl_crc16(check, 9u) != FL_CRC_CHECK) {
        printf("FAIL %s check value\n", FL_CRC_NAME);
        failures++;
    } else {
        printf("ok   %s check value 0x%04X\n", FL_CRC_NAME, (unsigned)FL_CRC_CHECK);
    }
/*@VECTORS@*/
    printf("%s: %d failure(s), declarations %s\n", failures ? "FAILED" : "passed", failures,
           FL_DECLARATIONS_DIGEST);
    return failures ? 1 : 0;
}
