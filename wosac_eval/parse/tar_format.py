"""A streaming reader of the tar format: POSIX ustar, pax, GNU and v7 headers.

tarfile's stream mode ends its iteration silently at a damaged header and keeps the reason in
private state that its patch releases change (the 2025 security fixes did). Reading the headers
here tells a clean end (the all-zero block) from a truncated or corrupt archive in the same way on
every CPython. Only what a submission needs is interpreted: member names (the ustar prefix, pax
`path`, GNU long names), sizes (octal, base-256, pax `size`) and types. Member data are read or
skipped in order from any object with `read(n)`; nothing is extracted.

Layout of a 512-byte header (offsets): name 0-100, size 124-136, checksum 148-156, type 156,
link name 157-257, magic 257-263, ustar prefix 345-500. Each member's data follow its header,
padded to a multiple of 512 bytes; the archive ends with a block of zeros.
"""

from __future__ import annotations

import dataclasses
import io
import re
from collections.abc import Callable, Iterator

BLOCK = 512

REGULAR_TYPES = ("0", "\x00", "7")  # file, old-style file, contiguous file
DIRECTORY_TYPE = "5"
HARD_LINK_TYPE, SYMLINK_TYPE = "1", "2"
DEVICE_TYPES = ("3", "4")  # character and block devices
FIFO_TYPE = "6"
GNU_SPARSE_TYPE = "S"
_GNU_LONG_NAME, _GNU_LONG_LINK = "L", "K"
_PAX_MEMBER, _PAX_GLOBAL = ("x", "X"), "g"  # 'X': Solaris's name for a pax member header
_META_TYPES = (_GNU_LONG_NAME, _GNU_LONG_LINK, *_PAX_MEMBER, _PAX_GLOBAL)

# Long names and pax records are held in memory: a header this big is an attack, not a name.
MAX_META_BYTES = 1 << 20
_USTAR_MAGIC = b"ustar\x00"
_OTHER_NUMBERS = ((100, 108), (108, 116), (116, 124), (136, 148), (329, 337), (337, 345))
_OCTAL = re.compile(rb"[0-7]*")
_PAX_RECORD = re.compile(rb"(\d+) ([^=\n]+)=")


class TarFormatError(Exception):
    """A header that is not valid tar (bad checksum, bad number, malformed pax record)."""


class TruncatedTarError(TarFormatError):
    """The archive ends inside a header or without its end-of-archive block."""


class TruncatedDataError(TruncatedTarError):
    """The archive ends inside the data of a member that was being skipped."""


@dataclasses.dataclass(frozen=True)
class TarMember:
    """One archive member's header, extended headers applied.

    Attributes:
      name: the member's name as stored ('/'-separated, a directory's without its trailing '/').
      type: the one-character type flag ('0' file, '5' directory, '2' symbolic link...).
      size: the number of data bytes that follow the header.
      linkname: the target of a link, else ''.
      sparse: True for GNU sparse files (type 'S' or pax GNU.sparse records).
    """

    name: str
    type: str
    size: int
    linkname: str = ""
    sparse: bool = False

    @property
    def is_file(self) -> bool:
        return self.type in REGULAR_TYPES and not self.sparse

    @property
    def is_dir(self) -> bool:
        return self.type == DIRECTORY_TYPE


def _text(field: bytes) -> str:
    """A NUL-terminated header string (UTF-8; undecodable bytes kept as surrogates, as tarfile does)."""
    return field.split(b"\x00", 1)[0].decode("utf-8", "surrogateescape")


def _number(field: bytes) -> int:
    """A numeric header field: octal digits (NUL/space padded), or base-256 when the top bit is set."""
    if field[:1] in (b"\x80", b"\xff"):
        value = int.from_bytes(field[1:], "big")
        return value - (1 << (8 * (len(field) - 1))) if field[:1] == b"\xff" else value
    digits = field.split(b"\x00", 1)[0].strip()
    if not _OCTAL.fullmatch(digits):
        raise TarFormatError(f"invalid header (number field {field!r})")
    return int(digits or b"0", 8)


