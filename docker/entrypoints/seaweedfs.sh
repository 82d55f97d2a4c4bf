#!/bin/sh
# Write the S3 identity (one key pair, all actions) from the environment, then run weed.
set -eu
: "${DCSEG_S3_ACCESS_KEY_ID:?set DCSEG_S3_ACCESS_KEY_ID}"
: "${DCSEG_S3_SECRET_ACCESS_KEY:?set DCSEG_S3_SECRET_ACCESS_KEY}"
printf '{"identities":[{"name":"dcseg","credentials":[{"accessKey":"%s","secretKey":"%s"}],"actions":["Admin","Read","Write","List","Tagging"]}]}' \
    "$DCSEG_S3_ACCESS_KEY_ID" "$DCSEG_S3_SECRET_ACCESS_KEY" >/etc/seaweedfs/s3.json
exec weed "$@"
