# dcseg CPU worker: Debian's Python 3.11 and the CPU build of torch (pinned: an unpinned torch
# is a multi-GB CUDA build). Build from the repository root (docker/build.sh does it):
#   bash docker/base.sh && DOCKER_BUILDKIT=0 docker build -f docker/worker-cpu.Dockerfile \
#       -t dcseg-worker-cpu .
# torch comes from docker/wheels/ when a wheel is there (docker/wheels/README.md), else from
# TORCH_INDEX; pass TORCH_INDEX= (empty) to use only docker/wheels/ and PyPI.
ARG BASE_IMAGE=debian:bookworm

# The same instructions as the API image's deps stage (shared layers), then torch.
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
ARG TORCH_SPEC=torch==2.13.0+cpu
ARG TORCH_INDEX=https://download.pytorch.org/whl/cpu
COPY docker/wheels/ /tmp/wheels/
RUN /opt/venv/bin/pip install -q --find-links /tmp/wheels \
        ${TORCH_INDEX:+--extra-index-url "$TORCH_INDEX"} "$TORCH_SPEC" \
    && /opt/venv/bin/python -c "import torch; assert not torch.version.cuda, torch.__version__"

FROM ${BASE_IMAGE}
RUN apt-get update \
    && apt-get install -y --no-install-recommends python3 libgomp1 ca-certificates procps \
    && rm -rf /var/lib/apt/lists/* \
    && groupadd --system dcseg && useradd --system --gid dcseg --home-dir /app dcseg
ENV PATH=/opt/venv/bin:$PATH \
    PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    DCSEG_STORAGE_DIR=/data \
    DCSEG_DEVICE=cpu \
    OMP_WAIT_POLICY=PASSIVE
# (OMP_WAIT_POLICY: torch's and numba's OpenMP pools must not spin against each other)
COPY --from=deps /opt/venv /opt/venv
WORKDIR /app
COPY pyproject.toml README.md ./
COPY dcseg ./dcseg
# the workers and what they share with the API (jobstore/); never service/
COPY jobstore ./jobstore
COPY worker ./worker
RUN pip install -q --no-deps --no-build-isolation . && rm -rf build ./*.egg-info \
    && mkdir -p /data /scratch /opt/numba-cache \
    && chown dcseg:dcseg /data /scratch /opt/numba-cache

# numba writes compiled kernels under NUMBA_CACHE_DIR, a folder the worker owns, filled here by
# `dcseg warmup` (~30 s of CPU once instead of in every new container). On a host whose CPU
# differs from the build host's, numba compiles again on first use and adds to the folder.
ENV NUMBA_CACHE_DIR=/opt/numba-cache
USER dcseg
RUN out="$(dcseg warmup)" && printf "%s\n" "$out" | tail -n 2
VOLUME ["/data", "/scratch"]
# healthy = the Celery node answers a ping through the broker
HEALTHCHECK --interval=30s --timeout=15s --start-period=30s --retries=3 \
    CMD ["sh", "-c", "celery -A worker.celery_app inspect ping -d celery@$HOSTNAME --timeout 10 >/dev/null"]
# One worker process per container (scale with replicas); it takes jobs of the `gpu` queue,
# the queue every job is sent to, whatever the device.
CMD ["dcseg", "worker", "--concurrency", "1"]
