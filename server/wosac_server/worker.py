"""Scoring workers: OS processes that pull jobs from the database queue.

Each worker loops: reap stale leases, claim the oldest queued job, score it.
A job is scored in a child process forked for it, under an address-space limit
(`WOSAC_JOB_MEMORY_BYTES`) and a CPU-time limit (`WOSAC_JOB_CPU_BUDGET_S`), so a
hostile or huge submission fails its own job with the reason, never the worker or
the host. While the child scores, the worker's heartbeat thread renews the lease
every `heartbeat_s` and enforces the wall-time budget: past it the job is marked
failed and the child killed. The worker records the child's peak RSS and CPU time
on the job. A worker killed outright (kill -9, OOM) takes its child with it
(parent-death signal; a child that finds its worker already gone ends itself) and
stops renewing; its lease expires and the reaper puts the job back in the queue for
another worker. The child's own scoring processes (`WOSAC_SCORE_THREADS` > 1) end
with it (`wosac_eval.runtime.processes`).

Run one with `wosac-server worker` (configured by the same `WOSAC_*`
environment as the API); `wosac_server.pool.WorkerPool` starts and supervises N of them. With
`WOSAC_RAY_ADDRESS` set, each job is fanned out to that Ray cluster, so one
big submission uses every node.

A worker of a `WorkerPool` is started as `python -m wosac_server.worker_main
--parent-pid PID` and ends with that process from its first lines on, before the
slow imports of this module: a supervisor that dies (SIGTERM during its start-up,
SIGKILL, OOM) at any moment leaves no worker behind (`wosac_eval.runtime.processes`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import secrets
import signal
import socket
import sys
import threading
import time
import traceback
from collections.abc import Callable
from pathlib import Path

from wosac_eval.extras import EngineAuthenticationError, EngineNotInstalledError, EngineUnavailableError
from wosac_eval.options import Engine, MetadataChecks
from wosac_eval.parse.scenarios import ScenarioIndex
from wosac_eval.parse.submission_source import SubmissionSource
from wosac_eval.scoring.evaluation import Evaluation, RunOptions, resolve_evaluation
from wosac_eval.scoring.journal import remove_journal
from wosac_eval.scoring.submission import InvalidSubmissionError, score_submission

from . import disk, jobs, results
from .db import Store
from .job_limits import limit_this_process, why_child_ended
from .settings import Settings, load_settings
from .supervision import parent_pid_argument, tie_to_supervisor

log = logging.getLogger("wosac_server.worker")


def evaluation_of(job: dict, settings: Settings, objects: Path) -> Evaluation:
    """The job's evaluation, resolved as every front resolves one (the library's rules, the service's limits);
    its per-object values go to `objects` (the scene pages read them)."""
    options = RunOptions(
        limits=settings.input_limits(),
        engine=Engine.RAY if settings.ray_address else Engine.LOCAL,
        ray_address=settings.ray_address or None,
        workers=settings.score_threads,
        allow_partial=bool(job["allow_partial"]),
        metadata_checks=MetadataChecks.parse(settings.metadata_checks),
        per_object=True,
        objects=objects,
    )
    return resolve_evaluation(job["challenge"], job["config"], options)


def draw_worst_scenes(
    index: ScenarioIndex,
    source: SubmissionSource,
    result: dict,
    folder: Path,
    count: int,
    objects: Path | None = None,
    objects_index: Path | None = None,
) -> list[dict]:
    """Pictures of the `count` lowest meta-metric scenes of a result, with their index (scenes.json).

    The rollouts come from what the scoring's validation recorded of the submission (no new walk).
    Files are named by rank, never by scenario id: ids come from the submission. With the job's
    per-object files (`scene_objects`), each scene's entry lists its worst objects and the worst one is
    drawn against its log (`<rank>.object.png`, as `wosac-eval plot --object`).
    """
    from wosac_eval.results.object_plot import object_png
    from wosac_eval.results.report import worst_scenarios
    from wosac_eval.results.scene_plot import scene_png, scene_view
    from wosac_eval.results.worst_objects import scene_worst_objects
    from wosac_eval.scoring.result_reader import parse_result

    from .scene_objects import scene_records

    ids = worst_scenarios(parse_result(result, str(source)), count)
    row_of = {s["scenario_id"]: i for i, s in enumerate(result["scenarios"])}
    wanted = [sid for sid in ids if sid in index]
    rollouts = source.rollouts(wanted)
    folder.mkdir(parents=True, exist_ok=True)
    index_of_scenes = []
    for rank, scenario_id in enumerate(sid for sid in wanted if sid in rollouts):
        scenario = index.load(scenario_id)
        png = scene_png(scene_view(scenario, rollouts[scenario_id], result["challenge"]), dpi=80)
        (folder / f"{rank}.png").write_bytes(png)
        row = row_of[scenario_id]
        entry = {
            "rank": rank,
            "scenario_id": scenario_id,
            "metametric": result["scenarios"][row]["metametric"],
            "row": row,
            "worst_objects": [],
            "object_picture": False,
        }
        records = scene_records(objects, objects_index, row) if objects and objects_index else None
        if records:
            entry["worst_objects"] = scene_worst_objects(records, result["scenarios"][row], result["config"])
        if entry["worst_objects"]:
            try:
                picture = object_png(
                    scenario,
                    rollouts[scenario_id],
                    entry["worst_objects"][0]["object_id"],
                    result["challenge"],
                    dpi=70,
                    config=result["config"],
                )
            except Exception:  # noqa: BLE001  (a picture helps; the scene's entry stands without it)
                log.warning("the worst object of scene %d could not be drawn:\n%s", rank, traceback.format_exc())
                picture = None
            if picture is not None:
                (folder / f"{rank}.object.png").write_bytes(picture)
                entry["object_picture"] = True
        index_of_scenes.append(entry)
    jobs.write_json_atomically(folder / "scenes.json", {"scenes": index_of_scenes})
    return index_of_scenes


def journal_rows(path: Path) -> int:
    """Scenario rows a job's journal holds (complete lines after its header); 0 when there is none."""
    try:
        with open(path, "rb") as f:
            return max(0, sum(1 for line in f if line.endswith(b"\n")) - 1)
    except FileNotFoundError:
        return 0


