# dcseg GPU worker: CUDA, torch (CUDA build) and gsplat through the `cuda` extra.
# Build from the repository root on a host that reaches the CUDA base image's registry:
#   bash docker/build.sh gpu        # DCSEG_CUDA_IMAGE=<image> for another base
# (build.sh stops with an explanation where the base is neither local nor pullable, as on
# machines without Docker Hub; the CPU images need no registry.)
# Match TORCH_INDEX to the CUDA of the base image; gsplat compiles its kernels against it
# (hence the -devel image with nvcc), for TORCH_CUDA_ARCH_LIST.
ARG CUDA_IMAGE=nvidia/cuda:12.4.1-cudnn-devel-ubuntu22.04
FROM ${CUDA_IMAGE}

ARG TORCH_INDEX=https://download.pytorch.org/whl/cu124
ARG TORCH_SPEC=torch
ARG TORCH_CUDA_ARCH_LIST="7.5;8.0;8.6;8.9;9.0"

ENV DEBIAN_FRONTEND=noninteractive \
    PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    TORCH_CUDA_ARCH_LIST=${TORCH_CUDA_ARCH_LIST} \
    DCSEG_STORAGE_DIR=/data \
    DCSEG_DEVICE=cuda

# Python 3.11 from deadsnakes (Ubuntu 22.04 ships 3.10).
RUN apt-get update \
    && apt-get install -y --no-install-recommends software-properties-common gpg-agent \
    && add-apt-repository -y ppa:deadsnakes/ppa \
    && apt-get update \
    && apt-get install -y --no-install-recommends \
        python3.11 python3.11-venv python3.11-dev build-essential git libgl1 libglib2.0-0 \
    && rm -rf /var/lib/apt/lists/*

RUN python3.11 -m venv /opt/venv
ENV PATH=/opt/venv/bin:$PATH
# torch's and numba's OpenMP pools must not spin against each other (5-20x slower on CPU).
ENV OMP_WAIT_POLICY=PASSIVE

WORKDIR /app
# torch from the CUDA index first, so `.[cuda]` does not pull another build.
RUN pip install --upgrade pip && pip install --index-url ${TORCH_INDEX} "${TORCH_SPEC}"

COPY pyproject.toml README.md ./
COPY dcseg ./dcseg
# the workers and what they share with the API (jobstore/); never service/
COPY jobstore ./jobstore
COPY worker ./worker
RUN pip install ".[cuda]" "psycopg[binary]>=3.1"

# numba writes compiled kernels next to the package (read-only for dcseg here) or under
# NUMBA_CACHE_DIR: a folder the worker owns, filled at build time by `dcseg warmup` (~30 s of
# CPU once instead of in every new container). On a host whose CPU differs from the build
# host's, numba compiles again on first use and adds those kernels to the same folder.
ENV NUMBA_CACHE_DIR=/opt/numba-cache
RUN groupadd --system dcseg && useradd --system --gid dcseg --home-dir /app dcseg \
    && mkdir -p /data /scratch /opt/numba-cache && chown dcseg:dcseg /data /scratch /opt/numba-cache
USER dcseg
RUN out="$(dcseg warmup)" && printf "%s\n" "$out" | tail -n 2
VOLUME ["/data", "/scratch"]
# healthy = the Celery node answers a ping through the broker
HEALTHCHECK --interval=30s --timeout=15s --start-period=30s --retries=3 \
    CMD ["sh", "-c", "celery -A worker.celery_app inspect ping -d celery@$HOSTNAME --timeout 10 >/dev/null"]
# One worker process per GPU; CUDA initialises in the task, never in the parent.
CMD ["dcseg", "worker", "--queues", "gpu", "--concurrency", "1"]
