"""Streaming reader and writer of TFRecord files, without TensorFlow.

A TFRecord file is a sequence of records, each framed as

    uint64 length (little endian) | uint32 masked CRC32C of those 8 bytes
    | `length` bytes of data      | uint32 masked CRC32C of the data

Files whose name ends in ``.gz`` are read and written gzip-compressed (the
whole stream, as TensorFlow's ``compression_type="GZIP"`` does); offsets then
count bytes of the decompressed stream. The name decides, not the content:
the first bytes of a plain TFRecord can look like a gzip header.

Records are read one at a time, so memory use is bounded by the largest
record, never by the file size.
"""

from __future__ import annotations

import gzip
import os
import struct
import zlib
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import BinaryIO, NamedTuple

import google_crc32c

from wosac_eval.parse.errors import CorruptRecordError, ParseError

_LENGTH = struct.Struct("<Q")
_CRC = struct.Struct("<I")
HEADER_BYTES = _LENGTH.size + _CRC.size  # 12
FOOTER_BYTES = _CRC.size  # 4

# A real WOMD scenario is a few MiB; a length above this is corruption (or an
# attack) and must not become a giant allocation.
DEFAULT_MAX_RECORD_BYTES = 1 << 30

_MASK_DELTA = 0xA282EAD8
_READ_CHUNK_BYTES = 16 << 20


class Record(NamedTuple):
    """One record's data and the byte offset of its header in the (decompressed) file."""

    offset: int
    data: bytes


def masked_crc32c(data: bytes) -> int:
    """The CRC32C of data, rotated and offset as the TFRecord format stores it."""
    crc = google_crc32c.value(data)
    return (((crc >> 15) | (crc << 17)) + _MASK_DELTA) & 0xFFFFFFFF


def looks_like_tfrecord(head: bytes) -> bool:
    """True when head (a file's first bytes) starts with a TFRecord header: a length and its masked CRC."""
    if len(head) < HEADER_BYTES:
        return False
    return _CRC.unpack_from(head, _LENGTH.size)[0] == masked_crc32c(head[: _LENGTH.size])


def is_gzip_path(path: str | os.PathLike[str]) -> bool:
    """True when the file is to be read and written gzip-compressed."""
    return str(path).endswith(".gz")


def _open_for_reading(path: Path) -> BinaryIO:
    """Open path for binary reading, decompressing .gz files on the fly."""
    if is_gzip_path(path):
        return gzip.open(path, "rb")  # type: ignore[return-value]
    return open(path, "rb")


def _read_exactly(stream: BinaryIO, size: int, path: Path, offset: int, what: str) -> bytes:
    """Read size bytes, or raise CorruptRecordError naming what was cut short."""
    # Read in bounded chunks: a CRC-valid but lying length must not make us
    # allocate its full size before we find out the file is shorter.
    chunks, remaining = [], size
    try:
        while remaining and (chunk := stream.read(min(remaining, _READ_CHUNK_BYTES))):
            chunks.append(chunk)
            remaining -= len(chunk)
    except (EOFError, OSError, zlib.error) as error:  # broken or truncated gzip stream
        raise CorruptRecordError(path, offset, f"cannot read {what}: {error}") from error
    data = chunks[0] if len(chunks) == 1 else b"".join(chunks)
    if len(data) != size:
        raise CorruptRecordError(path, offset, f"file truncated: {what} needs {size} bytes, only {len(data)} left")
    return data


def _read_header(stream: BinaryIO, path: Path, offset: int, max_record_bytes: int) -> int | None:
    """The data length of the record at offset, or None at a clean end of file."""
    try:
        header = stream.read(HEADER_BYTES)
    except (EOFError, OSError, zlib.error) as error:
        raise CorruptRecordError(path, offset, f"cannot read record header: {error}") from error
    if not header:
        return None
    if len(header) != HEADER_BYTES:
        raise CorruptRecordError(
            path,
            offset,
            f"file truncated: record header needs {HEADER_BYTES} bytes, only {len(header)} left",
        )
    length_bytes, crc_bytes = header[: _LENGTH.size], header[_LENGTH.size :]
    if masked_crc32c(length_bytes) != _CRC.unpack(crc_bytes)[0]:
        raise CorruptRecordError(path, offset, "length field fails its CRC32C check")
    (length,) = _LENGTH.unpack(length_bytes)
    if length > max_record_bytes:
        raise CorruptRecordError(path, offset, f"record length {length} exceeds the limit of {max_record_bytes} bytes")
    return length


