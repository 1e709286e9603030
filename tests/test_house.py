"""The house's size limits (issue 38), read from every module of src/ by its syntax tree: no
class over :data:`MAX_CLASS_LINES` lines or :data:`MAX_ATTRIBUTES` instance attributes (each
``self.NAME`` assigned anywhere in its methods, and each annotated field of its body but a
``ClassVar``), no function or method over :data:`MAX_FUNCTION_LINES` lines (from ``def`` to
its last line, docstring included; its decorators, such as a command's click options, are
its interface, not its body). A class or function past a limit has more than one concern:
split it by concern, never by line count. And ruff finds nothing in src/, tests/ and
benchmarks/ (mypy, which takes minutes, is ``make lint``'s)."""

from __future__ import annotations

import ast
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"

MAX_CLASS_LINES = 450
MAX_ATTRIBUTES = 30
MAX_FUNCTION_LINES = 80


def _length(node: ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    end = node.end_lineno
    assert end is not None
    return end - node.lineno + 1


def _own_nodes(cls: ast.ClassDef) -> Iterator[ast.AST]:
    """Every node of ``cls`` but those of the classes nested in it (counted on their own)."""
    stack: list[ast.AST] = [cls]
    while stack:
        node = stack.pop()
        yield node
        stack.extend(child for child in ast.iter_child_nodes(node)
                     if not isinstance(child, ast.ClassDef))


def instance_attributes(cls: ast.ClassDef) -> set[str]:
    """The names a ``cls`` instance holds: ``self.NAME`` assigned (plain, annotated,
    augmented, unpacked), and the annotated fields of its body but ``ClassVar``s."""
    names: set[str] = set()
    for node in _own_nodes(cls):
        if isinstance(node, ast.Assign):
            targets = node.targets
        elif isinstance(node, ast.AnnAssign | ast.AugAssign):
            targets = [node.target]
        else:
            continue
        for target in targets:
            names.update(sub.attr for sub in ast.walk(target)
                         if isinstance(sub, ast.Attribute) and isinstance(sub.value, ast.Name)
                         and sub.value.id == "self")
    for statement in cls.body:
        if (isinstance(statement, ast.AnnAssign) and isinstance(statement.target, ast.Name)
                and "ClassVar" not in ast.unparse(statement.annotation)):
            names.add(statement.target.id)
    return names


def offenders(source: str, where: str) -> list[str]:
    """Each class and function of ``source`` past a limit, one line each."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ClassDef):
            lines, attributes = _length(node), len(instance_attributes(node))
            if lines > MAX_CLASS_LINES or attributes > MAX_ATTRIBUTES:
                found.append(f"{where}:{node.lineno}: class {node.name}: {lines} lines "
                             f"(at most {MAX_CLASS_LINES}), {attributes} instance attributes "
                             f"(at most {MAX_ATTRIBUTES})")
        elif isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            lines = _length(node)
            if lines > MAX_FUNCTION_LINES:
                found.append(f"{where}:{node.lineno}: def {node.name}: {lines} lines (at most "
                             f"{MAX_FUNCTION_LINES})")
    return found


def test_no_class_or_function_in_src_is_past_the_house_limits() -> None:
    files = sorted(SRC.rglob("*.py"))
    assert len(files) > 100, "src/ not found where the tests expect it"
    found = [line for path in files
             for line in offenders(path.read_text(encoding="utf-8"),
                                   str(path.relative_to(ROOT)))]
    assert not found, "past the house limits (split by concern):\n" + "\n".join(found)


def _class_with(attributes: int, *, classvars: int = 0) -> str:
    body = "".join(f"    c{i}: ClassVar[int] = {i}\n" for i in range(classvars))
    body += "    def __init__(self) -> None:\n"
    body += "".join(f"        self.a{i} = {i}\n" for i in range(attributes))
    return f"class Many:\n{body}"


def test_the_limits_are_counted_as_said() -> None:
    # Past each limit by one is named; at it, not.
    assert offenders(_class_with(MAX_ATTRIBUTES), "x.py") == []
    assert offenders(_class_with(MAX_ATTRIBUTES, classvars=5), "x.py") == []
    [line] = offenders(_class_with(MAX_ATTRIBUTES + 1), "x.py")
    assert line.startswith("x.py:1: class Many:") and "31 instance attributes" in line
    fields = "class Fields:\n" + "".join(f"    f{i}: int = 0\n" for i in range(31))
    assert "31 instance attributes" in offenders(fields, "x.py")[0]
    # Each name once, however often and however it is assigned; a nested class apart.
    counted = ("class C:\n    def f(self) -> None:\n        self.a, (self.b, self.c) = 1, (2, 3)"
               "\n        self.a += 1\n        self.d: int = 4\n        self.e[0] = 1\n"
               "    class Inner:\n        def g(self) -> None:\n            self.z = 1\n")
    tree = ast.parse(counted)
    outer = tree.body[0]
    assert isinstance(outer, ast.ClassDef)
    assert instance_attributes(outer) == {"a", "b", "c", "d", "e"}
    long_function = "def f() -> None:\n" + "    x = 1\n" * (MAX_FUNCTION_LINES - 1)
    assert offenders(long_function, "x.py") == []
    [line] = offenders(long_function + "    x = 2\n", "x.py")
    assert line == f"x.py:1: def f: {MAX_FUNCTION_LINES + 1} lines (at most 80)"
    options = "".join(f"@option{i}\n" for i in range(10))
    assert offenders(options + long_function, "x.py") == []
    long_class = "class Long:\n" + "    x = 1\n" * MAX_CLASS_LINES
    assert "451 lines" in offenders(long_class, "x.py")[0]


def test_ruff_finds_nothing() -> None:
    # Cheap (seconds), so the suite holds it as make lint does.
    done = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "src", "tests",
                           "benchmarks"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
