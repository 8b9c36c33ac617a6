"""Submission files: what their bytes are, and their shards read from them safely and streaming.

A submission file is a single shard (any name; `.binproto` by convention),
optionally gzip/bzip2/xz-compressed as a whole (`submission.binproto.gz`), or
a tar archive, plain or compressed (`.tar`, `.tar.gz`, `.tgz`, ...) whose
regular members whose name contains ".binproto" are the shards, in archive
order. (A folder of shards is walked by `parse.submission_source`.)

In archives (and folders), hidden entries (name starting with "."),
`__MACOSX/` and documentation (README*, LICENSE*, NOTICE*, *.md, *.txt, *.rst)
are skipped; any other member is an error, so a mis-named shard is never
silently dropped.

The content decides the format, not the name: magic bytes are sniffed, and a
name that lies (a plain tar named .tar.gz, an archive named .binproto) gives an
`ArchiveNameWarning` and is read as what it is. A name promising an archive on
bytes that are neither tar nor compressed is an error.

Safety: archives are never extracted to disk and never held whole in memory;
one member at a time is read from a decompressing stream. Members with `..`
components or absolute names, symbolic and hard links, devices, FIFOs and other
special types are refused. Expansion is bounded by `InputLimits`
(`parse.limits`): each shard's decompressed size, the archive's total (headers
and skipped members included, and for a compressed file at most
`max_compression_ratio` times its size), the number of members, and the number
of messages of a shard, counted on the wire before it is parsed. Every failure
is a `ParseError` subclass naming the archive and member.

`check_container(path, limits)` applies the same rules without keeping any
member: the service calls it on an upload before accepting it.
"""

from __future__ import annotations

import bz2
import dataclasses
import gzip
import io
import lzma
import os
import re
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path, PurePosixPath
from typing import Any, BinaryIO, Union, cast

from wosac_eval.parse.errors import ArchiveError, SizeLimitError, UnsafeArchiveMemberError
from wosac_eval.parse.limits import InputLimits
from wosac_eval.parse.shards import HEAD_BYTES, looks_like_submission
from wosac_eval.parse.tar_format import (
    BLOCK,
    DEVICE_TYPES,
    FIFO_TYPE,
    HARD_LINK_TYPE,
    SYMLINK_TYPE,
    TarFormatError,
    TarMember,
    TarStreamReader,
    TruncatedDataError,
    TruncatedTarError,
    is_tar_header,
)

PathLike = Union[str, "os.PathLike[str]"]

SHARD_NAME_MARKER = ".binproto"
_DOC_PREFIXES = ("README", "LICENSE", "LICENCE", "NOTICE", "CHANGELOG")
_DOC_SUFFIXES = (".md", ".txt", ".rst")
_CHUNK_BYTES = 1 << 20
_SNIFF_BYTES = BLOCK  # one tar header

# Errors the decompressors raise on broken or truncated input.
_STREAM_ERRORS: tuple[type[Exception], ...] = (OSError, EOFError, zlib.error, lzma.LZMAError)
igzip: Any = None
try:  # ISA-L's inflate (the `isal` dependency): the same bytes as zlib's, about twice as fast (docs/speed.md)
    from isal import igzip, isal_zlib

    _STREAM_ERRORS += (cast("type[Exception]", isal_zlib.error),)
except ImportError:  # installed without its dependencies: zlib's alone
    pass

_MEMBER_DATA_ERRORS: tuple[type[Exception], ...] = (TruncatedDataError, *_STREAM_ERRORS)

_COMPRESSION_MAGIC = {
    b"\x1f\x8b": "gzip",
    b"BZh": "bzip2",
    b"\xfd7zXZ\x00": "xz",
}
_OPENERS = {"gzip": gzip.GzipFile, "bzip2": bz2.BZ2File, "xz": lzma.LZMAFile}


class _FastGzipFile(io.BufferedIOBase):
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
        except _STREAM_ERRORS:
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
            piece = self._file.read(min(left, _CHUNK_BYTES))
            if not piece:
                raise EOFError("the gzip stream ended before the bytes already read")
            left -= len(piece)


