"""The Foxglove layout in the repository opens the live view's panels: it is what
examples/foxglove/layout.py writes, and every topic it names is one the live view (or a
recording of the same topics) serves."""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

import pytest

from tests.fpgalink.live.test_live_view import BOARD_TOPICS, ROBOT_TOPICS
from tests.support.cli import ROOT

pytest.importorskip("foxglove")

LAYOUT = ROOT / "examples" / "foxglove" / "fpgalink.json"


def _generator() -> object:
    spec = importlib.util.spec_from_file_location("layout", LAYOUT.with_name("layout.py"))
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_layout_file_is_what_the_generator_writes() -> None:
    assert LAYOUT.read_text(encoding="utf-8") == _generator().render()  # type: ignore[attr-defined]


def test_every_topic_it_names_is_served() -> None:
    text = LAYOUT.read_text(encoding="utf-8")
    named = set(re.findall(r'"(/[a-z_]+(?:/[A-Za-z_]+)*)', text))
    served = BOARD_TOPICS | ROBOT_TOPICS
    assert named, "the layout names topics"
    assert {t.split(".")[0] for t in named} <= served, named - served
    document = json.loads(text)
    assert document["version"] == 1 and document["content"]["type"] == "split"


def test_the_docs_say_where_it_is() -> None:
    assert "examples/foxglove/fpgalink.json" in (ROOT / "docs" / "live.md").read_text()
    assert Path(LAYOUT).exists()
