"""Submission packaging: single files, folders, (compressed) tars, hostile archives."""

from __future__ import annotations

import gzip
import io
import random
import tarfile
import warnings
import zipfile
from pathlib import Path

import pytest

from wosac_eval.parse.decompress import ArchiveNameWarning
from wosac_eval.parse.member_names import safe_member_name
from wosac_eval.parse.limits import InputLimits
from wosac_eval.parse.shards import parse_submission_shard
from wosac_eval.parse.shard_walk import iter_submission_shards
from wosac_eval.parse.errors import (
    ArchiveError,
    InvalidShardError,
    ParseError,
    SizeLimitError,
    UnsafeArchiveMemberError,
)
from wosac_eval.protos import sim_agents_submission_pb2

from support.paths import SHARED

Submission = sim_agents_submission_pb2.SimAgentsChallengeSubmission


def small_submission(scenario_id: str, num_steps: int = 80) -> bytes:
    """A serialized one-scenario, one-rollout, one-object submission."""
    submission = Submission(submission_type=Submission.SIM_AGENTS_SUBMISSION, account_name="me@x")
    scene = submission.scenario_rollouts.add(scenario_id=scenario_id).joint_scenes.add()
    trajectory = scene.simulated_trajectories.add(object_id=1)
    for values in (
        trajectory.center_x,
        trajectory.center_y,
        trajectory.center_z,
        trajectory.heading,
    ):
        values.extend(float(step) for step in range(num_steps))
    return submission.SerializeToString()


@pytest.fixture(scope="module")
def shards() -> dict[str, bytes]:
    """Two shards of real bytes: official golden submissions when ../shared has them."""
    golden = sorted((SHARED / "golden").glob("*.binproto"))[:2]
    if len(golden) == 2:
        return {f"sub.binproto-0000{i}-of-00002": p.read_bytes() for i, p in enumerate(golden)}
    return {f"sub.binproto-0000{i}-of-00002": small_submission(f"s{i}") for i in range(2)}


def add_member(tar: tarfile.TarFile, name: str, data: bytes = b"", **fields) -> None:
    """Add one member with the given name, content and TarInfo fields (type, linkname, ...)."""
    info = tarfile.TarInfo(name)
    info.size = len(data)
    for key, value in fields.items():
        setattr(info, key, value)
    tar.addfile(info, io.BytesIO(data) if data else None)


def make_tar(path: Path, members: dict[str, bytes], mode: str = "w", extra=None) -> Path:
    """Write a tar archive with a folder entry, a README and the given members."""
    with tarfile.open(path, mode) as tar:
        add_member(tar, "submission", type=tarfile.DIRTYPE)
        add_member(tar, "submission/README.md", b"how we built it")
        for name, data in members.items():
            add_member(tar, f"submission/{name}", data)
        if extra:
            extra(tar)
    return path


def read_all(path: Path, **limits) -> list[tuple[str, bytes]]:
    """Every (name, bytes) shard at path."""
    return list(iter_submission_shards(path, limits=InputLimits(**limits)))


def test_single_shard_file(tmp_path, shards):
    name, data = next(iter(shards.items()))
    (tmp_path / "mine.binproto").write_bytes(data)
    assert read_all(tmp_path / "mine.binproto") == [("mine.binproto", data)]
    assert parse_submission_shard("mine.binproto", data).SerializeToString() == data


def test_gzip_compressed_single_shard(tmp_path, shards):
    data = next(iter(shards.values()))
    (tmp_path / "mine.binproto.gz").write_bytes(gzip.compress(data))
    assert read_all(tmp_path / "mine.binproto.gz") == [("mine.binproto", data)]


def test_folder_of_shards_sorted_with_docs_skipped(tmp_path, shards):
    folder = tmp_path / "sub"
    (folder / "part2").mkdir(parents=True)
    (folder / "__MACOSX").mkdir()
    names = sorted(shards)
    (folder / names[1]).write_bytes(shards[names[1]])
    (folder / "part2" / names[0]).write_bytes(shards[names[0]])
    for junk in ("README", "notes.txt", ".DS_Store", "__MACOSX/._x.binproto"):
        (folder / junk).write_bytes(b"\x00junk")
    found = read_all(folder)
    assert [name for name, _ in found] == [f"part2/{names[0]}", names[1]]
    assert [data for _, data in found] == [shards[names[0]], shards[names[1]]]


def test_folder_with_a_stray_file_or_no_shard_is_an_error(tmp_path):
    (tmp_path / "README.md").write_text("docs only")
    with pytest.raises(ArchiveError, match="folder holds no submission shard"):
        read_all(tmp_path)
    (tmp_path / "model.pb").write_bytes(small_submission("a"))
    with pytest.raises(ArchiveError, match="'model.pb' is neither a submission shard"):
        read_all(tmp_path)


