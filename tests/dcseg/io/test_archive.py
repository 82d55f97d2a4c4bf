"""Safe archive extraction: traversal, links, devices, bombs and corrupt files."""

from __future__ import annotations

import io
import stat
import tarfile
import zipfile
from pathlib import Path

import pytest

from dcseg.errors import InputError
from dcseg.io.archive import is_archive, safe_extract


def _zip(path: Path, entries: dict[str, bytes]) -> Path:
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name, data in entries.items():
            zf.writestr(name, data)
    return path


def _tar(path: Path, members: list[tuple[tarfile.TarInfo, bytes | None]], mode: str = "w") -> Path:
    with tarfile.open(path, "w:gz" if mode == "w:gz" else "w") as tf:
        for info, data in members:
            if data is not None:
                info.size = len(data)
            tf.addfile(info, io.BytesIO(data) if data is not None else None)
    return path


def _member(name: str, kind: bytes = tarfile.REGTYPE, link: str = "") -> tarfile.TarInfo:
    info = tarfile.TarInfo(name)
    info.type = kind
    info.linkname = link
    return info


def test_single_top_folder_is_returned(tmp_path: Path) -> None:
    archive = _zip(
        tmp_path / "a.zip",
        {"scene/a.txt": b"a", "scene/sub/b.txt": b"b", "__MACOSX/scene/._a.txt": b"junk"},
    )
    root = safe_extract(archive, tmp_path / "out")
    assert root == tmp_path / "out" / "scene"
    assert (root / "sub" / "b.txt").read_bytes() == b"b"
    assert not (tmp_path / "out" / "__MACOSX").exists()


def test_several_top_entries_return_dest(tmp_path: Path) -> None:
    archive = _tar(
        tmp_path / "a.tar.gz", [(_member("a.txt"), b"a"), (_member("d/b.txt"), b"b")], "w:gz"
    )
    assert safe_extract(archive, tmp_path / "out") == tmp_path / "out"
    assert (tmp_path / "out" / "d" / "b.txt").read_bytes() == b"b"


@pytest.mark.parametrize("name", ["../x", "a/../../x", "..\\x", "/etc/x", "C:/x"])
def test_zip_traversal(tmp_path: Path, name: str) -> None:
    archive = _zip(tmp_path / "evil.zip", {"ok.txt": b"fine", name: b"bad"})
    with pytest.raises(InputError, match=r"evil\.zip: archive entry .* (escapes|absolute)"):
        safe_extract(archive, tmp_path / "out")
    assert list((tmp_path / "out").iterdir()) == []  # nothing written before the check


def test_tar_traversal_message(tmp_path: Path) -> None:
    archive = _tar(tmp_path / "evil.tar", [(_member("../x"), b"bad")])
    with pytest.raises(InputError, match=r"archive entry '\.\./x' escapes the archive folder"):
        safe_extract(archive, tmp_path / "out")
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize(
    ("member", "word"),
    [
        (_member("link", tarfile.SYMTYPE, "/etc/passwd"), "link"),
        (_member("inside", tarfile.SYMTYPE, "a.txt"), "link"),
        (_member("hard", tarfile.LNKTYPE, "a.txt"), "link"),
        (_member("dev", tarfile.CHRTYPE), "device"),
        (_member("fifo", tarfile.FIFOTYPE), "device"),
    ],
)
def test_tar_links_and_devices(tmp_path: Path, member: tarfile.TarInfo, word: str) -> None:
    archive = _tar(tmp_path / "x.tar", [(_member("a.txt"), b"a"), (member, None)])
    with pytest.raises(InputError, match=rf"archive entry '{member.name}' is a {word}"):
        safe_extract(archive, tmp_path / "out")


def test_zip_symlink(tmp_path: Path) -> None:
    archive = tmp_path / "link.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        info = zipfile.ZipInfo("link")
        info.external_attr = (stat.S_IFLNK | 0o777) << 16
        zf.writestr(info, "/etc/passwd")
    with pytest.raises(InputError, match=r"archive entry 'link' is a link"):
        safe_extract(archive, tmp_path / "out")


def test_entry_count_cap(tmp_path: Path) -> None:
    entries = {f"f{i}.txt": b"" for i in range(11)}
    with pytest.raises(InputError, match="more than 10 entries"):
        safe_extract(_zip(tmp_path / "many.zip", entries), tmp_path / "o1", max_entries=10)
    members: list[tuple[tarfile.TarInfo, bytes | None]] = [
        (_member(f"f{i}.txt"), b"") for i in range(11)
    ]
    with pytest.raises(InputError, match="more than 10 entries"):
        safe_extract(_tar(tmp_path / "many.tar", members), tmp_path / "o2", max_entries=10)
    assert (
        safe_extract(
            _zip(tmp_path / "ten.zip", dict(list(entries.items())[:10])),
            tmp_path / "o3",
            max_entries=10,
        )
        == tmp_path / "o3"
    )


