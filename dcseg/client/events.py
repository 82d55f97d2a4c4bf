"""Server-sent events (the ``text/event-stream`` format of the WHATWG HTML standard, 9.2),
read line by line: what ``GET /v1/jobs/{id}/events`` sends."""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import Any

__all__ = ["Cursor", "EventParser", "ServerEvent", "parse_events"]


@dataclass(frozen=True)
class ServerEvent:
    """One event: ``type`` is ``status``, ``progress``, ``log`` or ``completed`` for a job;
    ``""`` stands for a comment line (a keep-alive, or the server saying the stream ends)."""

    type: str
    data: Any = None
    """The JSON payload (the raw text when it is not JSON)."""
    id: int | None = None
    """The job's event number (reconnect with ``Last-Event-ID`` set to the last one seen)."""
    retry_ms: int | None = None
    """The reconnection delay the server asks for, when the event set one."""


@dataclass
class Cursor:
    """Where a reader of a job's stream is: the last event seen (``Last-Event-ID`` for the
    next connection) and the reconnection delay the server asked for."""

    last: int = 0
    pause: float = 2.0

    def take(self, event: ServerEvent) -> bool:
        """Note ``event``; whether it is new (an event, not a comment or one seen before)."""
        if event.retry_ms is not None:
            self.pause = event.retry_ms / 1000
        if event.id is not None:
            if event.id <= self.last:
                return False
            self.last = event.id
        return bool(event.type)


def _decoded(text: str) -> Any:
    try:
        return json.loads(text)
    except ValueError:
        return text


class EventParser:
    """Turns a stream's lines (without their line ends), fed one by one, into events."""

    def __init__(self) -> None:
        self.fields: dict[str, str] = {}
        self.data: list[str] = []

    def feed(self, line: str) -> ServerEvent | None:
        """The event ``line`` completes (a blank line ends one; a comment line is a
        ``type=""`` event of its own, so a reader can check its clock while nothing happens)."""
        if line.startswith(":"):
            return ServerEvent("", line[1:].strip())
        if line == "":
            fields, data = self.fields, self.data
            self.fields, self.data = {}, []
            return _event(fields, data) if data or "event" in fields or "retry" in fields else None
        name, _, value = line.partition(":")
        value = value[1:] if value.startswith(" ") else value
        if name == "data":
            self.data.append(value)
        else:
            self.fields[name] = value
        return None


def parse_events(lines: Iterable[str]) -> Iterator[ServerEvent]:
    """The events of a stream's lines (see :class:`EventParser`)."""
    parser = EventParser()
    for line in lines:
        event = parser.feed(line)
        if event is not None:
            yield event


def _event(fields: dict[str, str], data: list[str]) -> ServerEvent:
    ident = fields.get("id", "")
    retry = fields.get("retry", "")
    return ServerEvent(
        type=fields.get("event", "message" if data else ""),
        data=_decoded("\n".join(data)) if data else None,
        id=int(ident) if ident.isdigit() else None,
        retry_ms=int(retry) if retry.isdigit() else None,
    )
