"""The C generator: ``fpgalink_protocol.h``, ``fpgalink_protocol.c``, a self-test with golden
vectors from the Python codec, and a Makefile — all from :mod:`fpgalink.protocol`.

What is data in the declarations (message IDs, layouts, the parameter table, the framing
bytes and limit, the CRC's parameters, the error and flag codes) is written out from it;
what is an algorithm (framing, the deframer, the body grammar, the CRC's table walk, the
handshake rule) is C kept beside this module in ``templates/`` and checked against the
Python codec by the tests (``tests/fpgalink/codegen/``).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from fpgalink.protocol import (
    COUNTER_MODULUS,
    DEFAULT_FRAMING,
    PARAMETERS,
    ChannelTelemetry,
    MalformedReason,
    MessageId,
    NackReason,
    Param,
    ParamAck,
    ParamGet,
    ParamNack,
    ParamSet,
    ParamType,
    References,
    Scope,
    Telemetry,
    TelemetryFlags,
    encode_frame,
    encode_message,
    float32,
)
from fpgalink.protocol.catalogue import BODIES, IdentityAnswer, IdentityQuery, Layout
from fpgalink.protocol.crc import CRC16, CRC_BYTES, WIRE_CRC_PARAM, append_crc
from fpgalink.protocol.identity import declarations_digest
from fpgalink.protocol.messages import LEN_RESERVED, SECTION_CLOSE, SECTION_OPEN

__all__ = ["GeneratedFile", "declarations_digest", "generate_c", "write_c"]

HEADER = "fpgalink_protocol.h"
SOURCE = "fpgalink_protocol.c"
SELFTEST = "fl_selftest.c"
MAKEFILE = "Makefile"

#: struct code → (C type, size, put helper, get helper)
_C_TYPES = {
    "B": ("uint8_t", 1, "fl_put_u8", "fl_get_u8"),
    "h": ("int16_t", 2, "fl_put_i16", "fl_get_i16"),
    "i": ("int32_t", 4, "fl_put_i32", "fl_get_i32"),
    "H": ("uint16_t", 2, "fl_put_u16", "fl_get_u16"),
    "I": ("uint32_t", 4, "fl_put_u32", "fl_get_u32"),
    "Q": ("uint64_t", 8, "fl_put_u64", "fl_get_u64"),
    "f": ("float", 4, "fl_put_f32", "fl_get_f32"),
    "4s": ("fl_value", 4, "fl_put_value", "fl_get_value"),
}


@dataclass(frozen=True, slots=True)
class GeneratedFile:
    name: str
    text: str


def _snake(name: str) -> str:
    """``TsTimerPeriod`` → ``TS_TIMER_PERIOD``, ``Kp_Wheel_Pid`` → ``KP_WHEEL_PID``."""
    return re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "_", name).replace("__", "_").upper()


def _hex_float(value: float) -> str:
    """An exact C99 hexadecimal float literal of a float32 value."""
    if not math.isfinite(value):
        raise ValueError(f"no C literal for {value!r} here")
    if value == 0.0:
        return "-0.0f" if math.copysign(1.0, value) < 0 else "0.0f"
    return float(value).hex() + "f"


def _comment(text: str) -> str:
    return "/* " + text.replace("*/", "* /") + " */"


# --- layouts ------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _Field:
    path: tuple[str, ...]  #: ("a", "position")
    code: str
    offset: int  #: within the body
    description: str

    @property
    def c_type(self) -> str:
        return _C_TYPES[self.code][0]

    @property
    def size(self) -> int:
        return _C_TYPES[self.code][1]


def _fields(layout: Layout, prefix: tuple[str, ...] = (), start: int = 0) -> list[_Field]:
    out: list[_Field] = []
    offset = start
    for entry in layout:
        if len(entry) == 2:
            name, inner = entry
            assert isinstance(inner, tuple)
            nested = _fields(inner, (*prefix, str(name)), offset)
            out += nested
            offset = nested[-1].offset + nested[-1].size if nested else offset
        else:
            name, code, description = entry
            field = _Field((*prefix, str(name)), str(code), offset, str(description))
            out.append(field)
            offset += field.size
    return out


def _body_len(msg_id: MessageId) -> int:
    return sum(f.size for f in _fields(BODIES[msg_id]))


def _lower(msg_id: MessageId) -> str:
    return msg_id.name.lower()


class _Structs:
    """The C struct types of the bodies: one typedef per layout, identical layouts (PS and
    PA, channel A and B of a TM) sharing one type through a typedef alias."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self._seen: list[tuple[Layout, str]] = []

    def type_of(self, layout: Layout, name: str, doc: str) -> str:
        for known, c_name in self._seen:
            if known == layout:
                if c_name != name:
                    self.lines.append(f"typedef {c_name} {name};  {_comment(doc)}")
                    self._seen.append((layout, name))
                return name
        members = []
        for entry in layout:
            if len(entry) == 2:
                inner_name, inner = entry
                assert isinstance(inner, tuple)
                inner_type = self.type_of(inner, f"{name[:-2]}_{inner_name}_t",
                                          f"{doc}: {inner_name}")
                members.append(f"    {inner_type} {inner_name};")
            else:
                field_name, code, description = entry
                members.append(f"    {_C_TYPES[str(code)][0]} {field_name};  "
                               f"{_comment(str(description))}")
        self.lines += [_comment(doc), "typedef struct {", *members, f"}} {name};", ""]
        self._seen.append((layout, name))
        return name


