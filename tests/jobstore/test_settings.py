"""Deployment settings (:mod:`jobstore.settings`) that must fit together: the SQLite busy
timeout below the stale-lease window, stage limits within the Celery task limits."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from jobstore.settings import Settings


def test_settings_busy_timeout_must_be_shorter_than_stale_lease_window():
    """Defect 3: the 30 s busy timeout equals the 30 s stale-lease window."""
    with pytest.raises(ValidationError, match="sqlite_busy_timeout_s .* 3 \\* heartbeat_s"):
        Settings(heartbeat_s=10.0, sqlite_busy_timeout_s=30.0)
    assert Settings(heartbeat_s=10.0, sqlite_busy_timeout_s=29.0).busy_timeout_s == 29.0
    assert Settings(heartbeat_s=10.0).busy_timeout_s == 5.0


def test_time_limit_settings_must_fit_together():
    """Stage time limits must be positive and fit in the Celery task limit (the defaults added
    up to 9.25 h against a 6 h soft limit), and soft < hard < visibility timeout."""
    from pydantic import ValidationError

    from jobstore.settings import Settings

    defaults = Settings()
    assert sum(defaults.stage_time_limit_s.values()) <= defaults.task_soft_time_limit_s
    with pytest.raises(ValidationError, match="must be > 0"):
        Settings(stage_time_limit_s={"train": 0})
    with pytest.raises(ValidationError, match="add up to"):
        Settings(stage_time_limit_s={"train": 9 * 3600, "segment": 2 * 3600})
    with pytest.raises(ValidationError, match="DCSEG_VISIBILITY_TIMEOUT_S"):
        Settings(task_time_limit_s=13 * 3600)
