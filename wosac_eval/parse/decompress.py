"""A submission file's bytes: what they are, sniffed from their first bytes, and their decompressed stream,
read a chunk at a time under a limit.

The content decides the format, not the name: magic bytes are sniffed, and a
name that lies (a plain tar named .tar.gz, an archive named .binproto) gives an
`ArchiveNameWarning` and is read as what it is. A name promising an archive on
bytes that are neither tar nor compressed is an error. Zip archives are refused.

A file compressed with gzip, bzip2 or xz is decompressed on the fly, never to
disk; gzip by ISA-L's inflate when it is installed (`FastGzipFile`: zlib takes
over at the first damaged byte, so the bytes before it are delivered as zlib's
reader delivers them). `LimitedStream` counts what is read and stops past the
limit it is given (`parse.limits.InputLimits`: the total, or for a compressed
file at most `max_compression_ratio` times its size).
"""

from __future__ import annotations

import bz2
import gzip
import io
import lzma
import zlib
from pathlib import Path
from typing import Any, BinaryIO, cast

from wosac_eval.parse.errors import ArchiveError, SizeLimitError
from wosac_eval.parse.limits import InputLimits
from wosac_eval.parse.tar_format import BLOCK, is_tar_header

CHUNK_BYTES = 1 << 20  # what a stream is read by
_SNIFF_BYTES = BLOCK  # one tar header

# Errors the decompressors raise on broken or truncated input.
STREAM_ERRORS: tuple[type[Exception], ...] = (OSError, EOFError, zlib.error, lzma.LZMAError)
igzip: Any = None
try:  # ISA-L's inflate (the `isal` dependency): the same bytes as zlib's, about twice as fast (docs/speed.md)
    from isal import igzip, isal_zlib

    STREAM_ERRORS += (cast("type[Exception]", isal_zlib.error),)
except ImportError:  # installed without its dependencies: zlib's alone
    pass

_COMPRESSION_MAGIC = {
    b"\x1f\x8b": "gzip",
    b"BZh": "bzip2",
    b"\xfd7zXZ\x00": "xz",
}
_OPENERS = {"gzip": gzip.GzipFile, "bzip2": bz2.BZ2File, "xz": lzma.LZMAFile}


class FastGzipFile(io.BufferedIOBase):
    """A gzip file inflated by ISA-L until its first error, then by zlib from where ISA-L stopped.

    ISA-L gives nothing of a deflate block it cannot finish, where zlib gives every byte it can: at a cut
    or damaged place zlib's reader delivers the intact bytes before it, then raises (every shard before
    the damage is read, as from a plain `gzip.GzipFile`). Intact files are read by ISA-L alone.
    """

    def __init__(self, path: Path) -> None:
        self._path = path
        self._file: Any = igzip.GzipFile(path, "rb")
        self._fast = True
        self._inflated = 0  # bytes delivered so far

    def readable(self) -> bool:
        return True

    def read(self, size: int | None = -1) -> bytes:
        return self._guarded("read", -1 if size is None else size)

    def read1(self, size: int = -1) -> bytes:
        return self._guarded("read1", size)

    def close(self) -> None:
        self._file.close()
        super().close()

    def _guarded(self, method: str, size: int) -> bytes:
        try:
            data = getattr(self._file, method)(size)
        except STREAM_ERRORS:
            if not self._fast:
                raise
            self._to_zlib()
            return self._guarded(method, size)
        self._inflated += len(data)
        return data

    def _to_zlib(self) -> None:
        """zlib's reader in ISA-L's place, past the bytes ISA-L delivered (zlib raises where the damage is)."""
        self._file.close()
        self._file, self._fast = gzip.GzipFile(self._path, "rb"), False
        left = self._inflated
        while left:
            piece = self._file.read(min(left, CHUNK_BYTES))
            if not piece:
                raise EOFError("the gzip stream ended before the bytes already read")
            left -= len(piece)


_ZIP_MAGIC = b"PK\x03\x04"


class ArchiveNameWarning(UserWarning):
    """A submission file whose name claims another format than its bytes show."""


class UncompressedTarWarning(UserWarning):
    """A plain tar where the challenge server expects a gzip-compressed one (told only to a report)."""


# --------------------------------------------------------------------------- sniffing


def _compression_of(head: bytes) -> str | None:
    """'gzip', 'bzip2' or 'xz' from the first bytes of a stream, else None."""
    for magic, kind in _COMPRESSION_MAGIC.items():
        if head.startswith(magic):
            return kind
    return None


def _claimed_format(name: str) -> str | None:
    """The format a file name promises: 'tar', 'tar.gz', 'compressed' or None."""
    lower = name.lower()
    if lower.endswith((".tar.gz", ".tgz", ".tar.bz2", ".tbz2", ".tbz", ".tar.xz", ".txz")):
        return "compressed tar"
    if lower.endswith(".tar"):
        return "tar"
    if lower.endswith((".gz", ".bz2", ".xz")):
        return "compressed"
    return None


def _describe(compression: str | None, is_tar: bool) -> str:
    """Human description of what the bytes are."""
    if is_tar:
        return f"{compression}-compressed tar" if compression else "uncompressed tar"
    return f"{compression}-compressed single shard" if compression else "single shard"


