"""A campaign's declaration: scenarios, the grid that multiplies them, and each scenario's
script. Read from TOML (``fpgalink-cli campaign SPEC.toml``) or built in Python; either way
every value is checked here, before any scenario runs, and a mistake is one
:class:`CampaignError` line naming where it is.

```toml
[campaign]
name = "in-place turns"
body = "kinematic"            # or "mujoco" (default: kinematic — fast and exact)
surface = "gravel"
seed = 0
mcap = true                   # record each scenario (into the run's directory)

[grid]                        # every scenario once per combination
surface = ["gravel", "marble"]
"Kp_Wheel_Pid" = [400.0, 520.0]

[[scenario]]
name = "turn"
script = [{ wheels = [50, -50], seconds = 20, settle = 3 }]
```
"""

from __future__ import annotations

import importlib.util
import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import quote

from fpgalink.protocol.errors import FpgalinkError
from fpgalink.protocol.faults import MAX_FAULTS, Unplug, parse_fault
from fpgalink.protocol.params import Scope, lookup, resolve
from fpgalink.protocol.robot import (
    BOARD_NAME,
    RobotDescription,
    load_robot,
    seed_robot,
)
from fpgalink.protocol.tomlfile import TomlFileError, load_toml

__all__ = ["Action", "Campaign", "CampaignError", "ParamSetting", "Scenario", "check_installed",
           "check_surface", "importable", "load_campaign", "parse_campaign"]

BODIES = ("kinematic", "mujoco")
#: The grounds of the mujoco body (fpgaemu's physics; a test holds the two lists equal). The
#: kinematic body takes the surfaces of the robot's description (the seed's robot: ideal,
#: gravel, marble, grass).
MUJOCO_SURFACES = ("gravel", "marble", "grass", "slope45-sand", "stairs")
_NOT_FLAT = ("slope45-sand", "stairs")  #: grounds no kinematic (flat) body can stand for
#: What a body needs beyond a plain install: the module, and the extra that brings it.
BODY_NEEDS = {"mujoco": ("mujoco", "MuJoCo", "physics")}
MAX_SCENARIOS = 100_000  #: a grid beyond this is a typo, not a campaign
MAX_ACTION_S = 3600.0  #: one action's emulated seconds
MAX_STEP_DPS = 1000.0  #: a step's target, deg/s (and a wheel speed's)
ACTION_KINDS = ("wheels", "drive", "goto", "step", "wait")


class CampaignError(FpgalinkError, ValueError):
    """A campaign that cannot be run as written; the message is one line."""


@dataclass(frozen=True, slots=True)
class ParamSetting:
    """A board parameter set after the robot starts: ``board`` ``None`` for every board,
    ``channel`` 0 for a board-wide one."""

    name: str
    channel: int
    value: float
    board: str | None = None

    @property
    def label(self) -> str:
        param = lookup(self.name)
        text = param.full_name(self.channel)
        return f"{self.board}.{text}" if self.board else text


@dataclass(frozen=True, slots=True)
class Action:
    """One line of a scenario's script.

    * ``wheels``: each side's wheels at ``left``/``right`` deg/s (the seed's §3.6 runs) for
      ``seconds``, measured after ``settle`` s: turn rate, radius, the centre's wander;
    * ``drive``: body speed ``v`` m/s and yaw rate ``omega`` deg/s for ``seconds``;
    * ``goto``: the seed's position controller (Algorithm 1) to ``x``, ``y`` (and
      ``theta`` deg), within ``seconds``: arrival, the true distance left;
    * ``step``: every wheel's reference from rest to ``to`` deg/s (drives straight) for
      ``seconds``: rise, settling, overshoot, the worst of the named ``wheel`` (a joint
      name, or ``A``/``B`` for every wheel on that channel; default every wheel);
    * ``wait``: ``seconds`` with the wheels at rest.
    """

    kind: str
    seconds: float
    label: str
    left: float = 0.0
    right: float = 0.0
    v: float = 0.0
    omega: float = 0.0
    x: float = 0.0
    y: float = 0.0
    theta: float | None = None
    to: float = 0.0
    wheel: str | None = None
    settle: float = 0.0


