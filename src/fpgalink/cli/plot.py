"""``plot``: fields of a recording against time, saved as a PNG (or SVG, PDF) — for a quick
look without Foxglove or PlotJuggler at hand.

Reads the MCAP files ``record``, ``drive --record`` and ``goto --record`` write (and any
MCAP with JSON messages), and the rosbag2 directories ``--rosbag2`` writes (CDR, decoded
with the ``rosbags`` library of the ros2 extra), through
:class:`fpgalink.recording.RecordingReader`: every chunk checked against its CRC, a damaged
one skipped and named (exit 9), the rest used. A recording whose writer was killed has no
summary; its complete chunks are still read, in file order, and the command says so.

Every message is seen as flat numeric fields: nested objects by ``.`` (``pose.pose.
position.x``), arrays by index or, beside a ``name`` array of the same length (a
``JointState``), by name (``velocity.FL``). A field asked for is a key, the flat
``a_speed`` spelt ``a.speed``, or a prefix naming a group (``velocity``: every wheel)."""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click

from fpgalink.cli.figures import check_plot_path, new_figure, save_figure
from fpgalink.cli.files import force_option
from fpgalink.cli.output import EXIT_CODES_HELP, CliError, ExitCode, note
from fpgalink.recording import NotARecording, RecordingReader
from fpgalink.recording.reader import Schema

__all__ = ["Reading", "Series", "field_value", "flatten", "plot", "read_series", "unit_of"]

DEFAULT_FIELDS = "a.speed+a.ref,b.speed+b.ref"
TELEMETRY_SUFFIX = "/telemetry"
#: A rosbag2 of the robot (``--rosbag2``): each wheel's speed, and the body's.
BAG_TOPICS = ("/joint_states", "/odom")
BAG_FIELDS = "velocity,twist.twist.linear.x,twist.twist.angular.z"
_CLOCKS = {
    "publish": "the board's sample time (publish_time; header stamps in a bag)",
    "log": "host receive time (log_time; the bag's time)",
}
#: The unit of a field, by its last name(s): the board's telemetry (record, drive
#: --record), the robot's topics (drive/goto --record) and the ROS messages of a bag.
UNITS = {
    "position": "encoder counts", "speed": "deg/s", "current": "A", "pwm": "PWM counts",
    "ref": "deg/s", "t_us": "µs", "timestamp": "s",
    "telemetry_rate": "TM/s", "x": "m", "y": "m", "theta": "rad", "v": "m/s",
    "omega": "rad/s", "left": "deg/s", "right": "deg/s", "distance": "m",
    "velocity": "rad/s", "effort": "N·m", "linear": "m/s", "angular": "rad/s",
}
#: In a bag, ``position`` is a joint's angle.
BAG_UNITS = {"position": "rad", "orientation": "", "covariance": ""}
#: The components of a ROS vector take their unit from what the vector is.
VECTOR_UNITS = {"position": "m", "linear": "m/s", "angular": "rad/s", "orientation": ""}


@dataclass
class Series:
    """One field of one topic: time (s since the recording's first message) and values."""

    topic: str
    field: str
    t: list[float] = dataclasses.field(default_factory=list)
    values: list[float] = dataclasses.field(default_factory=list)
    #: the field as it was asked for (``velocity`` for ``velocity.FL``)
    asked: str = ""


def _number(node: Any) -> float | None:
    if isinstance(node, bool) or not isinstance(node, int | float):
        try:  # numpy scalars
            import numpy as np

            if isinstance(node, np.integer | np.floating):
                return float(node)
        except ImportError:  # pragma: no cover - numpy is a dependency
            pass
        return None
    return float(node)


def flatten(record: Any, prefix: str = "", out: dict[str, float | None] | None = None
            ) -> dict[str, float | None]:
    """Every numeric field of a message (a JSON object or a ROS message) by its dotted
    path; ``None`` for a JSON ``null`` (a value not finite on the wire)."""
    out = {} if out is None else out
    if dataclasses.is_dataclass(record) and not isinstance(record, type):
        items: Any = ((f.name, getattr(record, f.name)) for f in dataclasses.fields(record)
                      if not f.name.startswith("__"))
        names = getattr(record, "name", None)
    elif isinstance(record, dict):
        items = record.items()
        names = record.get("name")
    else:
        return out
    for key, node in items:
        path = f"{prefix}{key}"
        if node is None:
            out[path] = None
        elif isinstance(node, dict) or (dataclasses.is_dataclass(node)
                                        and not isinstance(node, type)):
            flatten(node, path + ".", out)
        elif isinstance(node, str | bytes):
            continue
        elif hasattr(node, "__len__") and not isinstance(node, dict):
            labels = (list(names) if isinstance(names, list | tuple) and
                      len(names) == len(node) and key != "name" else range(len(node)))
            for label, element in zip(labels, node, strict=False):
                if dataclasses.is_dataclass(element) or isinstance(element, dict):
                    flatten(element, f"{path}.{label}.", out)
                else:
                    value = _number(element)
                    if value is not None:
                        out[f"{path}.{label}"] = value
        else:
            value = _number(node)
            if value is not None:
                out[path] = value
    return out