# A Ray cluster that refuses a connection may be restarting, or its client server may have lost the
# process it started for us (ray-project/ray#63202): a job tries again, after 2 s then 4 s, before it fails.
ENGINE_ATTEMPTS = 3
ENGINE_RETRY_S = 2.0


def _with_engine_retries(job_id: str, score: Callable[[], dict]) -> dict:
    """`score()`, tried again up to ENGINE_ATTEMPTS in all while the scoring engine is unavailable (the
    engine is reached before any other work, so a try costs only the connection; the last error is raised
    with the number of attempts). A missing Ray package, or a token the cluster refuses, fails at once."""
    for attempt in range(1, ENGINE_ATTEMPTS + 1):
        try:
            return score()
        except (EngineNotInstalledError, EngineAuthenticationError):
            raise  # Ray is not installed here, or the cluster refused our token: no retry brings either
        except EngineUnavailableError as exc:
            if attempt == ENGINE_ATTEMPTS:
                raise EngineUnavailableError(f"{exc} ({ENGINE_ATTEMPTS} attempts)") from exc
            wait = ENGINE_RETRY_S * attempt
            log.warning(
                "worker %s: job %s: the scoring engine is unavailable (%s); trying again in %g s",
                os.getpid(),
                job_id,
                exc,
                wait,
            )
            time.sleep(wait)
    raise AssertionError("unreachable")  # the loop returns or raises


class _Heartbeat(threading.Thread):
    """Renews one job's lease while its child scores; kills the child when the job must stop."""

    def __init__(self, worker: Worker, job: dict, child: int):
        super().__init__(name=f"heartbeat-{job['id']}", daemon=True)
        self.worker = worker
        self.job = job
        self.child = child
        self.deadline = time.monotonic() + worker.settings.job_time_budget_s
        self.done = threading.Event()

    def stop_child(self) -> None:
        with contextlib.suppress(ProcessLookupError):  # already ended
            os.kill(self.child, signal.SIGKILL)  # its scoring pool's processes see it gone and end

    def run(self) -> None:
        w, job_id = self.worker, self.job["id"]
        failing = False
        while not self.done.wait(w.settings.heartbeat_s):
            if w.stopping or not w.parent_alive():
                jobs.release(w.store, job_id, w.owner)
                log.info("worker %s: released job %s on shutdown", os.getpid(), job_id)
                self.stop_child()
                return
            if disk.full_now(w.settings):
                self.deadline += w.settings.heartbeat_s  # the job waits for space (DiskWait): not its scoring time
            if time.monotonic() > self.deadline:
                budget = w.settings.job_time_budget_s
                jobs.finish_failed(
                    w.store,
                    job_id,
                    w.owner,
                    f"scoring exceeded its time budget of {budget:g} s (WOSAC_JOB_TIME_BUDGET_S) and "
                    "was stopped; a submission this large needs a larger budget",
                )
                log.error("worker %s: job %s exceeded its %g s budget", os.getpid(), job_id, budget)
                self.stop_child()
                return
            try:
                renewed = jobs.renew_lease(w.store, job_id, w.owner, w.settings.lease_s)
            except Exception as exc:  # noqa: BLE001 - database briefly unreachable, or its disk full: try again next beat
                if not failing:  # once per streak: a full disk can last hours
                    log.warning("worker %s: could not renew the lease of %s: %s", os.getpid(), job_id, exc)
                failing = True
                continue
            failing = False
            if not renewed:
                row = jobs.get_submission(w.store, job_id)
                if row is not None and row["state"] in ("done", "failed"):
                    return  # the child recorded the outcome and is ending: not a lost lease
                log.error("worker %s: lost the lease of job %s", os.getpid(), job_id)
                self.stop_child()
                return


