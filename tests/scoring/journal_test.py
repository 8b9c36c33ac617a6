"""An interrupted scoring run resumes from its journal and writes the document an uninterrupted run writes."""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from support.runs import WOSAC_EVAL
from support.submissions import replicated_submission
from wosac_eval.scoring.submission import score_submission

N = 24


@pytest.fixture(scope="module")
def workload(tmp_path_factory):
    from support.paths import require_shared

    require_shared()
    return replicated_submission(tmp_path_factory.mktemp("journal"), N, per_shard=5)


@pytest.fixture(scope="module")
def uninterrupted(workload):
    scenarios, submission = workload
    return json.loads(json.dumps(score_submission([scenarios], submission)))


def _journal_lines(path: Path) -> list[bytes]:
    return path.read_bytes().splitlines(keepends=True)


def _progress_log():
    calls: list[tuple[int, int]] = []
    return calls, lambda done, total: calls.append((done, total))


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_journal_holds_every_row_and_resuming_scores_only_the_rest(workload, uninterrupted, tmp_path):
    scenarios, submission = workload
    journal = tmp_path / "run.journal"
    score_submission([scenarios], submission, journal=journal)
    lines = _journal_lines(journal)
    assert len(lines) == 1 + N  # the run's identity, then one row per scenario
    # As a kill would leave it: 10 rows, then half of the 11th.
    journal.write_bytes(b"".join(lines[:11]) + lines[11][: len(lines[11]) // 2])
    calls, progress = _progress_log()
    resumed = score_submission([scenarios], submission, journal=journal, progress=progress)
    assert json.loads(json.dumps(resumed)) == uninterrupted
    assert calls[0] == (10, N)  # the journal's rows counted as done, not scored again
    assert [done for done, _ in calls[1:]] == [10 + 8, 10 + 14]  # the 14 others, in tasks of 8
    assert len(_journal_lines(journal)) == 1 + N and journal.read_bytes().endswith(b"\n")


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_a_resumed_run_takes_the_validation_it_kept(workload, uninterrupted, tmp_path, monkeypatch):
    """Validation walks the whole submission (a quarter of a full run): the journal keeps it."""
    from wosac_eval.scoring import submission as scoring
    from wosac_eval.scoring.journal import remove_journal, validated_path

    scenarios, submission = workload
    journal = tmp_path / "run.journal"
    walks = []
    real = scoring.validate_submission
    monkeypatch.setattr(scoring, "validate_submission", lambda *a, **k: walks.append(1) or real(*a, **k))
    score_submission([scenarios], submission, journal=journal)
    assert walks == [1] and validated_path(journal).exists()
    lines = _journal_lines(journal)
    journal.write_bytes(b"".join(lines[:6]))  # killed after 5 rows
    resumed = score_submission([scenarios], submission, journal=journal)
    assert walks == [1]  # not walked again
    assert json.loads(json.dumps(resumed)) == uninterrupted
    validated_path(journal).write_bytes(b"cut sh")  # a kill while it was written: validated again
    journal.write_bytes(b"".join(lines[:6]))
    assert json.loads(json.dumps(score_submission([scenarios], submission, journal=journal))) == uninterrupted
    assert walks == [1, 1]
    score_submission([scenarios], submission, "2024", journal=journal)  # another run: its own validation
    assert walks == [1, 1, 1]
    remove_journal(journal)
    assert not journal.exists() and not validated_path(journal).exists()


def test_a_run_resumed_late_reads_the_members_it_kept_not_the_archive(workload, uninterrupted, tmp_path):
    """The last members of an archive stay beside the journal: a run resumed after every earlier member was
    scored reads those files and does not decompress the archive again (here it could not: its bytes are
    zeroed, its size and time kept, so that the run's identity is the same)."""
    import pickle
    import shutil

    from wosac_eval.scoring.journal import members_path, remove_journal, validated_path

    scenarios, original = workload
    submission = Path(shutil.copy2(original, tmp_path / original.name))
    journal = tmp_path / "run.journal"
    score_submission([scenarios], submission, journal=journal)
    records = pickle.loads(validated_path(journal).read_bytes())["records"]
    kept = [shard for shard, _ in records if shard.path is not None]
    assert kept and all(Path(shard.path).parent == members_path(journal) for shard in kept)
    assert [shard.name for shard, _ in records][-len(kept) :] == [shard.name for shard in kept], "the last ones"
    assert sum(shard.size for shard in kept) <= submission.stat().st_size
    left = len(records[-1][1])  # the last member's scenarios are not scored yet
    journal.write_bytes(b"".join(_journal_lines(journal)[: 1 + N - left]))
    stat = submission.stat()
    submission.write_bytes(bytes(stat.st_size))
    os.utime(submission, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    calls, progress = _progress_log()
    resumed = score_submission([scenarios], submission, journal=journal, progress=progress)
    assert json.loads(json.dumps(resumed)) == uninterrupted
    assert calls[0] == (N - left, N) and calls[-1] == (N, N)
    remove_journal(journal)
    assert not members_path(journal).exists()


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_journal_of_another_run_is_set_aside(workload, uninterrupted, tmp_path, caplog):
    scenarios, submission = workload
    journal = tmp_path / "run.journal"
    score_submission([scenarios], submission, "2024", journal=journal)  # another config: other rows
    with caplog.at_level(logging.WARNING, logger="wosac_eval.scoring.journal"):
        calls, progress = _progress_log()
        result = score_submission([scenarios], submission, journal=journal, progress=progress)
    assert json.loads(json.dumps(result)) == uninterrupted
    assert calls[0] == (0, N)
    assert "another run" in caplog.text and (tmp_path / "run.journal.old").exists()
    journal.write_bytes(b"not a journal\n")
    with caplog.at_level(logging.WARNING, logger="wosac_eval.scoring.journal"):
        score_submission([scenarios], submission, journal=journal)
    assert "not a scoring journal" in caplog.text


def _cli(*args: str) -> list[str]:
    return [*WOSAC_EVAL, "score", *args]


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_cli_interrupted_then_run_again_writes_the_same_document(workload, uninterrupted, tmp_path):
    scenarios, submission = workload
    output = tmp_path / "result.json"
    journal = tmp_path / "result.json.journal"
    command = _cli("--scenarios", str(scenarios), "--submission", str(submission), "-o", str(output))
    run = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and run.poll() is None:
        if journal.exists() and len(_journal_lines(journal)) >= 1 + 8:  # the first task's rows are in
            break
        time.sleep(0.01)
    assert run.poll() is None, "the run ended before it could be interrupted"
    run.send_signal(signal.SIGINT)  # Ctrl-C
    _, stderr = run.communicate(timeout=60)
    assert run.returncode == 130, stderr
    assert f"kept in {journal}" in stderr and not output.exists()
    kept = len(_journal_lines(journal)) - 1
    assert 8 <= kept < N

    again = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert f"resuming from {journal}" in again.stderr
    assert json.loads(output.read_text()) == uninterrupted
    assert not journal.exists() and not (tmp_path / "result.json.journal.validated").exists()  # nothing to resume
    assert not [p for p in os.listdir(tmp_path) if p.endswith(".tmp")]


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_cli_restart_discards_the_journal(workload, uninterrupted, tmp_path):
    scenarios, submission = workload
    output = tmp_path / "result.json"
    (tmp_path / "result.json.journal").write_bytes(b"left over\n")
    done = subprocess.run(
        _cli(
            "--scenarios",
            str(scenarios),
            "--submission",
            str(submission),
            "-o",
            str(output),
            "--restart",
            "--no-analysis",
        ),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    assert "resuming" not in done.stderr and not (tmp_path / "result.json.journal").exists()
    assert json.loads(output.read_text())["buckets"] == uninterrupted["buckets"]
    usage = subprocess.run(
        _cli("--scenarios", str(scenarios), "--submission", str(submission), "--restart"),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert usage.returncode == 2 and "--restart needs --output" in usage.stderr


def test_a_refused_submission_keeps_no_member(workload, tmp_path):
    from wosac_eval.scoring.journal import members_path
    from wosac_eval.scoring.submission import InvalidSubmissionError

    _, submission = workload
    fewer, _ = replicated_submission(tmp_path, 6, per_shard=5)  # 18 submitted scenarios it lacks
    journal = tmp_path / "run.journal"
    with pytest.raises(InvalidSubmissionError):
        score_submission([fewer], submission, journal=journal)
    assert not members_path(journal).exists()


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_a_resumed_run_whose_kept_members_are_gone_streams_them_again(workload, uninterrupted, tmp_path):
    import shutil

    from wosac_eval.scoring.journal import members_path

    scenarios, submission = workload
    journal = tmp_path / "run.journal"
    score_submission([scenarios], submission, journal=journal)
    assert any(members_path(journal).iterdir())
    shutil.rmtree(members_path(journal))
    journal.write_bytes(b"".join(_journal_lines(journal)[:4]))  # killed after 3 rows
    assert json.loads(json.dumps(score_submission([scenarios], submission, journal=journal))) == uninterrupted


@pytest.mark.parametrize(
    ("tamper", "named"),
    [
        (lambda row: [row], "a list, not a row"),
        (lambda row: {k: v for k, v in row.items() if k != "scenario_id"}, "no scenario_id"),
        (lambda row: {**row, "metametric": "high"}, "without a meta-metric"),
        (lambda row: {k: v for k, v in row.items() if k != "by_object_type"}, "other fields than the rows before"),
    ],
    ids=["not-a-row", "no-id", "bad-metametric", "fields-missing"],
)
def test_a_damaged_journal_is_named_with_what_to_do(workload, tmp_path, tamper, named):
    """A record of this run's journal altered after it was written (valid JSON, not a row of the run): the
    resumed run stops with one sentence naming the journal, the line and --restart, not an internal error.
    (`wosac-eval score` prints a ValueError's sentence as its own.)"""
    from wosac_eval.scoring.journal import JournalDamaged

    scenarios, submission = workload
    journal = tmp_path / "run.journal"
    score_submission([scenarios], submission, journal=journal)
    lines = _journal_lines(journal)
    lines[3] = (json.dumps(tamper(json.loads(lines[3]))) + "\n").encode()
    journal.write_bytes(b"".join(lines))
    with pytest.raises(JournalDamaged) as caught:
        score_submission([scenarios], submission, journal=journal)
    message = str(caught.value)
    assert isinstance(caught.value, ValueError) and named in message
    assert f"the journal {journal}" in message and "line 4" in message and "--restart" in message
    assert "damaged or altered" in message
