"""Creating, checking and migrating the store's tables (:mod:`jobstore.models`).

Bump :data:`jobstore.models.SCHEMA_VERSION` and add a step to :data:`MIGRATIONS` for every
change of the tables.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from sqlalchemy import Connection, func, insert, inspect, select
from sqlalchemy.exc import IntegrityError, OperationalError, ProgrammingError

from jobstore.models import (
    SCHEMA_VERSION,
    Base,
    SchemaVersion,
    WebhookAttempt,
    WebhookDelivery,
)
from jobstore.store.engine import StoreBase

logger = logging.getLogger(__name__)


def _add_upload_stored_bytes(conn: Connection) -> None:
    """v2: ``uploads.stored_bytes`` (bytes of the extracted upload; NULL = use ``size``)."""
    conn.exec_driver_sql("ALTER TABLE uploads ADD COLUMN stored_bytes BIGINT")


def _add_webhooks(conn: Connection) -> None:
    """v3: ``jobs.callback_url`` and the webhook outbox (``webhook_deliveries``,
    ``webhook_attempts``)."""
    if "callback_url" not in {c["name"] for c in inspect(conn).get_columns("jobs")}:
        conn.exec_driver_sql("ALTER TABLE jobs ADD COLUMN callback_url VARCHAR(2048)")
    tables = [WebhookDelivery.__table__, WebhookAttempt.__table__]
    Base.metadata.create_all(conn, tables=tables)  # type: ignore[arg-type]


MIGRATIONS: dict[int, Callable[[Connection], None]] = {
    2: _add_upload_stored_bytes,
    3: _add_webhooks,
}
"""``MIGRATIONS[v]`` upgrades a version ``v - 1`` schema to version ``v``."""


class SchemaError(RuntimeError):
    """The database schema cannot be used by this code."""


class SchemaMixin(StoreBase):
    """The schema's version: created, checked and migrated at startup."""

    def init_schema(self) -> int:
        """Create the tables, or check and migrate an existing schema; returns its version."""
        try:
            return self._init_schema()
        except (IntegrityError, OperationalError, ProgrammingError):
            # another process created the schema at the same moment: check what it made
            logger.info("schema creation raced with another process; checking again")
            return self._init_schema()

    def _init_schema(self) -> int:
        with self.engine.begin() as conn:
            if not inspect(conn).has_table(SchemaVersion.__tablename__):
                Base.metadata.create_all(conn)
                conn.execute(insert(SchemaVersion).values(version=SCHEMA_VERSION))
                logger.info("created job store schema v%d", SCHEMA_VERSION)
                return SCHEMA_VERSION
            current = conn.execute(select(func.max(SchemaVersion.version))).scalar()
            if current is None:
                raise SchemaError("schema_version table is empty; cannot tell the schema version")
            if current > SCHEMA_VERSION:
                raise SchemaError(
                    f"database schema v{current} is newer than this code (v{SCHEMA_VERSION}); "
                    "upgrade dcseg"
                )
            for version in range(current + 1, SCHEMA_VERSION + 1):
                MIGRATIONS[version](conn)
                conn.execute(insert(SchemaVersion).values(version=version))
                logger.info("migrated job store schema to v%d", version)
            return SCHEMA_VERSION
