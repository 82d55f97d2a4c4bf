#!/usr/bin/env bash
# Make the base image every dcseg image starts from (`FROM debian:bookworm`) where no registry
# provides it. A no-op when the image is already there or `docker pull` gets it.
#
# Without a registry: `debootstrap --variant=minbase bookworm` from the Debian mirror this
# machine's apt sources name, the host's extra CA certificates (/usr/local/share/ca-certificates,
# e.g. an egress proxy's) trusted inside, then `docker import` as debian:bookworm (~40 s).
# Build the images with the classic builder (DOCKER_BUILDKIT=0): BuildKit would look the base
# up in a registry instead of using the local tag.
#
#   bash docker/base.sh            # prints the image id
#   DCSEG_BASE_IMAGE=debian:bookworm DCSEG_PULL_TIMEOUT_S=60 bash docker/base.sh
set -euo pipefail

image="${DCSEG_BASE_IMAGE:-debian:bookworm}"
suite="${image#*:}"
pull_timeout="${DCSEG_PULL_TIMEOUT_S:-30}"

if docker image inspect "$image" >/dev/null 2>&1; then
    echo "base: $image already present" >&2
elif timeout "$pull_timeout" docker pull -q "$image" >/dev/null 2>&1; then
    echo "base: pulled $image" >&2
else
    command -v debootstrap >/dev/null || {
        echo "base: no registry gives $image and debootstrap is missing (apt-get install debootstrap)" >&2
        exit 1
    }
    mirror="$(grep -rhoE '^URIs: *http[^ ]+/debian$|^deb +(\[[^]]*\] +)?http[^ ]+/debian ' \
        /etc/apt/sources.list /etc/apt/sources.list.d 2>/dev/null | head -n 1 | grep -oE 'http[^ ]+/debian' || true)"
    mirror="${mirror:-http://deb.debian.org/debian}"
    root="$(mktemp -d)"
    trap 'rm -rf "$root"' EXIT
    echo "base: debootstrap $suite from $mirror" >&2
    debootstrap --variant=minbase --include=ca-certificates "$suite" "$root" "$mirror" >/dev/null
    printf 'deb %s %s main\ndeb %s %s-updates main\ndeb %s-security %s-security main\n' \
        "$mirror" "$suite" "$mirror" "$suite" "$mirror" "$suite" >"$root/etc/apt/sources.list"
    if compgen -G "/usr/local/share/ca-certificates/*.crt" >/dev/null; then
        cp /usr/local/share/ca-certificates/*.crt "$root/usr/local/share/ca-certificates/"
        chroot "$root" update-ca-certificates >/dev/null
    fi
    rm -rf "$root"/var/lib/apt/lists/* "$root"/var/cache/apt/archives/*.deb
    tar -C "$root" -c . | docker import \
        -c 'ENV LANG=C.UTF-8' -c 'CMD ["bash"]' - "$image" >/dev/null
    echo "base: imported $image" >&2
fi
docker image inspect -f '{{.Id}}' "$image"
