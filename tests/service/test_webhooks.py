"""Webhooks (``callback_url``): a local receiver on 127.0.0.1 gets each terminal job, signed;
failed attempts are retried and recorded; the outbox survives a dispatcher restart; private
addresses are refused unless the setting allows them. Store cases run on SQLite and
PostgreSQL (``tests.service.test_databases``)."""

from __future__ import annotations

import asyncio
import hashlib
import hmac
import json
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import timedelta
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import pytest

from jobstore.models import Job, Upload
from jobstore.settings import Settings
from jobstore.store import AttemptOutcome, Store, new_id
from service.webhooks import Dispatcher
from tests.service import test_databases
from tests.service.conftest import (
    AUTH_A,
    TAR,
    assert_problem,
    make_settings,
    state_of,
    wait_for,
)

postgres_server = test_databases.postgres_server
db_url = test_databases.db_url
store = test_databases.store

SECRET = "whsec-test-0123456789"
HOOK = {
    "webhook_secret": SECRET,
    "webhook_allow_private": True,
    "webhook_poll_s": 0.05,
    "webhook_backoff_s": 0.05,
}


@dataclass
class Receiver:
    """A tiny HTTP server: answers each POST with the next planned status (then 200) and
    keeps ``(headers, body)`` of every request."""

    url: str
    plan: list[int] = field(default_factory=list)
    seen: list[tuple[dict[str, str], bytes]] = field(default_factory=list)


@pytest.fixture
def receiver() -> Iterator[Receiver]:
    got = Receiver(url="")

    class Handler(BaseHTTPRequestHandler):
        def do_POST(self) -> None:  # noqa: N802 (http.server's name)
            body = self.rfile.read(int(self.headers.get("Content-Length", "0")))
            got.seen.append(({k.lower(): v for k, v in self.headers.items()}, body))
            status = got.plan.pop(0) if got.plan else 200
            self.send_response(status)
            self.send_header("Content-Length", "0")
            self.end_headers()

        def log_message(self, *args: Any) -> None:
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    got.url = f"http://127.0.0.1:{server.server_address[1]}/hook"
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield got
    server.shutdown()
    server.server_close()


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    """The service fixtures' settings, with webhooks on and allowed to reach 127.0.0.1."""
    return make_settings(tmp_path, **HOOK)


def submit(client: Any, upload_id: str, url: str) -> str:
    body = {"upload_id": upload_id, "callback_url": url}
    response = client.post("/v1/jobs", json=body, headers=AUTH_A)
    assert response.status_code == 202, response.text
    job_id: str = response.json()["id"]
    return job_id


def deliveries(client: Any, job_id: str) -> list[dict[str, Any]]:
    response = client.get(f"/v1/jobs/{job_id}/webhook-deliveries", headers=AUTH_A)
    assert response.status_code == 200, response.text
    found: list[dict[str, Any]] = response.json()["deliveries"]
    return found


def verify(headers: dict[str, str], body: bytes) -> None:
    """What a receiver does: recompute the signature over "<timestamp>.<body>", compare in
    constant time, and reject a timestamp older than five minutes."""
    timestamp = headers["x-dcseg-timestamp"]
    expected = hmac.new(SECRET.encode(), f"{timestamp}.".encode() + body, hashlib.sha256)
    assert hmac.compare_digest(headers["x-dcseg-signature"], "sha256=" + expected.hexdigest())
    assert abs(time.time() - int(timestamp)) < 300


def test_terminal_job_is_posted_signed_with_its_resource(client, upload_id, receiver):
    job_id = submit(client, upload_id, receiver.url)
    assert client.post(f"/v1/jobs/{job_id}:cancel", headers=AUTH_A).status_code == 200
    wait_for(lambda: receiver.seen, timeout=20)
    headers, body = receiver.seen[0]
    verify(headers, body)
    tampered = body.replace(b"canceled", b"succeeded")
    with pytest.raises(AssertionError):
        verify(headers, tampered)
    resource = client.get(f"/v1/jobs/{job_id}", headers=AUTH_A).json()
    assert json.loads(body) == resource
    assert resource["status"] == "canceled"
    [delivery] = wait_for(lambda: [d for d in deliveries(client, job_id) if d["attempts"]])
    assert delivery["state"] == "delivered" and delivery["job_status"] == "canceled"
    assert delivery["url"] == receiver.url and delivery["next_attempt_at"] is None
    [attempt] = delivery["attempts"]
    assert attempt["attempt"] == 1 and attempt["status_code"] == 200 and attempt["error"] is None


