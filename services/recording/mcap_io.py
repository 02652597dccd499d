"""The recording format: MCAP, one channel per key, the payloads exactly as they travelled.

- A channel per key: topic = the full key (`nod/rig1/vision/hand`), message encoding `json`,
  and the schema of its message type: name = the message class (`HandPose`), encoding
  `jsonschema`, data = the class's JSON Schema (`services.recording.json_channels`), so any
  MCAP reader decodes it. The channel metadata holds the contract topic, the message class, the
  schema version (`messages.SCHEMA_VERSION`) and the QoS.
- Each message: `log_time` = the recorder's wall clock at arrival (ns), `publish_time` = the
  message's own `t_ns` (the rig clock: simulated under `--sim`), `sequence` = its `seq` (mod
  2^32), `data` = the validated message as JSON (`messages.encode_json`).
- Recordings made before (schema 1 or 3) have message encoding `msgpack`: `data` is the
  original payload bytes, the schema described the msgpack map. They still read: `Entry.payload`
  gives every reader a msgpack payload in today's schema whatever the file's encoding or schema
  version (`nod record convert` rewrites one as today's).
- A payload that fails validation (or a key outside the contract) is kept, for the record, on a
  channel of its own for that key: no schema, encoding `application/octet-stream`, metadata
  `invalid` = the first error; publish_time = log_time. Players never republish those.
- File metadata records: `nod` at the start (rig, host, nod-hri version, start time, keys,
  parameters when given), `nod.session` when a session id first shows on experiment/trial, and
  `nod.end` at a clean stop (counts, drops, the sessions seen).
- Attachments: a Foxglove layout and a Rerun blueprint of a trial (`services.views`).

`McapIn` reads sequentially with the library's stream reader, so it reads a file whose writer
was killed (no summary, a chunk cut short) up to its last complete chunk, and says so.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

from mcap.exceptions import EndOfFile
from mcap.records import Attachment, Channel, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from services.core import messages as m
from services.core.contract import TOPICS
from services.core.keys import topic_of
from services.core.schema1 import upgrade
from services.recording.json_channels import JSON_ENCODING, SCHEMA_ENCODING, schema_data, to_wire

MESSAGE_ENCODING = JSON_ENCODING  # today's recordings
MSGPACK_ENCODING = "msgpack"  # recordings made before: the wire's payloads as they travelled
RAW_ENCODING = "application/octet-stream"
FILE_METADATA = "nod"
SESSION_METADATA = "nod.session"
END_METADATA = "nod.end"
COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
               "none": CompressionType.NONE}
# A Foxglove-style image channel (`nod record --images`): JSON messages with this schema.
FOXGLOVE_IMAGE = "foxglove.CompressedImage"
_FOXGLOVE_IMAGE_SCHEMA = {
    "title": FOXGLOVE_IMAGE,
    "description": "A compressed image",
    "type": "object",
    "properties": {
        "timestamp": {
            "type": "object",
            "title": "time",
            "properties": {"sec": {"type": "integer", "minimum": 0},
                           "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}},
        },
        "frame_id": {"type": "string"},
        "data": {"type": "string", "contentEncoding": "base64"},
        "format": {"type": "string"},
    },
}


def rig_of(key: str) -> str | None:
    """The rig chunk of a full key (`nod/<rig>/...`), or None."""
    parts = key.split("/", 2)
    return parts[1] if len(parts) == 3 and parts[0] == "nod" else None


def channel_metadata(topic: str) -> dict[str, str]:
    """What a valid channel's metadata says about its key."""
    spec = TOPICS[topic]
    return {
        "topic": topic,
        "message": spec.message.__name__,
        "schema_version": str(m.schema_version(spec.message)),  # a key's own: 1, or 2 for N
        "qos": spec.qos.describe(),
        "publishers": ",".join(spec.publishers),
    }


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("nod-hri")
    except PackageNotFoundError:
        return "dev"