def field_value(record: Any, path: str) -> float | None:
    """``path`` in a JSON record: ``a.speed`` is ``record["a"]["speed"]`` when nested, else
    the flat ``a_speed`` our telemetry uses. ``None`` when absent or not a number (a JSON
    ``null`` — a non-finite value on the wire — included)."""
    node: Any = record
    for part in path.split("."):
        if isinstance(node, dict) and part in node:
            node = node[part]
        else:
            node = None
            break
    if node is None and isinstance(record, dict):
        node = record.get(path.replace(".", "_"))
    if isinstance(node, bool) or not isinstance(node, int | float):
        return None
    return float(node)


def matching(keys: Any, asked: str) -> list[str]:
    """The flat keys ``asked`` names: itself, its ``_`` spelling, or a group under it."""
    flat = asked.replace(".", "_")
    group = asked + "."
    return [k for k in keys if k in (asked, flat) or k.startswith(group)]


def unit_of(field: str, bag: bool = False) -> str:
    """The unit of a field, from its last names (``""`` when not known)."""
    parts = [p for p in field.replace("_", ".").split(".") if p and not p.isdigit()]
    if len(parts) >= 2 and parts[-1] in ("x", "y", "z", "w") and parts[-2] in VECTOR_UNITS:
        return VECTOR_UNITS[parts[-2]]
    for part in reversed(parts):
        if bag and part in BAG_UNITS:
            return BAG_UNITS[part]
        if part in UNITS:
            return UNITS[part]
    return ""


# --- reading ----------------------------------------------------------------------------------


@dataclass
class Message:
    topic: str
    publish: float  #: s
    log: float  #: s
    record: Any  #: a JSON object, or a ROS message


def _reader(path: Path) -> RecordingReader:
    try:
        return RecordingReader(path)
    except NotARecording as exc:
        raise CliError(str(exc), ExitCode.BAD_INPUT) from None


def _account(reader: RecordingReader, state: dict[str, Any]) -> None:
    """What reading ``reader`` found besides its messages, into ``state``."""
    state["complete"] = state.get("complete", True) and reader.complete
    state["damage"] += [f"{reader.path}: {d.describe(reader.origin_ns)}"
                        for d in reader.damage]
    state["orphans"] += reader.skipped_messages
    state["topics"] = sorted({*state.get("topics", ()),
                              *(c.topic for c in reader.channels.values())})


def _read_mcap(path: Path, topics: list[str] | None, state: dict[str, Any]
               ) -> Iterator[Message]:
    with _reader(path) as reader:
        try:
            for _schema, channel, message in reader.messages(topics):
                try:
                    record = json.loads(message.data)
                except (ValueError, UnicodeDecodeError, RecursionError):
                    # Not JSON, or nested too deeply: one bad message is counted and said,
                    # the rest still plotted.
                    state["skipped"] += 1
                    continue
                yield Message(channel.topic, message.publish_time / 1e9,
                              message.log_time / 1e9, record)
        finally:
            _account(reader, state)


def is_bag(path: Path) -> bool:
    return path.is_dir() and (path / "metadata.yaml").is_file()


def _read_bag(path: Path, topics: list[str] | None, state: dict[str, Any]
              ) -> Iterator[Message]:
    """A rosbag2: its MCAP files read as every recording is (chunks checked), the CDR
    messages decoded with ``rosbags``' types (a type the bag defines and the Jazzy store
    does not know is taken from the bag); another storage (SQLite) through ``rosbags``."""
    try:
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise CliError(f"{path} is a rosbag2: reading it needs the rosbags library: pip "
                       "install 'fpgalink[ros2]'", ExitCode.BAD_INPUT) from None
    types = get_typestore(Stores.ROS2_JAZZY)
    files = sorted(path.glob("*.mcap"))
    if not files:
        yield from _read_other_bag(path, topics, state, types)
        return
    for file in files:
        with _reader(file) as reader:
            try:
                for schema, channel, message in reader.messages(topics):
                    ros = _decode(types, schema, message.data)
                    if ros is None:
                        state["skipped"] += 1
                        continue
                    stamp = getattr(getattr(ros, "header", None), "stamp", None)
                    log = message.log_time / 1e9
                    publish = log if stamp is None else stamp.sec + stamp.nanosec / 1e9
                    yield Message(channel.topic, publish, log, ros)
            finally:
                _account(reader, state)


