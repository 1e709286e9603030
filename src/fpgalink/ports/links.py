"""The stable name of a board's pty (``--link [NAME=]PATH``): a symlink that scripts and
``fpgalink.toml`` name instead of ``/dev/pts/N``, which changes from run to run.

Whose a symlink is can only be told by where it points. One to a pty that is gone was
left by a server killed before it could remove it, and is replaced; one to a pty that is
there may be another server's, live, and is never touched; nor is anything else at the
path. On the way out a server removes a link only while it still points at its own pty:
another may have taken the name since."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Sequence
from pathlib import Path

__all__ = [
    "LinkError",
    "LinkSpecError",
    "LinkTaken",
    "make_link",
    "parse_links",
    "remove_own_link",
]


class LinkError(Exception):
    """A link that could not be made (one line, naming the path)."""


class LinkTaken(LinkError):
    """The path is not this server's to take: a symlink to a pty that is there, or
    something other than a symlink."""


class LinkSpecError(ValueError):
    """A ``--link`` value that names no board or no path (one line)."""


def make_link(path: Path, target: str) -> None:
    """A symlink at ``path`` to ``target``. One there already that points at ``target``, or
    at nothing that exists (its pty is gone), is replaced; :class:`LinkTaken` for one to
    something that exists (another router or fpgaemu serve may be serving it) and for
    anything that is not a symlink; :class:`LinkError` when the system refuses."""
    if path.is_symlink():
        pointed = os.readlink(path)
        if pointed != target and os.path.exists(path):
            raise LinkTaken(f"--link {path}: a symlink to {pointed}, which exists (another "
                            "router or fpgaemu serve may be serving it); not replacing it — "
                            "remove it if it is stale")
        path.unlink()
    elif path.exists():
        raise LinkTaken(f"--link {path}: exists and is not a symlink; not replacing it")
    try:
        path.symlink_to(target)
    except FileExistsError:
        # Made by another between the look and the link: theirs.
        raise LinkTaken(f"--link {path}: made by another meanwhile; not replacing it"
                        ) from None
    except OSError as exc:
        raise LinkError(f"--link {path}: {exc.strerror or exc}") from None


def remove_own_link(path: Path, target: str) -> bool:
    """Remove the symlink at ``path`` if it still points at ``target``; whether it did."""
    with contextlib.suppress(OSError):
        if os.readlink(path) == target:
            path.unlink()
            return True
    return False


def parse_links(values: Sequence[str], names: Sequence[str]) -> list[tuple[str, Path]]:
    """``--link PATH`` (the one board) or ``--link NAME=PATH``, in the order given; a board
    may have several, a path only one board."""
    links: list[tuple[str, Path]] = []
    for value in values:
        name, sep, path = value.partition("=")
        if not sep:
            if len(names) != 1:
                raise LinkSpecError(f"--link {value!r}: with several boards give NAME=PATH, "
                                    f"NAME one of {', '.join(names)}")
            name, path = names[0], value
        if name not in names:
            raise LinkSpecError(f"--link {value!r}: no board named {name!r} (boards: "
                                f"{', '.join(names)})")
        if not path:
            raise LinkSpecError(f"--link {value!r}: no path")
        links.append((name, Path(path)))
    taken = [str(path) for _, path in links]
    if len(set(taken)) != len(taken):
        raise LinkSpecError("--link: the same path twice")
    return links
