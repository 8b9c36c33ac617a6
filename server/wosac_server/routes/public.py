"""The routes that need no key: the leaderboards and the health check."""
from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from .. import jobs
from ..models import Health, Leaderboard, LeaderboardEntry, iso
from ..service import ServiceDep
from .params import ChallengeQ, ConfigQ

router = APIRouter()


@router.get("/healthz", response_model=Health, tags=["service"], operation_id="health")
async def healthz(svc: ServiceDep):
    # On the event loop, not in the thread pool that uploads and pages share: it answers while they queue.
    shards = len(svc.settings.scenario_paths())
    try:
        svc.store.ping()
    except Exception as exc:  # the answer must say the DB is down, not crash
        return JSONResponse({"status": "error", "database": f"unreachable: {exc}", "scenario_shards": shards},
                            status_code=503)
    return Health(status="ok", database="ok", scenario_shards=shards)


@router.get("/v1/leaderboard", response_model=Leaderboard, tags=["leaderboard"], operation_id="leaderboard")
def get_leaderboard(svc: ServiceDep, challenge: ChallengeQ = "sim_agents", config: ConfigQ = None):
    """Best published result per method, one leaderboard per challenge and config (public, no key needed)."""
    config = svc.config_for(challenge, config)
    entries = [LeaderboardEntry(**{**e, "finished_at": iso(e["finished_at"])})
               for e in jobs.leaderboard(svc.store, config, challenge)]
    return Leaderboard(challenge=challenge, config=config, entries=entries)
