"""README.md tells the truth: every Python example in it (and in docs/library.md, where its
other examples went) is a complete program that runs as written (against emu://), and every
output it shows for a deterministic program or command is what that program or command
prints. It stays short: a README says what it is, how to install, one example, and links
(issue 41.15)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
LIBRARY = (ROOT / "docs" / "library.md").read_text(encoding="utf-8")
#: The most lines the README may have (amaranth's, aioquic's and h11's are 3.5–7 KB).
README_LINES = 150
#: A fenced block and the plain fenced block that directly follows it ("It prints:").
BLOCK = re.compile(r"```(\w*)\n(.*?)```", re.DOTALL)

pytestmark = pytest.mark.timeout(120)


def python_examples(text: str | None = None) -> list[tuple[str, str | None]]:
    """(program, the output shown after it if the next block is a plain one), of the README
    and docs/library.md (or of ``text``)."""
    if text is None:
        return python_examples(README) + python_examples(LIBRARY)
    blocks = [(m.group(1), m.group(2), m.end()) for m in BLOCK.finditer(text)]
    examples = []
    for i, (lang, code, end) in enumerate(blocks):
        if lang != "python":
            continue
        shown = None
        if i + 1 < len(blocks) and blocks[i + 1][0] == "":
            between = text[end:text.index("```", end)]
            if between.strip() == "It prints:":
                shown = blocks[i + 1][1]
        examples.append((code, shown))
    return examples


def test_the_readme_has_examples() -> None:
    assert len(python_examples(README)) >= 1
    assert len(python_examples()) >= 4


def test_the_readme_is_short_and_links_what_moved() -> None:
    assert len(README.splitlines()) <= README_LINES
    for moved in ("docs/install.md", "docs/performance.md", "docs/library.md",
                  "docs/live.md"):
        assert moved in README and (ROOT / moved).exists(), moved
    install = (ROOT / "docs" / "install.md").read_text(encoding="utf-8")
    for extra in ("plot", "physics", "foxglove", "ros2", "cosim", "dev"):
        assert f"| `{extra}` |" in install, extra
    assert "--install-tf2" in install


@pytest.mark.parametrize(("code", "shown"), python_examples(),
                         ids=lambda v: (v or "").strip().splitlines()[0][:40] if v else "-")
def test_every_python_example_runs_as_written(code: str, shown: str | None) -> None:
    result = subprocess.run([sys.executable, "-"], input=code, capture_output=True, text=True,
                            timeout=100, cwd=ROOT)
    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stdout.strip(), "an example should show something"
    if shown is not None:
        assert result.stdout == shown


def test_the_parameter_table_shown_is_what_param_list_prints(tmp_path: Path) -> None:
    section = README[README.index("$ .venv/bin/fpgalink-cli param list"):]
    table = section.splitlines()[1:]
    table = table[: table.index(next(s for s in table if s.startswith("└"))) + 1]
    shown = [line for line in table if line.startswith(("┃", "│"))]
    result = subprocess.run([sys.executable, "-m", "fpgalink", "param", "list"],
                            capture_output=True, text=True, timeout=60, cwd=ROOT,
                            env={"COLUMNS": "200", "NO_COLOR": "1", "PATH": "/usr/bin:/bin",
                                 "XDG_CONFIG_HOME": str(tmp_path)})
    assert result.returncode == 0, result.stderr
    assert section.splitlines()[1] == result.stderr.splitlines()[0]  # the emulator notice
    printed = [line.rstrip() for line in result.stdout.splitlines()
               if line.startswith(("┃", "│"))]
    assert printed == [line.rstrip() for line in shown]


def _demo_commands() -> list[list[str]]:
    """The Makefile's demo recipe, each line a fpgalink-cli command from the venv."""
    makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
    recipe = makefile[makefile.index("\ndemo:") + 1:].splitlines()[1:]
    lines = [li.strip() for li in recipe[: next(i for i, li in enumerate(recipe)
                                                  if not li.startswith("\t"))]]
    prefix = "$(VENV)/bin/fpgalink-cli "
    assert lines and all(li.startswith(prefix) for li in lines), lines
    return [li.removeprefix(prefix).split() for li in lines]


def test_make_demo_says_once_that_the_built_in_emulator_stands_in(tmp_path: Path) -> None:
    """Issue 26: the notice was printed by each of the demo's commands."""
    said = 0
    for args in _demo_commands():
        args = [str(tmp_path / a) if a.endswith(".png") else a for a in args]
        result = subprocess.run([sys.executable, "-m", "fpgalink", *args],
                                capture_output=True, text=True, timeout=60, cwd=ROOT,
                                env={"COLUMNS": "200", "NO_COLOR": "1",
                                     "PATH": "/usr/bin:/bin",
                                     "XDG_CONFIG_HOME": str(tmp_path),
                                     "PYTHONPATH": os.pathsep.join(
                                         [str(ROOT / "src"), str(ROOT)])})
        assert result.returncode == 0, result.stderr
        said += result.stderr.count("using the built-in emulator")
    assert said == 1


def _try_it_writers() -> list[list[str]]:
    """The "Try it" lines that write files (a plot, a recording), in order."""
    section = README[README.index("## Try it"):]
    block = section[section.index("```console"):].split("```", 2)[1]
    lines = []
    for line in block.splitlines():
        if not line.startswith("$ .venv/bin/fpgalink-cli "):
            continue
        command = line.removeprefix("$ .venv/bin/fpgalink-cli ").split("#")[0]
        if "'" in command or "|" in command or "&&" in command:
            continue  # the C core (an extra), pipes, make: not files this sequence writes
        args = command.split()
        if args[0] in ("plot", "record") or "--plot" in args or "--record" in args:
            lines.append(args)
    assert len(lines) >= 4, lines
    return lines


def test_the_try_it_sequence_runs_as_written_after_make_demo(tmp_path: Path) -> None:
    """Issue 41.9: `record run.mcap` after the `drive … --record run.mcap` before it
    replaced that run silently; now an existing file is refused, so no two lines of the
    sequence (nor `make demo` before them, nor the demo run twice) may write the same
    file."""
    env = {"COLUMNS": "200", "NO_COLOR": "1", "PATH": "/usr/bin:/bin",
           "XDG_CONFIG_HOME": str(tmp_path / "xdg"),
           "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), str(ROOT)])}
    for args in [*_demo_commands(), *_demo_commands(), *_try_it_writers()]:
        # In the CLI's own process (the built-in emulator): its boards keep the link's
        # time, so however loaded the machine, nothing stops a drive or a step.
        result = subprocess.run([sys.executable, "-m", "fpgalink", *args],
                                capture_output=True, text=True, timeout=100,
                                cwd=tmp_path, env=env)
        assert result.returncode == 0, (args, result.stderr)
    assert {"step.png", "step45.png", "run.mcap", "run.png", "idle.mcap"} <= {
        p.name for p in tmp_path.iterdir()}
