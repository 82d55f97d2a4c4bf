"""The per-view blend-weight cache on disk: compact dtypes, lazy depth, version-1 files."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from dcseg.blend import BlendWeights
from dcseg.errors import InputError
from dcseg.io.run_state import BlendMemory, load_views, save_views, write_view

K = np.eye(3)
POSE = np.eye(4)


def blend_of(width: int = 5, height: int = 4, seed: int = 0) -> BlendWeights:
    """A view's weights with 0-6 contributions per pixel."""
    rng = np.random.default_rng(seed)
    counts = rng.integers(0, 7, size=width * height)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    nnz = int(offsets[-1])
    return BlendWeights(
        height=height,
        width=width,
        offsets=torch.from_numpy(offsets),
        ids=torch.from_numpy(rng.integers(0, 1000, size=nnz).astype(np.int64)),
        weights=torch.from_numpy(rng.uniform(1e-3, 1.0, size=nnz).astype(np.float32)),
    )


def depth_of(width: int = 5, height: int = 4) -> np.ndarray:
    return np.linspace(0.5, 4.0, width * height, dtype=np.float32).reshape(height, width)


def test_view_file_stores_counts_and_half_weights(tmp_path: Path) -> None:
    """Per pixel one byte of count instead of eight of offset, weights as float16: the file
    reads back to the same CSR rows and weights within float16 rounding."""
    blend = blend_of()
    view = write_view(tmp_path / "0.npz", "f0", K, POSE, blend, depth_of())
    with np.load(tmp_path / "0.npz") as data:
        assert data["counts"].dtype == np.uint8
        assert data["weights"].dtype == np.float16
        assert "offsets" not in data.files
    back = view.blend
    assert torch.equal(back.offsets, blend.offsets)
    assert torch.equal(back.ids.long(), blend.ids)
    assert back.weights.dtype == torch.float32
    torch.testing.assert_close(back.weights, blend.weights, rtol=1e-3, atol=0)
    assert not torch.equal(back.weights, blend.weights)  # rounded, so the check above bites


def test_float32_weights_kept_when_asked(tmp_path: Path) -> None:
    blend = blend_of()
    view = write_view(tmp_path / "0.npz", "f0", K, POSE, blend, depth_of(), half_weights=False)
    assert torch.equal(view.blend.weights, blend.weights)


def test_view_held_in_memory_equals_the_one_read_back(tmp_path: Path) -> None:
    """A capture whose cache fits the memory budget must give the results of one read back:
    the held copy carries the float16-rounded weights too."""
    blend = blend_of()
    memory = BlendMemory(2**20)
    held = write_view(tmp_path / "0.npz", "f0", K, POSE, blend, depth_of(), memory)
    unheld = write_view(tmp_path / "1.npz", "f0", K, POSE, blend, depth_of())
    assert memory.nbytes > 0
    assert torch.equal(held.blend.weights, unheld.blend.weights)
    # the same dtypes too: each id type is a separate compilation of every numba kernel
    for part in ("offsets", "ids", "weights"):
        kept, read = getattr(held.blend, part), getattr(unheld.blend, part)
        assert kept.dtype == read.dtype, part
        assert torch.equal(kept, read), part
    assert held.blend.ids.dtype == torch.int32


