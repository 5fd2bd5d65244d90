"""Reading what is there of a recording that was cut short: MCAP, sqlite3 and ROS 1 bags, record by record.

A recorder that crashes, a disk that fills or a copy that stops half-way leaves a bag without its tail:
an MCAP file without its summary and footer, a ROS 1 bag without its index, an sqlite3 database with
pages missing. rosbags refuses such files (it needs the footer or index). Every one of these formats is
a plain sequence of records from the start, though, so scanning from the front recovers every message
before the cut, including those inside a chunk that is only partly there.
"""

from __future__ import annotations

import bz2
import os
import sqlite3
import struct
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import lz4.frame  # type: ignore[import-untyped]
from backports import zstd
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from monodock.recording.messages import humble_typestore, normalize_msgtype

__all__ = ["MCAP_MAGIC", "ROS1_MAGIC", "SQLITE_MAGIC", "Salvage", "SalvageError", "SalvagedConnection", "sniff"]

MCAP_MAGIC = b"\x89MCAP0\r\n"
ROS1_MAGIC = b"#ROSBAG V2.0\n"
SQLITE_MAGIC = b"SQLite format 3\x00"

_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")


def _read_at_most(fh: BinaryIO, length: int) -> bytes:
    """``fh.read(length)``, but no more than the file holds: a corrupt record length reads to the end of the file
    (and is found cut) instead of allocating its length first (a MemoryError)."""
    here = fh.tell()
    end = fh.seek(0, os.SEEK_END)
    fh.seek(here)
    return fh.read(max(0, min(length, end - here)))


class SalvageError(Exception):
    """The file is not one of the formats, or not even its start is readable."""


def sniff(path: Path) -> str | None:
    """The storage format of a file from its first bytes: "mcap", "sqlite3", "ros1" or None."""
    try:
        with path.open("rb") as fh:
            head = fh.read(16)
    except OSError:
        return None
    if head.startswith(MCAP_MAGIC):
        return "mcap"
    if head.startswith(SQLITE_MAGIC):
        return "sqlite3"
    if head.startswith(ROS1_MAGIC):
        return "ros1"
    return None


@dataclass(frozen=True)
class SalvagedConnection:
    """A topic as a damaged file describes it: its type (ROS 2 spelling) and definition, if stored."""

    id: int
    topic: str
    msgtype: str
    msgdef: str = ""
    msgdef_format: str = ""  # "msg", "idl" or "" (none stored)


class _TruncatedError(Exception):
    """The data ends in the middle of a record."""


class _Buf:
    """A cursor over bytes that raises _TruncatedError instead of returning short reads."""

    def __init__(self, data: bytes | memoryview) -> None:
        self.data = memoryview(data)
        self.pos = 0

    def left(self) -> int:
        return len(self.data) - self.pos

    def take(self, n: int) -> memoryview:
        if n > self.left():
            raise _TruncatedError
        out = self.data[self.pos : self.pos + n]
        self.pos += n
        return out

    def u16(self) -> int:
        return int(_U16.unpack(self.take(2))[0])

    def u32(self) -> int:
        return int(_U32.unpack(self.take(4))[0])

    def u64(self) -> int:
        return int(_U64.unpack(self.take(8))[0])

    def string(self) -> str:
        return bytes(self.take(self.u32())).decode("utf-8", "replace")


def _partial_decompress(data: bytes | memoryview, compression: str) -> bytes:
    """As much of a compressed stream as decodes; the whole of it when it is complete."""
    if compression in ("", "none"):
        return bytes(data)
    decompressor: Any
    if compression == "zstd":
        decompressor = zstd.ZstdDecompressor()
    elif compression == "lz4":
        decompressor = lz4.frame.LZ4FrameDecompressor()
    elif compression == "bz2":
        decompressor = bz2.BZ2Decompressor()
    else:
        raise SalvageError(f"compression '{compression}' is not supported")
    try:
        return bytes(decompressor.decompress(bytes(data)))
    except Exception as exc:  # each codec has its own error class; all mean "corrupt"
        raise SalvageError(f"{compression} data is corrupt: {exc}") from None


Message = tuple[int, int, bytes]  # connection id, time (ns), serialised message


