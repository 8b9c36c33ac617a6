"""One submission, walked once: its shards, and where each scenario's rollouts are.

A submission is one or more serialized `SimAgentsChallengeSubmission` shards:
a single shard file, a folder of shards (every file below it whose name
contains ".binproto", sorted by relative path; stray files are refused,
hidden entries and documentation skipped), or a tar archive (`parse.archive`),
walked by `parse.shard_walk.iter_shard_refs`.

`SubmissionSource` is the handle the stages share: validation walks it and
records where each scenario's rollouts are; scoring and the scene pictures then
read those byte ranges instead of walking again. The walk never holds an archive
member whole: it copies each to a file a piece at a time (the spool, when the
handle has a spool folder: the archive is then decompressed once and the later
stages read the spool; else a scratch file removed once the member is checked,
`release`, and a later stage streams the archive once more, reading only the
scenarios it asks for). Every read goes through the limits the handle was opened
with.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Callable, Generator, Iterable, Iterator
from pathlib import Path
from typing import IO, Any

from wosac_eval.parse.archive import MemberReader, iter_archive_members
from wosac_eval.parse.decode import decode_message
from wosac_eval.parse.decompress import sniff_file
from wosac_eval.parse.limits import InputLimits
from wosac_eval.parse.shard_walk import PathLike, Problems, ShardRef, iter_shard_refs
from wosac_eval.parse.shards import split_shard
from wosac_eval.protos import sim_agents_submission_pb2

# Where one scenario's serialized ScenarioRollouts are: (path, offset, size) of a file every
# worker can read, or the bytes themselves.
RolloutsLocator = tuple[str, int, int] | bytes
_COPY_BYTES = 1 << 20  # a member is copied to its file this much at a time


# --------------------------------------------------------------------------- the handle


class SubmissionSource:
    """A submission on disk as every stage reads it: one walk, one set of limits.

    `shards()` walks it (validation does, once); `record(name, entries)` keeps
    where each scenario of a shard is; `rollouts_locators()` and `rollouts()`
    then serve scoring and the pictures from those records. With `spool_dir`,
    the bytes of archive members are written there as they are walked, so the
    archive is decompressed once; the spool is removed by `close()` (or the
    `with` block).

    With `tail_dir`, the last archive members walked, up to `tail_bytes` in all,
    stay there as files after validation (the others' scratch files go once
    checked): the stages after it read those members from their files, and so
    does a run resumed from `records()`, which then decompresses the archive only
    up to the members before them (a gzip stream cannot be entered midway). The
    folder outlives the handle: its owner removes it (`scoring.journal`).

    Args:
      path: a shard file, a folder of shards or a (compressed) tar archive.
      limits: how far it may expand (`InputLimits`); default `InputLimits()`.
      spool_dir: a folder for the spool of decompressed archive members; None: no spool.
      tail_dir, tail_bytes: where to keep the last members walked, and how many bytes of them.
    """

    def __init__(
        self,
        path: PathLike,
        limits: InputLimits | None = None,
        *,
        spool_dir: PathLike | None = None,
        tail_dir: PathLike | None = None,
        tail_bytes: int = 0,
    ) -> None:
        self.path = Path(path)
        self._given = os.fspath(path)  # as the user wrote it, for reports
        self.limits = InputLimits() if limits is None else limits
        self._spool_dir = None if spool_dir is None else Path(spool_dir)
        self._spool_folder: str | None = None
        self._spool: IO[bytes] | None = None
        self._scratch_folder: str | None = None
        self._scratch: dict[str, str] = {}  # walked archive member -> its scratch file (no spool)
        self._scratch_files = 0
        self._tail_dir = None if tail_dir is None or spool_dir is not None else Path(tail_dir)
        self._tail_bytes = tail_bytes
        self._tail: dict[str, int] = {}  # members kept in tail_dir, oldest first -> their size
        # Each walked shard without its bytes: a range of the submission's file, of the spool or of a file
        # in tail_dir, or (no path) a member to stream again.
        self._kept: dict[str, ShardRef] = {}
        self._records: dict[str, list[tuple[str, tuple[int, int]]]] = {}  # shard name -> its entries, in order

    def __enter__(self) -> SubmissionSource:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def __str__(self) -> str:
        return self._given

    def close(self) -> None:
        """Remove the spool (the records of byte ranges in it are then unreadable) and scratch files."""
        if self._scratch_folder is not None:
            if self._tail_dir is None:
                shutil.rmtree(self._scratch_folder, ignore_errors=True)
            else:  # the members kept stay for a later run; a walk cut short leaves no other
                for name in [name for name in self._scratch if name not in self._tail]:
                    self._remove_scratch(name)
            self._scratch_folder = None
            self._scratch.clear()
        if self._spool is not None:
            self._spool.close()
            self._spool = None
        if self._spool_folder is not None:
            shutil.rmtree(self._spool_folder, ignore_errors=True)
            self._spool_folder = None

    def _member_file(self, member: MemberReader) -> ShardRef:
        """Copy an archive member, a piece at a time, to the spool (appended) or to a scratch file of its
        own; its byte range there."""
        out: IO[bytes]
        if self._spool_dir is not None:
            if self._spool is None:
                self._spool_folder = tempfile.mkdtemp(prefix="wosac-spool-", dir=self._spool_dir)
                self._spool = open(os.path.join(self._spool_folder, "members"), "w+b")  # noqa: SIM115
            out = self._spool
            offset = out.seek(0, os.SEEK_END)
        else:
            if self._scratch_folder is None:
                if self._tail_dir is not None:  # a new walk: what an earlier one kept is not this one's
                    shutil.rmtree(self._tail_dir, ignore_errors=True)
                    self._tail_dir.mkdir(parents=True)
                    self._scratch_folder = str(self._tail_dir)
                else:
                    self._scratch_folder = tempfile.mkdtemp(prefix="wosac-shards-")
            self._scratch_files += 1
            out = open(os.path.join(self._scratch_folder, str(self._scratch_files)), "wb")  # noqa: SIM115
            offset = 0
            self._scratch[member.name] = out.name
        try:
            while piece := member.read1(_COPY_BYTES):
                out.write(piece)
            out.flush()
        finally:
            if out is not self._spool:
                out.close()
        return ShardRef(member.name, member.size, path=out.name, offset=offset)

    def _keep(self, shard: ShardRef) -> None:
        """Remember a walked shard: a range of the submission's file or of the spool, or (a scratch file
        goes once checked) a member to stream again."""
        if shard.name in self._scratch:
            self._kept[shard.name] = ShardRef(shard.name, shard.size)
        else:
            self._kept[shard.name] = shard.without_data()

    def shards(self, problems: Problems | None = None, *, members_in_memory: bool = False) -> Iterator[ShardRef]:
        """The walk (`iter_shard_refs` under the handle's limits), remembering each shard. Archive members
        are byte ranges of the spool or of scratch files (`release` removes one once it is checked), or with
        `members_in_memory` (for workers on other hosts) carry their bytes."""
        member_file = None if members_in_memory and self._spool_dir is None else self._member_file
        for shard in iter_shard_refs(self.path, limits=self.limits, problems=problems, member_file=member_file):
            self._keep(shard)
            yield shard

    def release(self, shard_name: str) -> None:
        """A walked shard was checked (and recorded, if it is to be scored): its scratch file goes, unless
        it is among the last members kept in `tail_dir` (then the oldest kept one goes past the budget)."""
        if shard_name not in self._scratch:
            return
        if self._tail_dir is not None and shard_name in self._records:
            self._tail[shard_name] = self._kept[shard_name].size
            self._kept[shard_name] = ShardRef(shard_name, self._kept[shard_name].size, path=self._scratch[shard_name])
            while sum(self._tail.values()) > self._tail_bytes:
                oldest = next(iter(self._tail))
                del self._tail[oldest]
                self._kept[oldest] = ShardRef(oldest, self._kept[oldest].size)
                self._remove_scratch(oldest)
        else:
            self._remove_scratch(shard_name)

    def drop_tail(self) -> None:
        """Remove the members kept in `tail_dir` (a refused submission will not be scored from them)."""
        if self._tail_dir is None:
            return
        for name in self._tail:
            self._kept[name] = ShardRef(name, self._kept[name].size)
            self._scratch.pop(name, None)
        self._tail.clear()
        shutil.rmtree(self._tail_dir, ignore_errors=True)

    def _remove_scratch(self, shard_name: str) -> None:
        with contextlib.suppress(OSError):
            os.unlink(self._scratch.pop(shard_name))

    def record(self, shard_name: str, entries: Iterable[tuple[str | None, tuple[int, int]]]) -> None:
        """Where the scenarios of a walked shard are: (scenario_id, (start, end) in the shard), in order."""
        self._records[shard_name] = [(sid, span) for sid, span in entries if sid]

    def records(self) -> list[tuple[ShardRef, list[tuple[str, tuple[int, int]]]]] | None:
        """What the walk recorded (each shard without its bytes, and where its scenarios are), for a
        later run over the same file (`restore_records`); None when it lives in a spool, which ends
        with this handle."""
        if self._spool_folder is not None:
            return None
        return [(self._kept[name], entries) for name, entries in self._records.items()]

    def restore_records(self, records: list[tuple[ShardRef, list[tuple[str, tuple[int, int]]]]]) -> None:
        """Take the records of an earlier walk of the same file (`records`) instead of walking it: an
        interrupted run resumes without validating a whole submission again."""
        self._records = {shard.name: entries for shard, entries in records}
        archive = self.path.is_file() and self._spool_dir is None
        self._kept = {shard.name: _still_there(shard) if archive else shard for shard, _ in records}

    def _member_entries(
        self, wanted: Callable[[str], bool], shard: ShardRef, entries: list, members: Iterator
    ) -> Iterator[tuple[str, bytes | None]]:
        """The wanted scenarios' bytes of a member streamed from the archive (`members`, advanced to it)."""
        for member in members:
            if member.name != shard.name:
                continue
            for sid, (start, end) in entries:  # in the shard's order: increasing offsets
                if not wanted(sid):
                    yield sid, None
                    continue
                member.skip(start - member.position)
                yield sid, member.read(end - start)
            return

    def rollouts_locators(
        self, wanted: Callable[[str], bool] | None = None
    ) -> Iterator[tuple[str, RolloutsLocator | None]]:
        """(scenario_id, where its rollouts are) of every recorded scenario, in submission order.

        A range of a submission file (or of a member kept in `tail_dir`) is given as (path, offset, size)
        for the worker to read; a scenario of an archive as its bytes (the spool is this process's): the
        archive is streamed once more, under the same limits, up to the last recorded member it must give
        (what follows it, a truncated end say, was reported by the walk that recorded). With `wanted`, a
        scenario it declines has None, and an archive's are then not read (a member with none is skipped,
        not copied; the archive is not even opened when every member to read is kept in `tail_dir`): a
        resumed run skips what it finished.
        """
        wanted = wanted or (lambda sid: True)
        members: Generator | None = None
        try:
            for name, entries in self._records.items():
                shard = self._kept[name]
                if shard.path is None and not any(wanted(sid) for sid, _ in entries):
                    yield from ((sid, None) for sid, _ in entries)  # nothing to read: not even decompressed
                    continue
                if shard.path is None:
                    if members is None:
                        members = self._stream_members()
                    yield from self._member_entries(wanted, shard, entries, members)
                    continue
                for sid, (start, end) in entries:
                    if not wanted(sid):
                        yield sid, None
                    elif self._spool is not None and shard.path == self._spool.name:
                        yield sid, shard.read(start, end)
                    else:
                        yield sid, (shard.path, shard.offset + start, end - start)
        finally:
            if members is not None:
                members.close()

    def _stream_members(self) -> Generator:
        """The archive's members as readers, or a single compressed shard's bytes as one."""
        compression, is_tar, _ = sniff_file(self.path)
        if is_tar:
            yield from iter_archive_members(self.path, compression, self.limits)
            return
        for shard in iter_shard_refs(self.path, limits=self.limits):  # a single shard compressed as a whole
            yield _BytesReader(shard.name, shard.data if shard.data is not None else shard.read())

    def rollouts(self, scenario_ids: Iterable[str]) -> dict[str, sim_agents_submission_pb2.ScenarioRollouts]:
        """The `ScenarioRollouts` of the given scenarios, by id (the first entry of each); an id the
        submission lacks is absent. Served from the records when validation made them."""
        wanted, found = set(scenario_ids), {}
        for sid, data in self._scenario_bytes(wanted):
            if data is not None and sid in wanted and sid not in found:
                found[sid] = decode_message(sim_agents_submission_pb2.ScenarioRollouts, data)
                if len(found) == len(wanted):
                    break
        return found

    def _scenario_bytes(self, wanted: set[str]) -> Iterator[tuple[str, bytes | None]]:
        if self._records:
            for sid, locator in self.rollouts_locators(wanted.__contains__):
                yield sid, None if locator is None else read_locator(locator)
            return
        for shard in iter_shard_refs(self.path, limits=self.limits):
            yield from split_shard(shard.name, shard.read(), self.limits)


class _BytesReader:
    """A shard's bytes, read as a `MemberReader` is."""

    def __init__(self, name: str, data: bytes) -> None:
        self.name, self.data, self.position = name, data, 0

    def skip(self, size: int) -> None:
        self.position += size

    def read(self, size: int) -> bytes:
        self.position += size
        return self.data[self.position - size : self.position]


def _still_there(shard: ShardRef) -> ShardRef:
    """A recorded shard of an archive (or a single file) as a later run may read it: a member kept in a
    file that is gone (or shorter), the member to stream again."""
    if shard.path is None:
        return shard
    try:
        present = os.path.getsize(shard.path) >= shard.offset + shard.size
    except OSError:
        present = False
    return shard if present else ShardRef(shard.name, shard.size)


def read_locator(locator: RolloutsLocator) -> bytes:
    """The bytes a `RolloutsLocator` points at."""
    if isinstance(locator, bytes):
        return locator
    path, offset, size = locator
    return ShardRef("", size, path=path, offset=offset).read()


def find_scenario_rollouts(
    submission: PathLike | SubmissionSource, scenario_ids: Iterable[str], limits: InputLimits | None = None
) -> dict:
    """The `ScenarioRollouts` of the given scenarios in a submission (file, folder, archive or an open
    `SubmissionSource`), by id; shards are split on the wire and only the wanted entries are parsed."""
    if isinstance(submission, SubmissionSource):
        return submission.rollouts(scenario_ids)
    return SubmissionSource(submission, limits).rollouts(scenario_ids)