# --- the header -----------------------------------------------------------------------------


def _ids() -> list[str]:
    lines = ["/* --- message IDs (SPEC §4): FL_ID(first, second) as a 16-bit value --- */",
             "#define FL_ID(first, second) \\",
             "    ((uint16_t)((uint16_t)(uint8_t)(first) | ((uint16_t)(uint8_t)(second) << 8)))"]
    for m in MessageId:
        raw = bytes(m)
        who = m.sender.value + (", direct" if m.direct else "")
        if len(raw) == 2:
            lines.append(f"#define FL_ID_{m.name} FL_ID('{chr(raw[0])}', '{chr(raw[1])}')  "
                         f"{_comment(who)}")
        else:
            lines.append(f"#define FL_ID_{m.name} FL_ID('{chr(raw[0])}', 0)  {_comment(who)}")
    return lines


def _kinds() -> list[str]:
    lines = ["/* What fl_parse made of a frame's content. */", "typedef enum {",
             "    FL_MSG_MALFORMED = 0,  /* not a message: see fl_message.malformed */",
             "    FL_MSG_COUNTED = 1,    /* a well-formed counted message not in the catalogue */"]
    value = 2
    for m in MessageId:
        if m.direct:
            command = bytes(m).decode()
            lines.append(f"    FL_MSG_{m.name} = {value},  /* direct command {command!r} */")
            value += 1
    for m in BODIES:
        lines.append(f"    FL_MSG_{m.name} = {value},")
        value += 1
    lines += ["} fl_kind;", ""]
    lines += ["/* Why a frame's content is not a message (fl_message.malformed). */",
              "typedef enum {", "    FL_MALFORMED_NONE = 0,"]
    for number, reason in enumerate(MalformedReason, 1):
        lines.append(f"    FL_MALFORMED_{reason.name} = {number},  {_comment(reason.value)}")
    lines += ["} fl_malformed_reason;", ""]
    return lines


def _layout_defines() -> tuple[list[str], list[str]]:
    """The offsets (``#define``) and the struct types."""
    defines = ["/* --- layouts: each body is one binary section; offsets are within the body,",
               " * which starts at FL_BODY_OFFSET of the content; every field little-endian --- */"]
    structs = _Structs()
    structs.lines.append("/* A 4-byte parameter value, as its value_type says (raw: the bits). */")
    structs.lines += ["typedef union {", "    int32_t i;", "    float f;", "    uint32_t raw;",
                      "} fl_value;", ""]
    for msg_id, layout in BODIES.items():
        name = _lower(msg_id)
        upper = msg_id.name
        body = _body_len(msg_id)
        defines.append(f"#define FL_{upper}_BODY_LEN {body}u")
        defines.append(f"#define FL_{upper}_CONTENT_LEN {body + 10}u  "
                       f"/* ID, counter, '{{' LEN, body, '}}' */")
        for field in _fields(layout):
            macro = "_".join(p.upper() for p in field.path)
            defines.append(f"#define FL_{upper}_{macro} {field.offset}u  "
                           f"{_comment(f'{field.c_type}: {field.description}')}")
        defines.append("")
        structs.type_of(layout, f"fl_{name}_t", f"{upper} body")
    return defines, structs.lines


