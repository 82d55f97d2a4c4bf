# dcseg API: slim Python, no torch, no CUDA. Build from the repository root:
#   docker build -f docker/api.Dockerfile -t dcseg-api .

# The browser viewer served at /viewer/{job_id}: its JavaScript bundle, built from viewer/ with
# the versions locked in viewer/package-lock.json (nothing is fetched at run time).
FROM node:20-slim AS viewer
WORKDIR /src/viewer
COPY viewer/package.json viewer/package-lock.json ./
RUN npm ci --no-audit --no-fund --loglevel=error
COPY viewer/build.mjs ./
COPY viewer/src ./src
RUN npm run build

FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    DCSEG_STORAGE_DIR=/data

WORKDIR /app
RUN groupadd --system dcseg && useradd --system --gid dcseg --home-dir /app dcseg

# Dependencies first (cached layer); the project itself with --no-deps keeps torch out.
COPY docker/api-requirements.txt /tmp/api-requirements.txt
RUN pip install -r /tmp/api-requirements.txt

COPY pyproject.toml README.md ./
COPY dcseg ./dcseg
COPY --from=viewer /src/dcseg/viewer/static/viewer.js ./dcseg/viewer/static/viewer.js
# the API and what it shares with the workers (jobstore/); never worker/ (lint-imports checks
# that service imports none of it)
COPY jobstore ./jobstore
COPY service ./service
RUN pip install --no-deps . \
    && python -c "import sys, service.main; assert 'torch' not in sys.modules" \
    && mkdir -p /data && chown dcseg:dcseg /data

USER dcseg
VOLUME ["/data"]
EXPOSE 8000
HEALTHCHECK --interval=30s --timeout=5s --start-period=20s --retries=3 \
    CMD ["python", "-c", "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=4)"]
# One process per container; scale with replicas behind a proxy (rate limits are shared through
# Redis: DCSEG_RATE_LIMIT_URL, by default a redis:// DCSEG_BROKER_URL). `dcseg serve` refuses to
# bind 0.0.0.0 without DCSEG_API_KEYS (unless DCSEG_ALLOW_UNAUTHENTICATED=true) and, like
# uvicorn --proxy-headers, trusts X-Forwarded-For from FORWARDED_ALLOW_IPS (default 127.0.0.1).
# On SIGTERM it ends open event streams and exits within about 2 x DCSEG_SHUTDOWN_GRACE_S + 5 s
# (service/README.md, "Stage time limits and shutdown"): set the stop timeout above that.
CMD ["dcseg", "serve", "--host", "0.0.0.0", "--port", "8000"]