def test_a_500_is_retried_and_every_attempt_recorded(client, upload_id, receiver):
    receiver.plan = [500, 503]
    job_id = submit(client, upload_id, receiver.url)
    store_ = state_of(client).store
    assert store_.finish_job(job_id, "failed", {"type": "x", "detail": "y"}) == "failed"

    def done() -> list[dict[str, Any]]:
        return [d for d in deliveries(client, job_id) if d["state"] != "pending"]

    [delivery] = wait_for(done, timeout=20)
    assert delivery["state"] == "delivered" and delivery["job_status"] == "failed"
    codes = [(a["attempt"], a["status_code"], a["error"]) for a in delivery["attempts"]]
    assert codes == [(1, 500, "HTTP 500"), (2, 503, "HTTP 503"), (3, 200, None)]
    assert len(receiver.seen) == 3
    for headers, body in receiver.seen:
        verify(headers, body)


def test_nothing_is_sent_before_the_job_ends(client, upload_id, receiver):
    job_id = submit(client, upload_id, receiver.url)
    store_ = state_of(client).store
    assert store_.claim_job(job_id, "w", timedelta(seconds=60)) is not None
    assert store_.report_progress(job_id, "w", ("validate", 0, 4), 0.1, "validating") == "ok"
    assert client.post(f"/v1/jobs/{job_id}:cancel", headers=AUTH_A).json()["status"] == (
        "canceling"
    )
    time.sleep(0.5)  # ten dispatcher polls
    assert receiver.seen == [] and deliveries(client, job_id) == []
    assert store_.finish_job(job_id, "succeeded", worker="w") == "canceled"
    wait_for(lambda: receiver.seen, timeout=20)
    time.sleep(0.3)
    assert len(receiver.seen) == 1


def test_the_callback_url_is_part_of_an_idempotent_request(client, upload_id, receiver):
    headers = {**AUTH_A, "Idempotency-Key": "k1"}
    body = {"upload_id": upload_id, "callback_url": receiver.url}
    first = client.post("/v1/jobs", json=body, headers=headers)
    assert first.status_code == 202, first.text
    again = client.post("/v1/jobs", json=body, headers=headers)
    assert again.headers.get("idempotent-replayed") == "true"
    other = {"upload_id": upload_id, "callback_url": receiver.url + "/other"}
    assert_problem(client.post("/v1/jobs", json=other, headers=headers), 422)
    assert_problem(client.post("/v1/jobs", json={"upload_id": upload_id}, headers=headers), 422)


def test_private_and_malformed_urls_are_refused(make_client, scene_tar):
    client = make_client(webhook_secret=SECRET)
    response = client.post("/v1/uploads", content=scene_tar, headers={**AUTH_A, **TAR})
    upload_id = response.json()["id"]
    for url in (
        "http://127.0.0.1:9/hook",
        "http://localhost/hook",
        "http://10.1.2.3/hook",
        "http://169.254.169.254/latest",
        "http://[::1]/hook",
        "http://[::ffff:192.168.0.1]/hook",
        "http://224.0.0.1/hook",
        "ftp://example.com/hook",
        "http:///no-host",
        "https://example.com/" + "a" * 2048,
    ):
        body = {"upload_id": upload_id, "callback_url": url}
        problem = assert_problem(client.post("/v1/jobs", json=body, headers=AUTH_A), 422)
        assert "callback_url" in str(problem["errors"]), (url, problem)
    assert client.get("/v1/jobs", headers=AUTH_A).json()["jobs"] == []


def test_webhooks_are_off_without_a_secret(client_without_secret):
    client, upload_id = client_without_secret
    body = {"upload_id": upload_id, "callback_url": "http://127.0.0.1:9/hook"}
    problem = assert_problem(client.post("/v1/jobs", json=body, headers=AUTH_A), 422)
    assert problem["errors"][0]["path"] == "body.callback_url"
    assert "DCSEG_WEBHOOK_SECRET" in problem["detail"]


@pytest.fixture
def client_without_secret(make_client, scene_tar):
    client = make_client(webhook_allow_private=True)
    response = client.post("/v1/uploads", content=scene_tar, headers={**AUTH_A, **TAR})
    return client, response.json()["id"]


# ---- the outbox in the store (SQLite and PostgreSQL) ----