@pytest.mark.parametrize(
    "file_name, mode",
    [
        ("s.tar", "w"),
        ("s.tar.gz", "w:gz"),
        ("s.tgz", "w:gz"),
        ("s.tar.bz2", "w:bz2"),
        ("s.tar.xz", "w:xz"),
    ],
)
def test_tar_archives_stream_every_shard_in_order(tmp_path, shards, file_name, mode):
    if mode in ("w:bz2", "w:xz"):  # slow compressors: small shards keep the test quick
        shards = {name: small_submission(name) for name in shards}
    path = make_tar(tmp_path / file_name, shards, mode)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a truthful name gives no warning
        found = read_all(path)
    assert found == [(f"submission/{name}", data) for name, data in shards.items()]
    for name, data in found:
        assert parse_submission_shard(name, data).SerializeToString() == data
    assert sorted(p.name for p in tmp_path.iterdir()) == [file_name]  # nothing extracted


def test_a_plain_tar_named_tar_gz_is_read_with_a_warning(tmp_path, shards):
    path = make_tar(tmp_path / "lying.tar.gz", shards, "w")
    with pytest.warns(ArchiveNameWarning, match="name says compressed tar, but this is a uncompressed tar"):
        found = read_all(path)
    assert [data for _, data in found] == list(shards.values())


def test_an_archive_named_binproto_is_read_with_a_warning(tmp_path, shards):
    path = make_tar(tmp_path / "all.binproto", shards, "w:gz")
    with pytest.warns(ArchiveNameWarning, match="this is a gzip-compressed tar"):
        assert len(read_all(path)) == 2


def test_random_bytes_named_like_an_archive_are_refused(tmp_path):
    path = tmp_path / "sub.tar.gz"
    path.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(ArchiveError, match="sub.tar.gz: named like a compressed tar archive but is neither"):
        read_all(path)


def test_random_bytes_named_binproto_fail_when_parsed(tmp_path):
    path = tmp_path / "sub.binproto"
    path.write_bytes(b"\xff" * 64)
    ((name, data),) = read_all(path)
    with pytest.raises(InvalidShardError, match="shard sub.binproto: not a valid SimAgentsChallengeSubmission"):
        parse_submission_shard(name, data)


def test_zip_is_refused_with_advice(tmp_path):
    path = tmp_path / "sub.zip"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("a.binproto", small_submission("a"))
    with pytest.raises(ArchiveError, match="zip archives are not supported"):
        read_all(path)


@pytest.mark.parametrize(
    "name, problem",
    [
        ("../evil.binproto", "'..' component"),
        ("sub/../../evil.binproto", "'..' component"),
        ("sub\\..\\evil.binproto", "'..' component"),
        ("/abs/evil.binproto", "absolute path"),
        ("C:evil.binproto", "absolute path"),
    ],
)
def test_escaping_member_names_are_refused(tmp_path, name, problem):
    path = tmp_path / "bad.tar"
    with tarfile.open(path, "w") as tar:
        add_member(tar, name, small_submission("a"))
    with pytest.raises(UnsafeArchiveMemberError, match=problem) as caught:
        read_all(path)
    assert str(path) in str(caught.value) and repr(name) in str(caught.value)


def test_member_name_normalization():
    assert safe_member_name("a.tar", "./sub//x.binproto") == "sub/x.binproto"
    with pytest.raises(UnsafeArchiveMemberError, match="empty"):
        safe_member_name("a.tar", "")


@pytest.mark.parametrize(
    "fields, problem",
    [
        ({"type": tarfile.SYMTYPE, "linkname": "/etc/passwd"}, "is a symbolic link"),
        ({"type": tarfile.LNKTYPE, "linkname": "submission/README.md"}, "is a hard link"),
        ({"type": tarfile.CHRTYPE, "devmajor": 1, "devminor": 3}, "is a device file"),
        ({"type": tarfile.BLKTYPE, "devmajor": 8, "devminor": 0}, "is a device file"),
        ({"type": tarfile.FIFOTYPE}, "is a FIFO"),
        ({"type": tarfile.CONTTYPE}, None),  # contiguous file: a regular file
        ({"type": b"Z"}, "unsupported type"),
    ],
)
def test_special_members_are_refused(tmp_path, fields, problem):
    data = small_submission("a")

    def add_special(tar):
        add_member(
            tar,
            "submission/special.binproto",
            data if fields["type"] == tarfile.CONTTYPE else b"",
            **fields,
        )

    path = make_tar(tmp_path / "special.tar", {}, extra=add_special)
    if problem is None:
        assert read_all(path) == [("submission/special.binproto", data)]
        return
    with pytest.raises(UnsafeArchiveMemberError, match=problem) as caught:
        read_all(path)
    assert "'submission/special.binproto'" in str(caught.value)


