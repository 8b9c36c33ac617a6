"""Hostile submissions for the service's attack tests and benchmark: small files that expand a lot.

Every bomb is built in memory by streaming compressors (nothing large is held), and
every one is a well-formed container, so only the expansion limits can stop it.
"""

from __future__ import annotations

import bz2
import io
import lzma
import tarfile
import zlib

from wosac_eval.parse.wire import varint

MiB = 1 << 20


def _compressor(kind: str):
    if kind == "gz":
        return zlib.compressobj(9, zlib.DEFLATED, 31)  # 31: a gzip header and trailer
    if kind == "bz2":
        return bz2.BZ2Compressor(9)
    if kind == "xz":
        return lzma.LZMACompressor()
    raise ValueError(kind)


def tar_stream(members: list[tuple[str, int, bytes]], kind: str) -> bytes:
    """A compressed tar whose members are (name, size, pattern): `pattern` repeated to `size` bytes,
    compressed as it is generated."""
    comp = _compressor(kind)
    out = []
    for name, size, pattern in members:
        info = tarfile.TarInfo(name)
        info.size, info.mtime = size, 0
        out.append(comp.compress(info.tobuf(format=tarfile.GNU_FORMAT)))
        block = (pattern * (MiB // len(pattern) + 1))[:MiB]
        left = size
        while left:
            piece = block[: min(left, MiB)]
            out.append(comp.compress(piece))
            left -= len(piece)
        out.append(comp.compress(b"\0" * (-size % tarfile.BLOCKSIZE)))
    out.append(comp.compress(b"\0" * (2 * tarfile.BLOCKSIZE)))
    out.append(comp.flush())
    return b"".join(out)


def zeros_bomb(kind: str = "bz2", size: int = 1 << 30) -> bytes:
    """One shard member of `size` zero bytes (1 GiB in ~1 kB of bzip2)."""
    return tar_stream([("zeros.binproto", size, b"\0")], kind)


def empty_rollouts_bomb(count: int = 8_000_000, kind: str = "gz") -> bytes:
    """One shard of `count` empty scenario_rollouts (2 bytes each on the wire, ~55 bytes each parsed)."""
    return tar_stream([("rollouts.binproto", 2 * count, b"\x0a\x00")], kind)


def empty_trajectories_bomb(count: int = 8_000_000, kind: str = "gz") -> bytes:
    """One scenario, one joint scene of `count` empty trajectories (~100 bytes each parsed)."""
    scene = b"\x0a\x00" * count
    joint = b"\x12" + varint(len(scene)) + scene
    shard = b"\x0a" + varint(len(joint)) + joint
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode=f"w:{kind}") as tar:
        info = tarfile.TarInfo("trajectories.binproto")
        info.size = len(shard)
        tar.addfile(info, io.BytesIO(shard))
    return buf.getvalue()


def members_bomb(count: int = 100_000, kind: str = "gz") -> bytes:
    """`count` empty documentation members (512 bytes of header each)."""
    return tar_stream([(f"doc/{i}.md", 0, b"\0") for i in range(count)], kind)


def all_bombs() -> dict[str, bytes]:
    """The benchmark's set, by name."""
    return {
        "1 GiB of zeros, tar.bz2": zeros_bomb("bz2"),
        "1 GiB of zeros, tar.xz": zeros_bomb("xz"),
        "1 GiB of zeros, tar.gz": zeros_bomb("gz"),
        "8M empty scenario_rollouts, tar.gz": empty_rollouts_bomb(),
        "8M empty trajectories, tar.gz": empty_trajectories_bomb(),
        "100k archive members, tar.gz": members_bomb(),
    }
