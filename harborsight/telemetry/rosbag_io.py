"""Reading ROS 1 and ROS 2 bags message by message, whole or damaged.

A whole bag is read by rosbags' ``AnyReader``: a ROS 1 ``.bag`` file, or a ROS 2 bag folder
(``metadata.yaml`` beside its ``.db3`` or ``.mcap`` file; the file itself may be given). Its
readers need what a recorder writes last: a ROS 1 bag's index, a ROS 2 bag's ``metadata.yaml``,
an MCAP file's summary and end magic. A recording cut short (a battery pulled, a card full, a
copy interrupted) lacks it, and so does a lone ``.db3`` or ``.mcap`` file. Those are read from
the front instead, up to the damage, with a note:

* ROS 1 ``.bag`` (format 2.0): its records in file order (op 0x07 connections, 0x02 messages,
  0x05 chunks of them, uncompressed, bz2 or lz4); index records are skipped;
* ROS 2 SQLite ``.db3``: the ``topics`` and ``messages`` tables with Python's sqlite3, and, in a
  file whose pages are cut off, row by row (rows on missing pages are lost);
* MCAP: the ``mcap`` package's stream reader (schemas, channels, messages, chunks unpacked).

Messages are deserialised by rosbags' typestore: from the definitions the bag carries where it
has them, else ROS 1 Noetic's or ROS 2 Humble's standard types (every type harborsight reads is
standard). A message that does not deserialise is counted in the notes, never raised.
"""

from __future__ import annotations

import bz2
import io
import sqlite3
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from harborsight.errors import InputError

BAG_SUFFIXES = (".bag", ".db3", ".mcap")
ROS1_MAGIC = b"#ROSBAG V2.0\n"
#: the largest record a damaged ROS 1 bag may announce (a flipped length is not allocated)
MAX_RECORD_BYTES = 512 * 1024 * 1024
#: the largest damaged bag read from the front: it is read into memory whole
MAX_DAMAGED_BYTES = 4 * 1024 ** 3


@dataclass
class BagMessage:
    topic: str
    msgtype: str              # rosbags' name: sensor_msgs/msg/NavSatFix
    log_time_ns: int          # when the recorder received it (Unix time, ns)
    message: object           # the deserialised message


@dataclass
class TopicInfo:
    name: str
    msgtype: str
    count: int


@dataclass
class BagReader:
    """One bag, opened: its topics and a message iterator (module docstring)."""

    path: Path
    kind: str                                     # "ros1", "ros2-sqlite3", "ros2-mcap"
    topics: dict[str, TopicInfo]
    damaged: bool = False                         # read from the front, past an error
    notes: list[str] = field(default_factory=list)
    undecodable: int = 0
    _raw: list = field(default_factory=list, repr=False)   # (topic, msgtype, t_ns, bytes, cdr)
    _typestore: object = field(default=None, repr=False)
    _anyreader_path: Path | None = field(default=None, repr=False)

    def messages(self, topics: set[str] | None = None) -> Iterator[BagMessage]:
        """The messages of ``topics`` (all when None) in the order recorded (by log time)."""
        if self._anyreader_path is not None:
            yield from self._anyreader_messages(topics)
            return
        for topic, msgtype, t_ns, data, cdr in sorted(self._raw, key=lambda r: r[2]):
            if topics is not None and topic not in topics:
                continue
            message = self._deserialise(data, msgtype, cdr)
            if message is not None:
                yield BagMessage(topic, msgtype, t_ns, message)

    def _deserialise(self, data: bytes, msgtype: str, cdr: bool) -> object | None:
        try:
            if cdr:
                return self._typestore.deserialize_cdr(data, msgtype)
            return self._typestore.deserialize_ros1(data, msgtype)
        except Exception:          # damaged bytes raise many kinds of error
            self.undecodable += 1
            return None

    def _anyreader_messages(self, topics: set[str] | None) -> Iterator[BagMessage]:
        from rosbags.highlevel import AnyReader

        try:
            with AnyReader([self._anyreader_path], default_typestore=_standard(self.kind)) as reader:
                chosen = [c for c in reader.connections if topics is None or c.topic in topics]
                for connection, t_ns, data in reader.messages(connections=chosen):
                    try:
                        message = reader.deserialize(data, connection.msgtype)
                    except Exception:
                        self.undecodable += 1
                        continue
                    yield BagMessage(connection.topic, connection.msgtype, int(t_ns), message)
        except (OSError, ValueError, KeyError, AssertionError) as exc:
            raise InputError(self.path, None, f"cannot read the bag: {exc}") from None
        except Exception as exc:   # rosbags' reader errors
            raise InputError(self.path, None, f"cannot read the bag: {exc}") from None


