"""The tar reader (`parse.tar_format`) against tarfile's and GNU tar's output, and hostile archives.

What tarfile writes in each of its formats, and what GNU tar writes in each of its, must read back as
tarfile reads it: the same members in the same order, names, types, sizes and data. Damaged archives
must end in a TarFormatError (never another exception, never a hang), after yielding exactly the
members that precede the damage.
"""

from __future__ import annotations

import io
import random
import shutil
import subprocess
import tarfile

import pytest

from wosac_eval.parse.tar_format import (
    BLOCK,
    MAX_META_BYTES,
    TarFormatError,
    TarStreamReader,
    TruncatedTarError,
    is_tar_header,
    parse_header,
    parse_pax_records,
)

FORMATS = {"ustar": tarfile.USTAR_FORMAT, "gnu": tarfile.GNU_FORMAT, "pax": tarfile.PAX_FORMAT}


def read_with_reader(raw: bytes, chunk: int = 1 << 20) -> list[tuple[str, str, int, bytes]]:
    """(name, type, size, data of files) of every member, read through `read(n)` calls of at most
    `chunk` bytes (the reader must cope with short reads)."""
    source = io.BytesIO(raw)
    reader = TarStreamReader(lambda n: source.read(min(n, chunk)))
    return [(m.name, m.type, m.size, reader.read_data() if m.is_file else b"") for m in reader]


def read_with_tarfile(raw: bytes) -> list[tuple[str, str, int, bytes]]:
    with tarfile.open(fileobj=io.BytesIO(raw), mode="r:") as tar:
        return [
            (info.name, info.type.decode("latin-1"), info.size, tar.extractfile(info).read() if info.isreg() else b"")
            for info in tar.getmembers()
        ]


