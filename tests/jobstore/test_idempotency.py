"""Idempotency records (:mod:`jobstore.store.idempotency`): how long a request in flight
blocks its key."""

from __future__ import annotations


def test_in_flight_idempotency_window_is_a_setting(tmp_path):
    """Upload idempotency: a request still in flight blocked its key for a hard-coded 2 min
    (shorter than validating a large upload); the window is DCSEG_IDEMPOTENCY_IN_FLIGHT_S."""
    from datetime import timedelta

    from jobstore.store import Store

    store = Store(f"sqlite:///{tmp_path / 'db.sqlite'}")
    store.init_schema()
    store.ensure_tenant("t")
    assert store.idempotency_begin("t", "k", "h").kind == "new"
    long = timedelta(hours=2)
    assert store.idempotency_begin("t", "k", "h", in_flight=long).kind == "in_flight"
    assert store.idempotency_begin("t", "k", "h", in_flight=timedelta(0)).kind == "new"
    assert store.idempotency_begin("t", "k", "h").kind == "in_flight"  # the default is 1 h
    store.close()
