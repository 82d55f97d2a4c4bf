"""The dcseg Celery app running test stages: ``celery -A tests.worker.celery_test_app worker``.

``DCSEG_TEST_STAGES`` names a stage factory of :mod:`tests.worker.fakes` (default
``slow_stages``).
"""

from __future__ import annotations

import os

import worker.celery_app as base
from tests.worker import fakes

base.stages_factory = getattr(fakes, os.environ.get("DCSEG_TEST_STAGES", "slow_stages"))
app = base.app