def _checksum_matches(block: bytes) -> bool:
    """The stored checksum equals the sum of the header's bytes (the checksum field read as spaces),
    counted unsigned or, as some old writers did, signed."""
    stored = _number(block[148:156])
    masked = block[:148] + b" " * 8 + block[156:]
    unsigned = sum(masked)
    signed = unsigned - 256 * sum(1 for byte in masked if byte > 127)
    return stored in (unsigned, signed)


def parse_header(block: bytes) -> TarMember | None:
    """The member a 512-byte header block describes; None for the all-zero end-of-archive block.

    Raises TruncatedTarError for a short block, TarFormatError for an invalid one.
    """
    if len(block) < BLOCK:
        raise TruncatedTarError("truncated header" if block else "no end-of-archive block")
    if block.count(0) == BLOCK:
        return None
    if not _checksum_matches(block):
        raise TarFormatError("bad checksum")
    for start, end in _OTHER_NUMBERS:  # mode, ids, time and device numbers: unused, but must be numbers
        _number(block[start:end])
    size = _number(block[124:136])
    if size < 0:
        raise TarFormatError(f"invalid header (negative size {size})")
    type_flag = chr(block[156])
    name = _text(block[0:100])
    if block[257:263] == _USTAR_MAGIC and type_flag not in (_GNU_LONG_NAME, _GNU_LONG_LINK):
        prefix = _text(block[345:500])
        name = f"{prefix}/{name}" if prefix else name
    if type_flag == "\x00" and name.endswith("/"):  # old-style directories
        type_flag = DIRECTORY_TYPE
    if type_flag == DIRECTORY_TYPE:
        name = name.rstrip("/")
    return TarMember(name, type_flag, size, _text(block[157:257]), sparse=type_flag == GNU_SPARSE_TYPE)


def is_tar_header(block: bytes) -> bool:
    """True when `block` is a valid tar header, or the all-zero block of an empty archive."""
    try:
        parse_header(block)
    except TarFormatError:
        return False
    return True


def parse_pax_records(data: bytes) -> dict[str, str]:
    """The 'length key=value\\n' records of a pax extended header (length counts the whole record)."""
    records: dict[str, str] = {}
    position = 0
    while position < len(data) and data[position:].strip(b"\x00"):
        match = _PAX_RECORD.match(data, position)
        length = int(match.group(1)) if match else 0
        end = position + length
        if not match or end <= match.end() or end > len(data) or data[end - 1 : end] != b"\n":
            raise TarFormatError(f"malformed pax extended header record at byte {position}")
        key = match.group(2).decode("utf-8", "surrogateescape")
        records[key] = data[match.end() : end - 1].decode("utf-8", "surrogateescape")
        position = end
    return records


def _apply_pax(member: TarMember, records: dict[str, str]) -> TarMember:
    """The member with pax `path`, `linkpath` and `size` in force; GNU.sparse records mark it sparse."""
    changes: dict[str, object] = {}
    if "path" in records:
        changes["name"] = records["path"].rstrip("/") if member.is_dir else records["path"]
    if "linkpath" in records:
        changes["linkname"] = records["linkpath"]
    if "size" in records:
        if not records["size"].isdigit():
            raise TarFormatError(f"invalid pax size {records['size']!r}")
        changes["size"] = int(records["size"])
    if any(key.startswith("GNU.sparse.") for key in records):
        changes["sparse"] = True
    # `changes` maps field names to values of several types: mypy checks each against every field.
    return dataclasses.replace(member, **changes) if changes else member  # type: ignore[arg-type]