@dataclass(frozen=True, slots=True)
class Scenario:
    """One run: an emulated robot, started fresh, then its script. Picklable, so it can be
    sent to another process or a Dask worker as it is."""

    name: str
    index: int
    body: str
    surface: str
    seed: int
    description: RobotDescription
    robot_file: str | None
    params: tuple[ParamSetting, ...]
    faults: tuple[str, ...]
    script: tuple[Action, ...]
    #: the grid point this scenario came from (key → value), for the results table
    grid: tuple[tuple[str, Any], ...] = ()
    #: record the scenario into an MCAP file (in the directory the campaign is run with)
    mcap: bool = False

    def urls(self) -> dict[str, str]:
        """Each board's ``emu://`` URL: an in-process robot of its own (``run=`` keeps two
        scenarios in one process apart)."""
        query = [f"surface={self.surface}", f"body={self.body}", f"seed={self.seed}",
                 f"run={self.index}"]
        if self.robot_file:
            query.append(f"robot={quote(self.robot_file)}")  # a path may hold + # % &
        query += [f"fault={quote(fault)}" for fault in self.faults]
        return {name: f"emu://robot/{name}?" + "&".join(query)
                for name in self.description.boards}


@dataclass(frozen=True, slots=True)
class Campaign:
    name: str
    scenarios: tuple[Scenario, ...]
    source: str = "campaign"


def load_campaign(path: str | Path) -> Campaign:
    """A campaign from its TOML file (robot files named in it are relative to it)."""
    path = Path(path)
    try:
        document = load_toml(str(path))
    except TomlFileError as exc:
        raise CampaignError(str(exc)) from None
    return parse_campaign(document, source=str(path), base=path.parent)


def parse_campaign(document: Mapping[str, Any], *, source: str = "campaign",
                   base: Path | None = None) -> Campaign:
    where = source
    _only(document, {"campaign", "grid", "scenario"}, where)
    head = _table(document.get("campaign", {}), f"{where}: [campaign]")
    _only(head, {"name", "body", "surface", "seed", "robot", "params", "faults", "mcap"},
          f"{where}: [campaign]")
    defaults = _common(head, f"{where}: [campaign]", base, {
        "body": "kinematic", "surface": "gravel", "seed": 0, "robot": None,
        "params": (), "faults": (), "mcap": False})
    name = _text(head.get("name", Path(source).stem), f"{where}: [campaign] name")
    raw = document.get("scenario")
    if not isinstance(raw, list) or not raw:
        raise CampaignError(f"{where}: no [[scenario]]: a campaign needs at least one")
    grid_table = _table(document.get("grid", {}), f"{where}: [grid]")
    _count(grid_table, len(raw), f"{where}: [grid]")  # counted before anything is built
    grid = _grid(grid_table, f"{where}: [grid]")
    templates = []
    for number, table in enumerate(raw, 1):
        at = f"{where}: scenario {number}"
        table = _table(table, at)
        _only(table, {"name", "body", "surface", "seed", "robot", "params", "faults", "mcap",
                      "script"}, at)
        settings = _common(table, at, base, defaults)
        label = _text(table.get("name", f"scenario {number}"), f"{at} name")
        script = _script(table.get("script"), f"{at} ({label})")
        templates.append((f"{at} ({label})", label, settings, script))
    points = list(itertools.product(*(values for _, values in grid))) or [()]
    scenarios: list[Scenario] = []
    for at, label, settings, script in templates:
        for point in points:
            chosen = dict(settings)
            params = list(chosen["params"])
            for (key, _), value in zip(grid, point, strict=True):
                if key in ("body", "surface", "seed"):
                    chosen[key] = value
                else:
                    params = [p for p in params if p.label != value.label] + [value]
            shown = tuple((key, value.value if isinstance(value, ParamSetting) else value)
                          for (key, _), value in zip(grid, point, strict=True))
            description = chosen["description"]
            try:
                check_surface(chosen["body"], chosen["surface"], description)
            except CampaignError as exc:
                said = ", ".join(f"{key} = {value!r}" for key, value in shown)
                raise CampaignError(at + (f", grid point {said}" if said else "")
                                    + f": {exc}") from None
            if chosen["surface"] in description.surfaces:
                # The host's odometry uses the χ of the ground the robot is on; a surface
                # the description has no χ for (a slope, stairs) keeps its default.
                description = description.on_surface(chosen["surface"])
            _check_boards(params, chosen["faults"], description, f"{where}: {label}")
            scenarios.append(Scenario(
                name=label, index=len(scenarios), body=chosen["body"],
                surface=chosen["surface"], seed=chosen["seed"], description=description,
                robot_file=chosen["robot"], params=tuple(params), faults=chosen["faults"],
                script=script, grid=shown, mcap=chosen["mcap"]))
    return Campaign(name, tuple(scenarios), source)


