"""Service configuration, read once from `WOSAC_*` environment variables.

Every knob has a safe default so `wosac-server serve` runs with only
`WOSAC_SCENARIOS` set. Values are validated by pydantic at start-up, so a typo
in a number fails loudly before the first request instead of mid-job.
"""

from __future__ import annotations

import argparse
import glob
import os
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, Field, field_validator

ENV_PREFIX = "WOSAC_"
_DATA_DIR_HELP = "service data dir (WOSAC_DATA_DIR)"

GiB = 1024**3
MiB = 1024**2


class Settings(BaseModel):
    """The service's whole configuration (one instance per process)."""

    scenarios: list[str] = Field(
        default_factory=list,
        description="Scenario TFRecord shards to score against (WOSAC_SCENARIOS: paths or globs, "
        "separated by ',' or os.pathsep).",
    )
    data_dir: Path = Field(Path("wosac-data"), description="Uploads, results and the SQLite file.")
    db_url: str = Field("", description="sqlite:///path or postgresql://...; default: SQLite in data_dir.")
    max_upload_bytes: int = Field(
        64 * GiB,
        gt=0,
        description="Largest accepted submission, however sent "
        "(a resumable upload's whole length; WOSAC_MAX_UPLOAD_BYTES).",
    )
    max_single_upload_bytes: int = Field(
        16 * GiB,
        gt=0,
        description="Largest body of a single-request upload "
        "(POST /v1/submissions; WOSAC_MAX_SINGLE_UPLOAD_BYTES): larger ones go "
        "through /v1/uploads in chunks (`wosac-eval submit`).",
    )
    # Disk space of data_dir: past the floor new uploads and chunks get 507 (see wosac_server.disk).
    min_free_fraction: float = Field(
        0.10,
        ge=0,
        lt=1,
        description="Share of the data dir's disk kept free: "
        "uploads are refused once free space less what open uploads and queued "
        "jobs still need would fall below it (WOSAC_MIN_FREE_FRACTION).",
    )
    min_free_bytes: int = Field(
        0, ge=0, description="The same floor in bytes; the larger of the two counts (WOSAC_MIN_FREE_BYTES)."
    )
    disk_reserve_bytes: int = Field(
        64 * MiB,
        ge=0,
        description="A file of this size kept in the data dir and "
        "deleted when the disk fills, so that the database can still record "
        "upload states (WOSAC_DISK_RESERVE_BYTES; 0: none).",
    )
    workers: int = Field(1, ge=0, le=256, description="Scoring worker processes (0: API only).")
    score_threads: int = Field(1, ge=1, le=256, description="`workers=` passed to score_submission per job.")
    job_time_budget_s: float = Field(6 * 3600.0, gt=0, description="Wall time one scoring attempt may take.")
    lease_s: float = Field(30.0, gt=0, description="A claimed job is re-queued when its lease is this stale.")
    heartbeat_s: float = Field(5.0, gt=0, description="How often a busy worker renews its lease.")
    poll_s: float = Field(1.0, gt=0, description="How often an idle worker looks for a queued job.")
    max_attempts: int = Field(3, ge=1, description="Attempts before a job whose workers keep dying fails.")
    default_max_concurrent: int = Field(2, ge=1, description="Per-key running+queued jobs (new keys).")
    default_max_daily: int = Field(50, ge=1, description="Per-key submissions per 24 h (new keys).")
    default_max_daily_bytes: int = Field(
        128 * GiB,
        ge=1,
        description="Per-key upload bytes per 24 h (new keys): two validation-size submissions and a retry.",
    )
    shutdown_grace_s: float = Field(10.0, gt=0, description="On SIGTERM: wait this long for requests in flight.")
    configs: list[str] = Field(
        default_factory=lambda: ["2025", "2024", "2023", "scenario_gen_2025"],
        description="Metric configs a submission may ask for (WOSAC_CONFIGS, comma-separated).",
    )
    ray_address: str = Field(
        "",
        description="A Ray cluster (host:port or ray://host:10001) each job is fanned "
        "out to (WOSAC_RAY_ADDRESS); empty: score in this host's processes.",
    )
    metadata_checks: Literal["error", "warn"] = Field(
        "error",
        description="How a submission's metadata gaps (account, method name, flags) count (WOSAC_METADATA_CHECKS): "
        "error, as the challenge server (the job fails validation), or warn (listed, the job is scored).",
    )
    scene_pictures: int = Field(
        3,
        ge=0,
        le=20,
        description="Pictures of the lowest meta-metric scenes drawn "
        "after scoring, shown on the submission page (WOSAC_SCENE_PICTURES; 0: none).",
    )
    upload_ttl_s: float = Field(7 * 24 * 3600.0, gt=0, description="Unfinished resumable uploads expire after this.")
    max_open_uploads: int = Field(4, ge=1, description="Unfinished resumable uploads one key may hold at a time.")

    # How far an upload may expand (checked at upload, again by the worker before parsing).
    max_shard_bytes: int = Field(4 * GiB, gt=0, description="One shard of a submission, decompressed.")
    max_decompressed_bytes: int = Field(
        256 * GiB,
        gt=0,
        description="A whole submission, decompressed (read as a "
        "stream, never stored: a 64 GiB upload may expand 1.1-3x).",
    )
    max_compression_ratio: float = Field(
        100.0, gt=1, description="A compressed upload may expand at most this many times its size..."
    )
    compression_ratio_floor_bytes: int = Field(64 * MiB, gt=0, description="...once past this many bytes.")
    max_archive_members: int = Field(10_000, ge=1, description="Entries of an uploaded tar archive.")
    max_scenarios: int = Field(100_000, ge=1, description="scenario_rollouts entries of one submission.")
    api_threads: int = Field(
        8, ge=1, le=256, description="Threads of the API process for blocking work (database, files, upload checks)."
    )
    upload_checks: int = Field(
        2,
        ge=1,
        le=64,
        description="Uploads checked at the same time (the rest wait); each check decompresses the upload once.",
    )

    # What one scoring job may use; past it the job fails with the reason, never the host.
    job_memory_bytes: int = Field(
        8 * GiB, ge=0, description="Address space of a job's scoring process (RLIMIT_AS; 0: no limit)."
    )
    job_nice: int = Field(
        10, ge=0, le=19, description="How much lower a job's CPU priority is than the API's (added niceness)."
    )
    job_cpu_budget_s: float = Field(
        6 * 3600.0, ge=0, description="CPU seconds a job's scoring process may use (RLIMIT_CPU; 0: no limit)."
    )

    # Connections and authentication.
    header_timeout_s: float = Field(10.0, gt=0, description="A client must send its request headers within this.")
    body_timeout_s: float = Field(60.0, gt=0, description="A request body may pause at most this long between chunks.")
    max_connections_per_client: int = Field(32, ge=1, description="Open connections from one client address.")
    auth_failures_per_minute: int = Field(
        20, ge=1, description="Failed authentications per client address per minute before further attempts get 429."
    )
    trusted_proxies: str = Field(
        "",
        description="Addresses or networks (comma-separated, e.g. 10.0.0.5,"
        "172.16.0.0/12) of the reverse proxies whose X-Forwarded-For and "
        "X-Forwarded-Proto headers are believed; default none: the peer address "
        "counts, whatever the headers say (per-address caps and the guessing throttle).",
    )
    body_grace_s: float = Field(
        20.0, gt=0, description="A request body may take this long before its rate counts (WOSAC_BODY_GRACE_S)..."
    )
    body_min_rate: float = Field(
        500.0,
        ge=0,
        description="...then it must average at least this many bytes/s, "
        "else it is closed (WOSAC_BODY_MIN_RATE; 0: no rate rule).",
    )
    request_deadline_s: float = Field(
        3600.0,
        gt=0,
        description="A request's headers and body must be in within this of its first byte (WOSAC_REQUEST_DEADLINE_S).",
    )
    max_connections: int = Field(
        0, ge=0, description="Open connections in all (WOSAC_MAX_CONNECTIONS); 0: sized from the open-file limit."
    )
    cors_origins: str = Field(
        "",
        description="Origins (comma-separated, e.g. https://challenge.example.org; `*`: any) whose pages may call "
        "the API from a browser, e.g. a tus uploader on another site (WOSAC_CORS_ORIGINS); default none. "
        "Never with credentials: the key travels in Authorization.",
    )

    @field_validator("configs", mode="before")
    @classmethod
    def _split_configs(cls, value):
        if isinstance(value, str):
            return [p.strip() for p in value.split(",") if p.strip()]
        return value

    @field_validator("scenarios", mode="before")
    @classmethod
    def _split_scenarios(cls, value):
        if isinstance(value, str):
            parts = [p.strip() for chunk in value.split(",") for p in chunk.split(os.pathsep)]
            return [p for p in parts if p]
        return value

    @property
    def cors_origin_list(self) -> list[str]:
        return [o.strip().rstrip("/") for o in self.cors_origins.split(",") if o.strip()]

    def input_limits(self):
        """The `InputLimits` every upload check and scoring job applies."""
        from wosac_eval.parse.limits import InputLimits

        return InputLimits(
            max_member_bytes=self.max_shard_bytes,
            max_total_bytes=self.max_decompressed_bytes,
            max_members=self.max_archive_members,
            max_compression_ratio=self.max_compression_ratio,
            ratio_floor_bytes=self.compression_ratio_floor_bytes,
            max_scenarios=self.max_scenarios,
        )

    @property
    def resolved_db_url(self) -> str:
        return self.db_url or f"sqlite:///{(self.data_dir / 'wosac.sqlite3').resolve()}"

    def scenario_paths(self) -> list[Path]:
        """The configured scenario shards with globs expanded, sorted, de-duplicated."""
        found: set[Path] = set()
        for pattern in self.scenarios:
            matches = glob.glob(os.path.expanduser(pattern))
            found.update(Path(m).resolve() for m in matches)
        return sorted(found)

    # Folders inside data_dir; every file the service writes lives under one of them.
    @property
    def uploads_dir(self) -> Path:
        return self.data_dir / "uploads"

    @property
    def submissions_dir(self) -> Path:
        return self.data_dir / "submissions"

    @property
    def results_dir(self) -> Path:
        return self.data_dir / "results"

    def journal_path(self, submission_id: str) -> Path:
        """The rows of a job's scored scenarios (`score_submission(journal=)`): a retry after its worker
        died resumes from them; removed when the job ends."""
        return self.results_dir / f"{submission_id}.journal"

    @property
    def disk_reserve_path(self) -> Path:
        return self.data_dir / "disk-reserve"

    def scenes_dir(self, submission_id: str) -> Path:
        """Pictures of a scored submission's worst scenes, and their index `scenes.json`."""
        return self.results_dir / f"{submission_id}.scenes"

    def objects_path(self, submission_id: str) -> Path:
        """A scored submission's per-object values (`score_submission(per_object=True, objects=)`): one JSON
        record a line per evaluated object, grouped by scene in the result's order."""
        return self.results_dir / f"{submission_id}.objects.jsonl"

    def objects_index_path(self, submission_id: str) -> Path:
        """Where each result row's objects start in `objects_path` (`scene_objects.py`)."""
        return self.results_dir / f"{submission_id}.objects.idx"

    def ensure_dirs(self) -> None:
        for d in (self.data_dir, self.uploads_dir, self.submissions_dir, self.results_dir):
            d.mkdir(parents=True, exist_ok=True)


