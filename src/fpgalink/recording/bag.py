"""A rosbag2 (version 9, MCAP storage, CDR) through the same path as every recording: the
bag directory is made as ``NAME.partial/NAME`` and renamed into place when closed; its MCAP
file is written by :class:`~fpgalink.recording.mcapfile.McapFile` (chunks with CRCs, closed
every half second, the summary's room reserved), so a full disk closes the bag complete up to
there and any failure is one :class:`~fpgalink.recording.files.RecordingError` line.

``rosbags`` writes the bag (its message definitions, type hashes, QoS and ``metadata.yaml``)
with :class:`BagStorage` as its MCAP storage; this module does not import ``rosbags`` (ROS
stays in the CLI's ``--rosbag2`` and the node's ``--bag``): the caller hands over a
``rosbags.rosbag2.Writer`` whose ``STORAGE_PLUGINS`` map MCAP to :class:`BagStorage`.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from fpgalink.recording.files import DiskFull, Output
from fpgalink.recording.mcapfile import Lifecycle, McapFile, Recorded

__all__ = ["BagRecording", "BagStorage"]

#: Kept allocated beside the bag and released just before it is closed: room for its
#: ``metadata.yaml`` on a full disk (the MCAP file's summary has its own reserve).
METADATA_RESERVE_BYTES = 256 * 1024
RESERVE_NAME = ".fpgalink-reserve"
#: The first line of an IDL message definition (rosbags' mark for the ``ros2idl`` encoding).
_IDL = "=" * 80 + "\nIDL: "


class BagStorage:
    """``rosbags``' storage writer protocol over :class:`McapFile`: the bag directory's
    ``NAME.mcap``, profile ``ros2``, schemas ``ros2msg`` (or ``ros2idl``), channels with their
    ``offered_qos_profiles``, and the ``rosbag2`` metadata record ``rosbags`` writes."""

    def __init__(self, path: Path, compression: Any = None) -> None:
        self.path = path / f"{path.name}.mcap"
        self._file = self.path.open("xb")
        try:
            self.mcap = McapFile(self._file, library="fpgalink rosbag2", profile="ros2")
        except BaseException:
            self._file.close()
            raise
        self._schemas: dict[str, int] = {}
        self._channels: dict[int, int] = {}  # rosbags' connection id → the MCAP channel's

    def add_msgtype(self, connection: Any) -> None:
        text: str = connection.msgdef.data
        encoding = "ros2idl" if text.startswith(_IDL) else "ros2msg"
        self._schemas[connection.msgtype] = self.mcap.schema(connection.msgtype, encoding,
                                                             text.encode())

    def add_connection(self, connection: Any, offered_qos_profiles: str) -> None:
        self._channels[connection.id] = self.mcap.channel(
            connection.topic, connection.ext.serialization_format,
            self._schemas[connection.msgtype], {"offered_qos_profiles": offered_qos_profiles})

    def write(self, connection: Any, timestamp: int, data: bytes | memoryview) -> None:
        self.mcap.add(self._channels[connection.id], bytes(data), timestamp, timestamp)

    def close(self, version: int, metadata: str) -> None:
        self.mcap.metadata("rosbag2", {"serialized_metadata": metadata})
        self.mcap.finish()
        self._file.close()

    def abort(self) -> None:
        self.mcap.cut_back()
        with contextlib.suppress(OSError):
            self._file.close()


class BagRecording(Recorded):
    """One bag at ``target``: ``writer`` makes the (unopened) ``rosbags.rosbag2.Writer`` for a
    directory path, with :class:`BagStorage` for MCAP. ``force``: replace a bag there (else
    :class:`~fpgalink.recording.files.OutputRefused`); ``custom_data`` goes into its
    ``metadata.yaml``. Write through :meth:`add_connection` and :meth:`write`; a failure
    raises :class:`RecordingError` and stops the recording (every later write raises it
    again); :meth:`close` puts the bag in place and says, by raising, what went wrong
    (:class:`~fpgalink.recording.mcapfile.Lifecycle`, as for every recording)."""

    def __init__(self, target: Path, *, force: bool, writer: Callable[[Path], Any],
                 custom_data: dict[str, str]) -> None:
        self.path = target
        output = Output(target, force=force, directory=True)
        self._life = Lifecycle(target, output, "bag")
        self._reserve = output.partial / RESERVE_NAME
        try:
            self._hold_reserve()
            self.writer = writer(output.path)
            for key, value in custom_data.items():
                self.writer.set_custom_data(key, value)
            self.writer.open()
            storage = self.writer.storage
            if not isinstance(storage, BagStorage):
                raise TypeError("the bag's writer must store MCAP through BagStorage")
            self.storage = storage
            self._life.mcap = storage.mcap
        except BaseException as exc:
            if isinstance(exc, OSError):
                raise self._life.not_started(exc) from None
            output.discard()
            raise

    def _hold_reserve(self) -> None:
        fd = os.open(self._reserve, os.O_WRONLY | os.O_CREAT | os.O_CLOEXEC, 0o600)
        try:
            os.posix_fallocate(fd, 0, METADATA_RESERVE_BYTES)
        except OSError as exc:
            raise DiskFull(exc.errno, exc.strerror) from None
        finally:
            os.close(fd)

    def set_custom_data(self, data: dict[str, str]) -> None:
        """More ``custom_data`` for its ``metadata.yaml`` (written when it closes)."""
        for key, value in data.items():
            self.writer.set_custom_data(key, value)

    def add_connection(self, topic: str, msgtype: str, **options: Any) -> Any:
        """``rosbags``' ``Writer.add_connection``; its connection."""
        return self._life.write(self.writer.add_connection, topic, msgtype, **options)

    def write(self, connection: Any, log_ns: int, data: bytes | memoryview) -> None:
        self._life.write(self.writer.write, connection, log_ns, data)

    def _finish(self) -> None:
        with contextlib.suppress(OSError):
            self._reserve.unlink()  # its room is metadata.yaml's now
        self.writer.close()

    def close(self) -> None:
        """Close the bag (its MCAP summary, ``metadata.yaml``) and put it in place."""
        self._life.end(self._finish, self.writer.abort,
                       "`ros2 bag reindex` rebuilds its metadata")