def test_size_cap_on_bytes_written(tmp_path: Path) -> None:
    bomb = _tar(tmp_path / "bomb.tar.gz", [(_member("zeros"), bytes(3_000_000))], "w:gz")
    assert bomb.stat().st_size < 20_000
    with pytest.raises(InputError, match=r"bomb\.tar\.gz: archive expands to more than 1,000,000"):
        safe_extract(bomb, tmp_path / "out", max_total_bytes=1_000_000)


def test_size_cap_on_declared_zip_sizes(tmp_path: Path) -> None:
    archive = _zip(tmp_path / "big.zip", {"a": bytes(600), "b": bytes(600)})
    with pytest.raises(InputError, match="archive expands to 1,200 bytes, above the limit"):
        safe_extract(archive, tmp_path / "out", max_total_bytes=1000)


def test_lying_zip_header_is_caught(tmp_path: Path) -> None:
    archive = _zip(tmp_path / "liar.zip", {"a": bytes(5000)})
    data = bytearray(archive.read_bytes())
    # shrink the declared uncompressed size in both headers to 10 bytes
    for sig, offset in ((b"PK\x03\x04", 22), (b"PK\x01\x02", 24)):
        pos = data.find(sig)
        data[pos + offset : pos + offset + 4] = (10).to_bytes(4, "little")
    archive.write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"liar\.zip: corrupt or unreadable archive"):
        safe_extract(archive, tmp_path / "out", max_total_bytes=1000)
    written = sum(p.stat().st_size for p in (tmp_path / "out").rglob("*") if p.is_file())
    assert written <= 1000


@pytest.mark.parametrize("content", [b"", b"hello world" * 10, b"PK\x03\x04garbage"])
def test_not_an_archive(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "junk.zip"
    path.write_bytes(content)
    with pytest.raises(InputError, match=r"junk\.zip: not a supported archive"):
        safe_extract(path, tmp_path / "out")


def test_truncated_archives(tmp_path: Path) -> None:
    payload = bytes(range(256)) * 400
    tgz = _tar(tmp_path / "t.tar.gz", [(_member("a.bin"), payload)], "w:gz")
    tgz.write_bytes(tgz.read_bytes()[: tgz.stat().st_size // 2])
    with pytest.raises(InputError, match=r"t\.tar\.gz: corrupt or unreadable archive"):
        safe_extract(tgz, tmp_path / "o1")
    archive = _zip(tmp_path / "z.zip", {"a.bin": payload})
    data = bytearray(archive.read_bytes())
    data[60:80] = bytes(20)  # damage the compressed stream, keep the central directory
    archive.write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"z\.zip: corrupt or unreadable archive"):
        safe_extract(archive, tmp_path / "o2")


def test_missing_archive_and_suffixes(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"nope\.zip: missing"):
        safe_extract(tmp_path / "nope.zip", tmp_path / "out")
    assert is_archive(Path("a.TAR.GZ")) and is_archive(Path("b.tgz")) and is_archive(Path("c.zip"))
    assert not is_archive(Path("d.gz")) and not is_archive(Path("e"))


def test_top_folder_ignores_existing_files_and_dot_entries(tmp_path: Path) -> None:
    dest = tmp_path / "out"
    dest.mkdir()
    (dest / "already-here.txt").write_text("x")
    dot = _member(".", tarfile.DIRTYPE)
    archive = _tar(tmp_path / "a.tar", [(dot, None), (_member("./scene/a.txt"), b"a")])
    assert safe_extract(archive, dest) == dest / "scene"
    single_file = _zip(tmp_path / "f.zip", {"only.txt": b"x"})
    assert safe_extract(single_file, tmp_path / "o2") == tmp_path / "o2"


@pytest.mark.parametrize(
    ("member", "refusal"),
    [
        (_member("../x"), "escapes the archive folder"),
        (_member("/etc/cron.d/x"), "is an absolute path"),
        (_member("link", tarfile.SYMTYPE, "/etc/passwd"), "is a link"),
        (_member("dev", tarfile.CHRTYPE), "is a device"),
    ],
)
def test_tar_refusals_without_the_standard_data_filter(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, member: tarfile.TarInfo, refusal: str
) -> None:
    """Python 3.11 before 3.11.4 (Debian bookworm's, in the images) has no tarfile.data_filter:
    the archive checks refuse the same entries without it."""
    monkeypatch.setattr("dcseg.io.archive._DATA_FILTER", None)
    archive = _tar(tmp_path / "evil.tar", [(member, b"bad" if member.isfile() else None)])
    with pytest.raises(InputError, match=rf"archive entry '{member.name}' {refusal}"):
        safe_extract(archive, tmp_path / "out")
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").rglob("*"))
