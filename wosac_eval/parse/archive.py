"""Submission files: what their bytes are, and their shards read from them safely and streaming.

A submission file is a single shard (any name; `.binproto` by convention),
optionally gzip/bzip2/xz-compressed as a whole (`submission.binproto.gz`), or
a tar archive, plain or compressed (`.tar`, `.tar.gz`, `.tgz`, ...) whose
regular members whose name contains ".binproto" are the shards, in archive
order. (A folder of shards is walked by `parse.shard_walk`.)

Which names are shards, skipped or refused: `parse.member_names`. What a file's
bytes are (sniffed, whatever its name says) and their decompressed stream:
`parse.decompress`. This module walks a tar stream member by member.

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

import dataclasses
import os
import re
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import BinaryIO, Union

from wosac_eval.parse.decompress import (
    CHUNK_BYTES,
    STREAM_ERRORS,
    LimitedStream,
    drain,
    open_limited,
    sniff,
)
from wosac_eval.parse.errors import ArchiveError, SizeLimitError, UnsafeArchiveMemberError
from wosac_eval.parse.limits import InputLimits
from wosac_eval.parse.member_names import (
    SHARD_NAME_MARKER,
    is_ignored_name,
    is_shard_name,
    not_a_shard_message,
    safe_member_name,
)
from wosac_eval.parse.shards import HEAD_BYTES, looks_like_submission
from wosac_eval.parse.tar_format import (
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

_MEMBER_DATA_ERRORS: tuple[type[Exception], ...] = (TruncatedDataError, *STREAM_ERRORS)


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
    except STREAM_ERRORS as error:
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
    except STREAM_ERRORS as error:
        where = f"after member {last_member!r}" if last_member else "at its start"
        raise ArchiveError(f"{archive}: truncated or corrupt archive {where}: {error}") from error


def _iter_members(
    archive: Path, stream: LimitedStream, limits: InputLimits
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


def iter_archive_shards(path: Path, compression: str | None, limits: InputLimits) -> Iterator[tuple[str, bytes]]:
    """(name, bytes) of every shard of a (possibly compressed) tar file, streamed member by member."""
    source, stream = open_limited(path, compression, limits)
    with source:
        for tar, name, member in _iter_members(path, stream, limits):
            yield name, _read_member_data(tar, path, name, member.size)
        if compression is not None:
            drain(stream, path)


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
        except STREAM_ERRORS as error:
            raise _data_error(self._archive, self.name, error) from error
        self.position += len(data)
        if (len(data) != size) if whole else (size > 0 and not data):
            raise _truncated(self._archive, self.name, self.position, self.size)
        return data

    def skip(self, size: int) -> None:
        """Read past the next `size` bytes, a bounded piece at a time."""
        while size > 0:
            size -= len(self.read1(min(size, CHUNK_BYTES)))


def iter_archive_members(path: Path, compression: str | None, limits: InputLimits) -> Iterator[MemberReader]:
    """A `MemberReader` for every shard of a (possibly compressed) tar file, in order: the same walk and
    errors as `iter_archive_shards`, but a member's bytes are read in pieces by whoever takes it (before
    the next one is asked for), so that no shard is held whole."""
    source, stream = open_limited(path, compression, limits)
    with source:
        for tar, name, member in _iter_members(path, stream, limits):
            yield MemberReader(tar, path, name, member.size)
        if compression is not None:
            drain(stream, path)


# --------------------------------------------------------------------------- single files


def plain_shard_size(path: Path, limits: InputLimits) -> int:
    """The size of an uncompressed single shard file, refused past the per-member limit."""
    size = path.stat().st_size
    if size > limits.max_member_bytes:
        raise SizeLimitError(
            f"{path}: shard is {size} bytes, over the per-member limit of {limits.max_member_bytes} bytes"
        )
    return size


def open_single_shard(path: Path, compression: str, limits: InputLimits) -> tuple[BinaryIO, LimitedStream]:
    """A compressed single shard's decompressed bytes, bounded by the per-member limit too."""
    source, stream = open_limited(path, compression, limits)
    stream.member = path.name
    if limits.max_member_bytes < stream.limit:
        stream.limit, stream.limit_name = limits.max_member_bytes, "max_member_bytes"
    return source, stream


def read_compressed_shard(path: Path, compression: str, limits: InputLimits) -> tuple[str, bytes]:
    """(name without the compression suffix, bytes) of a single shard compressed as a whole."""
    source, stream = open_single_shard(path, compression, limits)
    try:
        with source:
            data = stream.read()
    except STREAM_ERRORS as error:
        raise ArchiveError(f"{path}: truncated or corrupt {compression} stream: {error}") from error
    return re.sub(r"\.(gz|bz2|xz)$", "", path.name, flags=re.IGNORECASE), data


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
    compression, head = sniff(path)
    is_tar = is_tar_header(head)
    if not is_tar:  # one shard: its first field, and for a compressed one its size as it decompresses
        if compression is None:
            size = plain_shard_size(path, limits)
            looks_like_submission(str(path), head)
            return ContainerSummary(None, False, 1, size)
        looks_like_submission(str(path), head)
        source, stream = open_single_shard(path, compression, limits)
        with source:
            drain(stream, path)
        return ContainerSummary(compression, False, 1, stream.bytes_read)
    source, stream = open_limited(path, compression, limits)
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
            drain(stream, path)
    return ContainerSummary(compression, True, shards, stream.bytes_read)
