"""The job store: every read and write of job records, uploads, events and API keys.

Shared by the API and the workers (no torch, no HTTP). Each mutation of a job locks its row
(``SELECT ... FOR UPDATE`` on PostgreSQL; SQLite write transactions start with
``BEGIN IMMEDIATE``, reads with a plain deferred ``BEGIN``) and appends its event in the same
transaction, so event numbers never repeat or skip. Lease, start, update and completion
times come from the database's clock, never from a worker's or API host's clock (only
``created_at`` is the API host's).

One class, :class:`Store`, made of one part per aggregate: the engine and clock
(:mod:`~jobstore.store.engine`), the schema (:mod:`~jobstore.store.schema`), tenants and keys
(:mod:`~jobstore.store.tenants`), uploads (:mod:`~jobstore.store.uploads`), events
(:mod:`~jobstore.store.events`), jobs as the API sees them (:mod:`~jobstore.store.jobs`),
their leases as the workers hold them (:mod:`~jobstore.store.leases`), idempotency records
(:mod:`~jobstore.store.idempotency`) and the webhook outbox (:mod:`~jobstore.store.webhooks`).
"""

from __future__ import annotations

from jobstore.store.engine import new_id
from jobstore.store.idempotency import IdempotencyMixin, IdempotencyOutcome
from jobstore.store.jobs import Conflict, Cursor, JobsMixin, TooManyJobs
from jobstore.store.leases import Lease, LeasesMixin
from jobstore.store.schema import SchemaError, SchemaMixin
from jobstore.store.tenants import TenantsMixin, hash_key
from jobstore.store.uploads import UploadInUse, UploadsMixin
from jobstore.store.webhooks import AttemptOutcome, DeliveryClaim, WebhooksMixin

__all__ = [
    "AttemptOutcome",
    "Conflict",
    "Cursor",
    "DeliveryClaim",
    "IdempotencyOutcome",
    "Lease",
    "SchemaError",
    "Store",
    "TooManyJobs",
    "UploadInUse",
    "hash_key",
    "new_id",
]


class Store(
    SchemaMixin,
    TenantsMixin,
    UploadsMixin,
    JobsMixin,
    LeasesMixin,
    IdempotencyMixin,
    WebhooksMixin,
):
    """Job records in a SQL database (SQLite file or PostgreSQL)."""