def test_oversize_member_is_named(tmp_path, shards):
    path = make_tar(
        tmp_path / "big.tar.gz",
        {"ok.binproto": b"\x10\x01", "big.binproto": b"\x00" * 5000},
        "w:gz",
    )
    with pytest.raises(
        SizeLimitError,
        match="member 'submission/big.binproto' is 5000 bytes, over the per-member limit of 4096",
    ):
        read_all(path, max_member_bytes=4096)


def test_total_decompressed_size_is_limited(tmp_path):
    members = {f"m{i}.binproto": b"\x00" * 3000 for i in range(10)}  # 30 kB of zeros, tiny when gzipped
    path = make_tar(tmp_path / "bomb.tar.gz", members, "w:gz")
    assert path.stat().st_size < 2000
    # The third member's header already shows the total would pass the limit: refused before its data.
    with pytest.raises(
        SizeLimitError,
        match="bomb.tar.gz: member 'submission/m2.binproto' is 3000 bytes: the archive would decompress "
        "to more than the total limit of 10000 bytes",
    ):
        read_all(path, max_total_bytes=10_000)
    single = tmp_path / "bomb.binproto.gz"
    single.write_bytes(gzip.compress(b"\x10\x01" * 50_000))
    with pytest.raises(SizeLimitError, match="per-member limit of 1000 bytes"):
        read_all(single, max_member_bytes=1000)


def test_duplicate_member_names_are_refused(tmp_path):
    def add_twice(tar):
        add_member(tar, "submission/a.binproto", b"\x10\x01")

    path = make_tar(tmp_path / "dup.tar", {"a.binproto": b"\x10\x01"}, extra=add_twice)
    with pytest.raises(ArchiveError, match="member 'submission/a.binproto' appears twice"):
        read_all(path)


def test_truncated_tar_gz_names_archive_and_member_after_streaming_earlier_ones(tmp_path, shards):
    first_name, first_data = next(iter(shards.items()))
    # An incompressible second member puts the cut well past the first one.
    members = {first_name: first_data, "late.binproto": random.Random(0).randbytes(1 << 20)}
    raw = make_tar(tmp_path / "full.tar.gz", members, "w:gz").read_bytes()
    path = tmp_path / "cut.tar.gz"
    path.write_bytes(raw[: len(raw) - (1 << 19)])
    stream = iter_submission_shards(path)
    # Streaming: the intact first shard comes out before the damage is reached.
    assert next(stream) == (f"submission/{first_name}", first_data)
    with pytest.raises(
        ArchiveError,
        match="cut.tar.gz: truncated or corrupt data in member 'submission/late.binproto'",
    ):
        list(stream)


@pytest.mark.parametrize("mode", ["w", "w:gz"])
def test_member_pieces_name_a_truncated_member(tmp_path, shards, mode):
    """`MemberReader.read1` (how the walk copies a member to its file) gives the member's bytes, then refuses
    a member cut short naming archive and member, as reading it whole does."""
    from wosac_eval.parse.archive import iter_archive_members
    from wosac_eval.parse.decompress import sniff_file

    first_name, first_data = next(iter(shards.items()))
    late = random.Random(1).randbytes(1 << 20)
    raw = make_tar(tmp_path / "full.tar", {first_name: first_data, "late.binproto": late}, mode).read_bytes()
    whole, cut = tmp_path / "whole.tar", tmp_path / "cut.tar"
    whole.write_bytes(raw)
    cut.write_bytes(raw[: len(raw) - (1 << 19)])
    compression = sniff_file(whole)[0]
    read = {}
    for member in iter_archive_members(whole, compression, InputLimits()):
        read[member.name] = b"".join(iter(lambda m=member: m.read1(1 << 16), b""))
    assert read[f"submission/{first_name}"] == first_data and read["submission/late.binproto"] == late
    members = iter_archive_members(cut, compression, InputLimits())
    with pytest.raises(
        ArchiveError,
        match=r"cut.tar: (member 'submission/late.binproto' is truncated|truncated or "
        r"corrupt data in member 'submission/late.binproto')",
    ):
        for member in members:
            while member.read1(1 << 16):
                pass