def name_notice(path: Path, compression: str | None, is_tar: bool) -> ArchiveNameWarning | None:
    """The warning for a name that lies about the content (None when it tells the truth); a promised
    archive that is not one is refused."""
    claimed = _claimed_format(path.name)
    actual = _describe(compression, is_tar)
    if claimed is None:
        if is_tar:
            return ArchiveNameWarning(f"{path}: the name does not say so, but this is a {actual}; reading it as one")
        return None
    if compression is None and not is_tar:
        raise ArchiveError(
            f"{path}: named like a {claimed} archive but is neither tar nor gzip/bzip2/xz "
            "(truncated or not an archive?); a single shard should be named *.binproto"
        )
    matches = {
        "compressed tar": compression is not None and is_tar,
        "tar": compression is None and is_tar,
        "compressed": compression is not None,
    }[claimed]
    if not matches:
        return ArchiveNameWarning(f"{path}: the name says {claimed}, but this is a {actual}; reading it as a {actual}")
    return None


def uncompressed_tar_notice(path: Path) -> UncompressedTarWarning | None:
    """The challenge server expects a gzip-compressed tar: a notice for a plain `.tar`."""
    if not path.name.lower().endswith(".tar"):
        return None
    return UncompressedTarWarning(
        f"{path}: an uncompressed tar; the challenge server expects a gzip-compressed "
        "tar (tar czf submission.tar.gz ...)"
    )


# --------------------------------------------------------------------------- streams


class LimitedStream:
    """A read-only stream over a (decompressing) source that counts the bytes read.

    Raises SizeLimitError once more than `limit` bytes were read, naming the
    member being read at the time (kept up to date by the tar reader). The
    source is read a chunk at a time, so the tar reader's small reads cost what
    plain decompression does (one decompressor call per chunk, not per header).
    A chunk is what one `read1` gives: whatever decompresses from the next piece
    of input, so the bytes before a damaged or truncated part of a compressed
    file are all delivered before its error is raised.
    """

    def __init__(self, archive: Path, source: BinaryIO, limit: int, limit_name: str = "max_total_bytes") -> None:
        self.archive, self._source, self.limit, self.limit_name = archive, source, limit, limit_name
        self.bytes_read = 0
        self.member = "(archive header)"
        self._chunk, self._pos = b"", 0
        self._read_chunk = getattr(source, "read1", source.read)

    def read(self, size: int = -1) -> bytes:
        if size is None or size < 0:  # read to the end, a bounded chunk at a time
            return b"".join(iter(lambda: self.read(CHUNK_BYTES), b""))
        if self._pos >= len(self._chunk):
            self._chunk, self._pos = self._read_chunk(max(size, CHUNK_BYTES)), 0
        data = self._chunk[self._pos : self._pos + size]
        self._pos += len(data)
        self.bytes_read += len(data)
        if self.bytes_read > self.limit:
            if self.limit_name == "max_member_bytes":  # a single compressed shard (`archive.open_single_shard`)
                raise SizeLimitError(
                    f"{self.archive}: shard decompresses to more than the per-member limit of {self.limit} bytes"
                )
            raise SizeLimitError(
                f"{self.archive}: decompresses to more than the total limit of {self.limit} bytes "
                f"(while reading member {self.member!r}; limit {self.limit_name}); raise it if this is genuine"
            )
        return data


def open_decompressed(path: Path, compression: str | None) -> BinaryIO:
    """The file's bytes, decompressed on the fly when compression is set."""
    if compression is None:
        return open(path, "rb")
    if compression == "gzip" and igzip is not None:
        return FastGzipFile(path)  # type: ignore[return-value]
    return _OPENERS[compression](path, "rb")


def sniff(path: Path) -> tuple[str | None, bytes]:
    """(compression, first decompressed bytes) of a file, refusing zip archives."""
    with open(path, "rb") as raw:
        head = raw.read(_SNIFF_BYTES)
    if head.startswith(_ZIP_MAGIC):
        raise ArchiveError(f"{path}: zip archives are not supported; package shards as .tar or .tar.gz")
    compression = _compression_of(head)
    if compression is None:
        return None, head
    try:
        with open_decompressed(path, compression) as stream:
            return compression, stream.read(_SNIFF_BYTES)
    except STREAM_ERRORS as error:
        raise ArchiveError(f"{path}: broken {compression} stream at its start: {error}") from error


def drain(stream: LimitedStream, archive: Path) -> None:
    """Read a compressed stream to its end so its trailer (CRC, size) gets checked."""
    try:
        while stream.read(CHUNK_BYTES):
            pass
    except SizeLimitError:
        raise
    except STREAM_ERRORS as error:
        raise ArchiveError(
            f"{archive}: compressed stream is truncated or corrupt after member {stream.member!r}: {error}"
        ) from error


def open_limited(path: Path, compression: str | None, limits: InputLimits) -> tuple[BinaryIO, LimitedStream]:
    """The file's decompressed bytes as a stream bounded by the total limit (the ratio one for compressed files)."""
    source = open_decompressed(path, compression)
    budget, name = limits.total_bytes_for(None if compression is None else path.stat().st_size)
    return source, LimitedStream(path, source, budget, name)


def sniff_file(path: Path) -> tuple[str | None, bool, ArchiveNameWarning | None]:
    """(compression, is a tar, the warning its name deserves) of a submission file, from its bytes."""
    compression, head = sniff(path)
    is_tar = is_tar_header(head)
    return compression, is_tar, name_notice(path, compression, is_tar)