_ZIP_MAGIC = b"PK\x03\x04"


class ArchiveNameWarning(UserWarning):
    """A submission file whose name claims another format than its bytes show."""


class UncompressedTarWarning(UserWarning):
    """A plain tar where the challenge server expects a gzip-compressed one (told only to a report)."""


# --------------------------------------------------------------------------- names


def is_shard_name(name: str) -> bool:
    """True for a file or member name that holds a submission shard."""
    return SHARD_NAME_MARKER in PurePosixPath(name).name


def is_ignored_name(name: str) -> bool:
    """True for hidden entries, macOS resource forks and documentation."""
    parts = PurePosixPath(name).parts
    base = parts[-1] if parts else ""
    if any(part.startswith(".") or part == "__MACOSX" for part in parts):
        return True
    return base.upper().startswith(_DOC_PREFIXES) or base.lower().endswith(_DOC_SUFFIXES)


def not_a_shard_message(container: object, name: str) -> str:
    """Why a file of a folder or a member of an archive is refused: it is neither a shard nor documentation."""
    return (
        f"{container}: {name!r} is neither a submission shard (a name containing {SHARD_NAME_MARKER!r}) "
        "nor documentation (README*, *.md, *.txt); rename or remove it"
    )


def safe_member_name(archive: object, name: str) -> str:
    """The member name normalized to 'a/b/c', refusing names that could escape.

    Refused: empty names, NUL bytes, absolute paths (/x, \\x, C:x) and any
    '..' component (with / or \\ as separator).
    """
    if not name or "\x00" in name:
        raise UnsafeArchiveMemberError(f"{archive}: member with an empty or NUL-containing name")
    if name.startswith(("/", "\\")) or re.match(r"^[A-Za-z]:", name):
        raise UnsafeArchiveMemberError(f"{archive}: member {name!r} has an absolute path")
    parts = [part for part in re.split(r"[/\\]", name) if part not in ("", ".")]
    if ".." in parts:
        raise UnsafeArchiveMemberError(f"{archive}: member {name!r} has a '..' component (would escape the archive)")
    return "/".join(parts)


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


class _LimitedStream:
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
            return b"".join(iter(lambda: self.read(_CHUNK_BYTES), b""))
        if self._pos >= len(self._chunk):
            self._chunk, self._pos = self._read_chunk(max(size, _CHUNK_BYTES)), 0
        data = self._chunk[self._pos : self._pos + size]
        self._pos += len(data)
        self.bytes_read += len(data)
        if self.bytes_read > self.limit:
            if self.limit_name == "max_member_bytes":  # a single compressed shard (`_open_single_shard`)
                raise SizeLimitError(
                    f"{self.archive}: shard decompresses to more than the per-member limit of {self.limit} bytes"
                )
            raise SizeLimitError(
                f"{self.archive}: decompresses to more than the total limit of {self.limit} bytes "
                f"(while reading member {self.member!r}; limit {self.limit_name}); raise it if this is genuine"
            )
        return data


def _open_decompressed(path: Path, compression: str | None) -> BinaryIO:
    """The file's bytes, decompressed on the fly when compression is set."""
    if compression is None:
        return open(path, "rb")
    if compression == "gzip" and igzip is not None:
        return _FastGzipFile(path)  # type: ignore[return-value]
    return _OPENERS[compression](path, "rb")


def _sniff(path: Path) -> tuple[str | None, bytes]:
    """(compression, first decompressed bytes) of a file, refusing zip archives."""
    with open(path, "rb") as raw:
        head = raw.read(_SNIFF_BYTES)
    if head.startswith(_ZIP_MAGIC):
        raise ArchiveError(f"{path}: zip archives are not supported; package shards as .tar or .tar.gz")
    compression = _compression_of(head)
    if compression is None:
        return None, head
    try:
        with _open_decompressed(path, compression) as stream:
            return compression, stream.read(_SNIFF_BYTES)
    except _STREAM_ERRORS as error:
        raise ArchiveError(f"{path}: broken {compression} stream at its start: {error}") from error