def _read_one(stream: BinaryIO, path: Path, offset: int, max_record_bytes: int) -> bytes | None:
    """The data of the record at offset (CRC-checked), or None at end of file."""
    length = _read_header(stream, path, offset, max_record_bytes)
    if length is None:
        return None
    data = _read_exactly(stream, length, path, offset, "record data")
    footer = _read_exactly(stream, FOOTER_BYTES, path, offset, "record data CRC")
    if masked_crc32c(data) != _CRC.unpack(footer)[0]:
        raise CorruptRecordError(path, offset, "record data fails its CRC32C check")
    return data


def iter_records(path: str | os.PathLike[str], *, max_record_bytes: int = DEFAULT_MAX_RECORD_BYTES) -> Iterator[Record]:
    """Yield every record of a TFRecord file with its byte offset, in file order.

    Raises CorruptRecordError (a ParseError) naming the file and offset of the
    first record that is truncated or fails a CRC check; FileNotFoundError and
    other OSErrors from opening the file pass through unchanged.
    """
    path = Path(path)
    with _open_for_reading(path) as stream:
        offset = 0
        while (data := _read_one(stream, path, offset, max_record_bytes)) is not None:
            yield Record(offset, data)
            offset += HEADER_BYTES + len(data) + FOOTER_BYTES


def read_records(path: str | os.PathLike[str], *, max_record_bytes: int = DEFAULT_MAX_RECORD_BYTES) -> Iterator[bytes]:
    """Yield the data of every record of a TFRecord file, in file order.

    Same checks and errors as iter_records; use that when offsets are needed.
    """
    for record in iter_records(path, max_record_bytes=max_record_bytes):
        yield record.data


def read_record_at(
    path: str | os.PathLike[str],
    offset: int,
    *,
    max_record_bytes: int = DEFAULT_MAX_RECORD_BYTES,
) -> bytes:
    """The data of the one record whose header starts at offset (from iter_records).

    For .gz files the seek decompresses from the start of the file, so random
    access there costs a pass over the preceding bytes.
    """
    path = Path(path)
    with _open_for_reading(path) as stream:
        try:
            stream.seek(offset)
        except (EOFError, OSError, zlib.error) as error:
            raise CorruptRecordError(path, offset, f"cannot seek to record: {error}") from error
        data = _read_one(stream, path, offset, max_record_bytes)
    if data is None:
        raise CorruptRecordError(path, offset, "no record starts here (end of file)")
    return data


def frame_record(data: bytes) -> bytes:
    """The bytes of one TFRecord-framed record holding data."""
    length_bytes = _LENGTH.pack(len(data))
    return b"".join(
        (
            length_bytes,
            _CRC.pack(masked_crc32c(length_bytes)),
            data,
            _CRC.pack(masked_crc32c(data)),
        )
    )


def write_records(path: str | os.PathLike[str], records: Iterable[bytes]) -> int:
    """Write records to a TFRecord file (gzip-compressed if path ends in .gz).

    The file is written under a temporary name and renamed into place, so a
    failure never leaves a half-written file at path. Returns the record count.
    """
    path = Path(path)
    partial = path.with_name(f".{path.name}.partial-{os.getpid()}")
    count = 0
    try:
        opener = gzip.open if is_gzip_path(path) else open
        with opener(partial, "wb") as stream:
            for data in records:
                if not isinstance(data, (bytes, bytearray, memoryview)):
                    raise TypeError(f"record {count} is {type(data).__name__}, not bytes")
                stream.write(frame_record(bytes(data)))
                count += 1
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)
    return count


__all__ = [
    "CorruptRecordError",
    "ParseError",
    "Record",
    "frame_record",
    "iter_records",
    "masked_crc32c",
    "read_record_at",
    "read_records",
    "write_records",
]
