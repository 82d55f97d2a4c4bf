"""What the API (``service``) and the workers (``worker``) share, and nothing else: settings,
the job store (tables and queries), blob storage (local folder or S3) and the job contract
(task name, statuses, folder layout). Imports neither ``service`` nor ``worker`` (checked by
import-linter, see ``[tool.importlinter]`` in pyproject.toml); no torch, no HTTP."""