# --------------------------------------------------------------------------- tar


def _check_member_type(archive: Path, name: str, member: TarMember) -> None:
    """Refuse links, devices, FIFOs, sparse files and every type that is not a file or folder."""
    if member.type == SYMLINK_TYPE:
        raise UnsafeArchiveMemberError(f"{archive}: member {name!r} is a symbolic link")
    if member.type == HARD_LINK_TYPE:
        raise UnsafeArchiveMemberError(f"{archive}: member {name!r} is a hard link")
    if member.type in DEVICE_TYPES:
        raise UnsafeArchiveMemberError(f"{archive}: member {name!r} is a device file")
    if member.type == FIFO_TYPE:
        raise UnsafeArchiveMemberError(f"{archive}: member {name!r} is a FIFO")
    if member.sparse:
        raise UnsafeArchiveMemberError(f"{archive}: member {name!r} is a sparse file (unsupported type)")
    if not (member.is_file or member.is_dir):
        raise UnsafeArchiveMemberError(f"{archive}: member {name!r} has an unsupported type {member.type!r}")


def _truncated(archive: Path, name: str, got: int, size: int) -> ArchiveError:
    """The error of a member whose data end before its size."""
    return ArchiveError(f"{archive}: member {name!r} is truncated ({got} of {size} bytes)")


def _data_error(archive: Path, name: str | None, error: Exception) -> ArchiveError:
    """The error of a member whose data end early or do not decompress."""
    return ArchiveError(f"{archive}: truncated or corrupt data in member {name!r}: {error}")


def _read_member_data(tar: TarStreamReader, archive: Path, name: str, size: int) -> bytes:
    """The first `size` bytes of the current member's data (it must have them)."""
    try:
        data = tar.read_data(size)
    except _STREAM_ERRORS as error:
        raise _data_error(archive, name, error) from error
    if len(data) != size:
        raise _truncated(archive, name, len(data), size)
    return data


def _next_member(tar: TarStreamReader, archive: Path, last_member: str | None) -> TarMember | None:
    """The next member header; None at a clean end. Stream and format errors become ArchiveError."""
    after = f"after member {last_member!r}" if last_member else "before the first member"
    try:
        return tar.next_member()
    except TruncatedDataError as error:
        raise _data_error(archive, last_member, error) from error
    except TruncatedTarError as error:
        raise ArchiveError(
            f"{archive}: truncated tar archive (ends {after} without an end-of-archive block)"
        ) from error
    except TarFormatError as error:
        raise ArchiveError(f"{archive}: corrupt tar header {after}: {error}") from error
    except _STREAM_ERRORS as error:
        where = f"after member {last_member!r}" if last_member else "at its start"
        raise ArchiveError(f"{archive}: truncated or corrupt archive {where}: {error}") from error


def _iter_members(
    archive: Path, stream: _LimitedStream, limits: InputLimits
) -> Iterator[tuple[TarStreamReader, str, TarMember]]:
    """(reader, name, header) of every shard member of a tar stream, in order, after every check
    that needs no member data: safe names and types, stray files, duplicates, the member count and
    the declared sizes against the limits. The reader skips whatever of a member's data was not read."""
    tar = TarStreamReader(stream.read)
    seen: set[str] = set()
    last_member: str | None = None
    members = 0
    while (member := _next_member(tar, archive, last_member)) is not None:
        members += 1
        if members > limits.max_members:
            raise SizeLimitError(f"{archive}: more than max_members={limits.max_members} archive members")
        name = safe_member_name(archive, member.name)
        _check_member_type(archive, name, member)
        last_member = stream.member = name
        if member.is_dir or is_ignored_name(name):
            continue
        if not is_shard_name(name):
            raise ArchiveError(not_a_shard_message(archive, name))
        if name in seen:
            raise ArchiveError(f"{archive}: member {name!r} appears twice")
        seen.add(name)
        if member.size > limits.max_member_bytes:
            raise SizeLimitError(
                f"{archive}: member {name!r} is {member.size} bytes, over the per-member "
                f"limit of {limits.max_member_bytes} bytes"
            )
        if stream.bytes_read + member.size > stream.limit:  # refused on its header, before any byte
            raise SizeLimitError(
                f"{archive}: member {name!r} is {member.size} bytes: the archive would decompress to more "
                f"than the total limit of {stream.limit} bytes (limit {stream.limit_name})"
            )
        yield tar, name, member
    if not seen:
        raise ArchiveError(
            f"{archive}: archive holds no submission shard (no member name containing {SHARD_NAME_MARKER!r})"
        )


