# wosac-eval in one image: the library (`wosac-eval`), the scoring service (`wosac-server`) and Ray.
# Build from the repository root; the default command is the service (API + scoring workers):
#
#   docker build -t wosac-eval .
#   docker volume create wosac-data
#   docker run --rm -v wosac-data:/data wosac-eval wosac-server keys create --name my-team
#   docker run -d --name wosac -p 8000:8000 --stop-timeout 30 \
#     -v /path/to/womd/validation:/scenarios:ro -v wosac-data:/data wosac-eval
#   docker run --rm -v "$PWD":/work -w /work wosac-eval wosac-eval score --scenarios ... --submission ...
#
# Configuration is by WOSAC_* environment variables (server/README.md). With PostgreSQL and a Ray
# cluster: server/compose.yaml. Python is Debian's python3 (security updates from Debian).
#
# Build argument EXTRA_CA_CERT (optional, PEM text): a CA to trust while pip downloads, for builds
# behind a TLS-intercepting proxy. Only the dependency stage sees it; it is not in the final image.

FROM debian:bookworm-slim AS base
ENV DEBIAN_FRONTEND=noninteractive
RUN apt-get update \
    && apt-get install -y --no-install-recommends python3 ca-certificates tini \
    && rm -rf /var/lib/apt/lists/*

# The dependencies (from the two pyproject.toml files only, so that this layer stays cached while
# the code changes), and the build backend, in a virtual environment at /opt/wosac.
FROM base AS deps
ARG EXTRA_CA_CERT=""
RUN apt-get update \
    && apt-get install -y --no-install-recommends python3-venv \
    && rm -rf /var/lib/apt/lists/* \
    && python3 -m venv /opt/wosac
COPY pyproject.toml /src/pyproject.toml
COPY server/pyproject.toml /src/server/pyproject.toml
RUN set -eu; \
    if [ -n "$EXTRA_CA_CERT" ]; then \
      { cat /etc/ssl/certs/ca-certificates.crt; printf '%s\n' "$EXTRA_CA_CERT"; } > /tmp/ca-bundle.pem; \
      export PIP_CERT=/tmp/ca-bundle.pem; \
    fi; \
    /opt/wosac/bin/python3 -c 'import tomllib; lib = tomllib.load(open("/src/pyproject.toml", "rb"))["project"]; srv = tomllib.load(open("/src/server/pyproject.toml", "rb"))["project"]; reqs = lib["dependencies"] + lib["optional-dependencies"]["ray"] + srv["dependencies"] + srv["optional-dependencies"]["postgres"]; print("\n".join(r for r in reqs if not r.startswith("wosac-eval")))' > /tmp/requirements.txt; \
    /opt/wosac/bin/pip install --no-cache-dir --disable-pip-version-check -r /tmp/requirements.txt \
      'setuptools>=68' wheel; \
    rm -rf /tmp/ca-bundle.pem /tmp/requirements.txt /src

# The image: the environment above, then wosac-eval and wosac-eval-server themselves (offline).
FROM base
ENV PATH=/opt/wosac/bin:$PATH \
    PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    WOSAC_HOST=0.0.0.0 \
    WOSAC_PORT=8000 \
    WOSAC_DATA_DIR=/data \
    WOSAC_SCENARIOS="/scenarios/*tfrecord*" \
    WOSAC_WORKERS=2 \
    NUMBA_CACHE_DIR=/opt/wosac/numba-cache
COPY --from=deps /opt/wosac /opt/wosac
COPY pyproject.toml README.md /src/
COPY wosac_eval /src/wosac_eval
COPY server /src/server
RUN pip install --no-cache-dir --disable-pip-version-check --no-index --no-deps --no-build-isolation \
      '/src[ray]' '/src/server[postgres]' \
    && pip check \
    && rm -rf /src \
    && wosac-eval --help > /dev/null \
    && wosac-server --help > /dev/null \
    && useradd --system --uid 10001 --user-group --home-dir /data --shell /usr/sbin/nologin wosac \
    && mkdir -p /data /scenarios "$NUMBA_CACHE_DIR" \
    && chown wosac:wosac /data "$NUMBA_CACHE_DIR"
USER wosac
# The compiled loops (searches, wire walks, criticality), built once here into the image's numba cache (numba
# compiles a loop on its first call; otherwise the first job of every container would take half a minute more).
RUN python3 -c "from wosac_eval.scoring.warm_up import compile_loops; compile_loops()"
WORKDIR /data
VOLUME ["/data"]
EXPOSE 8000
HEALTHCHECK --interval=15s --timeout=5s --start-period=60s --retries=3 \
    CMD ["python3", "-c", "import os, urllib.request; urllib.request.urlopen('http://127.0.0.1:%s/healthz' % os.environ.get('WOSAC_PORT', '8000'), timeout=4)"]
# tini (PID 1) passes SIGTERM (`docker stop`) on and reaps orphans; `wosac-server serve` then shuts
# down cleanly (requests in flight finish, running jobs go back to the queue) and, as uvicorn does,
# ends by re-raising the SIGTERM: `-e 143` makes that clean end exit status 0.
STOPSIGNAL SIGTERM
ENTRYPOINT ["/usr/bin/tini", "-e", "143", "--"]
CMD ["wosac-server", "serve"]