def _standard(kind: str):
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)


def open_bag(path: str | Path) -> BagReader:
    """Open a bag (module docstring); :class:`InputError` naming it when it is not one or
    nothing in it can be read."""
    path = Path(path)
    if not path.exists():
        raise InputError(path, None, "no such file or folder")
    folder, file = _ros2_parts(path)
    if path.suffix.lower() == ".bag":
        kind, anyreader_path = "ros1", path
    elif file is not None:
        kind = "ros2-mcap" if file.suffix.lower() == ".mcap" else "ros2-sqlite3"
        anyreader_path = folder if folder is not None else None
    else:
        raise InputError(path, None, "not a ROS bag: expected a ROS 1 .bag file, a ROS 2 bag "
                         "folder (metadata.yaml with a .db3 or .mcap file) or such a file")
    if anyreader_path is not None:
        reader = _open_whole(path, kind, anyreader_path)
        if reader is not None:
            return reader
    source = file if file is not None else path
    _check_damaged_size(path, source, kind)
    reader = {"ros1": _read_ros1_records, "ros2-mcap": _read_mcap_stream,
              "ros2-sqlite3": _read_sqlite}[kind](source)
    reader.path = path
    if not reader.topics:
        raise InputError(path, None, "no message could be read: " + "; ".join(reader.notes)
                         if reader.notes else "no message could be read")
    return reader


def _check_damaged_size(path: Path, source: Path, kind: str) -> None:
    """A bag its reader refused is read into memory: refuse one too large for that, saying
    how to repair it."""
    try:
        size = source.stat().st_size
    except OSError as exc:
        raise InputError(path, None, f"cannot read: {exc.strerror or exc}") from None
    if size > MAX_DAMAGED_BYTES:
        repair = ("rosbag reindex" if kind == "ros1" else
                  "ros2 bag reindex (a lost metadata.yaml) or mcap recover (a cut MCAP file)")
        raise InputError(path, None, f"the bag cannot be opened as it is (no index, no "
                         f"metadata.yaml or a cut file) and at {size / 1024 ** 3:.1f} GB it is "
                         f"too large to read from the front here: repair it with {repair}")


def _ros2_parts(path: Path) -> tuple[Path | None, Path | None]:
    """A ROS 2 bag's folder (with metadata.yaml; None without) and its storage file."""
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.suffix.lower() in (".db3", ".mcap"))
        if not files:
            return None, None
        return (path if (path / "metadata.yaml").is_file() else None), files[0]
    if path.suffix.lower() in (".db3", ".mcap"):
        return (path.parent if (path.parent / "metadata.yaml").is_file() else None), path
    return None, None


def _open_whole(path: Path, kind: str, anyreader_path: Path) -> BagReader | None:
    """The bag through AnyReader, or None when its reader refuses it (damaged: read from the
    front instead)."""
    from rosbags.highlevel import AnyReader

    try:
        with AnyReader([anyreader_path], default_typestore=_standard(kind)) as reader:
            topics: dict[str, TopicInfo] = {}
            for connection in reader.connections:
                info = topics.setdefault(connection.topic, TopicInfo(connection.topic,
                                                                     connection.msgtype, 0))
                info.count += connection.msgcount
    except Exception:             # rosbags raises its own errors and OS/value errors
        return None
    return BagReader(path, kind, topics, _anyreader_path=anyreader_path)


def _damaged(path: Path, kind: str, what: str) -> BagReader:
    reader = BagReader(path, kind, {}, damaged=True)
    reader.notes.append(f"{what}: read from the front up to the damage")
    return reader


def _add(reader: BagReader, topic: str, msgtype: str, t_ns: int, data: bytes, cdr: bool) -> None:
    reader._raw.append((topic, msgtype, t_ns, bytes(data), cdr))
    info = reader.topics.setdefault(topic, TopicInfo(topic, msgtype, 0))
    info.count += 1