def _drain(stream: _LimitedStream, archive: Path) -> None:
    """Read a compressed stream to its end so its trailer (CRC, size) gets checked."""
    try:
        while stream.read(_CHUNK_BYTES):
            pass
    except SizeLimitError:
        raise
    except _STREAM_ERRORS as error:
        raise ArchiveError(
            f"{archive}: compressed stream is truncated or corrupt after member {stream.member!r}: {error}"
        ) from error


def _open_limited(path: Path, compression: str | None, limits: InputLimits) -> tuple[BinaryIO, _LimitedStream]:
    """The file's decompressed bytes as a stream bounded by the total limit (the ratio one for compressed files)."""
    source = _open_decompressed(path, compression)
    budget, name = limits.total_bytes_for(None if compression is None else path.stat().st_size)
    return source, _LimitedStream(path, source, budget, name)


def iter_archive_shards(path: Path, compression: str | None, limits: InputLimits) -> Iterator[tuple[str, bytes]]:
    """(name, bytes) of every shard of a (possibly compressed) tar file, streamed member by member."""
    source, stream = _open_limited(path, compression, limits)
    with source:
        for tar, name, member in _iter_members(path, stream, limits):
            yield name, _read_member_data(tar, path, name, member.size)
        if compression is not None:
            _drain(stream, path)


class MemberReader:
    """The data of one archive member, read in pieces from the stream (never held whole).

    `read(n)` gives its next `n` bytes (fewer only at its end); a member that ends early raises the
    `ArchiveError` reading it whole would (`_read_member_data`). Moving to the next member skips
    whatever was not read.
    """

    def __init__(self, tar: TarStreamReader, archive: Path, name: str, size: int) -> None:
        self._tar, self._archive, self.name, self.size = tar, archive, name, size
        self.position = 0

    def read(self, size: int) -> bytes:
        return self._take(self._tar.read_data, size, whole=True)

    def read1(self, size: int) -> bytes:
        """Up to `size` of its next bytes, as one read of the stream gives them (a copy loop's pieces: no
        piece is gathered from smaller ones); b'' at its end. A member that ends early raises as `read`."""
        return self._take(self._tar.read_data1, size, whole=False)

    def _take(self, read_data: Callable[[int], bytes], size: int, *, whole: bool) -> bytes:
        """The next bytes by `read_data` (all `size` of them when `whole`, else at least one), at most to the
        member's end; a stream that ends or breaks first is the member's error."""
        size = min(size, self.size - self.position)
        try:
            data = read_data(size)
        except _STREAM_ERRORS as error:
            raise _data_error(self._archive, self.name, error) from error
        self.position += len(data)
        if (len(data) != size) if whole else (size > 0 and not data):
            raise _truncated(self._archive, self.name, self.position, self.size)
        return data

    def skip(self, size: int) -> None:
        """Read past the next `size` bytes, a bounded piece at a time."""
        while size > 0:
            size -= len(self.read1(min(size, _CHUNK_BYTES)))


def iter_archive_members(path: Path, compression: str | None, limits: InputLimits) -> Iterator[MemberReader]:
    """A `MemberReader` for every shard of a (possibly compressed) tar file, in order: the same walk and
    errors as `iter_archive_shards`, but a member's bytes are read in pieces by whoever takes it (before
    the next one is asked for), so that no shard is held whole."""
    source, stream = _open_limited(path, compression, limits)
    with source:
        for tar, name, member in _iter_members(path, stream, limits):
            yield MemberReader(tar, path, name, member.size)
        if compression is not None:
            _drain(stream, path)


