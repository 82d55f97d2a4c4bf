"""Downloads that survive the network: a partial file is continued with ``Range`` after a
dropped connection, a restart of the service or an interrupted earlier run; a server that
ignores ``Range`` (200) restarts the file; presigned object-store URLs are tried first."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from dcseg.client.files import verified
from dcseg.client.shared import Tries, range_request

if TYPE_CHECKING:
    import httpx

    from dcseg.client.sync import Client

__all__ = ["fetch_presigned", "range_start", "resume"]


def resume(client: Client, item: dict[str, Any], partial: Path) -> None:
    """Download ``item`` through the API into ``partial``, continuing from its size with a
    ``Range`` request; a dropped connection or a 5xx/429 is retried (policy), a server
    ignoring ``Range`` (200) restarts the file."""
    import httpx

    tries = Tries(client.retry, "GET", client._http.base_url.join(item["url"]))
    while True:
        try:
            refused = _try(client, item, partial)
        except httpx.TransportError as error:
            client._sleep(tries.dropped(error))
            continue
        if refused is None:
            return
        client._sleep(tries.refused(refused))


def _try(client: Client, item: dict[str, Any], partial: Path) -> httpx.Response | None:
    """One try of :func:`resume`: None when the file was received to its end, the
    (read) answer when its status is worth retrying."""
    request = range_request(item, partial)
    if request is None:
        return None
    have, headers = request
    with client._http.stream("GET", item["url"], headers=headers) as response:
        if response.status_code in client.retry.statuses:
            response.read()
            return response
        if response.status_code >= 400:
            response.read()
            client._json(response)
        append = response.status_code == 206 and range_start(response) == have
        with partial.open("ab" if append else "wb") as out:
            for chunk in response.iter_bytes():
                out.write(chunk)
    return None


def fetch_presigned(item: dict[str, Any], partial: Path, timeout: httpx.Timeout) -> bool:
    """Download the artifact's presigned ``download_url`` straight from the object store
    (no API key is sent there); False when it has none or it fails (expired, unreachable,
    corrupted): the caller then downloads through the API."""
    import httpx

    url = item.get("download_url")
    if not url:
        return False
    try:
        with (
            httpx.stream("GET", url, timeout=timeout) as response,
            partial.open("wb") as out,
        ):
            if response.status_code == 200:
                for chunk in response.iter_bytes():
                    out.write(chunk)
    except httpx.HTTPError:
        pass
    if verified(partial, item):
        return True
    partial.unlink(missing_ok=True)
    return False


def range_start(response: httpx.Response) -> int | None:
    """The first byte a 206 answer carries (``Content-Range: bytes a-b/n``)."""
    value = response.headers.get("Content-Range", "")
    unit, _, span = value.partition(" ")
    first = span.partition("-")[0]
    return int(first) if unit.lower() == "bytes" and first.isdigit() else None
