# wosac-eval scoring service: `wosac-eval serve` (API + scoring worker processes).
#
#   docker build -t wosac-eval .
#   docker run -p 8000:8000 -v /path/to/womd/validation:/scenarios:ro -v wosac-data:/data wosac-eval
#   docker run --rm -v wosac-data:/data wosac-eval keys create --name my-team
#
# Configuration is by WOSAC_* environment variables (README, "Scoring service").
# PostgreSQL instead of the SQLite file in /data: -e WOSAC_DB_URL=postgresql://user:pass@host/db

FROM python:3.11-slim-bookworm AS build
WORKDIR /src
COPY pyproject.toml README.md ./
COPY wosac_eval ./wosac_eval
# Wheels for the package and every dependency, so the runtime stage needs no compiler or network.
RUN pip wheel --no-cache-dir --wheel-dir /wheels ".[postgres]"

FROM python:3.11-slim-bookworm
ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    WOSAC_HOST=0.0.0.0 \
    WOSAC_PORT=8000 \
    WOSAC_DATA_DIR=/data \
    WOSAC_SCENARIOS="/scenarios/*tfrecord*" \
    WOSAC_WORKERS=2
COPY --from=build /wheels /wheels
RUN pip install --no-cache-dir --no-index --find-links /wheels "wosac-eval[postgres]" \
    && rm -rf /wheels \
    && useradd --system --uid 10001 --home-dir /data --shell /usr/sbin/nologin wosac \
    && mkdir -p /data /scenarios \
    && chown wosac /data
USER wosac
WORKDIR /data
VOLUME ["/data"]
EXPOSE 8000
HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
    CMD ["python", "-c", "import os, urllib.request; urllib.request.urlopen('http://127.0.0.1:%s/healthz' % os.environ.get('WOSAC_PORT', '8000'), timeout=4)"]
# `serve` shuts down cleanly on SIGTERM (docker stop): running jobs go back to the queue.
STOPSIGNAL SIGTERM
ENTRYPOINT ["wosac-eval"]
CMD ["serve"]
