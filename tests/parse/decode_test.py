"""decode_message: a parse refused for memory is a MemoryError, damaged bytes stay a DecodeError."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

# Each run is a process of its own: it lowers its address-space limit to `mapped + margin` bytes
# and prints, line by line, what each parse gave.
_PROGRAM = textwrap.dedent("""
    import resource, sys
    from google.protobuf.message import DecodeError
    from wosac_eval.parse.decode import decode_message
    from wosac_eval.protos import scenario_pb2

    scenario = scenario_pb2.Scenario(scenario_id="big")
    for track_id in range(400):  # about 1 MB on the wire
        track = scenario.tracks.add(id=track_id)
        for step in range(91):
            track.states.add(center_x=step + 0.5, center_y=track_id + 0.25, velocity_x=1.5, valid=True)
    data = scenario.SerializeToString()

    def outcome(parse, data):
        try:
            parse(data)
            return "parsed"
        except (DecodeError, MemoryError) as error:
            return type(error).__name__

    with open("/proc/self/statm") as statm:
        mapped = int(statm.read().split()[0]) * resource.getpagesize()
    hard = resource.getrlimit(resource.RLIMIT_AS)[1]
    soft = mapped + int(sys.argv[1])
    resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
    print("runtime:", outcome(scenario_pb2.Scenario.FromString, data), flush=True)
    print("valid:", outcome(lambda d: decode_message(scenario_pb2.Scenario, d), data), flush=True)
    print("damaged:", outcome(lambda d: decode_message(scenario_pb2.Scenario, d), data[: len(data) // 2]), flush=True)
    print("limit kept:", resource.getrlimit(resource.RLIMIT_AS) == (soft, hard), flush=True)
""")


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_a_parse_refused_for_memory_is_a_memory_error_and_damaged_bytes_stay_a_decode_error(tmp_path):
    # Where upb's first refused allocation lands depends on the margin, and at some margins upb
    # itself crashes (SIGSEGV) instead of failing the parse: a process of the service's jobs ended
    # so is reported by its signal (job_limits.why_child_ended). So several margins are tried, and each
    # line a run printed before it ended is checked.
    printed = []
    for margin in range(0, 2**21 + 1, 2**17):
        done = subprocess.run(  # (not run in the repository: `-c` imports from its working folder)
            [sys.executable, "-c", _PROGRAM, str(margin)], capture_output=True, text=True, timeout=60, cwd=tmp_path
        )
        assert done.returncode in (0, -11), (margin, done.returncode, done.stderr)
        printed.append(dict(line.split(": ") for line in done.stdout.splitlines()))
    for lines in printed:
        assert lines.get("valid", "MemoryError") in ("MemoryError", "parsed"), printed  # never "damaged"
        assert lines.get("damaged", "DecodeError") == "DecodeError", printed
        assert lines.get("limit kept", "True") == "True", printed
    # The reason decode_message exists: the runtime reports a refused allocation as damaged bytes.
    assert any(
        lines.get("runtime") == "DecodeError"
        and lines.get("valid") == "MemoryError"
        and lines.get("damaged") == "DecodeError"
        for lines in printed
    ), printed