def padded(size: int) -> int:
    """Bytes a member's data occupy in the archive: its size rounded up to whole blocks."""
    return -(-size // BLOCK) * BLOCK


class TarStreamReader:
    """Members of a tar stream, in order, and the data of the current one.

    `read` is called with the number of bytes wanted and may return fewer (then it is called again)
    or b'' at the end of the stream. Iterating yields each member after its extended headers were
    applied and stops at the end-of-archive block; `read_data(n)` returns the current member's next
    bytes, and moving to the next member skips whatever of its data was not read.
    """

    def __init__(self, read: Callable[[int], bytes]) -> None:
        self._read = read
        self._global_pax: dict[str, str] = {}
        self._left = 0  # data bytes of the current member not yet read
        self._padding = 0  # padding after them

    def read_exact(self, size: int) -> bytes:
        """`size` bytes of the stream, or fewer when it ends first."""
        # Gathered in one growing buffer, not a list of pieces joined at the end: a 400 MB shard then
        # costs its own size (and a little slack), not twice it.
        gathered, wanted = io.BytesIO(), size
        while wanted > 0:
            piece = self._read(wanted)
            if not piece:
                break
            gathered.write(piece)
            wanted -= len(piece)
        return gathered.getvalue()

    def read_data(self, size: int | None = None) -> bytes:
        """The current member's next `size` data bytes (all that are left by default); fewer when the
        stream ends inside them."""
        size = self._left if size is None else min(size, self._left)
        data = self.read_exact(size)
        self._left -= len(data)
        if len(data) < size:  # the stream ended: nothing more can be skipped either
            self._left = self._padding = 0
        return data

    def read_data1(self, size: int) -> bytes:
        """Up to `size` of the current member's next data bytes: what one read of the stream gives (a copy
        loop's pieces, never gathered); b'' once its data are all read, or when the stream ends in them."""
        if size <= 0 or self._left == 0:
            return b""
        data = self._read(min(size, self._left))
        if not data:  # the stream ended: nothing more can be skipped either
            self._left = self._padding = 0
        self._left -= len(data)
        return data

    def skip_data(self) -> None:
        """Read past what is left of the current member's data and padding, a bounded piece at a time
        (TruncatedDataError when the stream ends inside them)."""
        remaining, self._left, self._padding = self._left + self._padding, 0, 0
        while remaining > 0:
            piece = self._read(min(remaining, 1 << 20))  # whatever comes: nothing is kept, nothing joined
            if not piece:
                raise TruncatedDataError("the archive ends inside its data")
            remaining -= len(piece)

    def _meta_data(self, member: TarMember) -> bytes:
        """The data of a long-name or pax header, bounded."""
        if member.size > MAX_META_BYTES:
            raise TarFormatError(f"extended header of {member.size} bytes (over {MAX_META_BYTES})")
        data = self.read_exact(padded(member.size))
        if len(data) < padded(member.size):
            raise TruncatedTarError("truncated extended header")
        return data[: member.size]

    def next_member(self) -> TarMember | None:
        """The next member (extended headers applied), None at the end-of-archive block."""
        self.skip_data()
        long_name = long_link = None
        records: dict[str, str] = {}
        while True:
            member = parse_header(self.read_exact(BLOCK))
            if member is None:
                if long_name is not None or long_link is not None or records:
                    raise TarFormatError("extended header without the member it describes")
                return None
            if member.type not in _META_TYPES:
                break
            data = self._meta_data(member)
            if member.type == _GNU_LONG_NAME:
                long_name = _text(data)
            elif member.type == _GNU_LONG_LINK:
                long_link = _text(data)
            elif member.type == _PAX_GLOBAL:
                self._global_pax.update(parse_pax_records(data))
            else:
                records.update(parse_pax_records(data))
        if long_name is not None:
            member = dataclasses.replace(member, name=long_name.rstrip("/") if member.is_dir else long_name)
        if long_link is not None:
            member = dataclasses.replace(member, linkname=long_link)
        member = _apply_pax(member, {**self._global_pax, **records})
        # Only files (and types unknown to tar, as tarfile does) are followed by data.
        known = (DIRECTORY_TYPE, HARD_LINK_TYPE, SYMLINK_TYPE, FIFO_TYPE, *DEVICE_TYPES)
        self._left = 0 if member.type in known else member.size
        self._padding = padded(self._left) - self._left
        return member

    def __iter__(self) -> Iterator[TarMember]:
        while (member := self.next_member()) is not None:
            yield member