def test_a_scan_longer_than_the_budget_finds_the_first_views_held(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Five views, a budget for two: every later scan in order reads three views, not five
    (an LRU would evict each view before the scan returns to it); the budget is never passed."""
    import dcseg.io.run_state as run_state

    blend = blend_of()
    paths = [tmp_path / f"{i}.npz" for i in range(5)]
    for path in paths:
        write_view(path, "f", K, POSE, blend, depth_of())
    size = run_state._read_blend(paths[0], blend.width, blend.height).nbytes()
    reads: list[Path] = []
    original = run_state._read_blend

    def counted(path: Path, width: int, height: int) -> BlendWeights:
        reads.append(path)
        return original(path, width, height)

    monkeypatch.setattr(run_state, "_read_blend", counted)
    memory = BlendMemory(2 * size + size // 2)  # room for two views, not three
    for _ in range(3):
        for path in paths:
            memory.get(path, blend.width, blend.height)
        assert memory.nbytes <= memory.budget
    assert reads == paths + 2 * paths[2:]


def test_depth_is_read_on_use_not_held(tmp_path: Path) -> None:
    view = write_view(tmp_path / "0.npz", "f0", K, POSE, blend_of(), depth_of())
    assert view.held_depth is None
    assert view.depth.dtype == np.float32
    np.testing.assert_array_equal(view.depth, depth_of().astype(np.float16).astype(np.float32))


def test_many_contributions_per_pixel_widen_the_count(tmp_path: Path) -> None:
    offsets = torch.tensor([0, 300, 300], dtype=torch.int64)
    blend = BlendWeights(1, 2, offsets, torch.arange(300), torch.full((300,), 0.5))
    view = write_view(tmp_path / "0.npz", "f0", K, POSE, blend, np.ones((1, 2), np.float32))
    with np.load(tmp_path / "0.npz") as data:
        assert data["counts"].dtype == np.uint16
    assert torch.equal(view.blend.offsets, offsets)


def save_version_1(folder: Path, blend: BlendWeights, depth: np.ndarray) -> None:
    """A run's state as version 1 wrote it: int64 offsets and float32 weights."""
    (folder / "views").mkdir(parents=True)
    np.savez(
        folder / "views" / "0.npz",
        offsets=blend.offsets.numpy(),
        ids=blend.ids.numpy().astype(np.int32),
        weights=blend.weights.numpy(),
        depth=depth.astype(np.float16),
    )
    meta = [{"name": "f0", "width": 5, "height": 4, "K": K.tolist(), "c2w": POSE.tolist()}]
    (folder / "views.json").write_text(json.dumps({"version": 1, "views": meta}))


def test_version_1_state_still_reads(tmp_path: Path) -> None:
    blend = blend_of()
    save_version_1(tmp_path, blend, depth_of())
    (view,) = load_views(tmp_path)
    assert torch.equal(view.blend.offsets, blend.offsets)
    assert torch.equal(view.blend.weights, blend.weights)
    assert view.depth.shape == (4, 5)


def test_saved_views_round_trip_as_version_2(tmp_path: Path) -> None:
    blend = blend_of()
    view = write_view(tmp_path / "cache" / "0.npz", "f0", K, POSE, blend, depth_of())
    save_views(tmp_path / "state", [view])
    body = json.loads((tmp_path / "state" / "views.json").read_text())
    assert body["version"] == 2
    (back,) = load_views(tmp_path / "state")
    assert torch.equal(back.blend.weights, view.blend.weights)


def test_a_truncated_view_file_is_named(tmp_path: Path) -> None:
    blend = blend_of()
    save_version_1(tmp_path, blend, depth_of())
    path = tmp_path / "views" / "0.npz"
    np.savez(path, offsets=blend.offsets.numpy()[:-3], ids=blend.ids.numpy(),
             weights=blend.weights.numpy(), depth=depth_of())  # fmt: skip
    (view,) = load_views(tmp_path)
    with pytest.raises(InputError, match=r"0\.npz.*do not fit a 5x4 view"):
        _ = view.blend


def test_a_missing_view_file_is_named(tmp_path: Path) -> None:
    save_version_1(tmp_path, blend_of(), depth_of())
    (tmp_path / "views" / "0.npz").unlink()
    with pytest.raises(InputError, match=r"0\.npz.*missing"):
        load_views(tmp_path)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda meta: meta.update(K={"a": 1}), "views[0].K: must be a 3x3 array of finite"),
        (lambda meta: meta["c2w"][1].__setitem__(3, "x"), "views[0].c2w: must be a 4x4 array"),
        (lambda meta: meta.pop("name"), "views[0].name: missing"),
        (lambda meta: meta.update(width=None), "views[0].width: must not be null"),
    ],
)
def test_a_damaged_views_json_is_named(tmp_path: Path, change: Any, message: str) -> None:
    save_views(
        tmp_path, [write_view(tmp_path / "c" / "0.npz", "f0", K, POSE, blend_of(), depth_of())]
    )
    path = tmp_path / "views.json"
    body = json.loads(path.read_text())
    change(body["views"][0])
    path.write_text(json.dumps(body))
    with pytest.raises(InputError) as info:
        load_views(tmp_path)
    assert str(info.value).startswith(f"{path}: {message}")


def test_views_json_that_is_not_json_is_named(tmp_path: Path) -> None:
    (tmp_path / "views.json").write_bytes(b'{"version": 2, "views": [\xff')
    with pytest.raises(InputError, match=r"views\.json: not UTF-8 text"):
        load_views(tmp_path)