def _ended_job(store: Store, url: str, status: str = "succeeded") -> str:
    if store.get_upload("u1", "t") is None:
        store.add_upload(
            Upload(id="u1", tenant_id="t", sha256="0" * 64, size=1, content_type="x", summary={})
        )
    job = Job(
        id=new_id(),
        tenant_id="t",
        upload_id="u1",
        status="queued",
        config={},
        event_seq=0,
        callback_url=url,
    )
    job_id = store.create_job(job).id
    assert store.webhook_deliveries(job_id) == []
    assert store.finish_job(job_id, status) == status
    return job_id


def test_a_lease_keeps_a_delivery_from_a_second_dispatcher(store):
    job_id = _ended_job(store, "http://127.0.0.1:9/hook")
    [(delivery, attempts)] = store.webhook_deliveries(job_id)
    assert delivery.state == "pending" and attempts == []
    lease = timedelta(milliseconds=300)
    [claim] = store.claim_webhook_deliveries("a", lease)
    assert claim.attempt == 1 and claim.job_id == job_id
    assert store.claim_webhook_deliveries("b", lease) == []  # held by "a"
    time.sleep(0.4)  # "a" died: its lease ends
    [again] = store.claim_webhook_deliveries("b", lease)
    assert again.id == claim.id
    ok = AttemptOutcome(204, None)
    retry = timedelta(seconds=1)
    assert store.record_webhook_attempt(claim, "a", ok, max_attempts=3, retry_in=retry) is None
    assert store.record_webhook_attempt(again, "b", ok, max_attempts=3, retry_in=retry) == (
        "delivered"
    )
    [(delivery, attempts)] = store.webhook_deliveries(job_id)
    assert delivery.state == "delivered" and [a.status_code for a in attempts] == [204]
    assert store.claim_webhook_deliveries("c", lease) == []


def test_the_last_failed_attempt_gives_up(store):
    job_id = _ended_job(store, "http://127.0.0.1:9/hook", "canceled")
    down = AttemptOutcome(None, "ConnectError: refused")
    for attempt in (1, 2):
        [claim] = store.claim_webhook_deliveries("a", timedelta(seconds=60))
        assert claim.attempt == attempt
        state = store.record_webhook_attempt(
            claim, "a", down, max_attempts=2, retry_in=timedelta(0)
        )
    assert state == "failed"
    [(delivery, attempts)] = store.webhook_deliveries(job_id)
    assert delivery.completed_at is not None and [a.attempt for a in attempts] == [1, 2]
    assert store.delete_job(job_id, "t") is not None
    assert store.webhook_deliveries(job_id) == []


def test_a_restarted_dispatcher_resumes_a_pending_delivery(store, receiver, tmp_path):
    settings = make_settings(tmp_path, **HOOK)
    receiver.plan = [500]
    job_id = _ended_job(store, receiver.url)

    async def once(dispatcher: Dispatcher) -> int:
        try:
            return await dispatcher.run_once()
        finally:
            await dispatcher.client.aclose()

    assert asyncio.run(once(Dispatcher(store, settings))) == 1  # got the 500, then "died"
    # a dispatcher that died holding the delivery: its lease must end first
    [claim] = wait_for(lambda: store.claim_webhook_deliveries("dead", timedelta(seconds=0.3)))
    assert claim.attempt == 2
    assert asyncio.run(once(Dispatcher(store, settings))) == 0  # still leased
    time.sleep(0.4)
    assert asyncio.run(once(Dispatcher(store, settings))) == 1  # the restarted one sends it
    [(delivery, attempts)] = store.webhook_deliveries(job_id)
    assert delivery.state == "delivered"
    assert [(a.attempt, a.status_code) for a in attempts] == [(1, 500), (2, 200)]
    assert len(receiver.seen) == 2
    for headers, body in receiver.seen:
        verify(headers, body)


def test_schema_v2_gains_the_webhook_outbox(tmp_path):
    from sqlalchemy import delete, insert, inspect

    from jobstore.models import SCHEMA_VERSION, SchemaVersion

    old = Store(f"sqlite:///{tmp_path / 'v2.db'}")
    old.init_schema()
    with old.engine.begin() as conn:
        conn.exec_driver_sql("DROP TABLE webhook_attempts")
        conn.exec_driver_sql("DROP TABLE webhook_deliveries")
        conn.exec_driver_sql("ALTER TABLE jobs DROP COLUMN callback_url")
        conn.execute(delete(SchemaVersion))
        conn.execute(insert(SchemaVersion).values(version=2))
    assert old.init_schema() == SCHEMA_VERSION == 3
    names = inspect(old.engine).get_table_names()
    assert {"webhook_deliveries", "webhook_attempts"} <= set(names)
    assert "callback_url" in {c["name"] for c in inspect(old.engine).get_columns("jobs")}
    old.close()
