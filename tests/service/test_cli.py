"""The ``serve`` and ``worker`` verbs refuse unsafe or impossible set-ups before starting."""

from __future__ import annotations

import importlib.util
import logging

import pytest
from pydantic import SecretStr

from dcseg.cli import main
from dcseg.cli.serve import embedded_worker, is_loopback
from jobstore.settings import Settings, get_settings
from worker.local import EmbeddedWorker


@pytest.fixture(autouse=True)
def fresh_settings(monkeypatch: pytest.MonkeyPatch, tmp_path):
    for name in ("DCSEG_API_KEYS", "DCSEG_BROKER_URL", "DCSEG_DATABASE_URL"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("DCSEG_STORAGE_DIR", str(tmp_path))
    get_settings.cache_clear()
    yield
    get_settings.cache_clear()


def test_serve_refuses_public_address_without_keys(capsys):
    assert main(["serve", "--host", "0.0.0.0"]) == 2
    assert "API keys" in capsys.readouterr().err


def test_worker_needs_a_broker(capsys):
    assert main(["worker"]) == 2
    assert "DCSEG_BROKER_URL" in capsys.readouterr().err


def test_serve_runs_an_embedded_worker_only_without_a_broker(tmp_path):
    local = Settings(storage_dir=tmp_path)
    worker = embedded_worker(local)
    assert isinstance(worker, EmbeddedWorker) and worker.mode == "process"
    threaded = embedded_worker(local.model_copy(update={"embedded_worker": "thread"}))
    assert isinstance(threaded, EmbeddedWorker) and threaded.mode == "thread"
    assert embedded_worker(local.model_copy(update={"embedded_worker": "off"})) is None
    assert embedded_worker(local.model_copy(update={"broker_url": "redis://r:6379/0"})) is None


def test_serve_without_broker_refuses_when_the_worker_package_is_missing(monkeypatch, capsys):
    """The API image ships no ``worker`` package: without a broker nothing would run jobs."""
    find_spec = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "worker" else find_spec(name)
    )
    assert main(["serve"]) == 2
    error = capsys.readouterr().err
    assert "worker package is not installed" in error and "DCSEG_BROKER_URL" in error


def test_loopback_detection():
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("example.org")


def test_settings_from_environment(monkeypatch, tmp_path):
    keys = tmp_path / "keys.txt"
    keys.write_text("# tenants\ntenant-a:alpha-0123456789ab\ntenant-b:beta-0123456789abc\n")
    monkeypatch.setenv("DCSEG_API_KEYS", f"@{keys}")
    monkeypatch.setenv("DCSEG_STAGE_TIME_LIMIT_S", '{"reconstruct": 60}')
    settings = Settings()
    assert settings.parsed_api_keys() == {
        "alpha-0123456789ab": "tenant-a",
        "beta-0123456789abc": "tenant-b",
    }
    assert settings.stage_time_limit_s == {"reconstruct": 60.0}
    assert settings.db_url == f"sqlite:///{tmp_path.resolve() / 'dcseg.db'}"
    with pytest.raises(ValueError, match="tenant:key"):
        Settings(api_keys=SecretStr("no-colon")).parsed_api_keys()


def test_client_verbs_do_not_log_every_request(caplog):
    from dcseg.client import client_from_args

    httpx_logger = logging.getLogger("httpx")
    caplog.set_level(logging.INFO)
    try:
        client_from_args("http://127.0.0.1:1", None).close()
        assert httpx_logger.getEffectiveLevel() == logging.WARNING
    finally:
        httpx_logger.setLevel(logging.NOTSET)