# --- pieces ------------------------------------------------------------------------------


def _common(table: Mapping[str, Any], where: str, base: Path | None,
            defaults: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(defaults)
    if "body" in table:
        out["body"] = _choice(table["body"], BODIES, f"{where} body")
    if "surface" in table:  # which surfaces the body knows: checked per scenario
        out["surface"] = _text(table["surface"], f"{where} surface")
    if "seed" in table:
        out["seed"] = _seed(table["seed"], f"{where} seed")
    if "robot" in table:
        path = Path(_text(table["robot"], f"{where} robot"))
        if base is not None and not path.is_absolute():
            path = base / path
        out["robot"] = str(path)
        try:
            out["description"] = load_robot(out["robot"])
        except (FpgalinkError, OSError) as exc:
            raise CampaignError(f"{where} robot: {exc}") from None
    out.setdefault("description", seed_robot())
    if "params" in table:
        out["params"] = tuple(_params(table["params"], f"{where} params"))
    if "mcap" in table:
        if not isinstance(table["mcap"], bool):
            raise CampaignError(f"{where} mcap: true or false")
        out["mcap"] = table["mcap"]
    if "faults" in table:
        out["faults"] = _faults(table["faults"], f"{where} faults")
    return out


def _faults(faults: object, where: str) -> tuple[str, ...]:
    """``["L:restart=5", …]``: each spec checked with the emulator's own grammar
    (:mod:`fpgalink.protocol.faults`), bounds and all; which boards there are is checked
    per scenario, with its robot."""
    if not isinstance(faults, list) or not all(isinstance(f, str) for f in faults):
        raise CampaignError(f"{where}: a list of \"BOARD:FAULT\" strings, as fpgaemu serve "
                            "--fault takes them (e.g. \"L:restart=5\")")
    per_board: dict[str, int] = {}
    for number, text in enumerate(faults, 1):
        at = f"{where}[{number}] {text[:120]!r}"
        board, sep, spec = text.partition(":")
        if not sep or not BOARD_NAME.fullmatch(board):
            raise CampaignError(f"{at}: write BOARD:FAULT (e.g. \"L:restart=5\")")
        try:
            fault = parse_fault(spec)
        except FpgalinkError as exc:
            raise CampaignError(f"{at}: {exc}") from None
        if isinstance(fault, Unplug):
            raise CampaignError(f"{at}: unplug is a fault of fpgaemu serve's pty or TCP "
                                "link; a campaign's boards run in its own process")
        per_board[board] = per_board.get(board, 0) + 1
        if per_board[board] > MAX_FAULTS:
            raise CampaignError(f"{where}: more than {MAX_FAULTS} faults for board {board}; "
                                f"at most {MAX_FAULTS}")
    return tuple(faults)


def _params(table: object, where: str) -> list[ParamSetting]:
    if not isinstance(table, Mapping):
        raise CampaignError(f"{where}: a table of NAME = value (e.g. Kp_Wheel_Pid = 400.0)")
    settings: dict[str, tuple[str, ParamSetting]] = {}
    for key, value in table.items():
        setting = _param(key, value, where)
        if setting.label in settings:  # Kp_Wheel_PidA and Kp_Wheel_Pid.A: one would be lost
            raise CampaignError(f"{where}: {settings[setting.label][0]!r} and {key!r} both "
                                f"set {setting.label}: give it once")
        settings[setting.label] = (key, setting)
    return [setting for _, setting in settings.values()]


def _param(key: str, value: object, where: str) -> ParamSetting:
    """``[BOARD.]NAME[.CHANNEL]`` or the seed's ``NAME`` with its A/B suffix; a per-channel
    name without a channel means both channels, none of the board's name means every board
    (both kept as given: expanded when set)."""
    parts = key.split(".")
    board = None
    if len(parts) == 3 or (len(parts) == 2 and parts[1].upper() not in ("A", "B")):
        board = parts.pop(0)
        if not BOARD_NAME.fullmatch(board):
            raise CampaignError(f"{where}: {key!r}: {board!r} is not a board name")
    name, channel = parts[0], parts[1] if len(parts) > 1 else None
    try:
        param = lookup(name)
        if channel is None and param.scope is Scope.CHANNEL and name.lower() == \
                param.name.lower():
            code = 0  # both channels
        else:
            param, code = resolve(name, channel)
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise CampaignError(f"{where}: {key} = {value!r}: a number")
        param.coerce(value)
    except FpgalinkError as exc:
        raise CampaignError(f"{where}: {key}: {exc}") from None
    return ParamSetting(param.name, code, float(value), board)


def _count(table: Mapping[str, Any], templates: int, where: str) -> None:
    """The grid's scenarios, counted from the lengths of its lists before a value is read
    or a combination built: a grid too large to run is refused at once, whatever its size."""
    lengths = []
    for key, values in table.items():
        if not isinstance(values, list) or not values:
            raise CampaignError(f"{where} {key}: a non-empty list of values")
        lengths.append(len(values))
    total = math.prod(lengths) * templates
    if total > MAX_SCENARIOS:
        product = " × ".join(f"{n:,}" for n in lengths)
        raise CampaignError(f"{where}: {total:,} scenarios ({product} values × {templates} "
                            f"[[scenario]]); at most {MAX_SCENARIOS:,}")


def _grid(table: Mapping[str, Any], where: str) -> list[tuple[str, list[Any]]]:
    grid: list[tuple[str, list[Any]]] = []
    for key, values in table.items():
        if key == "body":
            grid.append((key, [_choice(v, BODIES, f"{where} body") for v in values]))
        elif key == "surface":
            grid.append((key, [_text(v, f"{where} surface") for v in values]))
        elif key == "seed":
            grid.append((key, [_seed(v, f"{where} seed") for v in values]))
        else:
            settings = [_param(key, v, where) for v in values]
            for other, earlier in grid:
                if other not in ("body", "surface", "seed") and _overlap(earlier[0],
                                                                          settings[0]):
                    raise CampaignError(f"{where}: {other!r} and {key!r} both set "
                                        f"{settings[0].label}: give it one key")
            grid.append((key, settings))
    return grid


def _overlap(a: ParamSetting, b: ParamSetting) -> bool:
    """Whether two settings set the same parameter of some board's channel (a name without
    a board means every board; channel 0 of a channel parameter, both channels)."""
    return a.name == b.name and (a.board is None or b.board is None or a.board == b.board) \
        and (a.channel == 0 or b.channel == 0 or a.channel == b.channel)


def _script(raw: object, where: str) -> tuple[Action, ...]:
    if not isinstance(raw, list) or not raw:
        raise CampaignError(f"{where}: script must be a non-empty list of actions, e.g. "
                            "[{ drive = [0.3, 0.0], seconds = 5 }]")
    actions = []
    labels: set[str] = set()
    for number, item in enumerate(raw, 1):
        at = f"{where} script[{number}]"
        if not isinstance(item, Mapping):
            raise CampaignError(f"{at}: an inline table such as {{ wait = 1.0 }}")
        kinds = [k for k in ACTION_KINDS if k in item]
        if len(kinds) != 1:
            raise CampaignError(f"{at}: exactly one of {', '.join(ACTION_KINDS)}")
        action = _action(kinds[0], item, at, number)
        if action.label in labels:
            raise CampaignError(f"{at}: label {action.label!r} used twice")
        labels.add(action.label)
        actions.append(action)
    return tuple(actions)


def _action(kind: str, item: Mapping[str, Any], where: str, number: int) -> Action:
    allowed = {kind, "seconds", "label"} | {"wheels": {"settle"}, "step": {"wheel"},
                                            "goto": {"theta"}}.get(kind, set())
    _only(item, allowed, where)
    label = _text(item.get("label", f"{number}.{kind}"), f"{where} label")
    default_s = {"goto": 60.0, "step": 2.0}.get(kind)
    if "seconds" in item or default_s is None:
        if kind == "wait" and "seconds" not in item:
            seconds = _number(item["wait"], f"{where} wait", 0.0, MAX_ACTION_S)
        else:
            seconds = _number(item.get("seconds"), f"{where} seconds", 0.0, MAX_ACTION_S)
    else:
        seconds = default_s
    if kind == "wheels":
        left, right = _pair(item["wheels"], f"{where} wheels", MAX_STEP_DPS)
        settle = _number(item.get("settle", 0.0), f"{where} settle", 0.0, MAX_ACTION_S)
        return Action(kind, seconds, label, left=left, right=right, settle=settle)
    if kind == "drive":
        v, omega = _pair(item["drive"], f"{where} drive", 100.0)
        return Action(kind, seconds, label, v=v, omega=omega)
    if kind == "goto":
        x, y = _pair(item["goto"], f"{where} goto", 10_000.0)
        theta = item.get("theta")
        return Action(kind, seconds, label, x=x, y=y, theta=None if theta is None else
                      _number(theta, f"{where} theta", -360.0, 360.0))
    if kind == "step":
        to = _number(item["step"], f"{where} step", -MAX_STEP_DPS, MAX_STEP_DPS)
        if to == 0:
            raise CampaignError(f"{where} step: a step to 0 deg/s from rest is no step")
        wheel = item.get("wheel")
        if wheel is not None:
            wheel = _text(wheel, f"{where} wheel")
        return Action(kind, seconds, label, to=to, wheel=wheel)
    return Action(kind, seconds, label)


def check_surface(body: str, surface: str, description: RobotDescription) -> None:
    """:class:`CampaignError` (one line, no location) if ``body`` cannot stand on
    ``surface``: the kinematic body knows the description's surfaces (it needs their χ),
    the mujoco body its physical grounds. The emulator holds to the same rule."""
    if body == "mujoco":
        if surface not in MUJOCO_SURFACES:
            raise CampaignError(f"surface {surface!r}: the mujoco body knows "
                                f"{', '.join(MUJOCO_SURFACES)}")
    elif surface not in description.surfaces:
        known = ", ".join(description.surfaces)
        if surface in _NOT_FLAT:
            raise CampaignError(f"surface {surface!r} on the kinematic body: it knows {known} "
                                "(it is flat: slopes and stairs need the mujoco body)")
        raise CampaignError(f"surface {surface!r}: the kinematic body knows {known}; the "
                            f"mujoco body {', '.join(MUJOCO_SURFACES)}")


def check_installed(scenarios: Sequence[Scenario], where: str = "campaign") -> None:
    """:class:`CampaignError` (one line naming what is missing and the pip command) if a
    scenario's body needs what is not installed here. Called before any scenario runs, so
    a campaign never runs its first half to fail its second. (On a Dask cluster the machine
    that submits needs it too.)"""
    for body, (module, what, extra) in BODY_NEEDS.items():
        count = sum(1 for s in scenarios if s.body == body)
        if count and not importable(module):
            raise CampaignError(f"{where}: {count} of {len(scenarios)} scenario(s) run on "
                                f"body {body!r}, which needs {what}, not installed here: "
                                f"pip install 'fpgalink[{extra}]'")


def importable(module: str) -> bool:
    """Whether ``module`` can be found here, without importing it."""
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):  # a finder that refuses it, a broken half-import
        return False


