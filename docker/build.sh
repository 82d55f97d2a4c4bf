#!/usr/bin/env bash
# Build dcseg's images with the classic builder (works with Docker 20.10 and current Docker) and
# print their sizes. Run from anywhere; the build context is the repository root.
#
#   bash docker/build.sh                  # base, api, worker-cpu, redis, postgres, seaweedfs
#   bash docker/build.sh api worker-cpu   # only these (the base is always made first)
#   bash docker/build.sh gpu              # the GPU worker (needs its CUDA base image)
#
# Settings: DCSEG_IMAGE_TAG (default latest), DCSEG_BASE_IMAGE (debian:bookworm),
# DCSEG_TORCH_INDEX (the CPU worker's torch index; default PyTorch's CPU index, or none when a
# CPU wheel is staged in docker/wheels/), DCSEG_CUDA_IMAGE (the GPU worker's base).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

tag="${DCSEG_IMAGE_TAG:-latest}"
base="${DCSEG_BASE_IMAGE:-debian:bookworm}"
cuda="${DCSEG_CUDA_IMAGE:-nvidia/cuda:12.4.1-cudnn-devel-ubuntu22.04}"
torch_spec="torch==2.13.0+cpu"
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(api worker-cpu redis postgres seaweedfs)

build() {  # build NAME DOCKERFILE [--build-arg ...]; the output is shown only on failure
    local name="$1" file="$2" log
    shift 2
    local start=$SECONDS
    log="$(mktemp)"
    echo "build: dcseg-$name:$tag from $file" >&2
    if ! DOCKER_BUILDKIT=0 docker build --force-rm -f "$file" -t "dcseg-$name:$tag" \
        --build-arg "BASE_IMAGE=$base" "$@" . >"$log" 2>&1; then
        tail -n 60 "$log" >&2
        rm -f "$log"
        echo "build: dcseg-$name failed (the last lines of its build are above)" >&2
        return 1
    fi
    rm -f "$log"
    echo "build: dcseg-$name:$tag in $((SECONDS - start)) s" >&2
}

# The CPU worker's torch: a CPU wheel staged in docker/wheels/ (copied from what this
# machine's pip finds, e.g. its find-links) is used offline; else the image asks the index.
stage_torch() {
    if ! compgen -G "docker/wheels/torch-*.whl" >/dev/null; then
        python3 -m pip download -q --no-deps -d docker/wheels "$torch_spec" >/dev/null 2>&1 || true
    fi
    if compgen -G "docker/wheels/torch-*.whl" >/dev/null; then
        torch_index="${DCSEG_TORCH_INDEX-}"
    else
        torch_index="${DCSEG_TORCH_INDEX-https://download.pytorch.org/whl/cpu}"
    fi
}

gpu() {
    if ! docker image inspect "$cuda" >/dev/null 2>&1 \
        && ! timeout 120 docker pull -q "$cuda" >/dev/null 2>&1; then
        cat >&2 <<MSG
build: the GPU worker starts FROM $cuda (a CUDA -devel image: gsplat compiles its kernels with
nvcc), which is not on this machine and which no reachable registry gives. Build it on a host
that reaches Docker Hub (or nvcr.io), or load that image first (docker load), or name another
local CUDA devel image: DCSEG_CUDA_IMAGE=<image> bash docker/build.sh gpu
MSG
        return 3
    fi
    build worker-gpu docker/worker-gpu.Dockerfile --build-arg "CUDA_IMAGE=$cuda"
}

DCSEG_BASE_IMAGE="$base" bash docker/base.sh >/dev/null
for target in "${targets[@]}"; do
    case "$target" in
        api | redis | postgres | seaweedfs) build "$target" "docker/$target.Dockerfile" ;;
        worker-cpu)
            stage_torch
            build worker-cpu docker/worker-cpu.Dockerfile --build-arg "TORCH_INDEX=$torch_index"
            ;;
        gpu) gpu ;;
        *)
            echo "build: unknown image '$target' (api, worker-cpu, redis, postgres, seaweedfs, gpu)" >&2
            exit 2
            ;;
    esac
done
docker image ls --format '{{.Repository}}:{{.Tag}}\t{{.Size}}' | grep -E "^dcseg-.*:$tag\b" | sort
