"""``fpgalink.ports.links``: the ``--link`` symlink ``fpgaemu serve`` and ``fpgalink-cli
router`` make to a pty. Whose a symlink is can only be told by where it points: a live
pty's is another server's and never touched; a dangling one is replaced; on the way out
only one still pointing at one's own pty is removed."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from fpgalink.ports import (
    LinkError,
    LinkSpecError,
    LinkTaken,
    make_link,
    parse_links,
    remove_own_link,
)


@pytest.fixture
def live_pty() -> Iterator[str]:
    """The path of a pty that is there (another server's, as far as a link can tell)."""
    master, slave = os.openpty()
    try:
        yield os.ttyname(slave)
    finally:
        os.close(master)
        os.close(slave)


def test_a_link_to_a_live_pty_is_not_taken_over(tmp_path: Path, live_pty: str) -> None:
    link = tmp_path / "fpga0"
    link.symlink_to(live_pty)
    with pytest.raises(LinkTaken, match="which exists") as caught:
        make_link(link, "/dev/pts/999999")
    assert "another router or fpgaemu serve" in str(caught.value)
    assert os.readlink(link) == live_pty
    make_link(link, live_pty)  # the pty we now have: ours, replaced
    assert os.readlink(link) == live_pty
    link.unlink()
    link.symlink_to(tmp_path / "gone")  # dangling: a killed server's
    make_link(link, live_pty)
    assert os.readlink(link) == live_pty


def test_a_link_never_replaces_a_file_and_says_why_the_system_refused(
        tmp_path: Path, live_pty: str) -> None:
    precious = tmp_path / "notes.txt"
    precious.write_text("mine")
    with pytest.raises(LinkTaken, match="not a symlink"):
        make_link(precious, live_pty)
    assert precious.read_text() == "mine"
    with pytest.raises(LinkError, match="No such file or directory") as caught:
        make_link(tmp_path / "no-such-dir" / "fpga0", live_pty)
    assert not isinstance(caught.value, LinkTaken)  # the system's refusal, not another's


def test_only_a_link_still_pointing_at_our_pty_is_removed(tmp_path: Path,
                                                          live_pty: str) -> None:
    link = tmp_path / "fpga0"
    make_link(link, "/dev/pts/ours")
    assert remove_own_link(link, "/dev/pts/ours") and not link.is_symlink()
    link.symlink_to(live_pty)  # another server took the name since
    assert not remove_own_link(link, "/dev/pts/ours")
    assert os.readlink(link) == live_pty
    assert not remove_own_link(tmp_path / "never-made", "/dev/pts/ours")


def test_links_name_their_board_and_a_path_once() -> None:
    assert parse_links(["/tmp/a"], ["L"]) == [("L", Path("/tmp/a"))]
    # A board may have several, in the order given.
    assert parse_links(["L=/tmp/a", "R=/tmp/b", "L=/tmp/c"], ["L", "R"]) == [
        ("L", Path("/tmp/a")), ("R", Path("/tmp/b")), ("L", Path("/tmp/c"))]


@pytest.mark.parametrize(("values", "needle"), [
    (["/tmp/a"], "with several boards give NAME=PATH, NAME one of L, R"),
    (["X=/tmp/a"], "no board named 'X' (boards: L, R)"),
    (["L="], "'L=': no path"),
    (["L=/tmp/a", "R=/tmp/a"], "the same path twice"),
])
def test_a_bad_link_is_one_line(values: list[str], needle: str) -> None:
    with pytest.raises(LinkSpecError) as caught:
        parse_links(values, ["L", "R"])
    assert needle in str(caught.value) and "\n" not in str(caught.value)
