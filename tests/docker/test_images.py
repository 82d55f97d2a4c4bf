"""The container files: what each image copies and installs, and that the build context,
compose file and Dockerfiles agree (scripts/compose_test.sh builds and runs them)."""

from __future__ import annotations

import fnmatch
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
import yaml  # type: ignore[import-untyped]

REPO = Path(__file__).resolve().parents[2]
DOCKER = REPO / "docker"
sys.path.insert(0, str(DOCKER))
from requirements import requirements  # type: ignore[import-not-found]  # noqa: E402

OURS = ["api", "worker-cpu", "redis", "postgres", "seaweedfs"]
"""Images built from the local Debian base (the GPU worker starts from a CUDA image)."""


def dockerfile(name: str) -> str:
    return (DOCKER / f"{name}.Dockerfile").read_text(encoding="utf-8")


@pytest.mark.parametrize(
    ("image", "packages"),
    [
        ("api", {"dcseg", "jobstore", "service"}),
        ("worker-cpu", {"dcseg", "jobstore", "worker"}),
        ("worker-gpu", {"dcseg", "jobstore", "worker"}),
    ],
)
def test_images_ship_their_layer_and_what_it_imports(image: str, packages: set[str]):
    """The API image has no ``worker/`` and the worker images no ``service/`` (they never
    import each other; lint-imports checks it)."""
    assert set(re.findall(r"^COPY (\w+) \./\1$", dockerfile(image), re.M)) == packages


def test_api_requirements_are_the_project_dependencies_without_torch(tmp_path: Path):
    pyproject = tmp_path / "pyproject.toml"
    pyproject.write_text(
        '[project]\ndependencies = ["torch>=2.4", "numpy>=1.26", "Torch_Vision", "usd-core==25.11"]'
    )
    assert requirements(pyproject, {"torch"}) == ["numpy>=1.26", "Torch_Vision", "usd-core==25.11"]
    assert requirements(pyproject, {"torch-vision"}) == [
        "torch>=2.4",
        "numpy>=1.26",
        "usd-core==25.11",
    ]
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["dependencies"]
    api = requirements(REPO / "pyproject.toml", {"torch"})
    left_out = [d for d in project if d not in api]
    assert len(left_out) == 1 and left_out[0].startswith("torch>=")


def test_the_api_process_never_loads_torch():
    """The API image has no torch: nothing the API or its export child imports may load it."""
    code = (
        "import sys, service.main, service.uploads, dcseg.io.validate, dcseg.io.archive\n"
        "import service.export_child, dcseg.export.gaussians, dcseg.export.meshes\n"
        "assert 'torch' not in sys.modules, 'an API-image import loaded torch'\n"
    )
    subprocess.run([sys.executable, "-c", code], timeout=60, check=True)


def copied_sources(text: str) -> list[str]:
    """The build-context paths of a Dockerfile's COPY lines (not ``--from`` stages)."""
    out = []
    for line in re.findall(r"^COPY (?!--from)(.+)$", text, re.M):
        out += line.split()[:-1]
    return out


def admitted(path: str, rules: list[str]) -> bool:
    """Whether ``.dockerignore`` rules (later lines win) let ``path`` into the context."""
    inside = False
    for rule in rules:
        negated = rule.startswith("!")
        pattern = rule.lstrip("!")
        if fnmatch.fnmatch(path, pattern) or fnmatch.fnmatch(path + "/x", pattern):
            inside = negated
    return inside


@pytest.mark.parametrize("image", [*OURS, "worker-gpu"])
def test_the_build_context_admits_every_copied_path(image: str):
    lines = (REPO / ".dockerignore").read_text().splitlines()
    rules = [line.strip() for line in lines if line.strip() and not line.startswith("#")]
    for source in copied_sources(dockerfile(image)):
        assert (REPO / source).exists(), f"{image}: COPY {source}: no such path"
        assert admitted(source.rstrip("/"), rules), f"{image}: .dockerignore leaves out {source}"
    assert not admitted(".venv", rules) and not admitted("benchmarks", rules)


@pytest.mark.parametrize("image", OURS)
def test_our_images_start_from_the_local_base(image: str):
    text = dockerfile(image)
    assert re.findall(r"^FROM (\S+)", text, re.M)[-1] == "${BASE_IMAGE}"
    assert "ARG BASE_IMAGE=debian:bookworm" in text


@pytest.mark.parametrize("image", [*OURS, "worker-gpu"])
def test_every_image_runs_unprivileged_with_a_health_check(image: str):
    text = dockerfile(image)
    users = re.findall(r"^USER (\S+)", text, re.M)
    assert users and users[-1] != "root"
    assert re.search(r"^HEALTHCHECK ", text, re.M)
    assert not re.search(r"^(ARG|ENV) \S*(SECRET|PASSWORD|KEY)", text, re.M)  # no build secrets


def test_compose_services_build_our_images():
    compose = yaml.safe_load((DOCKER / "compose.yaml").read_text())
    services = compose["services"]
    assert set(services) == {"s3", "redis", "postgres", "api", "worker", "worker-gpu"}
    for name, service in services.items():
        built = Path(service["build"]["dockerfile"]).name.removesuffix(".Dockerfile")
        assert (DOCKER / f"{built}.Dockerfile").exists(), name
        assert service["image"].startswith(f"dcseg-{built}:"), name
    assert services["worker-gpu"]["profiles"] == ["gpu"]