class McapOut:
    """An MCAP file being written: channels per key, schemas per message class, metadata.

    Chunked (zstd by default); `flush()` closes the chunk in progress and hands it to the OS, so
    a writer killed after it leaves a file readable up to there (`McapIn`).
    """

    def __init__(
        self, path: str | Path, *, chunk_bytes: int = 1 << 20, compression: str = "zstd"
    ) -> None:
        self.path = Path(path)
        self._fh: BinaryIO = open(self.path, "wb")  # noqa: SIM115 (closed by finish)
        self._writer = Writer(
            self._fh, chunk_size=chunk_bytes, compression=COMPRESSION[compression]
        )
        from mcap.writer import LIBRARY_IDENTIFIER

        self._writer.start(profile="", library=f"nod-hri {_version()}; {LIBRARY_IDENTIFIER}")
        self._schemas: dict[tuple[str, str, bytes], int] = {}
        self._channels: dict[tuple[str, str], int] = {}  # (topic, kind) -> channel id
        self.messages = 0
        self.payload_bytes = 0
        self.finished = False

    # -- schemas and channels ----------------------------------------------------------------

    def schema(self, name: str, encoding: str, data: bytes) -> int:
        """The id of a schema (registered once)."""
        ident = (name, encoding, data)
        sid = self._schemas.get(ident)
        if sid is None:
            sid = self._schemas[ident] = self._writer.register_schema(name, encoding, data)
        return sid

    def channel(self, key: str) -> int:
        """The channel of a key of the contract (its message type's schema)."""
        cid = self._channels.get((key, "msg"))
        if cid is None:
            topic = topic_of(key)
            if topic is None:
                raise KeyError(f"{key!r} is not a key of the contract")
            cls = TOPICS[topic].message
            sid = self.schema(cls.__name__, SCHEMA_ENCODING, schema_data(cls))
            cid = self._writer.register_channel(key, MESSAGE_ENCODING, sid, channel_metadata(topic))
            self._channels[(key, "msg")] = cid
        return cid

    def raw_channel(self, key: str, why: str) -> int:
        """The channel of a key's invalid payloads (no schema; `invalid` = the first error)."""
        cid = self._channels.get((key, "invalid"))
        if cid is None:
            meta = {"invalid": why[:500], "schema_version": str(m.SCHEMA_VERSION)}
            cid = self._writer.register_channel(key, RAW_ENCODING, 0, meta)
            self._channels[(key, "invalid")] = cid
        return cid

    def image_channel(self, key: str) -> int:
        """A Foxglove CompressedImage channel (JSON) derived from the frames of `key`."""
        topic = f"{key}/image"
        cid = self._channels.get((topic, "image"))
        if cid is None:
            sid = self.schema(
                FOXGLOVE_IMAGE, SCHEMA_ENCODING, json.dumps(_FOXGLOVE_IMAGE_SCHEMA).encode()
            )
            cid = self._writer.register_channel(topic, "json", sid, {"derived_from": key})
            self._channels[(topic, "image")] = cid
        return cid

    def copy_channel(self, channel: Channel, schema: Schema | None) -> int:
        """A channel like one of another file (same topic, encodings, schema and metadata)."""
        meta = sorted(channel.metadata.items())
        ident = (channel.topic, f"copy:{channel.message_encoding}:{meta}:{channel.schema_id}")
        cid = self._channels.get(ident)
        if cid is None:
            sid = 0 if schema is None else self.schema(schema.name, schema.encoding, schema.data)
            cid = self._writer.register_channel(
                channel.topic, channel.message_encoding, sid, dict(channel.metadata)
            )
            self._channels[ident] = cid
        return cid

    @property
    def channel_count(self) -> int:
        """Channels registered so far."""
        return len(self._channels)

    # -- records -----------------------------------------------------------------------------

    def write_message(self, key: str, msg: m.Message, log_time: int) -> None:
        """A valid message of the contract on its key's channel, as JSON (publish_time = t_ns)."""
        self.write(self.channel(key), log_time, msg.t_ns, m.encode_json(msg), msg.seq)

    def rewrite(self, e: Entry) -> m.Message | None:
        """A message of another recording in today's form; the message decoded, if valid.

        A valid one is decoded and written as JSON in today's schema; an invalid payload or a
        derived image is copied as it was; a payload of a valid channel that no longer decodes
        goes to its key's invalid channel.
        """
        topic = topic_of(e.key)
        if e.valid and topic is not None:
            try:
                msg = m.decode(TOPICS[topic].message, e.payload)
            except m.MessageError as exc:
                self.write(self.raw_channel(e.key, str(exc)), e.message.log_time,
                           e.message.log_time, e.message.data)
                return None
            self.write_message(e.key, msg, e.message.log_time)
            return msg
        self.write(self.copy_channel(e.channel, e.schema), e.message.log_time,
                   e.message.publish_time, e.message.data, e.message.sequence)
        return None

    def attach(self, name: str, media_type: str, data: bytes, log_time: int = 0) -> None:
        """An attachment (a file kept in the recording: a viewer's layout)."""
        self._writer.add_attachment(create_time=log_time, log_time=log_time, name=name,
                                    media_type=media_type, data=data)

    def write(
        self, channel_id: int, log_time: int, publish_time: int, data: bytes, sequence: int = 0
    ) -> None:
        """One message."""
        self._writer.add_message(
            channel_id, log_time=log_time, data=data, publish_time=publish_time,
            sequence=sequence & 0xFFFFFFFF,
        )
        self.messages += 1
        self.payload_bytes += len(data)

    def write_image(self, key: str, frame: m.VisionFrame, log_time: int) -> None:
        """A frame's JPEG again on its Foxglove image channel."""
        import base64

        sec, nsec = divmod(frame.t_ns, 1_000_000_000)
        body = {
            "timestamp": {"sec": sec, "nsec": nsec},
            "frame_id": "camera",
            "data": base64.b64encode(frame.jpeg).decode(),
            "format": "jpeg",
        }
        self.write(self.image_channel(key), log_time, frame.t_ns, json.dumps(body).encode(),
                   frame.seq)

    def metadata(self, name: str, data: dict[str, Any]) -> None:
        """A metadata record (values become strings; dicts and lists JSON)."""
        flat = {
            str(k): v if isinstance(v, str) else json.dumps(v, default=str)
            for k, v in data.items()
        }
        self._writer.add_metadata(name, flat)

    def flush(self) -> None:
        """Close the chunk in progress and hand everything to the OS (no fsync)."""
        self._writer.flush()

    def size(self) -> int:
        """Bytes written to the file so far."""
        return self._fh.tell()

    def finish(self) -> None:
        """Write the summary (indexes, statistics) and close the file (idempotent)."""
        if self.finished:
            return
        self.finished = True
        try:
            self._writer.finish()
        finally:
            self._fh.close()


