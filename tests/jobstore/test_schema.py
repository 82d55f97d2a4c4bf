"""The schema (:mod:`jobstore.store.schema`): an older database migrates at startup."""

from __future__ import annotations


def test_schema_v1_gains_uploads_stored_bytes(tmp_path):
    """The quota's per-upload byte count is a new column: a v1 store migrates to v2 and its
    old uploads count their archive size."""
    from sqlalchemy import delete, insert, inspect

    from jobstore.models import SCHEMA_VERSION, SchemaVersion
    from jobstore.store import Store

    store = Store(f"sqlite:///{tmp_path / 'v1.db'}")
    store.init_schema()
    with store.engine.begin() as conn:
        conn.exec_driver_sql("ALTER TABLE uploads DROP COLUMN stored_bytes")
        conn.execute(delete(SchemaVersion))
        conn.execute(insert(SchemaVersion).values(version=1))
        conn.exec_driver_sql("INSERT INTO tenants (id, created_at) VALUES ('t', '2026-01-01')")
        conn.exec_driver_sql(
            "INSERT INTO uploads (id, tenant_id, sha256, size, content_type, summary, "
            "created_at) VALUES ('u', 't', '', 123, 'application/x-tar', '{}', '2026-01-01')"
        )
    assert store.init_schema() == SCHEMA_VERSION == 3
    columns = {c["name"] for c in inspect(store.engine).get_columns("uploads")}
    assert "stored_bytes" in columns
    assert store.tenant_storage("t") == (123, [])
    store.close()
