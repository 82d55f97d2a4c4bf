# dcseg API: Debian's Python 3.11, no torch, no CUDA. Build from the repository root with the
# base image docker/base.sh provides (docker/build.sh does both and reports the size):
#   bash docker/base.sh && DOCKER_BUILDKIT=0 docker build -f docker/api.Dockerfile -t dcseg-api .
ARG BASE_IMAGE=debian:bookworm

# The browser viewer served at /viewer/{job_id}: its JavaScript bundle, built from viewer/ with
# the versions locked in viewer/package-lock.json (nothing is fetched at run time).
FROM ${BASE_IMAGE} AS viewer
RUN apt-get update \
    && apt-get install -y --no-install-recommends nodejs npm ca-certificates \
    && rm -rf /var/lib/apt/lists/*
# npm trusts the system's certificates (and so any the base image added)
ENV NODE_EXTRA_CA_CERTS=/etc/ssl/certs/ca-certificates.crt
WORKDIR /src/viewer
COPY viewer/package.json viewer/package-lock.json ./
RUN npm ci --no-audit --no-fund --loglevel=error
COPY viewer/build.mjs ./
COPY viewer/src ./src
RUN npm run build

# The dependencies in a virtual environment of their own (compilers stay in this stage). The
# instructions up to the pip install are the same in worker-cpu.Dockerfile: both images share
# these layers.
FROM ${BASE_IMAGE} AS deps
RUN apt-get update \
    && apt-get install -y --no-install-recommends \
        python3 python3-venv python3-dev build-essential ca-certificates \
    && rm -rf /var/lib/apt/lists/*
ENV PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_CERT=/etc/ssl/certs/ca-certificates.crt
RUN python3 -m venv /opt/venv && /opt/venv/bin/pip install -q --upgrade pip "setuptools>=68" wheel
COPY pyproject.toml docker/requirements.py /tmp/deps/
RUN python3 /tmp/deps/requirements.py /tmp/deps/pyproject.toml torch > /tmp/deps/api.txt \
    && /opt/venv/bin/pip install -q -r /tmp/deps/api.txt

FROM ${BASE_IMAGE}
RUN apt-get update \
    && apt-get install -y --no-install-recommends python3 libgomp1 ca-certificates \
    && rm -rf /var/lib/apt/lists/* \
    && groupadd --system dcseg && useradd --system --gid dcseg --home-dir /app dcseg
ENV PATH=/opt/venv/bin:$PATH \
    PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    DCSEG_STORAGE_DIR=/data
COPY --from=deps /opt/venv /opt/venv
WORKDIR /app
COPY pyproject.toml README.md ./
COPY dcseg ./dcseg
COPY --from=viewer /src/dcseg/viewer/static/viewer.js ./dcseg/viewer/static/viewer.js
# the API and what it shares with the workers (jobstore/); never worker/ (lint-imports checks
# that service imports none of it)
COPY jobstore ./jobstore
COPY service ./service
RUN pip install -q --no-deps --no-build-isolation . && rm -rf build ./*.egg-info \
    && python -c "import sys, service.main; assert 'torch' not in sys.modules" \
    && mkdir -p /data /opt/numba-cache && chown dcseg:dcseg /data /opt/numba-cache
# numba (the exports' kernels, gsply's) caches compiled code under NUMBA_CACHE_DIR: the
# package folders are not the dcseg user's to write. No torch here, so no `dcseg warmup`:
# the first export of a container compiles them.
ENV NUMBA_CACHE_DIR=/opt/numba-cache

USER dcseg
VOLUME ["/data"]
EXPOSE 8000
HEALTHCHECK --interval=10s --timeout=5s --start-period=20s --retries=3 \
    CMD ["python", "-c", "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=4)"]
# One process per container; scale with replicas behind a proxy (rate limits are shared through
# Redis: DCSEG_RATE_LIMIT_URL, by default a redis:// DCSEG_BROKER_URL). `dcseg serve` refuses to
# bind 0.0.0.0 without DCSEG_API_KEYS (unless DCSEG_ALLOW_UNAUTHENTICATED=true) and, like
# uvicorn --proxy-headers, trusts X-Forwarded-For from FORWARDED_ALLOW_IPS (default 127.0.0.1).
# On SIGTERM it ends open event streams and exits within about 2 x DCSEG_SHUTDOWN_GRACE_S + 5 s
# (service/README.md, "Stage time limits and shutdown"): set the stop timeout above that.
CMD ["dcseg", "serve", "--host", "0.0.0.0", "--port", "8000"]