def _param_header() -> list[str]:
    lines = ["/* --- parameters (SPEC §5, and WireCrc): the table is fl_params[] --- */",
             "#define FL_CHANNEL_BOARD 0u", "#define FL_CHANNEL_A 1u", "#define FL_CHANNEL_B 2u",
             "typedef enum { "
             + ", ".join(f"FL_SCOPE_{s.name} = {int(s)}" for s in Scope) + " } fl_scope;",
             "typedef enum { "
             + ", ".join(f"FL_TYPE_{t.name} = {int(t)}" for t in ParamType) + " } fl_type;",
             "/* PN codes, checked in this order; the first failure answers. */",
             "typedef enum {"]
    lines += [f"    FL_NACK_{r.name} = {int(r)},  {_comment(r.text)}" for r in NackReason]
    lines += ["} fl_nack;", ""]
    for p in PARAMETERS:
        unit = f" {p.unit}" if p.unit else ""
        doc = f"{p.scope.name.lower()}, {p.type.name.lower()} {p.range_text}{unit}: {p.description}"
        lines.append(f"#define FL_PARAM_{_snake(p.name)} {p.id}u  {_comment(doc)}")
    slots = sum(1 if p.scope is Scope.BOARD else 2 for p in PARAMETERS)
    allowed = max((len(p.allowed) for p in PARAMETERS if p.allowed), default=1)
    lines += [
        f"#define FL_PARAM_COUNT {len(PARAMETERS)}u",
        f"#define FL_PARAM_MAX_ID {max(p.id for p in PARAMETERS)}u",
        f"#define FL_PARAM_SLOTS {slots}u  /* (parameter, channel) addresses: one store each */",
        f"#define FL_PARAM_MAX_ALLOWED {allowed}u",
        "#define FL_RANGE_MIN_EXCLUSIVE 0x01u",
        "#define FL_RANGE_NO_MIN 0x02u",
        "#define FL_RANGE_NO_MAX 0x04u",
        "#define FL_RANGE_ALLOWED 0x08u  /* a discrete set (allowed[]) instead of a range */",
        "",
        "typedef struct {",
        "    uint8_t id;",
        "    uint8_t scope;          /* fl_scope */",
        "    uint8_t type;           /* fl_type: the value travels as int32 or float32 */",
        "    uint8_t range;          /* FL_RANGE_* flags */",
        "    uint8_t slot;           /* first store slot: one for a board parameter, A then B */",
        "    uint8_t allowed_count;",
        "    fl_value minimum;       /* as the type (.i or .f) */",
        "    fl_value maximum;",
        "    fl_value power_up;      /* the power-up value */",
        "    int32_t allowed[FL_PARAM_MAX_ALLOWED];",
        "    const char *name;       /* without the channel suffix A/B */",
        "    const char *unit;",
        "} fl_param_info;",
        "",
        "extern const fl_param_info fl_params[FL_PARAM_COUNT];",
        "",
    ]
    return lines


def _flags() -> list[str]:
    lines = ["/* TM flags per channel */"]
    lines += [f"#define FL_TM_FLAG_{f.name} {int(f)}u" for f in TelemetryFlags]
    return [*lines, ""]