def _check_boards(params: Sequence[ParamSetting], faults: Sequence[str],
                  description: RobotDescription, where: str) -> None:
    for p in params:
        if p.board is not None and p.board not in description.boards:
            raise CampaignError(f"{where}: {p.label}: the robot has boards "
                                f"{', '.join(description.boards)}")
    for fault in faults:
        board, sep, _ = fault.partition(":")
        if not sep or board not in description.boards:
            raise CampaignError(f"{where}: fault {fault!r}: write BOARD:FAULT, BOARD one of "
                                f"{', '.join(description.boards)}")


def _only(table: Mapping[str, Any], known: set[str], where: str) -> None:
    unknown = sorted(set(table) - known)
    if unknown:
        raise CampaignError(f"{where}: unknown key {unknown[0]!r}; known: "
                            f"{', '.join(sorted(known))}")


def _table(value: object, where: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise CampaignError(f"{where}: a table")
    return value


def _text(value: object, where: str) -> str:
    if not isinstance(value, str) or not value or len(value) > 200:
        raise CampaignError(f"{where}: a non-empty string of at most 200 characters")
    return value


def _choice(value: object, choices: Sequence[str], where: str) -> str:
    if not isinstance(value, str) or value not in choices:
        raise CampaignError(f"{where}: {value!r}; one of {', '.join(choices)}")
    return value


def _seed(value: object, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < 2**32:
        raise CampaignError(f"{where}: a whole number 0..4294967295")
    return value


def _number(value: object, where: str, low: float, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) \
            or not math.isfinite(value) or not low <= value <= high:
        raise CampaignError(f"{where}: a number in {low:g}..{high:g}, got {value!r}")
    return float(value)


def _pair(value: object, where: str, limit: float) -> tuple[float, float]:
    if not isinstance(value, list) or len(value) != 2:
        raise CampaignError(f"{where}: two numbers, e.g. [0.3, 0.0]")
    return (_number(value[0], where, -limit, limit), _number(value[1], where, -limit, limit))
