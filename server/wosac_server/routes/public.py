"""The routes that need no key: the leaderboards and the health check."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from ..models import DiskHealth, Health, Leaderboard, LeaderboardEntry, iso
from ..reading import ReadingDep
from ..service import ServiceDep
from .params import ChallengeQ, ConfigQ

router = APIRouter()


@router.get("/healthz", response_model=Health, tags=["service"], operation_id="health")
async def healthz(svc: ServiceDep):
    # On the event loop, not in the thread pool that uploads and pages share: it answers while they queue.
    shards = len(svc.settings.scenario_paths())
    try:
        svc.store.ping()
    except Exception as exc:  # noqa: BLE001 - the answer must say the DB is down, not crash
        return JSONResponse(
            {"status": "error", "database": f"unreachable: {exc}", "scenario_shards": shards}, status_code=503
        )
    try:
        state = svc.disk_state()
    except OSError:  # the data dir itself is unreadable: uploads fail, status and results may still be served
        return Health(status="degraded", database="ok", scenario_shards=shards)
    # Still 200 while uploads are refused: status, results and the leaderboard are served, and a restart
    # (what a failed health check brings) would free no space.
    disk = DiskHealth(
        free_bytes=state.free, reserved_bytes=state.reserved, floor_bytes=state.floor, refusing_uploads=state.refusing
    )
    return Health(status="degraded" if state.refusing else "ok", database="ok", scenario_shards=shards, disk=disk)


@router.get("/v1/leaderboard", response_model=Leaderboard, tags=["leaderboard"], operation_id="leaderboard")
def get_leaderboard(read: ReadingDep, challenge: ChallengeQ = "sim_agents", config: ConfigQ = None):
    """Best published result per method, one leaderboard per challenge and config (public, no key needed)."""
    config, rows = read.leaderboard(challenge, config)
    entries = [LeaderboardEntry(**{**e, "finished_at": iso(e["finished_at"])}) for e in rows]
    return Leaderboard(challenge=challenge, config=config, entries=entries)