def operator_store(data_dir: str | None):
    """(settings, migrated job store) for the operator's commands (`keys`, `methods`); `data_dir`
    (their --data-dir) overrides WOSAC_DATA_DIR."""
    from .db import Store

    if data_dir:
        os.environ["WOSAC_DATA_DIR"] = data_dir
    settings = load_settings()
    settings.ensure_dirs()
    store = Store(settings.resolved_db_url)
    store.migrate()
    return settings, store


def load_settings(environ: dict[str, str] | None = None) -> Settings:
    """Build `Settings` from `WOSAC_<FIELD>` variables (field name upper-cased)."""
    env = os.environ if environ is None else environ
    values = {}
    for name in Settings.model_fields:
        raw = env.get(ENV_PREFIX + name.upper())
        if raw is not None and raw != "":
            values[name] = raw
    settings = Settings(**values)
    settings.data_dir = settings.data_dir.expanduser().resolve()
    return settings


def add_data_dir_option(command: argparse.ArgumentParser, actions: list[argparse.ArgumentParser]) -> None:
    """`--data-dir` before or after an operator command's action (`keys --data-dir D create ...` and
    `keys create ... --data-dir D`); given after, it wins."""
    command.add_argument("--data-dir", help=_DATA_DIR_HELP)
    for action in actions:
        action.add_argument("--data-dir", default=argparse.SUPPRESS, help=_DATA_DIR_HELP)