def _ros1_type(name: str) -> str:
    """ROS 1's ``sensor_msgs/NavSatFix`` as rosbags names it, ``sensor_msgs/msg/NavSatFix``."""
    package, _, rest = name.partition("/")
    return name if "/msg/" in name or not rest else f"{package}/msg/{rest}"


def _header_fields(data: bytes) -> dict[str, bytes]:
    """A ROS 1 record header: ``len name=value`` fields."""
    fields, at = {}, 0
    while at + 4 <= len(data):
        (size,) = struct.unpack_from("<I", data, at)
        at += 4
        if size > len(data) - at:
            break
        name, _, value = data[at:at + size].partition(b"=")
        fields[name.decode("latin-1")] = value
        at += size
    return fields


def _bytes_starting_with(path: Path, magic: bytes, refusal: str) -> bytes:
    """The whole file, refused with ``refusal`` unless it starts with ``magic``."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(path, None, f"cannot read: {exc.strerror or exc}") from None
    if not data.startswith(magic):
        raise InputError(path, None, refusal)
    return data


def _read_ros1_records(path: Path) -> BagReader:
    """A ROS 1 bag read record by record from the front (module docstring)."""
    from rosbags.typesys import get_types_from_msg

    reader = _damaged(path, "ros1", "ROS 1 bag without a readable index (cut short?)")
    data = _bytes_starting_with(path, ROS1_MAGIC, "not a ROS 1 bag (no '#ROSBAG V2.0' line)")
    typestore = _standard("ros1")
    connections: dict[int, tuple[str, str]] = {}
    definitions: dict[str, str] = {}
    problems: list[str] = []

    def records(blob: bytes, at: int) -> Iterator[tuple[dict, bytes]]:
        while at + 4 <= len(blob):
            (header_size,) = struct.unpack_from("<I", blob, at)
            if header_size > MAX_RECORD_BYTES or at + 4 + header_size + 4 > len(blob):
                if at + 4 + header_size + 4 > len(blob) and header_size <= MAX_RECORD_BYTES:
                    problems.append(f"cut inside a record at byte {at}")
                else:
                    problems.append(f"implausible record length at byte {at}")
                return
            header = _header_fields(blob[at + 4:at + 4 + header_size])
            at += 4 + header_size
            (data_size,) = struct.unpack_from("<I", blob, at)
            at += 4
            if data_size > MAX_RECORD_BYTES:
                problems.append(f"implausible data length at byte {at - 4}")
                return
            body = blob[at:at + data_size]
            at += data_size
            yield header, body
            if len(body) < data_size:
                problems.append("cut inside the last record")
                return

    def handle(header: dict, body: bytes) -> None:
        op = header.get("op", b"")[:1]
        if op == b"\x07" and len(header.get("conn", b"")) == 4:
            conn = struct.unpack("<I", header["conn"])[0]
            inner = _header_fields(body)
            topic = header.get("topic", inner.get("topic", b"")).decode("utf-8", "replace")
            msgtype = _ros1_type(inner.get("type", b"").decode("utf-8", "replace"))
            connections[conn] = (topic, msgtype)
            definition = inner.get("message_definition", b"").decode("utf-8", "replace")
            if definition and msgtype not in definitions:
                definitions[msgtype] = definition
        elif op == b"\x02" and len(header.get("conn", b"")) == 4 and len(header.get("time", b"")) == 8:
            conn = struct.unpack("<I", header["conn"])[0]
            if conn in connections:
                sec, nsec = struct.unpack("<II", header["time"])
                topic, msgtype = connections[conn]
                _add(reader, topic, msgtype, sec * 1_000_000_000 + nsec, body, False)
        elif op == b"\x05":
            compression = header.get("compression", b"none")
            try:
                if compression == b"bz2":
                    body = bz2.decompress(body)
                elif compression == b"lz4":
                    import lz4.frame

                    body = lz4.frame.decompress(body)
                elif compression != b"none":
                    problems.append(f"a chunk compressed with {compression!r} skipped")
                    return
            except Exception:
                problems.append("a damaged compressed chunk skipped")
                return
            for inner_header, inner_body in records(body, 0):
                handle(inner_header, inner_body)

    for header, body in records(data, len(ROS1_MAGIC)):
        handle(header, body)
    for msgtype, definition in definitions.items():
        try:
            typestore.register(get_types_from_msg(definition, msgtype))
        except Exception:
            problems.append(f"the definition of {msgtype} is unreadable (standard types used)")
    reader._typestore = typestore
    reader.notes += list(dict.fromkeys(problems))
    return reader


MCAP_MAGIC = b"\x89MCAP0\r\n"
_MCAP_SCHEMA, _MCAP_CHANNEL, _MCAP_MESSAGE, _MCAP_CHUNK = 0x03, 0x04, 0x05, 0x06


def _mcap_records(blob: bytes, at: int, problems: list[str]) -> Iterator[tuple[int, bytes, bool]]:
    """MCAP records from ``at``: (opcode, content, whole); the last one may be cut short."""
    while at + 9 <= len(blob):
        opcode = blob[at]
        (length,) = struct.unpack_from("<Q", blob, at + 1)
        if length > MAX_RECORD_BYTES:
            problems.append(f"implausible record length at byte {at}")
            return
        content = blob[at + 9:at + 9 + length]
        whole = len(content) == length
        yield opcode, content, whole
        if not whole:
            problems.append(f"cut inside a record at byte {at}")
            return
        at += 9 + length


def _partial_chunk_records(content: bytes) -> bytes | None:
    """The records of an uncompressed chunk cut short (what of them there is); None for a
    compressed one (its records cannot be had without its end)."""
    if len(content) < 32:
        return None
    (name_length,) = struct.unpack_from("<I", content, 28)
    compression = content[32:32 + name_length]
    if compression != b"" or len(content) < 32 + name_length + 8:
        return None
    return content[32 + name_length + 8:]


def _read_mcap_stream(path: Path) -> BagReader:
    """An MCAP file read record by record from the front (the ``mcap`` package parses each
    record; an uncompressed chunk cut short gives the messages it holds whole)."""
    from mcap.data_stream import ReadDataStream
    from mcap.records import Channel, Chunk, Message, Schema
    from mcap.stream_reader import get_chunk_data_stream
    from rosbags.typesys import get_types_from_msg

    reader = _damaged(path, "ros2-mcap", "MCAP file read on its own (no metadata.yaml, or its "
                      "summary unreadable)")
    blob = _bytes_starting_with(path, MCAP_MAGIC, "not an MCAP file (no MCAP magic)")
    typestore = _standard("ros2")
    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, str]] = {}
    problems: list[str] = []

    def handle(opcode: int, content: bytes, whole: bool) -> None:
        stream = ReadDataStream(io.BytesIO(content))
        if opcode == _MCAP_CHUNK:
            if whole:
                inner, size = get_chunk_data_stream(Chunk.read(stream))
                records = inner.read(size)
            else:
                records = _partial_chunk_records(content)
                if records is None:
                    problems.append("a compressed chunk cut short lost")
                    return
            for inner_record in _mcap_records(records, 0, problems):
                if inner_record[2]:
                    handle(*inner_record)
            return
        if not whole:
            return
        if opcode == _MCAP_SCHEMA:
            schema = Schema.read(stream)
            schemas[schema.id] = schema.name
            if schema.encoding == "ros2msg" and schema.data:
                try:
                    typestore.register(get_types_from_msg(schema.data.decode(), schema.name))
                except Exception:
                    problems.append(f"the schema of {schema.name} is unreadable")
        elif opcode == _MCAP_CHANNEL:
            channel = Channel.read(stream)
            channels[channel.id] = (channel.topic, schemas.get(channel.schema_id, ""))
        elif opcode == _MCAP_MESSAGE:
            message = Message.read(stream, len(content))
            if message.channel_id in channels:
                _add(reader, *channels[message.channel_id], int(message.log_time), message.data,
                     True)

    for record in _mcap_records(blob, len(MCAP_MAGIC), problems):
        try:
            handle(*record)
        except Exception as exc:    # a salted record: the mcap parser's many errors
            problems.append(f"a damaged record skipped ({type(exc).__name__})")
    if not reader.topics and not channels:
        raise InputError(path, None, "not an MCAP file with ROS 2 messages (nothing readable)")
    reader._typestore = typestore
    reader.notes += list(dict.fromkeys(problems))
    return reader


def _read_sqlite(path: Path) -> BagReader:
    """A ROS 2 SQLite bag's tables read directly. A file cut short is read from a copy padded
    to the page count its header states (SQLite refuses a file shorter than that), row by
    row: the rows on the pages that survive."""
    reader = _damaged(path, "ros2-sqlite3", "ROS 2 .db3 read on its own (no metadata.yaml, or "
                      "rosbags refused it)")
    try:
        with open(path, "rb") as handle:
            head = handle.read(100)
        size = path.stat().st_size
    except OSError as exc:
        raise InputError(path, None, f"cannot read: {exc.strerror or exc}") from None
    if not head.startswith(b"SQLite format 3\x00") or len(head) < 100:
        raise InputError(path, None, "not a SQLite file (a ROS 2 .db3 bag is one)")
    try:
        _sqlite_rows(path, reader, row_by_row=False)
    except sqlite3.DatabaseError:
        (page_size,) = struct.unpack_from(">H", head, 16)
        page_size = 65536 if page_size == 1 else page_size
        (pages,) = struct.unpack_from(">I", head, 28)
        if page_size < 512 or page_size & (page_size - 1) or not size <= pages * page_size \
                <= max(size, 1) * 64:
            raise InputError(path, "header", "the SQLite header is damaged (page size or page "
                             "count)") from None
        import tempfile

        reader._raw.clear()
        reader.topics.clear()
        with tempfile.TemporaryDirectory(prefix="harborsight-db3-") as folder:
            padded = Path(folder) / "bag.db3"
            with open(padded, "wb") as out, open(path, "rb") as source:
                while chunk := source.read(1 << 20):
                    out.write(chunk)
                out.truncate(pages * page_size)
            lost = _sqlite_rows(padded, reader, row_by_row=True)
        reader.notes.append(f"the file is cut short or damaged: read row by row, {lost} row(s) "
                            "on missing or damaged pages lost")
    reader._typestore = _standard("ros2")
    return reader


#: what a damaged SQLite file raises: its own errors, and a column name that is not UTF-8 in
#: a salted schema (Python's sqlite3 decodes the names strictly)
_SQLITE_ERRORS = (sqlite3.DatabaseError, UnicodeDecodeError)


def _sqlite_rows(path: Path, reader: BagReader, row_by_row: bool) -> int:
    """Add the messages of a SQLite bag to ``reader``; the rows lost (row by row: those whose
    pages cannot be read). Raises sqlite3.DatabaseError where the whole read fails."""
    connection = sqlite3.connect(path.resolve().as_uri() + "?mode=ro&immutable=1", uri=True)
    connection.text_factory = lambda raw: raw.decode("utf-8", "replace")    # salted names
    try:
        try:
            topics = {row[0]: (row[1], row[2]) for row in
                      connection.execute("SELECT id, name, type FROM topics")}
        except _SQLITE_ERRORS as exc:
            if not row_by_row:
                raise sqlite3.DatabaseError(str(exc)) from None
            raise InputError(reader.path, "topics", f"the bag's topic table is unreadable: "
                             f"{exc}") from None
        if not row_by_row:
            try:
                for topic_id, t_ns, data in connection.execute(
                        "SELECT topic_id, timestamp, data FROM messages ORDER BY id"):
                    if topic_id in topics and isinstance(data, bytes) and isinstance(t_ns, int):
                        _add(reader, *topics[topic_id], t_ns, data, True)
            except UnicodeDecodeError as exc:
                raise sqlite3.DatabaseError(str(exc)) from None
            return 0
        lost, misses, rowid = 0, 0, 1
        while misses < 1000:
            try:
                row = connection.execute("SELECT topic_id, timestamp, data FROM messages "
                                         "WHERE id = ?", (rowid,)).fetchone()
            except _SQLITE_ERRORS:
                row, lost = None, lost + 1
            misses = misses + 1 if row is None else 0
            if row is not None and row[0] in topics and isinstance(row[2], bytes) \
                    and isinstance(row[1], int):
                _add(reader, *topics[row[0]], row[1], row[2], True)
            rowid += 1
        return lost
    finally:
        connection.close()