# --------------------------------------------------------------------------- single files


def plain_shard_size(path: Path, limits: InputLimits) -> int:
    """The size of an uncompressed single shard file, refused past the per-member limit."""
    size = path.stat().st_size
    if size > limits.max_member_bytes:
        raise SizeLimitError(
            f"{path}: shard is {size} bytes, over the per-member limit of {limits.max_member_bytes} bytes"
        )
    return size


def _open_single_shard(path: Path, compression: str, limits: InputLimits) -> tuple[BinaryIO, _LimitedStream]:
    """A compressed single shard's decompressed bytes, bounded by the per-member limit too."""
    source, stream = _open_limited(path, compression, limits)
    stream.member = path.name
    if limits.max_member_bytes < stream.limit:
        stream.limit, stream.limit_name = limits.max_member_bytes, "max_member_bytes"
    return source, stream


def read_compressed_shard(path: Path, compression: str, limits: InputLimits) -> tuple[str, bytes]:
    """(name without the compression suffix, bytes) of a single shard compressed as a whole."""
    source, stream = _open_single_shard(path, compression, limits)
    try:
        with source:
            data = stream.read()
    except _STREAM_ERRORS as error:
        raise ArchiveError(f"{path}: truncated or corrupt {compression} stream: {error}") from error
    return re.sub(r"\.(gz|bz2|xz)$", "", path.name, flags=re.IGNORECASE), data


def sniff_file(path: Path) -> tuple[str | None, bool, ArchiveNameWarning | None]:
    """(compression, is a tar, the warning its name deserves) of a submission file, from its bytes."""
    compression, head = _sniff(path)
    is_tar = is_tar_header(head)
    return compression, is_tar, name_notice(path, compression, is_tar)


@dataclasses.dataclass(frozen=True)
class ContainerSummary:
    """What `check_container` found: the file's kind and its suffix, its shards and decompressed size."""

    compression: str | None
    is_tar: bool
    shards: int
    decompressed_bytes: int

    @property
    def suffix(self) -> str:
        """The file suffix matching the bytes (".tar.gz", ".tar", ".binproto.xz"...)."""
        ext = {"gzip": ".gz", "bzip2": ".bz2", "xz": ".xz", None: ""}[self.compression]
        return (".tar" if self.is_tar else ".binproto") + ext


def check_container(path: PathLike, limits: InputLimits | None = None) -> ContainerSummary:
    """Check a submission file as the reader will take it, without keeping any member.

    Streams the file once (the cost of decompressing it): sniffing, every member rule (names, types,
    stray files, duplicates, counts, sizes, the compression ratio) and the first bytes of every shard.
    Raises the reader's ParseError subclasses; NotASubmissionError for another kind of file.
    """
    limits = InputLimits() if limits is None else limits
    path = Path(path)
    compression, head = _sniff(path)
    is_tar = is_tar_header(head)
    if not is_tar:  # one shard: its first field, and for a compressed one its size as it decompresses
        if compression is None:
            size = plain_shard_size(path, limits)
            looks_like_submission(str(path), head)
            return ContainerSummary(None, False, 1, size)
        looks_like_submission(str(path), head)
        source, stream = _open_single_shard(path, compression, limits)
        with source:
            _drain(stream, path)
        return ContainerSummary(compression, False, 1, stream.bytes_read)
    source, stream = _open_limited(path, compression, limits)
    shards = 0
    with source:
        for tar, name, member in _iter_members(path, stream, limits):
            head = _read_member_data(tar, path, name, min(HEAD_BYTES, member.size))
            try:  # a member cut short is told as such before its first bytes are judged
                tar.skip_data()
            except _MEMBER_DATA_ERRORS as error:
                raise _data_error(path, name, error) from error
            looks_like_submission(f"{path}: member {name!r}", head)
            shards += 1
        if compression is not None:
            _drain(stream, path)
    return ContainerSummary(compression, True, shards, stream.bytes_read)