# --- reading --------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Entry:
    """One message of a recording, with its channel and schema."""

    index: int  # the message's position in the file (0, 1, ...)
    channel: Channel
    schema: Schema | None
    message: Message

    @property
    def key(self) -> str:
        """The channel topic: the full key."""
        return self.channel.topic

    @property
    def payload(self) -> bytes:
        """The message as a msgpack payload in today's schema, whatever the file's encoding.

        A JSON message (today's recordings) is decoded, checked and encoded as msgpack; a
        msgpack one (older recordings) is returned as it travelled, a schema-1 one rewritten
        (`schema1`). A JSON message that fails the contract (a file edited by hand) is returned
        as it is, so every decoder downstream refuses it as it refuses any bad payload.
        """
        topic = topic_of(self.key)
        data = self.message.data
        if topic is None:
            return data
        if self.channel.message_encoding == JSON_ENCODING:
            try:
                return to_wire(TOPICS[topic].message, data)
            except m.MessageError:
                return data
        return upgrade(topic, data)

    @property
    def valid(self) -> bool:
        """A validated message of the contract (not an invalid payload, not a derived image)."""
        meta = self.channel.metadata
        return (
            self.channel.message_encoding in (JSON_ENCODING, MSGPACK_ENCODING)
            and "invalid" not in meta and "derived_from" not in meta
        )


@dataclass
class McapIn:
    """A recording read front to back, also one whose writer was killed.

    Iterate for the messages; afterwards `complete` says whether the footer was reached and
    `truncated` why reading stopped early (None if it did not). `metadata` holds the metadata
    records read so far, in order.
    """

    path: Path
    header: Header | None = None
    metadata: list[tuple[str, dict[str, str]]] = field(default_factory=list)
    channels: dict[int, Channel] = field(default_factory=dict)
    schemas: dict[int, Schema] = field(default_factory=dict)
    attachments: list[Attachment] = field(default_factory=list)
    complete: bool = False
    truncated: str | None = None
    count: int = 0

    def __post_init__(self) -> None:
        self.path = Path(self.path)
        with self.path.open("rb") as fh:
            magic = fh.read(8)
        if magic != b"\x89MCAP0\r\n":
            raise ValueError(f"{self.path} is not an MCAP file")

    def __iter__(self) -> Iterator[Entry]:
        self.metadata, self.channels, self.schemas, self.attachments = [], {}, {}, []
        self.complete, self.truncated, self.count = False, None, 0
        with self.path.open("rb") as fh:
            records = StreamReader(fh, validate_crcs=True).records
            while True:
                try:
                    record = next(records)
                except StopIteration:
                    break
                except EndOfFile:  # the file ends between or inside records: no footer
                    self.truncated = "the file ends before its footer (the writer was stopped)"
                    return
                except Exception as exc:  # noqa: BLE001 a record cut short fails in any decoder
                    # (a short read, zstd/lz4, a CRC): everything before it was read whole
                    self.truncated = f"a damaged record ({type(exc).__name__}: {exc})"
                    return
                if isinstance(record, Message):
                    channel = self.channels.get(record.channel_id)
                    if channel is None:
                        continue
                    schema = self.schemas.get(channel.schema_id)
                    yield Entry(self.count, channel, schema, record)
                    self.count += 1
                elif isinstance(record, Channel):
                    self.channels[record.id] = record
                elif isinstance(record, Schema):
                    self.schemas[record.id] = record
                elif isinstance(record, Metadata):
                    self.metadata.append((record.name, dict(record.metadata)))
                elif isinstance(record, Attachment):
                    self.attachments.append(record)
                elif isinstance(record, Header):
                    self.header = record
                elif isinstance(record, Footer):
                    self.complete = True

    def file_metadata(self) -> dict[str, str]:
        """The `nod` metadata record (after iterating, or from a quick scan of the start)."""
        if not self.metadata:
            for _ in self._until_first_message():
                pass
        for name, data in self.metadata:
            if name == FILE_METADATA:
                return data
        return {}

    def _until_first_message(self) -> Iterator[Entry]:
        for entry in self:
            yield entry
            return

    def sessions(self) -> list[str]:
        """The session ids the `nod.session` records name (after iterating)."""
        return [d["session"] for n, d in self.metadata if n == SESSION_METADATA and "session" in d]
