"""Archive limits apply before the archive is read (issue 17, service hardening: defects 2-4)."""

from __future__ import annotations

import gzip
import io
import tarfile
import zipfile
from pathlib import Path
from typing import Any

import pytest

from dcseg.errors import InputError
from dcseg.io.archive import safe_extract
from dcseg.io.limits import LimitProblem


def _many_entry_zip(path: Path, n: int) -> Path:
    with zipfile.ZipFile(path, "w") as zf:
        for i in range(n):
            zf.writestr(f"d{i}/", b"")
    return path


def _refuse_zipfile(monkeypatch: pytest.MonkeyPatch) -> None:
    def boom(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("zipfile.ZipFile must not be constructed")

    monkeypatch.setattr(zipfile, "ZipFile", boom)


def _limit_of(error: InputError) -> str:
    problem = error.problems[0]
    assert isinstance(problem, LimitProblem), problem
    return problem.limit


def test_zip_central_directory_count_checked_before_reading(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Defect 2: zipfile.ZipFile() reads the whole central directory before the entry cap."""
    archive = _many_entry_zip(tmp_path / "many.zip", 50)
    _refuse_zipfile(monkeypatch)
    with pytest.raises(InputError, match=r"many\.zip: archive has more than 10 entries") as err:
        safe_extract(archive, tmp_path / "out", max_entries=10)
    assert _limit_of(err.value) == "max_entries"


def test_zip64_end_record_count_checked_before_reading(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Defect 2: the entry count is also read from a ZIP64 end-of-central-directory record."""
    archive = tmp_path / "z64.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        for i in range(20):
            zf.writestr(f"f{i}.txt", b"x")
    data = archive.read_bytes()
    eocd = data.rfind(b"PK\x05\x06")
    cd_size = int.from_bytes(data[eocd + 12 : eocd + 16], "little")
    cd_offset = int.from_bytes(data[eocd + 16 : eocd + 20], "little")
    zip64 = b"PK\x06\x06" + (44).to_bytes(8, "little") + (45).to_bytes(2, "little") * 2
    zip64 += bytes(8) + (20).to_bytes(8, "little") * 2
    zip64 += cd_size.to_bytes(8, "little") + cd_offset.to_bytes(8, "little")
    locator = b"PK\x06\x07" + bytes(4) + eocd.to_bytes(8, "little") + (1).to_bytes(4, "little")
    end = bytearray(data[eocd:])
    end[8:12] = b"\xff\xff\xff\xff"  # entry counts: see the ZIP64 record
    archive.write_bytes(data[:eocd] + zip64 + locator + bytes(end))
    assert len(zipfile.ZipFile(archive).infolist()) == 20  # a valid ZIP64 end record
    _refuse_zipfile(monkeypatch)
    with pytest.raises(InputError, match=r"more than 10 entries"):
        safe_extract(archive, tmp_path / "out", max_entries=10)


def test_zip_lying_entry_count_caught_by_directory_size(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Defect 2: an end record that understates the count still cannot hide a big directory."""
    archive = _many_entry_zip(tmp_path / "liar.zip", 200)
    data = bytearray(archive.read_bytes())
    eocd = data.rfind(b"PK\x05\x06")
    data[eocd + 8 : eocd + 12] = (1).to_bytes(2, "little") * 2  # "1 entry"
    archive.write_bytes(bytes(data))
    _refuse_zipfile(monkeypatch)
    with pytest.raises(InputError, match=r"central directory is [\d,]+ bytes, above") as err:
        safe_extract(archive, tmp_path / "out", max_entries=10, max_directory_bytes=1000)
    assert _limit_of(err.value) == "max_directory_bytes"


def _header(name: str, size: int) -> bytes:
    info = tarfile.TarInfo(name)
    info.size = size
    return info.tobuf(format=tarfile.GNU_FORMAT)


def test_tar_declared_size_checked_before_extracting(tmp_path: Path) -> None:
    """Defect 3: tar had no declared-size check (bytes were counted only while writing)."""
    archive = tmp_path / "big.tar"
    with tarfile.open(archive, "w") as tf:
        info = tarfile.TarInfo("scene/big.bin")
        info.size = 5000
        tf.addfile(info, io.BytesIO(bytes(5000)))
    with pytest.raises(InputError, match=r"entry 'scene/big\.bin' declares 5,000 bytes") as err:
        safe_extract(archive, tmp_path / "out", max_total_bytes=1000)
    assert _limit_of(err.value) == "max_total_bytes"
    assert not (tmp_path / "out" / "scene" / "big.bin").exists()


def test_tar_limits_apply_before_the_stream_is_read(tmp_path: Path) -> None:
    """Defect 3: listing tar members decompressed the whole stream before limits applied."""
    # The first header declares 1 GB; the stream then breaks off. Reading past the header
    # (as listing all members does) fails, so only a check at the header gives this message.
    stream = _header("huge.bin", 10**9) + bytes(4096)
    archive = tmp_path / "huge.tar.gz"
    archive.write_bytes(gzip.compress(stream))
    with pytest.raises(InputError, match=r"entry 'huge\.bin' declares 1,000,000,000 bytes"):
        safe_extract(archive, tmp_path / "out", max_total_bytes=10**6)
    many = b"".join(_header(f"f{i}", 0) for i in range(20)) + b"\x00garbage" * 100
    archive.write_bytes(gzip.compress(many))
    with pytest.raises(InputError, match=r"more than 10 entries"):
        safe_extract(archive, tmp_path / "out2", max_entries=10)


def test_tar_pax_header_size_is_capped(tmp_path: Path) -> None:
    """Defect 3: pax / GNU long-name header records were read whole, whatever their size."""
    archive = tmp_path / "pax.tar"
    with tarfile.open(archive, "w", format=tarfile.PAX_FORMAT) as tf:
        info = tarfile.TarInfo("a.txt")
        info.size = 1
        info.pax_headers = {"comment": "x" * 100_000}
        tf.addfile(info, io.BytesIO(b"a"))
    with pytest.raises(InputError, match=r"tar header record \(pax or GNU long name\)") as err:
        safe_extract(archive, tmp_path / "out", max_header_bytes=10_000)
    assert _limit_of(err.value) == "max_header_bytes"
    long_name = tmp_path / "long.tar"
    with tarfile.open(long_name, "w", format=tarfile.GNU_FORMAT) as tf:
        info = tarfile.TarInfo("d/" + "n" * 20_000)
        tf.addfile(info, io.BytesIO(b""))
    with pytest.raises(InputError, match=r"of 20,\d{3} bytes, above the limit of 10,000"):
        safe_extract(long_name, tmp_path / "out2", max_header_bytes=10_000)
    assert safe_extract(archive, tmp_path / "out3") == tmp_path / "out3"  # default cap: fine


@pytest.mark.parametrize(("mode", "name"), [("w:bz2", "bzip2"), ("w:xz", "xz")])
def test_tar_bz2_and_xz_are_refused(tmp_path: Path, mode: str, name: str) -> None:
    """Defect 3: bz2 / xz tar archives were accepted (only tar and tar.gz are supported)."""
    archive = tmp_path / f"a.{name}"
    with tarfile.open(archive, mode) as tf:  # type: ignore[call-overload]
        info = tarfile.TarInfo("a.txt")
        info.size = 1
        tf.addfile(info, io.BytesIO(b"a"))
    with pytest.raises(InputError, match=rf"{name}-compressed archives are not supported"):
        safe_extract(archive, tmp_path / "out")


def test_tar_non_utf8_entry_name_is_refused(tmp_path: Path) -> None:
    """Defect 4: a non-UTF-8 tar entry name was extracted (and broke the service later)."""
    archive = tmp_path / "latin1.tar"
    with tarfile.open(archive, "w", encoding="utf-8", errors="surrogateescape") as tf:
        info = tarfile.TarInfo("scene/caf\udce9.png")
        info.size = 1
        tf.addfile(info, io.BytesIO(b"a"))
    assert b"caf\xe9.png" in archive.read_bytes()
    with pytest.raises(InputError, match=r"entry 'scene/caf\\xe9\.png' has a name that is not"):
        safe_extract(archive, tmp_path / "out")
    assert not any((tmp_path / "out").rglob("*.png"))


def test_zip_bad_utf8_name_is_corrupt_not_a_crash(tmp_path: Path) -> None:
    """Defect 4: a zip flagged UTF-8 whose name is not UTF-8 raised UnicodeDecodeError."""
    archive = tmp_path / "bad.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        zf.writestr("caf\u00e9.txt", b"x")  # stored with the UTF-8 flag
    data = archive.read_bytes().replace("caf\u00e9".encode(), b"caf\xe9\xff")
    archive.write_bytes(data)
    with pytest.raises(InputError, match=r"bad\.zip: corrupt or unreadable archive"):
        safe_extract(archive, tmp_path / "out")