def _header(digest: str) -> str:
    defines, structs = _layout_defines()
    unions = "\n".join(f"    fl_{_lower(m)}_t {_lower(m)};" for m in BODIES)
    encoders = "\n".join(
        f"size_t fl_encode_{_lower(m)}(uint8_t *content, uint32_t counter, "
        f"const fl_{_lower(m)}_t *body);" for m in BODIES)
    template = resources.files("fpgalink.codegen").joinpath("templates/header.h").read_text(
        encoding="utf-8")
    framing = DEFAULT_FRAMING
    replacements = {
        "DIGEST": digest,
        "FRAMING": "\n".join([
            f"#define FL_START 0x{framing.start:02X}u  /* '{chr(framing.start)}' */",
            f"#define FL_STOP 0x{framing.stop:02X}u  /* '{chr(framing.stop)}' */",
            f"#define FL_SKIP 0x{framing.skip:02X}u  /* backslash */",
            f"#define FL_MAX_CONTENT {framing.max_content}u  "
            "/* content bytes; the 201st makes the frame garbage */",
        ]),
        "MESSAGES": "\n".join([
            f"#define FL_COUNTER_MODULUS {COUNTER_MODULUS}u  /* five digits, 99999 wraps to 0 */",
            f"#define FL_SECTION_OPEN 0x{SECTION_OPEN:02X}u  /* '{{' */",
            f"#define FL_SECTION_CLOSE 0x{SECTION_CLOSE:02X}u  /* '}}' */",
            f"#define FL_LEN_RESERVED {LEN_RESERVED}u",
            *_ids(), "", *_kinds(), *_flags(), *defines, *structs,
        ]),
        "UNION": unions,
        "ENCODERS": encoders,
        "PARAMS": "\n".join(_param_header()),
        "CRC": "\n".join([
            f"#define FL_CRC_NAME \"{CRC16.name}\"",
            f"#define FL_CRC_POLY 0x{CRC16.poly:04X}u",
            f"#define FL_CRC_INIT 0x{CRC16.init:04X}u",
            f"#define FL_CRC_XOROUT 0x{CRC16.xorout:04X}u  /* no reflection in or out */",
            f"#define FL_CRC_CHECK 0x{CRC16.check:04X}u  /* of the ASCII bytes 123456789 */",
            f"#define FL_CRC_BYTES {CRC_BYTES}u  /* after the body, little-endian */",
            f"#define FL_WIRE_CRC_PARAM {WIRE_CRC_PARAM}u",
        ]),
    }
    return _fill(template, replacements)


def _fill(template: str, replacements: dict[str, str]) -> str:
    def one(match: re.Match[str]) -> str:
        return replacements[match.group(1)]

    text = re.sub(r"/\*@(\w+)@\*/", one, template)
    leftover = re.findall(r"@\w+@", text)
    if leftover:
        raise AssertionError(f"unfilled template markers {leftover}")
    return text


# --- the source -----------------------------------------------------------------------------


def _encoder(msg_id: MessageId) -> list[str]:
    name, upper = _lower(msg_id), msg_id.name
    lines = [f"size_t fl_encode_{name}(uint8_t *content, uint32_t counter, "
             f"const fl_{name}_t *body)", "{"]
    fields = _fields(BODIES[msg_id])
    floats = [f for f in fields if f.code == "f"]
    if msg_id is MessageId.RV:
        # A non-finite reference would poison a controller that trusts its host.
        test = " || ".join(f"!fl_finite(body->{'.'.join(f.path)})" for f in floats)
        lines += [f"    if ({test})", "        return 0u;"]
    lines.append(f"    fl_put_header(content, FL_ID_{upper}, counter, FL_{upper}_BODY_LEN);")
    for f in fields:
        macro = "_".join(p.upper() for p in f.path)
        put = _C_TYPES[f.code][2]
        lines.append(f"    {put}(content + FL_BODY_OFFSET + FL_{upper}_{macro}, "
                     f"body->{'.'.join(f.path)});")
    lines += [f"    content[FL_{upper}_CONTENT_LEN - 1u] = FL_SECTION_CLOSE;",
              f"    return FL_{upper}_CONTENT_LEN;", "}", ""]
    return lines


def _decoder(msg_id: MessageId) -> list[str]:
    name, upper = _lower(msg_id), msg_id.name
    lines = [f"static void fl_get_{name}(const uint8_t *body, fl_{name}_t *out)", "{"]
    for f in _fields(BODIES[msg_id]):
        macro = "_".join(p.upper() for p in f.path)
        get = _C_TYPES[f.code][3]
        lines.append(f"    out->{'.'.join(f.path)} = {get}(body + FL_{upper}_{macro});")
    return [*lines, "}", ""]


def _typed_cases() -> list[str]:
    lines = []
    for msg_id in BODIES:
        name, upper = _lower(msg_id), msg_id.name
        lines += [
            f"    case FL_ID_{upper}:",
            f"        if (length == FL_{upper}_CONTENT_LEN"
            f" && fl_typed_frame(content, FL_{upper}_BODY_LEN)) {{",
            f"            fl_get_{name}(content + FL_BODY_OFFSET, &message->body.{name});",
            f"            return fl_counted(message, FL_MSG_{upper}, id, content);",
            "        }",
            "        catalogued = true;",
            "        break;",
        ]
    return lines