def _decode(types: Any, schema: Schema | None, data: bytes) -> Any:
    """A CDR message of ``schema``'s type, or ``None`` when it cannot be decoded."""
    if schema is None:
        return None
    try:
        if schema.name not in types.fielddefs:
            from rosbags.typesys import get_types_from_idl, get_types_from_msg

            text = schema.data.decode("utf-8")
            types.register(get_types_from_idl(text) if schema.encoding == "ros2idl"
                           else get_types_from_msg(text, schema.name))
        return types.deserialize_cdr(data, schema.name)
    except Exception:  # rosbags' errors on a definition or message it cannot read
        return None


def _read_other_bag(path: Path, topics: list[str] | None, state: dict[str, Any],
                    types: Any) -> Iterator[Message]:
    from rosbags.highlevel import AnyReader

    with AnyReader([path], default_typestore=types) as reader:
        state["topics"] = sorted({c.topic for c in reader.connections})
        chosen = [c for c in reader.connections if topics is None or c.topic in topics]
        for connection, timestamp, raw in reader.messages(connections=chosen):
            message = reader.deserialize(raw, connection.msgtype)
            stamp = getattr(getattr(message, "header", None), "stamp", None)
            log = timestamp / 1e9
            publish = log if stamp is None else stamp.sec + stamp.nanosec / 1e9
            yield Message(connection.topic, publish, log, message)


@dataclass
class Reading:
    """What :func:`read_series` found: the series, whether the file was complete, how many
    messages of the chosen topics were skipped because they could not be read as a record
    (not JSON, nested too deeply, a number beyond any float …), every topic with the fields
    its first message has (to say what there is when something asked for is not), and the
    damage: each part of the file skipped (one line each), and the messages of intact chunks
    skipped because their channel was defined in a damaged one."""

    series: list[Series]
    complete: bool
    skipped: int = 0
    available: dict[str, list[str]] = dataclasses.field(default_factory=dict)
    damage: list[str] = dataclasses.field(default_factory=list)
    orphans: int = 0


def read_series(path: Path, topics: list[str] | None, fields: list[str],
                clock: str = "publish") -> Reading:
    """Each (topic, field) pair as a time series, and what else was found (:class:`Reading`).
    ``topics=None``: every ``/board/NAME/telemetry`` topic (in a bag: ``/joint_states`` and
    ``/odom``)."""
    bag = is_bag(path)
    series: dict[tuple[str, str], Series] = {}
    available: dict[str, list[str]] = {}
    origin: float | None = None
    state: dict[str, Any] = {"skipped": 0, "damage": [], "orphans": 0}
    default_topics = topics is None
    wanted = list(BAG_TOPICS) if bag and default_topics else topics
    try:
        reader = _read_bag(path, wanted, state) if bag else _read_mcap(path, wanted, state)
        for message in reader:
            topic = message.topic
            if default_topics and not bag and not topic.endswith(TELEMETRY_SUFFIX):
                available.setdefault(topic, [])
                continue
            try:
                flat = flatten(message.record)
            except (RecursionError, OverflowError):
                state["skipped"] += 1
                continue
            if topic not in available or not available[topic]:
                available[topic] = list(flat)
            stamp = message.publish if clock == "publish" else message.log
            origin = stamp if origin is None else min(origin, stamp)
            for asked in fields:
                for key in matching(flat, asked):
                    value = flat[key]
                    label = asked if key in (asked, asked.replace(".", "_")) else key
                    line = series.get((topic, label))
                    if line is None:
                        line = series[(topic, label)] = Series(topic, label, asked=asked)
                    if value is not None and math.isfinite(value):
                        line.t.append(stamp)
                        line.values.append(value)
    except CliError:
        raise
    except NotARecording as exc:
        raise CliError(str(exc), ExitCode.BAD_INPUT) from None
    except OSError as exc:
        raise CliError(f"{path}: cannot read: {exc.strerror or exc}", ExitCode.FAILURE) from None
    except Exception as exc:  # a foreign bag rosbags cannot read
        if not bag:
            raise
        raise CliError(f"{path}: not a readable rosbag2 ({type(exc).__name__}: {exc})",
                       ExitCode.BAD_INPUT) from None
    for topic in state.get("topics", []):
        available.setdefault(topic, [])
    for line in series.values():
        order = sorted(range(len(line.t)), key=line.t.__getitem__)
        line.t = [line.t[i] - (origin or 0.0) for i in order]
        line.values = [line.values[i] for i in order]
    ranked = sorted(series.values(), key=lambda s: (s.topic, fields.index(s.asked), s.field))
    return Reading(ranked, bool(state.get("complete", False)), int(state["skipped"]), available,
                   list(state["damage"]), int(state["orphans"]))


