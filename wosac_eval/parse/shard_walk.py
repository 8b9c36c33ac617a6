"""The one walk over a submission: its shards, in order, wherever they are.

A submission is one or more serialized `SimAgentsChallengeSubmission` shards:
a single shard file, a folder of shards (every file below it whose name
contains ".binproto", sorted by relative path; stray files are refused,
hidden entries and documentation skipped), or a tar archive (`parse.archive`).

`iter_shard_refs(path, limits, problems=...)` is the one walk every reader
uses. Its error policy is a parameter: without `problems` the first problem is
raised (a `ParseError` naming file and member); with it, each problem is handed
to `problems` and the walk goes on wherever the format allows (a folder's other
files; nothing after a broken archive member), as validation reports them.
The handle the stages share around it is `parse.submission_source.SubmissionSource`.
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path

from wosac_eval.parse.archive import (
    MemberReader,
    iter_archive_members,
    iter_archive_shards,
    plain_shard_size,
    read_compressed_shard,
)
from wosac_eval.parse.decompress import sniff_file, uncompressed_tar_notice
from wosac_eval.parse.errors import ArchiveError, ParseError, SizeLimitError
from wosac_eval.parse.limits import InputLimits
from wosac_eval.parse.member_names import SHARD_NAME_MARKER, is_ignored_name, is_shard_name, not_a_shard_message

PathLike = str | os.PathLike
# Called with each problem of a reporting walk: a ParseError, or a warning about names.
Problems = Callable[[Exception], None]
SubmissionShard = tuple[str, bytes]
# Where a walk puts an archive member it streams: a file it writes the member to, piece by piece.
MemberFile = Callable[[MemberReader], "ShardRef"]


class NotAShardError(ArchiveError):
    """A file of a submission folder that is neither a shard nor documentation."""


@dataclasses.dataclass(frozen=True)
class ShardRef:
    """Where one shard's bytes are: a byte range of a plain file, or the bytes themselves.

    Shards of a folder or a single uncompressed file are byte ranges: whoever
    scores them (a worker process, a Ray node with the same shared filesystem)
    reads only the bytes it needs. Shards of an archive were decompressed from
    a stream and carry their bytes.

    Attributes:
      name: the shard's name (archive member or path relative to the folder).
      size: its size in bytes.
      path, offset: the file and the offset of the shard's first byte in it.
      data: the shard's bytes, when it is not a byte range of a file.
    """

    name: str
    size: int
    path: str | None = None
    offset: int = 0
    data: bytes | None = None

    def read(self, start: int = 0, end: int | None = None) -> bytes:
        """Bytes `[start, end)` of the shard (all of it by default)."""
        end = self.size if end is None else end
        if self.data is not None:
            return self.data[start:end]
        assert self.path is not None  # a shard is its bytes or a byte range of a file
        with open(self.path, "rb") as f:
            f.seek(self.offset + start)
            data = f.read(end - start)
        if len(data) != end - start:
            raise ArchiveError(
                f"{self.path}: shard {self.name!r} is shorter than when it was listed "
                f"({self.offset + start + len(data)} of {self.offset + end} bytes); "
                "was it modified?"
            )
        return data

    def without_data(self) -> ShardRef:
        """The same shard without the bytes it carries (what to keep while others are read)."""
        return dataclasses.replace(self, data=None) if self.data is not None else self


def _raise(problem: Exception) -> None:
    raise problem


def _notify(problems: Problems | None, notice: Warning | None) -> None:
    """A warning goes to the report when there is one, else to `warnings`."""
    if notice is None:
        return
    if problems is None:
        warnings.warn(notice, stacklevel=4)
    else:
        problems(notice)


# --------------------------------------------------------------------------- folders


def _folder_files(folder: Path, problems: Problems) -> list[tuple[str, Path]]:
    """(relative name, path) of every shard below a folder, sorted; stray files are problems."""
    found: list[tuple[str, Path]] = []

    def unlistable(error: OSError) -> None:  # os.walk would skip such a folder silently
        problems(ArchiveError(f"{folder}: cannot list {error.filename}: {error.strerror}"))

    for root, dirs, files in os.walk(folder, onerror=unlistable):
        dirs[:] = sorted(d for d in dirs if not is_ignored_name(d))
        for file_name in sorted(files):
            path = Path(root) / file_name
            relative = path.relative_to(folder).as_posix()
            if is_ignored_name(relative):
                continue
            if is_shard_name(relative):
                found.append((relative, path))
            else:
                problems(NotAShardError(not_a_shard_message(folder, relative), shard=relative))
    if not found:
        problems(
            ArchiveError(f"{folder}: folder holds no submission shard (no file name containing {SHARD_NAME_MARKER!r})")
        )
    return sorted(found)


def _iter_folder(folder: Path, limits: InputLimits, problems: Problems) -> Iterator[ShardRef]:
    """Shards below a folder, as byte ranges (symlinked files are followed). A shard over the per-member
    limit is a problem and skipped; past the total limit, the rest is not read."""
    total = 0
    for relative, path in _folder_files(folder, problems):
        size = path.stat().st_size
        if size > limits.max_member_bytes:
            problems(
                SizeLimitError(
                    f"{folder}: shard {relative!r} is {size} bytes, over the per-member limit of "
                    f"{limits.max_member_bytes} bytes",
                    shard=relative,
                )
            )
            continue
        total += size
        if total > limits.max_total_bytes:
            problems(
                SizeLimitError(
                    f"{folder}: shards exceed the total limit of {limits.max_total_bytes} bytes "
                    f"at {relative!r}; the remaining shards are not read",
                    shard=relative,
                )
            )
            return
        yield ShardRef(relative, size, path=str(path.resolve()))


# --------------------------------------------------------------------------- files


def _file_shards(
    path: Path, limits: InputLimits, problems: Problems | None, member_file: MemberFile | None = None
) -> Iterator[ShardRef]:
    """Shards of a single shard file or a tar archive (archive members carry their bytes, or with
    `member_file` are copied to a file a piece at a time and given as its byte range).

    What the name deserves is told once the first shard was read (a file that cannot be read at all
    gets its error alone)."""
    compression, is_tar, misnamed = sniff_file(path)
    shards: Iterator[ShardRef]
    if is_tar and member_file is not None:
        shards = (member_file(member) for member in iter_archive_members(path, compression, limits))
    elif is_tar:
        shards = (ShardRef(name, len(data), data=data) for name, data in iter_archive_shards(path, compression, limits))
    elif compression is None:
        shards = iter([ShardRef(path.name, plain_shard_size(path, limits), path=str(path.resolve()))])
    else:
        name, data = read_compressed_shard(path, compression, limits)
        shards = iter([ShardRef(name, len(data), data=data)])
    first = next(shards, None)
    _notify(problems, misnamed)
    if misnamed is None and problems is not None:
        _notify(problems, uncompressed_tar_notice(path))
    if first is None:
        return
    yield first
    del first  # hold no shard while the next one is read
    yield from shards


def _reported(shards: Iterator[ShardRef], problems: Problems) -> Iterator[ShardRef]:
    """The shards of a file until its first problem, which goes to the report (nothing after it is read)."""
    try:
        yield from shards
    except ParseError as error:
        problems(error)


def iter_shard_refs(
    path: PathLike,
    *,
    limits: InputLimits | None = None,
    problems: Problems | None = None,
    member_file: MemberFile | None = None,
) -> Iterator[ShardRef]:
    """Every submission shard found at path, as a `ShardRef`, in order: the one walk.

    Shards of a folder or an uncompressed shard file are byte ranges (nothing
    is read yet); archive members are decompressed one at a time and carry
    their bytes.

    problems: None: the first problem raises (`ParseError` subclasses naming the file and member; a
      misleading name is a `warnings` warning). Else each problem (or warning, including
      `UncompressedTarWarning`) is passed to it and the walk goes on where it can.
    member_file: where archive members go instead of memory: called with each member's reader (before
      the next member is read), it copies the member to a file and returns that byte range.
    Raises FileNotFoundError when path does not exist, in both policies.
    """
    limits = InputLimits() if limits is None else limits
    path = Path(path)
    if path.is_dir():
        return _iter_folder(path, limits, problems or _raise)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such submission file or folder")
    shards = _file_shards(path, limits, problems, member_file)
    return shards if problems is None else _reported(shards, problems)


def iter_submission_shards(path: PathLike, *, limits: InputLimits | None = None) -> Iterator[SubmissionShard]:
    """Yield (shard_name, raw_bytes) for every submission shard found at path.

    At most one shard's bytes are held at a time. Raises ParseError subclasses
    (ArchiveError, UnsafeArchiveMemberError, SizeLimitError) naming the archive
    and member at fault; FileNotFoundError when path does not exist.
    """
    for ref in iter_shard_refs(path, limits=limits):
        yield ref.name, ref.read()