def tar_bytes(members: list[tuple[str, bytes | None]], format: int, pax_headers=None) -> bytes:
    """An archive of files (data) and folders (None), written by tarfile in `format`."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w", format=format, pax_headers=pax_headers or {}) as tar:
        for name, data in members:
            info = tarfile.TarInfo(name)
            if data is None:
                info.type = tarfile.DIRTYPE
            else:
                info.size = len(data)
            tar.addfile(info, io.BytesIO(data) if data else None)
    return buffer.getvalue()


def with_checksum(block: bytearray) -> bytes:
    """The header block with its checksum recomputed (what a crafted archive carries)."""
    block[148:156] = b" " * 8
    block[148:156] = f"{sum(block):06o}\x00 ".encode()
    return bytes(block)


def sample_members(rng: random.Random) -> list[tuple[str, bytes | None]]:
    """Folders and files with short, long (over 100 and 255 bytes), nested and non-ASCII names, and
    sizes around the block boundaries."""
    members: list[tuple[str, bytes | None]] = [("top", None)]
    sizes = [0, 1, 511, 512, 513, 1024, 5000, 20_000]
    for index in range(12):
        depth = rng.choice([1, 2, 8, 30])
        parts = ["top", *(f"d{rng.randrange(10**6)}" for _ in range(depth - 1)), f"f{index}é.binproto"]
        members.append(("/".join(parts), rng.randbytes(rng.choice(sizes))))
    members.append(("top/" + "x" * 150, b"long base name"))
    return members


@pytest.mark.parametrize("format_name", FORMATS)
def test_tarfile_archives_read_as_tarfile_reads_them(format_name):
    rng = random.Random(format_name)
    for _ in range(5):
        members = sample_members(rng)
        if format_name == "ustar":  # ustar cannot hold names past 255 bytes or a base name past 100
            members = [(n, d) for n, d in members if len(n.encode()) <= 255 and len(n.split("/")[-1]) <= 100]
        raw = tar_bytes(members, FORMATS[format_name])
        expected = read_with_tarfile(raw)
        assert [name for name, *_ in expected] == [name.rstrip("/") for name, _ in members]
        assert read_with_reader(raw) == expected
        assert read_with_reader(raw, chunk=7) == expected  # short reads everywhere


def test_pax_global_header_and_path_records_apply_as_in_tarfile():
    raw = tar_bytes([("a.binproto", b"1"), ("b.binproto", b"22")], tarfile.PAX_FORMAT, {"comment": "ours"})
    assert (
        read_with_reader(raw) == read_with_tarfile(raw) == [("a.binproto", "0", 1, b"1"), ("b.binproto", "0", 2, b"22")]
    )
    assert parse_pax_records(b"21 path=a/b.binproto\n11 size=42\n") == {"path": "a/b.binproto", "size": "42"}


@pytest.mark.skipif(shutil.which("tar") is None, reason="GNU tar is not installed")
@pytest.mark.parametrize("tar_format", ["gnu", "oldgnu", "posix", "ustar", "v7"])
def test_gnu_tar_archives_read_as_tarfile_reads_them(tmp_path, tar_format):
    root = tmp_path / "submission"
    (root / "nested" / "deeper").mkdir(parents=True)
    rng = random.Random(tar_format)
    files = {"a.binproto": 0, "nested/b.binproto": 511, "nested/deeper/c.binproto": 70_000, "README.md": 3}
    if tar_format not in ("ustar", "v7"):
        files["nested/" + "long" * 30 + ".binproto"] = 1000
    for name, size in files.items():
        (root / name).write_bytes(rng.randbytes(size))
    archive = tmp_path / "s.tar"
    subprocess.run(
        ["tar", f"--format={tar_format}", "-cf", str(archive), "-C", str(tmp_path), "submission"], check=True
    )
    raw = archive.read_bytes()
    members = read_with_reader(raw)
    assert members == read_with_tarfile(raw)
    assert {name for name, kind, *_ in members if kind in "0\x00"} == {f"submission/{n}" for n in files}


@pytest.mark.parametrize("chunk", [1, 700, 1 << 20])
def test_read_data1_gives_each_member_in_pieces_of_at_most_what_was_asked(chunk):
    """`read_data1` (a copy loop's reads) gives a member's bytes in pieces of whatever one read of the stream
    gives, never past the member nor the size asked, and b'' at its end; the next member reads whole after."""
    rng = random.Random(chunk)
    files = [("a.bin", rng.randbytes(5000)), ("b.bin", rng.randbytes(3 * BLOCK + 17)), ("c.bin", b"")]
    raw = tar_bytes(files, tarfile.PAX_FORMAT)
    source = io.BytesIO(raw)
    reader = TarStreamReader(lambda n: source.read(min(n, chunk)))
    for member, (name, data) in zip(reader, files):
        assert member.name == name
        pieces = []
        while piece := reader.read_data1(1024):
            assert len(piece) <= min(1024, chunk)
            pieces.append(piece)
        assert b"".join(pieces) == data
        assert reader.read_data1(1024) == b""


def test_read_data1_ends_with_the_stream():
    """A stream cut inside a member's data: the bytes before the cut, then b'' (the caller, which knows the
    member's size, names the truncation)."""
    raw = tar_bytes([("a.bin", bytes(range(256)) * 40)], tarfile.USTAR_FORMAT)[: BLOCK + 3000]
    source = io.BytesIO(raw)
    reader = TarStreamReader(source.read)
    member = next(iter(reader))
    got = b""
    while piece := reader.read_data1(1000):
        got += piece
    assert got == (bytes(range(256)) * 40)[:3000] and member.size == 10240


def test_cut_archives_yield_the_members_before_the_cut_then_a_format_error():
    rng = random.Random(1)
    raw = tar_bytes(
        [
            ("a.binproto", rng.randbytes(700)),
            ("d", None),
            ("b.binproto", rng.randbytes(40)),
            ("c" * 120 + ".binproto", b"xyz"),
        ],
        tarfile.GNU_FORMAT,
    )
    full = read_with_reader(raw)
    end = len(raw) - raw[::-1].index(next(b for b in reversed(raw) if b).to_bytes(1, "big"))
    for cut in range(0, end + BLOCK):  # every cut up to one block past the last non-zero byte
        source = io.BytesIO(raw[:cut])
        reader = TarStreamReader(source.read)
        got = []
        try:
            for member in reader:
                data = reader.read_data() if member.is_file else b""
                got.append((member.name, member.type, member.size, data))
        except TarFormatError:
            pass
        complete = [m for m in got if len(m[3]) == m[2] or m[1] not in "0\x00"]
        # Every member read whole is the archive's own, in order; at most the last one is cut short.
        assert complete == full[: len(complete)] and len(got) - len(complete) <= 1, cut


def test_clean_end_truncation_and_corruption_are_told_apart():
    raw = tar_bytes([("a.binproto", b"x" * 600), ("b.binproto", b"y")], tarfile.USTAR_FORMAT)
    second = raw.index(b"b.binproto")

    def outcome(data: bytes) -> str:
        source = io.BytesIO(data)
        try:
            names = [m.name for m in TarStreamReader(source.read)]
        except TruncatedTarError:
            return "truncated"
        except TarFormatError as error:
            return f"corrupt: {error}"
        return ",".join(names)

    assert outcome(raw) == "a.binproto,b.binproto"
    assert outcome(raw[:second]) == "truncated"  # ends after a member without the end block
    assert outcome(raw[: second + 100]) == "truncated"  # ends inside a header
    flipped = bytearray(raw)
    flipped[second] ^= 0x20
    assert outcome(bytes(flipped)) == "corrupt: bad checksum"
    header = bytearray(raw[second : second + BLOCK])
    header[124:136] = b"0000000000x\x00"
    assert outcome(raw[:second] + with_checksum(header) + raw[second + BLOCK :]).startswith("corrupt: invalid header")


def test_headers_parse_as_tarfile_parses_them():
    info = tarfile.TarInfo("some/where/x.binproto")
    info.size = 8**11  # past the 11 octal digits: tarfile's GNU format writes base-256
    block = info.tobuf(tarfile.GNU_FORMAT)[:BLOCK]
    member = parse_header(block)
    assert (member.name, member.size, member.type) == ("some/where/x.binproto", 8**11, "0")
    assert parse_header(b"\x00" * BLOCK) is None and is_tar_header(b"\x00" * BLOCK)
    assert not is_tar_header(b"\x00" * 100) and not is_tar_header(b"not a tar header".ljust(BLOCK, b"!"))
    negative = bytearray(block)
    negative[124:136] = b"\xff" * 12
    with pytest.raises(TarFormatError, match="negative size"):
        parse_header(with_checksum(negative))


@pytest.mark.parametrize(
    "record, problem",
    [
        (b"99 path=x\n", "malformed pax"),
        (b"9 path=x\x00", "malformed pax"),
        (b"0 =\n", "malformed pax"),
        (b"garbage", "malformed pax"),
    ],
)
def test_malformed_pax_records_are_format_errors(record, problem):
    with pytest.raises(TarFormatError, match=problem):
        parse_pax_records(record)


def test_oversized_and_dangling_extended_headers_are_refused():
    huge = tarfile.TarInfo("././@LongLink")
    huge.type, huge.size = tarfile.GNUTYPE_LONGNAME, MAX_META_BYTES + 1
    with pytest.raises(TarFormatError, match="extended header of"):
        list(TarStreamReader(io.BytesIO(huge.tobuf(tarfile.GNU_FORMAT)).read))
    dangling = tarfile.TarInfo("././@LongLink")
    dangling.type, dangling.size = tarfile.GNUTYPE_LONGNAME, 4
    raw = dangling.tobuf(tarfile.GNU_FORMAT) + b"abc\x00".ljust(BLOCK, b"\x00") + b"\x00" * 2 * BLOCK
    with pytest.raises(TarFormatError, match="without the member"):
        list(TarStreamReader(io.BytesIO(raw).read))


def test_mutated_archives_fail_cleanly_or_read_as_tarfile_does():
    """Random byte changes in headers, checksums recomputed as a crafted archive would have them: the
    reader raises TarFormatError or agrees with tarfile."""
    rng = random.Random(7)
    raw = tar_bytes(
        [
            ("d", None),
            ("d/a.binproto", rng.randbytes(300)),
            ("d/" + "n" * 130, b"q" * 10),
            ("d/b.binproto", rng.randbytes(1000)),
        ],
        tarfile.PAX_FORMAT,
    )
    header_offsets = [
        o for o in range(0, len(raw), BLOCK) if is_tar_header(raw[o : o + BLOCK]) and any(raw[o : o + BLOCK])
    ]
    agreed = failed = 0
    for _ in range(3000):
        data = bytearray(raw)
        header = rng.choice(header_offsets)
        offset = header + rng.randrange(BLOCK)
        data[offset] = rng.randrange(256)
        if offset - header not in range(148, 156):
            data[header : header + BLOCK] = with_checksum(data[header : header + BLOCK])
        try:
            ours = read_with_reader(bytes(data))
        except TarFormatError:
            failed += 1
            continue
        assert ours == read_with_tarfile(bytes(data)), offset
        agreed += 1
    assert agreed > 1000 and failed > 100  # both outcomes were exercised