def _collapse(keys: list[str]) -> list[str]:
    """An array's elements as one entry (``pose.covariance.0..35``), so the names that
    matter are not buried under a covariance matrix."""
    out: list[str] = []
    ranges: dict[str, list[int]] = {}
    for key in keys:
        head, _, last = key.rpartition(".")
        if head and last.isdigit():
            if head not in ranges:
                ranges[head] = []
                out.append(head)
            ranges[head].append(int(last))
        else:
            out.append(key)
    return [f"{k}.{min(ranges[k])}..{max(ranges[k])}" if k in ranges else k for k in out]


def _listing(available: dict[str, list[str]], topics: list[str]) -> str:
    """What the recording has, for an error that says what to ask for instead."""
    parts = []
    for topic in topics:
        keys = _collapse(available.get(topic, []))
        shown = ", ".join(keys[:40]) + (f", … ({len(keys)} in all)" if len(keys) > 40 else "")
        parts.append(f"{topic} has {shown or 'no numeric fields'}")
    return "; ".join(parts)


# --- the command ------------------------------------------------------------------------------


@click.command(epilog=EXIT_CODES_HELP)
@click.argument("recording", type=click.Path(exists=True, path_type=Path))
@click.option("--topic", "topics", multiple=True, metavar="TOPIC",
              help="Topic to plot (repeatable). Default: every /board/NAME/telemetry; in a "
                   "rosbag2, /joint_states and /odom.")
@click.option("--fields", metavar="F1,F2+F3,…",
              help="Fields to plot, one panel each; F2+F3 share a panel. A field is a.speed "
                   f"or a_speed; nested as a.b.c; a prefix is a group (velocity: every "
                   f"wheel). Default: {DEFAULT_FIELDS}; in a rosbag2, {BAG_FIELDS}.")
@click.option("--time", "clock", type=click.Choice(sorted(_CLOCKS)), default="publish",
              show_default=True,
              help="Time axis: the board's sample time (publish) or host receive time (log).")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path),
              help="Image to write (.png, .svg or .pdf). Default: RECORDING with .png.")
@force_option
def plot(recording: Path, topics: tuple[str, ...], fields: str | None, clock: str,
         output: Path | None, force: bool) -> int:
    """Plot fields of a recording against time into a PNG.

    RECORDING is an MCAP file (record, drive/goto --record) or a rosbag2 directory
    (--rosbag2). One panel per field (or per group joined with +), one line per topic and
    field, references dashed; each axis gives its unit. Values the recording holds as null
    (non-finite on the wire) are gaps. A field or topic that is not in the recording is an
    error that lists what is. Every chunk of the recording is checked (its CRC): a damaged
    one is skipped and named with its time span, the rest plotted, and the exit is 8. Needs
    matplotlib (pip install 'fpgalink[plot]').
    """
    bag = is_bag(recording)
    if recording.is_dir() and not bag:
        raise CliError(f"{recording}: a directory, but not a rosbag2 (no metadata.yaml)",
                       ExitCode.BAD_INPUT)
    fields = fields or (BAG_FIELDS if bag else DEFAULT_FIELDS)
    panels = [[f.strip() for f in group.split("+") if f.strip()] for group in fields.split(",")]
    panels = [p for p in panels if p]
    names = list(dict.fromkeys(f for panel in panels for f in panel))
    if not names:
        raise CliError("--fields: give at least one field name", ExitCode.BAD_INPUT)
    output = output or (recording.parent / f"{recording.name}.png" if bag
                        else recording.with_suffix(".png"))
    check_plot_path(output, "--output", force=force)
    reading = read_series(recording, list(topics) or None, names, clock)
    series, available = reading.series, reading.available
    for damage in reading.damage:
        note(f"damaged: {damage}; skipped")
    if reading.orphans:
        note(f"damaged: skipped {reading.orphans} message(s) of intact chunks whose channel "
             "was defined in a damaged one")
    damaged = len(reading.damage) + (1 if reading.orphans else 0)
    if not reading.complete:
        note(f"{recording} was not closed (no summary): plotting the complete chunks it holds")
    if damaged and not any(s.values for s in series):
        raise CliError(f"{recording}: damaged, and nothing intact to plot ({damaged} damaged "
                       "part(s), named above)", ExitCode.DAMAGED)
    if reading.skipped:
        note(f"skipped {reading.skipped} message(s) that are not JSON records with plottable "
             "numbers (not JSON, nested too deeply, or a number beyond a float's range)")
    missing_topics = [t for t in topics if t not in available]
    if missing_topics:
        every = sorted(available)
        raise CliError(f"{recording}: no topic {', '.join(missing_topics)}; it has "
                       f"{', '.join(every) or 'no messages'}", ExitCode.BAD_INPUT)
    chosen = sorted({s.topic for s in series})
    looked_in = list(topics) or sorted(t for t in available if bag or
                                       t.endswith(TELEMETRY_SUFFIX))
    unknown = [n for n in names if not any(s.asked == n for s in series)]
    if unknown:
        raise CliError(f"{recording}: no field {', '.join(unknown)} on "
                       f"{', '.join(looked_in) or 'any /board/NAME/telemetry topic'} "
                       f"({_listing(available, looked_in) or 'no such topics'}; every "
                       f"topic: {', '.join(sorted(available)) or 'none'})",
                       ExitCode.BAD_INPUT)
    empty = [n for n in names if not any(s.values for s in series if s.asked == n)]
    if len(empty) == len(names):
        raise CliError(f"{recording}: no values for {', '.join(names)} on "
                       f"{', '.join(chosen)}", ExitCode.BAD_INPUT)
    if empty:
        note(f"no values for {', '.join(empty)}: left out")
    shown = [[n for n in panel if n not in empty] for panel in panels]
    shown = [panel for panel in shown if panel]
    _draw(output, recording, series, shown, chosen, clock, bag, force)
    points = sum(len(s.values) for s in series)
    note(f"plotted {points} points of {len(names) - len(empty)} field(s) from "
         f"{len(chosen)} topic(s) to {output}")
    if damaged:
        raise CliError(f"{recording}: damaged: {damaged} part(s) skipped (named above); "
                       f"plotted what is intact to {output}", ExitCode.DAMAGED)
    return ExitCode.OK


