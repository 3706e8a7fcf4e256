"""The MCAP file: written with the Foxglove SDK's writer, read back with the ``mcap`` library.

Writing goes through the SDK (its native writer, one call per message, zstd in the writing thread:
worker threads of its own would compete with the bus's threads). Reading uses the ``mcap``
library's stream reader record by record, so a file cut short (a process killed mid-motion) reads
up to its last complete record; ``pvtflow report`` and the tests read recordings this way.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcap.exceptions import McapError
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader

log = logging.getLogger("pvtflow.recording")

PROFILE = "pvtflow"
CHUNK_BYTES = 256 * 1024  # a chunk is closed at this size at the latest


class McapFile:
    """An MCAP file of the Foxglove SDK's writer and the context whose channels it records."""

    def __init__(self, path: Path, chunk_bytes: int) -> None:
        import foxglove
        from foxglove.mcap import MCAPCompression, MCAPWriteOptions

        self.context = foxglove.Context()
        # compression in the writing thread (0): zstd's own worker threads would compete with the bus's
        options = MCAPWriteOptions(
            compression=MCAPCompression.Zstd, profile=PROFILE, chunk_size=chunk_bytes, compression_threads=0
        )
        self.writer = foxglove.open_mcap(path, allow_overwrite=True, context=self.context, writer_options=options)

    def write_metadata(self, name: str, metadata: dict[str, str]) -> None:
        self.writer.write_metadata(name, metadata)

    def attach(self, **kwargs: Any) -> None:
        self.writer.attach(**kwargs)

    def flush(self) -> None:
        self.writer.flush()

    def close(self) -> None:
        self.writer.close()


def open_mcap_file(path: Path, chunk_bytes: int = CHUNK_BYTES) -> McapFile:
    return McapFile(path, chunk_bytes)


# --- reading -----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Recorded:
    topic: str
    log_time_ns: int
    data: dict[str, Any]
    schema: str


@dataclass
class Recording:
    """What ``read_recording`` found: messages in file order, metadata, attachments, and whether
    the file ended properly (False: cut short, e.g. a process killed mid-motion)."""

    messages: list[Recorded]
    metadata: dict[str, dict[str, str]]
    attachments: dict[str, bytes]
    complete: bool

    def topic(self, name: str) -> list[Recorded]:
        return [m for m in self.messages if m.topic == name]

    @property
    def topics(self) -> set[str]:
        return {m.topic for m in self.messages}


class RecordingError(ValueError):
    """Not an MCAP file pvtflow can read (one line for the user)."""


def read_recording(path: str | Path) -> Recording:
    """Every complete record of an MCAP file, also of one cut short (a truncated chunk is dropped)."""
    from mcap.records import Attachment, DataEnd, Footer, Metadata

    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    out = Recording([], {}, {}, complete=False)
    if not Path(path).is_file():
        raise RecordingError(f"{path}: no such file")
    with Path(path).open("rb") as handle:
        records: Iterator[Any] = StreamReader(handle, validate_crcs=True).records
        try:
            for record in records:
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Message):
                    channel = channels[record.channel_id]
                    schema = schemas.get(channel.schema_id)
                    out.messages.append(
                        Recorded(
                            channel.topic,
                            record.log_time,
                            json.loads(record.data),
                            schema.name if schema else "",
                        )
                    )
                elif isinstance(record, Metadata):
                    out.metadata[record.name] = dict(record.metadata)
                elif isinstance(record, Attachment):
                    out.attachments[record.name] = bytes(record.data)
                elif isinstance(record, DataEnd | Footer):
                    out.complete = True
        except McapError as exc:
            if not out.messages and not out.metadata and "Magic" in type(exc).__name__:
                raise RecordingError(f"{path}: not an MCAP file") from None
        except (EOFError, ValueError, KeyError, OSError) as exc:
            log.debug("%s: read up to a damaged record: %s", path, exc)
    return out
