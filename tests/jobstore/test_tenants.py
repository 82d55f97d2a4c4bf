"""Tenants and API keys (:mod:`jobstore.store.tenants`) synced by replicas starting together."""

from __future__ import annotations

from typing import Any

import pytest

from jobstore.store import Store
from tests.service import test_databases


@pytest.mark.integration
def test_replicas_starting_together_both_sync_their_keys(postgres_server, monkeypatch):
    """Found by the deployed load benchmark: two API processes starting on a fresh database
    both insert the tenant of their keys; the loser failed startup with a unique violation.
    Another replica's insert lands between this one's check and its insert."""
    from jobstore.models import Tenant

    url = postgres_server
    test_databases._reset(url)
    first, other = Store(url), Store(url)
    first.init_schema()
    raced: list[str] = []

    def racing(s: Any, tenant: str) -> None:
        missing = s.get(Tenant, tenant) is None
        if missing and not raced:
            raced.append(tenant)
            other.ensure_tenant(tenant)  # the other replica commits first
        if missing:
            s.add(Tenant(id=tenant))

    monkeypatch.setattr(Store, "_ensure_tenant", staticmethod(racing))
    try:
        hashes = first.sync_api_keys({"k" * 16: "bench"})
        assert raced == ["bench"] and list(hashes.values()) == ["bench"]
        assert other.sync_api_keys({"k" * 16: "bench"}) == hashes
    finally:
        first.close()
        other.close()
