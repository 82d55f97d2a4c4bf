"""Authentication and rate limits (:mod:`service.deps`): loopback-only open mode, secret keys
of a minimum length, rate limits shared through Redis, and limited failed authentication."""

from __future__ import annotations

import logging
import time
import types
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from dcseg.cli import main
from jobstore.settings import Settings, get_settings
from service.main import create_app
from tests.service.conftest import (
    AUTH_A,
    KEY_A,
    KEY_B,
    TestClient,
    assert_problem,
    make_settings,
    reachable,
)

REDIS_URL = "redis://127.0.0.1:6379/0"
LOOPBACK = {"base_url": "http://127.0.0.1:8000", "client": ("127.0.0.1", 50000)}
BAD_KEY = {"Authorization": "Bearer wrong-key-0123456789"}


@pytest.fixture
def cli_env(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Iterator[None]:
    for name in ("DCSEG_API_KEYS", "DCSEG_BROKER_URL", "DCSEG_DATABASE_URL"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("DCSEG_STORAGE_DIR", str(tmp_path / "data"))
    get_settings.cache_clear()
    yield
    get_settings.cache_clear()


def open_client(tmp_path: Path, **client_args: Any) -> TestClient:
    """A client of an app with no API keys (and, unless told, auth not explicitly off)."""
    return TestClient(create_app(make_settings(tmp_path, api_keys="")), **client_args)


# Defect 1: auth off by accident -------------------------------------------------------------


@pytest.mark.parametrize("keys", ["@empty", "#x", " , ,"])
def test_serve_guard_tests_parsed_keys_not_the_raw_string(cli_env, monkeypatch, tmp_path, keys):
    """ "the CLI tests the raw string, so DCSEG_API_KEYS=@empty-file or "#x" passes the guard"."""
    empty = tmp_path / "empty"
    empty.write_text("# no keys yet\n")
    monkeypatch.setenv("DCSEG_API_KEYS", keys.replace("@empty", f"@{empty}"))
    monkeypatch.setattr("uvicorn.run", lambda *a, **k: pytest.fail("uvicorn started"))
    assert main(["serve", "--host", "0.0.0.0"]) == 2


def test_serve_public_bind_allowed_when_auth_explicitly_off(cli_env, monkeypatch, capsys):
    """ "unless auth is explicitly turned off": DCSEG_ALLOW_UNAUTHENTICATED=true binds 0.0.0.0."""
    started: list[str] = []
    monkeypatch.setenv("DCSEG_ALLOW_UNAUTHENTICATED", "true")
    monkeypatch.setattr("uvicorn.run", lambda app, host, **k: started.append(host))
    assert main(["serve", "--host", "0.0.0.0"]) == 0
    assert started == ["0.0.0.0"]


def test_open_mode_refuses_foreign_host_header(tmp_path):
    """ "the loopback-open mode must check the Host header (DNS rebinding)"."""
    with open_client(tmp_path, **LOOPBACK) as client:
        assert client.get("/v1/jobs").status_code == 200
        for host in ("localhost:8000", "127.0.0.2", "[::1]:8000", "LOCALHOST"):
            assert client.get("/v1/jobs", headers={"Host": host}).status_code == 200, host
        for host in ("evil.example", "evil.example:8000", "127.0.0.1.evil.example", "[::2]"):
            body = assert_problem(client.get("/v1/jobs", headers={"Host": host}), 421)
            assert "Host" in body["detail"]


def test_open_mode_refuses_non_loopback_client(tmp_path):
    """ "The app itself must refuse to serve a non-loopback bind without keys"."""
    with open_client(tmp_path, base_url="http://127.0.0.1", client=("203.0.113.7", 4000)) as c:
        body = assert_problem(c.get("/v1/jobs"), 403)
        assert "DCSEG_API_KEYS" in body["detail"]
        assert c.get("/healthz").status_code == 200  # health checks stay open
    with open_client(tmp_path, base_url="http://127.0.0.1", client=("::ffff:127.0.0.1", 1)) as c:
        assert c.get("/v1/jobs").status_code == 200


def test_explicit_unauthenticated_mode_serves_everyone(tmp_path):
    """ "unless auth is explicitly turned off": any client and Host, tenant ``local``."""
    settings = make_settings(tmp_path, api_keys="", allow_unauthenticated=True)
    with TestClient(create_app(settings), client=("203.0.113.7", 4000)) as client:
        assert client.get("/v1/jobs", headers={"Host": "evil.example"}).status_code == 200


# Defect 2: keys in repr, no minimum length --------------------------------------------------


def test_settings_repr_never_shows_api_keys(tmp_path, caplog):
    """ "repr(Settings) prints every API key"."""
    settings = make_settings(tmp_path)
    caplog.set_level(logging.INFO)
    logging.getLogger("test").info("settings: %s %r", settings, settings)
    shown = [repr(settings), str(settings), settings.model_dump_json(), caplog.text]
    for text in shown:
        assert KEY_A not in text and KEY_B not in text
    assert settings.parsed_api_keys() == {KEY_A: "tenant-a", KEY_B: "tenant-b"}


def test_short_api_key_refused_naming_the_tenant(tmp_path):
    """ "keys have no minimum length": a clear startup error naming the tenant, not the key."""
    settings = make_settings(tmp_path, api_keys=f"tenant-a:{KEY_A},tenant-short:abc123")
    with pytest.raises(ValueError, match="tenant-short") as error:
        settings.parsed_api_keys()
    assert "abc123" not in str(error.value) and "16" in str(error.value)
    with pytest.raises(ValueError, match="tenant-short"), TestClient(create_app(settings)):
        pass
    relaxed = make_settings(tmp_path, api_keys="t:abc123", min_api_key_length=6)
    assert relaxed.parsed_api_keys() == {"abc123": "t"}


def test_serve_refuses_short_key_naming_the_tenant(cli_env, monkeypatch, capsys):
    """ "keys have no minimum length": ``dcseg serve`` exits 2 naming the tenant."""
    monkeypatch.setenv("DCSEG_API_KEYS", "tenant-x:tiny")
    monkeypatch.setattr("uvicorn.run", lambda *a, **k: pytest.fail("uvicorn started"))
    assert main(["serve"]) == 2
    err = capsys.readouterr().err
    assert "tenant-x" in err and "tiny" not in err


# Defect 3: per-process rate limits; failed auth never limited -------------------------------


@pytest.fixture
def frozen_clock(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every limiter sees one instant in the middle of a window (no minute rolls over)."""
    fake = types.SimpleNamespace(time=lambda: 1_800_000_030.0, monotonic=time.monotonic)
    monkeypatch.setattr("service.deps.time", fake)


@pytest.fixture
def redis_url() -> str:
    if not reachable("127.0.0.1", 6379):
        pytest.skip("Redis is not listening on 127.0.0.1:6379 (the shared limiter needs it)")
    return REDIS_URL


def redis_settings(tmp_path: Path, prefix: str, **overrides: Any) -> Settings:
    return make_settings(
        tmp_path, rate_limit_url=REDIS_URL, rate_limit_key_prefix=prefix, **overrides
    )


@pytest.mark.integration
def test_rate_limit_shared_by_replicas_through_redis(tmp_path, redis_url, frozen_clock):
    """ "Rate limiting is per process; N API replicas allow N times the rate"."""
    prefix = f"dcseg-test:{uuid.uuid4().hex}:"
    one = redis_settings(tmp_path / "one", prefix, rate_limit_per_minute=5)
    two = redis_settings(tmp_path / "two", prefix, rate_limit_per_minute=5)
    with TestClient(create_app(one)) as first, TestClient(create_app(two)) as second:
        codes = [c.get("/v1/jobs", headers=AUTH_A).status_code for c in [first, second] * 5]
        assert codes.count(200) == 5 and codes.count(429) == 5
        assert codes[:5] == [200] * 5


def test_redis_limiter_is_the_default_with_a_redis_broker(tmp_path):
    """ "Share it (Redis)": a redis:// broker URL enables the shared limiter by default."""
    assert make_settings(tmp_path).effective_rate_limit_url is None
    broker = make_settings(tmp_path, broker_url=REDIS_URL)
    assert broker.effective_rate_limit_url == REDIS_URL
    forced = make_settings(tmp_path, broker_url=REDIS_URL, rate_limit_url="memory")
    assert forced.effective_rate_limit_url is None
    amqp = make_settings(tmp_path, broker_url="amqp://guest@localhost//")
    assert amqp.effective_rate_limit_url is None


def test_unreachable_redis_falls_back_to_process_limits(tmp_path, frozen_clock, caplog):
    """If Redis is unreachable the limiter fails open to the in-process limits, with a warning."""
    settings = make_settings(
        tmp_path, rate_limit_url="redis://127.0.0.1:1/0", rate_limit_per_minute=2
    )
    with TestClient(create_app(settings)) as client:
        codes = [client.get("/v1/jobs", headers=AUTH_A).status_code for _ in range(3)]
    assert codes == [200, 200, 429]
    assert "rate limiter" in caplog.text and "Redis" in caplog.text


def test_repeated_bad_keys_answer_429(tmp_path, frozen_clock):
    """ "failed-auth requests are never limited": per client address, then 429 (even for a good
    key from that address, so guessing stops), other addresses unaffected."""
    settings = make_settings(tmp_path, failed_auth_per_minute=3)
    with TestClient(create_app(settings)) as client:
        codes = [client.get("/v1/jobs", headers=BAD_KEY).status_code for _ in range(4)]
        assert codes == [401, 401, 401, 429]
        limited = assert_problem(client.get("/v1/jobs", headers=AUTH_A), 429)
        assert "failed" in limited["detail"]
        assert 1 <= int(client.get("/v1/jobs").headers["retry-after"]) <= 60
    with TestClient(create_app(settings), client=("198.51.100.9", 1)) as other:
        assert other.get("/v1/jobs", headers=AUTH_A).status_code == 200


@pytest.mark.integration
def test_repeated_bad_keys_answer_429_across_replicas(tmp_path, redis_url, frozen_clock):
    """ "failed-auth requests are never limited": the failure count is shared through Redis."""
    prefix = f"dcseg-test:{uuid.uuid4().hex}:"
    one = redis_settings(tmp_path / "one", prefix, failed_auth_per_minute=2)
    two = redis_settings(tmp_path / "two", prefix, failed_auth_per_minute=2)
    with TestClient(create_app(one)) as first, TestClient(create_app(two)) as second:
        codes = [c.get("/v1/jobs", headers=BAD_KEY).status_code for c in [first, second] * 2]
        assert codes == [401, 401, 429, 429]
