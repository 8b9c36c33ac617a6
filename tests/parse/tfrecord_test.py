"""TFRecord framing: hand-built files, corruption, truncation, gzip."""

from __future__ import annotations

import gzip
import struct

import google_crc32c
import pytest

from wosac_eval.parse.errors import CorruptRecordError, ParseError
from wosac_eval.parse.tfrecord import (
    frame_record,
    iter_records,
    masked_crc32c,
    read_record_at,
    read_records,
    write_records,
)

PAYLOADS = [b"first record", b"", b"\x00\xff" * 300]


def masked_crc_by_hand(data: bytes) -> int:
    """The TFRecord CRC written out from the format description."""
    crc = google_crc32c.value(data)
    rotated = ((crc >> 15) | (crc << 17)) & 0xFFFFFFFF
    return (rotated + 0xA282EAD8) & 0xFFFFFFFF


def hand_built(payloads: list[bytes]) -> bytes:
    """A TFRecord file assembled field by field, independently of frame_record."""
    out = b""
    for data in payloads:
        length = struct.pack("<Q", len(data))
        out += length + struct.pack("<I", masked_crc_by_hand(length))
        out += data + struct.pack("<I", masked_crc_by_hand(data))
    return out


def offsets_of(payloads: list[bytes]) -> list[int]:
    """Header offsets of consecutive records (12-byte header, 4-byte footer)."""
    offsets, position = [], 0
    for data in payloads:
        offsets.append(position)
        position += 12 + len(data) + 4
    return offsets


def test_masked_crc_of_known_vector():
    # CRC32C("123456789") is the standard check value 0xE3069283.
    assert google_crc32c.value(b"123456789") == 0xE3069283
    assert masked_crc32c(b"123456789") == masked_crc_by_hand(b"123456789")


def test_reads_hand_built_file_with_offsets(tmp_path):
    path = tmp_path / "good.tfrecord"
    path.write_bytes(hand_built(PAYLOADS))
    records = list(iter_records(path))
    assert [r.data for r in records] == PAYLOADS
    assert [r.offset for r in records] == offsets_of(PAYLOADS)
    assert list(read_records(path)) == PAYLOADS


def test_writer_produces_the_hand_built_bytes(tmp_path):
    path = tmp_path / "written.tfrecord"
    assert write_records(path, iter(PAYLOADS)) == len(PAYLOADS)
    assert path.read_bytes() == hand_built(PAYLOADS)
    assert frame_record(b"x") == hand_built([b"x"])
    assert [p.name for p in tmp_path.iterdir()] == ["written.tfrecord"]  # no temp file left


def test_writer_rejects_non_bytes_and_leaves_no_file(tmp_path):
    path = tmp_path / "bad.tfrecord"
    with pytest.raises(TypeError, match="record 1 is str"):
        write_records(path, [b"ok", "not bytes"])
    assert list(tmp_path.iterdir()) == []


def test_random_access_by_offset(tmp_path):
    path = tmp_path / "good.tfrecord"
    path.write_bytes(hand_built(PAYLOADS))
    for offset, data in zip(offsets_of(PAYLOADS), PAYLOADS, strict=True):
        assert read_record_at(path, offset) == data
    with pytest.raises(CorruptRecordError, match="length field fails"):
        read_record_at(path, 1)
    with pytest.raises(CorruptRecordError, match="end of file"):
        read_record_at(path, len(hand_built(PAYLOADS)))


def test_empty_file_has_no_records(tmp_path):
    path = tmp_path / "empty.tfrecord"
    path.write_bytes(b"")
    assert list(iter_records(path)) == []


def corrupt_read(tmp_path, raw: bytes) -> CorruptRecordError:
    """The error raised when reading raw as a TFRecord file."""
    path = tmp_path / "bad.tfrecord"
    path.write_bytes(raw)
    with pytest.raises(CorruptRecordError) as caught:
        list(iter_records(path))
    assert isinstance(caught.value, ParseError) and isinstance(caught.value, ValueError)
    assert str(path) in str(caught.value)
    return caught.value


def flip_bit(raw: bytes, byte_index: int) -> bytes:
    """raw with the lowest bit of one byte flipped."""
    return raw[:byte_index] + bytes([raw[byte_index] ^ 1]) + raw[byte_index + 1 :]


def test_flipped_bit_in_length_is_reported_at_its_record(tmp_path):
    raw = hand_built(PAYLOADS)
    second = offsets_of(PAYLOADS)[1]
    error = corrupt_read(tmp_path, flip_bit(raw, second + 2))
    assert error.offset == second
    assert "byte offset 28" in str(error) and "length field fails its CRC32C" in str(error)


def test_flipped_bit_in_data_is_reported_at_its_record(tmp_path):
    raw = hand_built(PAYLOADS)
    third = offsets_of(PAYLOADS)[2]
    error = corrupt_read(tmp_path, flip_bit(raw, third + 12 + 100))
    assert error.offset == third and "record data fails its CRC32C" in str(error)


def test_flipped_bit_in_data_crc_is_reported(tmp_path):
    raw = hand_built([b"abc"])
    error = corrupt_read(tmp_path, flip_bit(raw, len(raw) - 1))
    assert error.offset == 0 and "data fails" in str(error)


@pytest.mark.parametrize("cut", [1, 4, 11, 12, 20, 27])
def test_truncation_anywhere_in_a_record_is_reported(tmp_path, cut):
    raw = hand_built([b"payload-0123456"])  # 31 bytes in all
    error = corrupt_read(tmp_path, raw[:cut])
    assert error.offset == 0 and "truncated" in str(error)


def test_truncated_second_record_names_its_offset(tmp_path):
    raw = hand_built(PAYLOADS)
    error = corrupt_read(tmp_path, raw[:-3])
    assert error.offset == offsets_of(PAYLOADS)[2]


def test_lying_length_with_valid_crc_is_bounded(tmp_path):
    length = struct.pack("<Q", 1 << 40)
    raw = length + struct.pack("<I", masked_crc32c(length)) + b"short"
    error = corrupt_read(tmp_path, raw)
    assert "exceeds the limit" in str(error)
    small = struct.pack("<Q", 500)
    error = corrupt_read(tmp_path, small + struct.pack("<I", masked_crc32c(small)) + b"short")
    assert "only 5 left" in str(error)


def test_gzip_files_are_read_and_written_by_name(tmp_path):
    path = tmp_path / "records.tfrecord.gz"
    write_records(path, PAYLOADS)
    assert gzip.decompress(path.read_bytes()) == hand_built(PAYLOADS)
    assert list(read_records(path)) == PAYLOADS
    assert read_record_at(path, offsets_of(PAYLOADS)[2]) == PAYLOADS[2]


def test_truncated_gzip_is_a_corrupt_record(tmp_path):
    path = tmp_path / "cut.tfrecord.gz"
    path.write_bytes(gzip.compress(hand_built(PAYLOADS))[:-10])
    with pytest.raises(CorruptRecordError, match="cut.tfrecord.gz"):
        list(iter_records(path))


def test_not_gzip_despite_the_name(tmp_path):
    path = tmp_path / "plain.tfrecord.gz"
    path.write_bytes(hand_built(PAYLOADS))
    with pytest.raises(CorruptRecordError, match="plain.tfrecord.gz: corrupt TFRecord at byte offset 0"):
        list(iter_records(path))