class Salvage:
    """What can be read of a damaged MCAP, sqlite3 or ROS 1 file, scanned from its start.

    Opening scans the whole file once to learn its topics, message counts and where it breaks off;
    ``messages`` scans again and yields the messages of the topics asked for, in file order.
    """

    def __init__(self, path: Path, kind: str) -> None:
        self.path = path
        self.kind = kind
        self.ros1 = kind == "ros1"
        self.connections: dict[int, SalvagedConnection] = {}
        self.counts: dict[int, int] = {}
        self.reason: str | None = None
        scanners: dict[str, Callable[[Collection[int] | None], Iterator[Message]]] = {
            "mcap": self._scan_mcap,
            "sqlite3": self._scan_sqlite,
            "ros1": self._scan_ros1,
        }
        if kind not in scanners:
            raise SalvageError(f"cannot read a '{kind}' file record by record")
        self._scanner = scanners[kind]
        for cid, _, _ in self._scanner(None):
            self.counts[cid] = self.counts.get(cid, 0) + 1
        if not self.connections:
            raise SalvageError(self.reason or "no topics in the readable part")

    @property
    def total(self) -> int:
        """Messages in the readable part."""
        return sum(self.counts.values())

    def messages(self, connection_ids: Collection[int]) -> Iterator[Message]:
        """The readable messages of these connections, in file order."""
        wanted = set(connection_ids)
        for msg in self._scanner(wanted):
            if msg[0] in wanted:
                yield msg

    def typestore(self) -> Typestore:
        """The message types of the file's own definitions; ROS 2 Humble's where it stores none."""
        types: dict[str, Any] = {}
        for c in self.connections.values():
            try:
                if c.msgdef_format == "msg":
                    types.update(get_types_from_msg(c.msgdef, c.msgtype))
                elif c.msgdef_format == "idl":
                    sep = "=" * 80 + "\n"
                    parts = c.msgdef.split(sep)[1:] if c.msgdef.startswith(sep + "IDL: ") else [c.msgdef]
                    for part in parts:
                        types.update(get_types_from_idl(part.split("\n", 1)[1] if part.startswith("IDL: ") else part))
            except Exception:  # a broken definition: messages of its type will not decode, and say so
                continue
        if not types:
            return humble_typestore()

        store = get_typestore(Stores.EMPTY)
        store.register(types)
        return store

    # --- MCAP -----------------------------------------------------------------------------------

    def _mcap_record(
        self, op: int, body: _Buf, schemas: dict[int, tuple[str, str, str]], wanted: Collection[int] | None
    ) -> Message | None:
        if op == 0x03:  # schema: id, name, encoding, data
            sid = body.u16()
            name, encoding = body.string(), body.string()
            schemas[sid] = (normalize_msgtype(name), encoding, body.string())
        elif op == 0x04:  # channel: id, schema id, topic, message encoding, metadata
            cid, sid = body.u16(), body.u16()
            topic = body.string()
            name, encoding, data = schemas.get(sid, ("", "", ""))
            fmt = {"ros2msg": "msg", "ros2idl": "idl", "omgidl": "idl"}.get(encoding, "")
            if cid not in self.connections and name:
                self.connections[cid] = SalvagedConnection(cid, topic, name, data, fmt)
        elif op == 0x05:  # message: channel id, sequence, log time, publish time, data
            cid = body.u16()
            body.take(4)
            log_time = body.u64()
            body.take(8)
            if wanted is None or cid in wanted:
                return cid, log_time, bytes(body.take(body.left()))
            return cid, log_time, b""
        return None

    def _scan_mcap(self, wanted: Collection[int] | None) -> Iterator[Message]:
        schemas: dict[int, tuple[str, str, str]] = {}
        self.reason = None
        with self.path.open("rb") as fh:
            if fh.read(8) != MCAP_MAGIC:
                raise SalvageError("not an MCAP file")
            while True:
                pos = fh.tell()
                head = fh.read(9)
                if not head:
                    self.reason = "the file ends without its MCAP footer"
                    return
                if len(head) < 9:
                    self.reason = f"the file ends inside a record at byte {pos}"
                    return
                op, length = head[0], int(_U64.unpack(head[1:])[0])
                if op in (0x02, 0x0F):  # footer, data end: the data section is complete
                    return
                body = _read_at_most(fh, length)  # a corrupt length must not allocate exabytes
                cut = len(body) < length
                if cut and op != 0x06:
                    self.reason = f"the file ends inside a record at byte {pos}"
                    return
                if op == 0x06:
                    yield from self._mcap_chunk(_Buf(body), schemas, wanted, cut, pos)
                    if cut:
                        self.reason = self.reason or f"the file ends inside a chunk at byte {pos}"
                        return
                    continue
                try:
                    msg = self._mcap_record(op, _Buf(body), schemas, wanted)
                except _TruncatedError:
                    self.reason = f"the record at byte {pos} is corrupt"
                    return
                if msg is not None:
                    yield msg

    def _mcap_chunk(
        self, rec: _Buf, schemas: dict[int, tuple[str, str, str]], wanted: Collection[int] | None, cut: bool, pos: int
    ) -> Iterator[Message]:
        try:
            rec.take(8 + 8 + 8 + 4)  # start time, end time, uncompressed size, crc
            compression = rec.string()
            size = rec.u64()
        except _TruncatedError:
            return

        def record(inner: _Buf) -> Message | None:
            op = inner.take(1)[0]
            return self._mcap_record(op, _Buf(inner.take(inner.u64())), schemas, wanted)

        yield from self._chunk(rec.data[rec.pos : rec.pos + size], compression, record, (_TruncatedError,), cut, pos)

    def _chunk(
        self,
        data: bytes | memoryview,
        compression: str,
        record: Callable[[_Buf], Message | None],
        broken: tuple[type[Exception], ...],
        cut: bool,
        pos: int,
    ) -> Iterator[Message]:
        """The messages of one chunk (MCAP or ROS 1), decompressed as far as it goes, each record read by ``record``;
        a record that raises one of ``broken`` ends the chunk (and the scan's reason is set, unless ``cut``: the
        chunk the file was cut in ends where it ends)."""
        try:
            inner = _Buf(_partial_decompress(data, compression))
        except SalvageError as exc:
            self.reason = f"chunk at byte {pos}: {exc}"
            return
        while inner.left():
            start = inner.pos
            try:
                msg = record(inner)
            except broken:
                if not cut:
                    self.reason = f"chunk at byte {pos} is corrupt at its byte {start}"
                return
            if msg is not None:
                yield msg

    # --- sqlite3 ---------------------------------------------------------------------------------

    def _scan_sqlite(self, wanted: Collection[int] | None) -> Iterator[Message]:
        self.reason = None
        uri = f"{self.path.resolve().as_uri()}?mode=ro&immutable=1"
        try:
            con = sqlite3.connect(uri, uri=True)
            # SQLite calls a file shorter than its header's page count corrupt, unless the schema is "writable";
            # the connection is read-only and immutable all the same, so nothing can be written.
            con.execute("PRAGMA writable_schema=ON")
        except sqlite3.Error as exc:
            raise SalvageError(f"cannot open the database: {exc}") from None
        try:
            if not self.connections:
                self._sqlite_topics(con)
            # One row per query, by row id (the order of writing). Python's sqlite3 steps one row ahead of what
            # it returns, so a plain scan loses the last good row to the error on the next page; LIMIT 1 does not.
            last = -(2**63)
            try:
                while True:
                    row = con.execute("SELECT id, topic_id FROM messages WHERE id > ? ORDER BY id LIMIT 1", (last,))
                    found = row.fetchone()
                    if found is None:
                        return
                    last, cid = int(found[0]), int(found[1])
                    if wanted is not None and cid not in wanted:
                        yield cid, 0, b""
                        continue
                    stamp, data = con.execute("SELECT timestamp, data FROM messages WHERE id = ?", (last,)).fetchone()
                    yield cid, int(stamp), bytes(data)
            except sqlite3.Error as exc:
                self.reason = f"the database is damaged ({exc})"
        finally:
            con.close()

    def _sqlite_topics(self, con: sqlite3.Connection) -> None:
        try:
            rows = con.execute("SELECT id, name, type FROM topics ORDER BY id").fetchall()
        except sqlite3.Error as exc:
            raise SalvageError(f"cannot read its topics: {exc}") from None
        defs: dict[str, tuple[str, str]] = {}
        try:
            for name, encoding, text in con.execute(
                "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions"
            ):
                defs[normalize_msgtype(name)] = ({"ros2msg": "msg", "ros2idl": "idl"}.get(encoding, ""), text)
        except sqlite3.Error:
            pass  # Foxy/Humble databases store no definitions: the reader uses the Humble types
        for cid, topic, msgtype in rows:
            t = normalize_msgtype(msgtype)
            fmt, text = defs.get(t, ("", ""))
            self.connections[int(cid)] = SalvagedConnection(int(cid), topic, t, text, fmt)

    # --- ROS 1 -----------------------------------------------------------------------------------

    @staticmethod
    def _ros1_fields(buf: _Buf) -> dict[str, bytes]:
        fields: dict[str, bytes] = {}
        while buf.left():
            item = bytes(buf.take(buf.u32()))
            name, _, value = item.partition(b"=")
            fields[name.decode("ascii", "replace")] = value
        return fields

    def _ros1_record(self, header: dict[str, bytes], data: _Buf, wanted: Collection[int] | None) -> Message | None:
        op = header.get("op", b"\x00")[0]
        if op == 0x07:  # connection
            cid = int(_U32.unpack(header["conn"])[0])
            fields = self._ros1_fields(data)
            topic = header.get("topic", fields.get("topic", b"")).decode()
            msgtype = normalize_msgtype(fields.get("type", b"").decode())
            msgdef = fields.get("message_definition", b"").decode()
            if cid not in self.connections:
                self.connections[cid] = SalvagedConnection(cid, topic, msgtype, msgdef, "msg")
        elif op == 0x02:  # message data
            cid = int(_U32.unpack(header["conn"])[0])
            sec, nsec = struct.unpack("<II", header["time"])
            payload = bytes(data.take(data.left())) if wanted is None or cid in wanted else b""
            return cid, sec * 1_000_000_000 + nsec, payload
        return None

    def _scan_ros1(self, wanted: Collection[int] | None) -> Iterator[Message]:
        self.reason = None
        indexed = False
        with self.path.open("rb") as fh:
            if fh.readline() != ROS1_MAGIC:
                raise SalvageError("not a ROS 1 bag (version 2.0)")
            while True:
                pos = fh.tell()
                raw = fh.read(4)
                if not raw:
                    if not indexed:
                        self.reason = "the bag ends without its index"
                    return
                header_bytes = _read_at_most(fh, int(_U32.unpack(raw)[0])) if len(raw) == 4 else b""
                size_raw = fh.read(4)
                if len(size_raw) < 4:
                    self.reason = f"the bag ends inside a record at byte {pos}"
                    return
                try:
                    header = self._ros1_fields(_Buf(header_bytes))
                except _TruncatedError:
                    self.reason = f"the record at byte {pos} is corrupt"
                    return
                size = int(_U32.unpack(size_raw)[0])
                data = _read_at_most(fh, size)
                cut = len(data) < size
                op = header.get("op", b"\x00")[0]
                if op == 0x05:  # chunk
                    compression = header.get("compression", b"none").decode()
                    yield from self._ros1_chunk(data, compression, wanted, cut, pos)
                    if cut:
                        self.reason = self.reason or f"the bag ends inside a chunk at byte {pos}"
                        return
                    continue
                if cut:
                    self.reason = f"the bag ends inside a record at byte {pos}"
                    return
                if op in (0x04, 0x06):  # index data and chunk info: the index, after the data
                    indexed = indexed or op == 0x06
                    continue
                try:
                    msg = self._ros1_record(header, _Buf(data), wanted)
                except (_TruncatedError, KeyError, struct.error):
                    self.reason = f"the record at byte {pos} is corrupt"
                    return
                if msg is not None:
                    yield msg

    def _ros1_chunk(
        self, data: bytes, compression: str, wanted: Collection[int] | None, cut: bool, pos: int
    ) -> Iterator[Message]:

        def record(inner: _Buf) -> Message | None:
            header = self._ros1_fields(_Buf(inner.take(inner.u32())))
            return self._ros1_record(header, _Buf(inner.take(inner.u32())), wanted)

        yield from self._chunk(data, compression, record, (_TruncatedError, KeyError, struct.error), cut, pos)