def _param_table() -> list[str]:
    lines = ["const fl_param_info fl_params[FL_PARAM_COUNT] = {"]
    slot = 0
    for p in PARAMETERS:
        lines.append("    " + _param_entry(p, slot) + ",")
        slot += 1 if p.scope is Scope.BOARD else 2
    return [*lines, "};", ""]


def _value_literal(param: Param, value: float) -> str:
    if param.type is ParamType.INT:
        if not float(value).is_integer() or not -(2**31) <= value < 2**31:
            raise ValueError(f"{param.name}: {value!r} is not an int32")
        number = int(value)
        # INT32_MIN has no literal of its own type in C.
        text = f"{number}" if number > -(2**31) else "(-2147483647 - 1)"
        return f"{{ .i = {text} }}"
    return f"{{ .f = {_hex_float(float32(value))} }}"


def _param_entry(p: Param, slot: int) -> str:
    flags = []
    if p.min_exclusive:
        flags.append("FL_RANGE_MIN_EXCLUSIVE")
    if p.minimum == -math.inf:
        flags.append("FL_RANGE_NO_MIN")
    if p.maximum == math.inf:
        flags.append("FL_RANGE_NO_MAX")
    if p.allowed is not None:
        flags.append("FL_RANGE_ALLOWED")
    minimum = _value_literal(p, p.minimum) if math.isfinite(p.minimum) else "{ .raw = 0u }"
    maximum = _value_literal(p, p.maximum) if math.isfinite(p.maximum) else "{ .raw = 0u }"
    allowed = ", ".join(str(v) for v in (p.allowed or (0,)))
    return (f"{{ FL_PARAM_{_snake(p.name)}, FL_SCOPE_{p.scope.name}, FL_TYPE_{p.type.name}, "
            f"{' | '.join(flags) or '0u'}, {slot}u, {len(p.allowed or ())}u, {minimum}, "
            f"{maximum}, {_value_literal(p, p.default)}, {{ {allowed} }}, \"{p.name}\", "
            f"\"{p.unit}\" }}")


def _crc_table() -> list[str]:
    table = CRC16.table()
    rows = [", ".join(f"0x{v:04X}u" for v in table[i : i + 8]) for i in range(0, 256, 8)]
    return [f"/* {CRC16.name}, one entry per leading byte (MSB first) */",
            "static const uint16_t fl_crc_table[256] = {",
            *(f"    {row}," for row in rows), "};", ""]


def _source() -> str:
    template = resources.files("fpgalink.codegen").joinpath("templates/codec.c").read_text(
        encoding="utf-8")
    encoders: list[str] = []
    decoders: list[str] = []
    for msg_id in BODIES:
        encoders += _encoder(msg_id)
        decoders += _decoder(msg_id)
    return _fill(template, {
        "DECODERS": "\n".join(decoders),
        "TYPED_CASES": "\n".join(_typed_cases()),
        "ENCODERS": "\n".join(encoders),
        "PARAM_TABLE": "\n".join(_param_table()),
        "CRC_TABLE": "\n".join(_crc_table()),
    })


# --- the self-test: golden vectors from the Python codec ------------------------------------


def _c_bytes(data: bytes) -> str:
    return "{ " + ", ".join(f"0x{b:02X}u" for b in data) + " }" if data else "{ 0u }"


