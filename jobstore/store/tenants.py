"""Tenants and their API keys (stored as SHA-256 hashes), synced from the settings at startup."""

from __future__ import annotations

import hashlib
import logging

from sqlalchemy import select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from jobstore.models import ApiKey, Tenant
from jobstore.store.engine import StoreBase

logger = logging.getLogger(__name__)

SYNC_ATTEMPTS = 3
"""Tries of :meth:`TenantsMixin.sync_api_keys` when replicas starting together collide."""


def hash_key(key: str) -> str:
    """How API keys are stored: random tokens, so a plain SHA-256 is enough."""
    return hashlib.sha256(key.encode()).hexdigest()


class TenantsMixin(StoreBase):
    """Tenant rows and the API keys that name them."""

    def sync_api_keys(self, keys: dict[str, str]) -> dict[str, str]:
        """Make the stored keys exactly ``keys`` (``{key: tenant}``); returns ``{hash: tenant}``.

        API replicas starting together race to insert the same rows: a unique violation means
        another replica got there first, and the sync runs again (it then finds the rows).
        """
        for attempt in range(SYNC_ATTEMPTS):
            try:
                return self._sync_api_keys(keys)
            except IntegrityError:
                if attempt == SYNC_ATTEMPTS - 1:
                    raise
                logger.info("API keys were being synced by another replica; syncing again")
        raise AssertionError("unreachable")  # pragma: no cover

    def _sync_api_keys(self, keys: dict[str, str]) -> dict[str, str]:
        wanted = {hash_key(k): t for k, t in keys.items()}
        with self.session() as s:
            for tenant in sorted(set(wanted.values())):
                self._ensure_tenant(s, tenant)
            s.flush()
            for row in s.scalars(select(ApiKey)):
                if wanted.get(row.key_hash) != row.tenant_id:
                    s.delete(row)
            s.flush()
            stored = set(s.scalars(select(ApiKey.key_hash)))
            s.add_all(ApiKey(key_hash=h, tenant_id=t) for h, t in wanted.items() if h not in stored)
        return wanted

    def ensure_tenant(self, tenant: str) -> None:
        try:
            with self.session() as s:
                self._ensure_tenant(s, tenant)
        except IntegrityError:  # another replica inserted it meanwhile
            with self.session(write=False) as s:
                if s.get(Tenant, tenant) is None:
                    raise

    @staticmethod
    def _ensure_tenant(s: Session, tenant: str) -> None:
        if s.get(Tenant, tenant) is None:
            s.add(Tenant(id=tenant))