class Worker:
    """One worker process's loop."""

    def __init__(self, settings: Settings, parent_pid: int | None = None):
        """`parent_pid`: the supervisor, as it told this process (`--parent-pid`); without one (a worker
        run on its own), the parent at this moment."""
        self.settings = settings
        self.parent_pid = os.getppid() if parent_pid is None else parent_pid
        self.store = Store(settings.resolved_db_url)
        self.owner = f"{socket.gethostname()}:{os.getpid()}:{secrets.token_hex(4)}"
        self.stopping = False
        self._last_upload_sweep = 0.0
        self.disk_wait = disk.DiskWait(settings, lambda: self.stopping or not self.parent_alive())

    def parent_alive(self) -> bool:
        # Re-parented means the supervisor died; stop rather than score unsupervised forever.
        return os.getppid() == self.parent_pid

    def run_forever(self) -> None:
        signal.signal(signal.SIGTERM, self._on_term)
        signal.signal(signal.SIGINT, self._on_term)
        # (A SIGTERM before the line above ended this process: nothing to release yet.)
        log.info("worker %s: ready, looking for queued jobs every %g s", os.getpid(), self.settings.poll_s)
        while not self.stopping and self.parent_alive():
            try:
                busy = self.run_once()
            except Exception as exc:
                if not disk.is_disk_full(exc):
                    raise
                self.disk_wait.wait(exc)  # reaping, claiming or sweeping could not write: wait, not crash-loop
                continue
            self.disk_wait.recovered()
            if not busy:
                time.sleep(self.settings.poll_s)

    def _on_term(self, signum, frame) -> None:
        self.stopping = True

    def run_once(self) -> bool:
        """Reap, then claim and score one job; False when the queue was empty."""
        jobs.reap_expired(self.store, self.settings.max_attempts)
        self._sweep_stale_uploads()
        job = jobs.claim_next(self.store, self.owner, self.settings.lease_s)
        if job is None:
            return False
        self.score_job(job)
        return True

    def _public(self, value, submission_path: Path):
        """`value` (a message, or a report's dict) without the server's absolute paths: the upload is
        called `submission`, scenario shards by their file names, other data-dir files relatively."""
        data_dir = self.settings.data_dir
        swaps = [(str(submission_path.resolve()), "submission"), (str(submission_path), "submission")]
        for shard in self.settings.scenario_paths():
            swaps += [(str(shard.resolve().parent) + os.sep, ""), (str(shard.parent) + os.sep, "")]
        swaps += [(str(data_dir.resolve()) + os.sep, ""), (str(data_dir) + os.sep, "")]
        return jobs.without_paths(value, swaps)

    def score_job(self, job: dict) -> None:
        """Score one claimed job in a child process under the job limits; record what it used."""
        settings, job_id = self.settings, job["id"]
        log.info("worker %s: scoring %s (attempt %d)", os.getpid(), job_id, job["attempts"])
        worker_pid = os.getpid()
        child = os.fork()
        if child == 0:  # the child: no thread of the worker runs here, its database connection is not used
            code = 1
            try:
                limit_this_process(settings, worker_pid)
                self.store = Store(settings.resolved_db_url)
                # It ends with its worker, so it never stops waiting; each try validates the upload again, so
                # tries come when space was freed, or else rarely.
                self.disk_wait = disk.DiskWait(settings, min_backoff_s=60.0, max_backoff_s=600.0)
                # A full disk (journal, result or database writes) is waited out, then the job is scored again
                # from its journal: what was computed is not lost, and the job is not failed for it.
                self.disk_wait.until_written(lambda: self.score_here(job))
                code = 0
            finally:
                os._exit(code)
        heartbeat = _Heartbeat(self, job, child)
        heartbeat.start()
        try:
            _, status, usage = os.wait4(child, 0)
        finally:
            heartbeat.done.set()
            heartbeat.join()
        peak_rss, cpu_s = usage.ru_maxrss * 1024, usage.ru_utime + usage.ru_stime
        self.disk_wait.until_written(
            lambda: self.store.execute(
                "UPDATE submissions SET peak_rss_bytes = ?, cpu_s = ? WHERE id = ?", (peak_rss, cpu_s, job_id)
            )
        )
        # Still ours and unfinished: the child died before recording an outcome.
        reason = why_child_ended(status, settings, peak_rss)
        if self.disk_wait.until_written(lambda: jobs.finish_failed(self.store, job_id, self.owner, reason)):
            log.error("worker %s: job %s failed: %s", os.getpid(), job_id, reason)
        self._drop_journal_if_ended(job_id)

    def _drop_journal_if_ended(self, job_id: str) -> None:
        """A job done or failed for good needs its journal no more (a re-queued one resumes from it)."""
        row = jobs.get_submission(self.store, job_id)
        if row is None or row["state"] in ("done", "failed"):
            remove_journal(self.settings.journal_path(job_id))  # with its validation and any set aside

    def draw_pictures(self, index: ScenarioIndex, source: SubmissionSource, result: dict, job_id: str) -> None:
        """The job's worst scenes; pictures help, but a drawing problem must not fail a scored job."""
        try:
            draw_worst_scenes(
                index,
                source,
                result,
                self.settings.scenes_dir(job_id),
                self.settings.scene_pictures,
                self.settings.objects_path(job_id),
                self.settings.objects_index_path(job_id),
            )
        except Exception:  # noqa: BLE001
            log.error("worker %s: pictures of %s failed:\n%s", os.getpid(), job_id, traceback.format_exc())

    def index_objects(self, result: dict, job_id: str) -> None:
        """The row index of the job's objects file (scene pages read one scene's objects through it); a
        problem here leaves the scene pages without worst objects, never fails a scored job."""
        from .scene_objects import write_index

        objects = self.settings.objects_path(job_id)
        if not objects.is_file():
            return
        try:
            write_index(
                objects, [row["scenario_id"] for row in result["scenarios"]], self.settings.objects_index_path(job_id)
            )
        except Exception as exc:
            if disk.is_disk_full(exc):
                raise  # waited out and done again, as every other write of the job
            log.error("worker %s: the objects index of %s failed:\n%s", os.getpid(), job_id, traceback.format_exc())

    def score_here(self, job: dict) -> None:
        """Score a job in this process and record its outcome (done or failed, with the reason)."""
        job_id = job["id"]
        submission_path = self.settings.submissions_dir / job["file_name"]
        try:
            scenarios = self.settings.scenario_paths()
            if not scenarios:
                jobs.finish_failed(
                    self.store, job_id, self.owner, "the server has no scenario shards configured (WOSAC_SCENARIOS)"
                )
                return
            result, scored_now = self._score(job, ScenarioIndex(scenarios), submission_path)
            jobs.finish_done(self.store, job_id, self.owner, result)
            log.info("worker %s: %s done (%d scenarios scored in this attempt)", os.getpid(), job_id, scored_now)
        except Exception as exc:  # a scorer bug must fail the job with a reason, not hang it
            if disk.is_disk_full(exc):
                raise  # not the submission's doing: until_written (score_job) waits for space and resumes
            error, report = self._failure(job_id, exc, submission_path)
            jobs.finish_failed(self.store, job_id, self.owner, error, report)

    def _score(self, job: dict, index: ScenarioIndex, submission_path: Path) -> tuple[dict, int]:
        """(the job's result, stored; the scenarios this attempt scored), its pictures drawn."""
        settings, job_id = self.settings, job["id"]
        evaluation = evaluation_of(job, settings, settings.objects_path(job_id))
        journal = settings.journal_path(job_id)
        resumed = journal_rows(journal)
        if resumed:
            log.info(
                "worker %s: job %s resumes from its journal: %d scenarios already scored", os.getpid(), job_id, resumed
            )
        # Validation walks the upload under the service's limits and records where each scenario is;
        # scoring and the pictures stream the archive again rather than keep a decompressed copy on disk.
        with SubmissionSource(submission_path, evaluation.options.limits) as source:
            # The same function `wosac-eval score` calls; finished scenarios go to the journal as they are
            # scored, so a retry after this process died (or waited out a full disk) skips them.
            # Per-object values too: streamed from the journal into the objects file (never all in memory),
            # then indexed by row so that a scene's worst objects are read without a pass over the file.
            result = _with_engine_retries(
                job_id,
                lambda: score_submission(
                    index,
                    source,
                    progress=self._progress_of(job_id),
                    evaluation=evaluation,
                    journal=journal,
                ),
            )
            # The objects file is the server's own (scene pages): the result served stays the document of
            # `wosac-eval score` without --per-object, byte for byte.
            result.pop("per_object", None)
            # The summary and the rows apart (results.py): served in bounded memory, however many rows.
            results.write_result(settings.results_dir, job_id, result)
            self.index_objects(result, job_id)
            if settings.scene_pictures:
                self.draw_pictures(index, source, result, job_id)
        return result, journal_rows(journal) - resumed

    def _progress_of(self, job_id: str) -> Callable[[int, int], None]:
        """The job's progress, written at most every 0.5 s (and at its first and last scenario)."""
        last_write = [0.0]

        def progress(done: int, total: int) -> None:
            now = time.monotonic()
            if done in (0, total) or now - last_write[0] >= 0.5:
                last_write[0] = now
                try:
                    jobs.record_progress(self.store, job_id, self.owner, done, total)
                except Exception as exc:
                    if not disk.is_disk_full(exc):
                        raise  # progress is only shown: a full disk must not stop the scoring for it

        return progress

    def _failure(self, job_id: str, exc: Exception, submission_path: Path) -> tuple[str, dict | None]:
        """(the failed job's error, its validation report) for a submission that could not be scored, as its
        sender may see them (no server path)."""
        if isinstance(exc, InvalidSubmissionError):
            report = getattr(exc, "report", None)
            payload = None
            if report is not None:
                payload = self._public({"text": report.format_text(), "details": report.to_dict()}, submission_path)
            return self._public(
                f"the submission is invalid: {exc.reason}; the report lists each", submission_path
            ), payload
        if isinstance(exc, MemoryError):
            return (
                f"scoring ran out of its memory limit of {self.settings.job_memory_bytes} bytes "
                "(WOSAC_JOB_MEMORY_BYTES) and was stopped"
            ), None
        if isinstance(exc, EngineUnavailableError):  # the Ray cluster is down or refuses us: its own one sentence
            log.error("worker %s: job %s: %s", os.getpid(), job_id, exc)
            return self._public(f"the scoring engine is unavailable: {exc}", submission_path), None
        if isinstance(exc, ValueError):  # e.g. no scenario in common with the server's scenario set
            return self._public(f"the submission could not be scored: {exc}", submission_path), None
        log.error("worker %s: job %s crashed:\n%s", os.getpid(), job_id, traceback.format_exc())
        return self._public(f"internal error while scoring ({type(exc).__name__}: {exc})", submission_path), None

    def _sweep_stale_uploads(self) -> None:
        now = time.time()
        if now - self._last_upload_sweep < 60:
            return
        self._last_upload_sweep = now
        # Journals of jobs that ended elsewhere (failed by the reaper, or by the time budget).
        for journal in self.settings.results_dir.glob("*.journal"):
            self._drop_journal_if_ended(journal.name.split(".")[0])
        for row in jobs.expired_uploads(self.store, now - self.settings.upload_ttl_s):
            part = self.settings.uploads_dir / f"{row['id']}.part"
            part.unlink(missing_ok=True)
            self.store.execute("DELETE FROM uploads WHERE id = ? AND submission_id IS NULL", (row["id"],))


def main(parent_pid: int | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    Worker(load_settings(), parent_pid).run_forever()
    return 0


if __name__ == "__main__":  # `WorkerPool` starts `wosac_server.worker_main`, which ties before the slow imports
    _parent_pid = parent_pid_argument(sys.argv[1:])
    if _parent_pid is not None:
        tie_to_supervisor(_parent_pid)
    sys.exit(main(_parent_pid))