STYLES = ("-", "--", ":", "-.")


def _pair_key(field: str) -> str:
    """A channel's fields (``a.speed``, ``a_ref``) share a colour; any other its own."""
    parts = field.replace("_", ".").split(".")
    return parts[0] if len(parts) == 2 and parts[0] in ("a", "b") else field


def _is_reference(field: str) -> bool:
    last = field.replace("_", ".").split(".")[-1]
    return last in ("ref", "reference")


def _draw(output: Path, recording: Path, series: list[Series], panels: list[list[str]],
          chosen: list[str], clock: str, bag: bool, force: bool) -> None:
    """One panel per group of fields: a colour per topic and channel, references dashed
    over the measured line (equal lines both stay visible), the units on each axis."""
    figure = new_figure((9, 2.2 * len(panels) + 0.8))
    axes = figure.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0]
    palette = [f"C{i}" for i in range(10)]
    for ax, panel in zip(axes, panels, strict=True):
        colours: dict[tuple[str, str], str] = {}
        units: dict[str, str] = {}
        members: dict[str, int] = {}
        for line in series:
            if line.asked not in panel or not line.values:
                continue
            # A reference shares the colour of what follows it (a.ref with a.speed).
            key = (line.topic, _pair_key(line.field))
            colours.setdefault(key, palette[len(colours) % len(palette)])
            label = line.field if len(chosen) == 1 else f"{line.topic} {line.field}"
            if _is_reference(line.field):
                ax.plot(line.t, line.values, label=label, linewidth=1.2, linestyle="--",
                        color=colours[key], drawstyle="steps-post")
            else:
                # Members of a group (velocity.FL, velocity.BL …) often run on one another:
                # a style each keeps every one of them in sight.
                members[line.asked] = members.get(line.asked, -1) + 1
                style = STYLES[members[line.asked] % len(STYLES)] if line.field != line.asked \
                    else "-"
                ax.plot(line.t, line.values, label=label, linewidth=1, color=colours[key],
                        linestyle=style)
            units[line.asked] = unit_of(line.field, bag)
        known = set(units.values())
        if len(known) == 1 and "" not in known:
            ax.set_ylabel(f"{' / '.join(panel)}, {known.pop()}")
        else:
            ax.set_ylabel(" / ".join(f"{n} ({units.get(n) or 'no unit'})" for n in panel))
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize="small")
    title = recording.name if len(chosen) > 1 else f"{recording.name}: {chosen[0]}"
    axes[0].set_title(title)
    axes[-1].set_xlabel(f"s since the first message, {_CLOCKS[clock]}")
    save_figure(figure, output, force=force)