def _golden() -> list[tuple[str, bytes, str]]:
    """(what, plain content, the C statements that build the same body into ``m``)."""
    a = ChannelTelemetry(-123456, 44.75, 1.5, 20000, 45.0, 5)
    b = ChannelTelemetry(7, -12.5, -0.25, -32760, -30.0, 2)
    cases: list[tuple[str, bytes, str]] = [
        ("PS int", encode_message(ParamSet(1, 0, 1, 7), 0),
         "m.ps.param_id = 1u; m.ps.channel = 0u; m.ps.value_type = 1u; m.ps.value.i = 7;"),
        ("PS float", encode_message(ParamSet(8, 2, 2, 123.5), 99999),
         "m.ps.param_id = 8u; m.ps.channel = 2u; m.ps.value_type = 2u; "
         "m.ps.value.f = 123.5f;"),
        ("PG", encode_message(ParamGet(11, 0), 83),
         "m.pg.param_id = 11u; m.pg.channel = 0u;"),
        ("PA", encode_message(ParamAck(7, 1, 1, -1), 12345),
         "m.pa.param_id = 7u; m.pa.channel = 1u; m.pa.value_type = 1u; m.pa.value.i = -1;"),
        ("PN", encode_message(ParamNack(83, 80, 3), 5),
         "m.pn.param_id = 83u; m.pn.channel = 80u; m.pn.error = 3u;"),
        ("RV", encode_message(References(45.0, -0.5), 42),
         "m.rv.ref_a = 45.0f; m.rv.ref_b = -0.5f;"),
        ("TM", encode_message(Telemetry(4294967295, a, b), 77777),
         "m.tm.t_us = 4294967295u; "
         "m.tm.a.position = -123456; m.tm.a.speed = 44.75f; m.tm.a.current = 1.5f; "
         "m.tm.a.pwm = 20000; m.tm.a.reference = 45.0f; m.tm.a.flags = 5u; "
         "m.tm.b.position = 7; m.tm.b.speed = -12.5f; m.tm.b.current = -0.25f; "
         "m.tm.b.pwm = -32760; m.tm.b.reference = -30.0f; m.tm.b.flags = 2u;"),
        ("IQ", encode_message(IdentityQuery(0x7B5C5350), 31),
         "m.iq.nonce = 0x7B5C5350u;"),
        ("IA", encode_message(IdentityAnswer(0x7B5C5350, 0xFEDCBA9876543210, 1, 65535, 7,
                                             0xDEADBEEF, (1 << 57) - 1), 65432),
         "m.ia.nonce = 0x7B5C5350u; m.ia.declarations = UINT64_C(0xFEDCBA9876543210); "
         "m.ia.firmware_major = 1u; m.ia.firmware_minor = 65535u; m.ia.firmware_patch = 7u; "
         "m.ia.build = 0xDEADBEEFu; m.ia.serial = UINT64_C(0x1FFFFFFFFFFFFFF);"),
    ]
    return cases


def _selftest() -> str:
    template = resources.files("fpgalink.codegen").joinpath("templates/selftest.c").read_text(
        encoding="utf-8")
    vectors = []
    kinds = {m.name: _lower(m) for m in BODIES}
    for what, content, build in _golden():
        key = what.split()[0]
        name = kinds[key]
        counter = int(content[2:7])
        wire = encode_frame(content)
        checked = encode_frame(append_crc(content))
        vectors += [
            "    {",
            f"        static const uint8_t want[] = {_c_bytes(content)};",
            f"        static const uint8_t want_wire[] = {_c_bytes(wire)};",
            f"        static const uint8_t want_checked[] = {_c_bytes(checked)};",
            "        fl_body_union m;",
            f"        {build}",
            f"        failures += check_message(\"{what}\", FL_MSG_{key}, {counter}u,",
            f"            fl_encode_{name}(content, {counter}u, &m.{name}), want, sizeof want,",
            "            want_wire, sizeof want_wire, want_checked, sizeof want_checked);",
            "    }",
        ]
    return _fill(template, {"VECTORS": "\n".join(vectors)})


def _makefile() -> str:
    return resources.files("fpgalink.codegen").joinpath("templates/Makefile").read_text(
        encoding="utf-8")


def generate_c() -> list[GeneratedFile]:
    """Every file of the C codec, in memory."""
    digest = declarations_digest()
    stamp = (f"/* Generated by `python -m fpgalink.codegen c` from fpgalink.protocol "
             f"(declarations {digest}). Do not edit. */\n")
    return [
        GeneratedFile(HEADER, stamp + _header(digest)),
        GeneratedFile(SOURCE, stamp + _source()),
        GeneratedFile(SELFTEST, stamp + _selftest()),
        GeneratedFile(MAKEFILE, f"# Generated by `python -m fpgalink.codegen c` "
                                f"(declarations {digest}). Do not edit.\n" + _makefile()),
    ]


def write_c(outdir: Path) -> list[Path]:
    """Write the C codec into ``outdir`` (created if missing); a file whose text is already
    what it would be is left untouched, so ``make`` rebuilds nothing needlessly."""
    outdir.mkdir(parents=True, exist_ok=True)
    written = []
    for generated in generate_c():
        path = outdir / generated.name
        if not path.exists() or path.read_text(encoding="utf-8") != generated.text:
            path.write_text(generated.text, encoding="utf-8")
        written.append(path)
    return written