@pytest.mark.parametrize("first", ["shard", "small"])
def test_isal_reads_what_zlib_reads_and_refuses_the_same_damage(tmp_path, shards, monkeypatch, first):
    """.tar.gz members are inflated by ISA-L (the `isal` dependency) when it is installed, and by zlib from
    a stream's first error on (ISA-L gives nothing of a deflate block it cannot finish): the same shards
    and the same refusals as zlib's reader alone, for a first member of one deflate block or many."""
    from wosac_eval.parse import decompress

    pytest.importorskip("isal")
    first_name, first_data = next(iter(shards.items()))
    if first == "small":
        first_data = small_submission("s0")
    members = {first_name: first_data, "late.binproto": random.Random(0).randbytes(1 << 20)}
    raw = make_tar(tmp_path / "full.tar.gz", members, "w:gz").read_bytes()
    middle = len(raw) // 2  # in the incompressible late member
    archives = {
        "full.tar.gz": raw,
        "cut.tar.gz": raw[: len(raw) - (1 << 19)],
        "trailer.tar.gz": raw[:-4],
        "flipped.tar.gz": raw[:middle] + bytes([raw[middle] ^ 0xFF]) + raw[middle + 1 :],
    }
    for name, data in archives.items():
        (tmp_path / name).write_bytes(data)

    def outcomes() -> dict:
        out = {}
        for name in archives:
            got: list = []
            try:
                for shard in iter_submission_shards(tmp_path / name):
                    got.append(shard)
                out[name] = (got, None)
            except ArchiveError as refused:
                out[name] = (got, str(refused))
        return out

    assert isinstance(decompress.open_decompressed(tmp_path / "full.tar.gz", "gzip"), decompress.FastGzipFile)
    with_isal = outcomes()
    monkeypatch.setattr(decompress, "igzip", None)  # zlib alone, as without the dependency
    assert not isinstance(decompress.open_decompressed(tmp_path / "full.tar.gz", "gzip"), decompress.FastGzipFile)
    assert outcomes() == with_isal
    assert with_isal["full.tar.gz"] == ([(f"submission/{n}", d) for n, d in members.items()], None)
    for name in ("cut.tar.gz", "trailer.tar.gz", "flipped.tar.gz"):
        got, message = with_isal[name]
        assert got[:1] == [(f"submission/{first_name}", first_data)], name
        assert message.startswith(f"{tmp_path / name}: ") and "'submission/late.binproto'" in message, message


def test_truncated_gzip_trailer_is_detected(tmp_path, shards):
    raw = make_tar(tmp_path / "full.tar.gz", shards, "w:gz").read_bytes()
    path = tmp_path / "cut.tar.gz"
    path.write_bytes(raw[:-4])  # only the gzip size trailer is missing
    with pytest.raises(ArchiveError, match="cut.tar.gz"):
        read_all(path)


def test_truncated_plain_tar_inside_data_and_inside_header(tmp_path):
    members = {"a.binproto": small_submission("a"), "b.binproto": small_submission("b")}
    raw = make_tar(tmp_path / "full.tar", members).read_bytes()
    last_header = raw.rfind(b"submission/b.binproto")
    (tmp_path / "data.tar").write_bytes(raw[: last_header + 512 + 100])
    with pytest.raises(ArchiveError, match="member 'submission/b.binproto' is truncated|unexpected end"):
        read_all(tmp_path / "data.tar")
    (tmp_path / "header.tar").write_bytes(raw[: last_header + 200])
    with pytest.raises(
        ArchiveError,
        match="header.tar: truncated tar archive \\(ends after member 'submission/a.binproto'",
    ):
        read_all(tmp_path / "header.tar")
    garbage = raw[:last_header] + b"\x7f" * 512 + raw[last_header + 512 :]
    (tmp_path / "garbage.tar").write_bytes(garbage)
    with pytest.raises(ArchiveError, match="garbage.tar: corrupt tar header after member 'submission/a.binproto'"):
        read_all(tmp_path / "garbage.tar")


def test_archive_without_shards_is_an_error(tmp_path):
    path = make_tar(tmp_path / "docs.tar", {})
    with pytest.raises(ArchiveError, match="archive holds no submission shard"):
        read_all(path)


def test_stray_member_is_an_error(tmp_path):
    path = make_tar(tmp_path / "stray.tar", {"weights.pt": b"\x00"})
    with pytest.raises(ArchiveError, match="'submission/weights.pt' is neither a submission shard"):
        read_all(path)


def test_invalid_utf8_in_a_string_field_is_named():
    bad_id = Submission.FromString(b"\x0a\x04\x0a\x02\xff\xfe")  # scenario_id = b"\xff\xfe"
    with pytest.raises(
        InvalidShardError,
        match="shard s.binproto: field scenario_rollouts\\[0\\].scenario_id is not valid UTF-8",
    ):
        parse_submission_shard("s.binproto", bad_id.SerializeToString())
    with pytest.raises(InvalidShardError, match="field authors\\[0\\]"):
        parse_submission_shard("s.binproto", b"\x2a\x01\xff")


def test_errors_are_parse_errors():
    for error in (ArchiveError, InvalidShardError, SizeLimitError, UnsafeArchiveMemberError):
        assert issubclass(error, ParseError) and issubclass(error, ValueError)


def test_missing_path_is_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such submission"):
        read_all(tmp_path / "nope.tar")
