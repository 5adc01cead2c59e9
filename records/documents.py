"""One stream of run documents per run: RunStart, a Descriptor per data stream, Events, RunStop.

The shapes are those of the Bluesky event model (its ``event-model`` package ships the JSON
schemas; the test suite validates every document kind against them): a run is announced by a
**start** document (``uid``, ``time`` and free metadata such as ``sample`` / ``operator``),
each data stream by a **descriptor** (``data_keys``: ``dtype``, ``shape``, ``units``,
``source`` per field), every record is an **event** (``descriptor``, ``seq_num``, ``data``,
``timestamps``) and the run ends with a **stop** document (``exit_status`` success / abort /
fail, ``reason``, ``num_events`` per stream). Times are UNIX seconds (float), uids UUID4 text.

:class:`RunPublisher` makes the documents of one run and hands each, in order, to its
subscribers (``fn(name, doc)``, the signature Bluesky's callbacks use). It is also the adapter
the jobs talk to, so no job knows of documents:

* a cell observer (:class:`snan_hil.calibration.observer.CellObserver`, duck-typed:
  ``on_pulses``, ``on_cell``, ``on_cells``) -- pulses and cell results become events of the
  streams ``pulses`` and ``cells``;
* a progress callback (:meth:`progress`, :mod:`snan_hil.common.progress`) -- events of the
  stream ``progress`` (throttled to one per task every :data:`PROGRESS_INTERVAL_S`, plus every
  note and each task's last event);
* :meth:`event` for anything else (``launches`` of a hardware run, ``console`` commands,
  ``plan`` steps).

The history database (:class:`snan_hil.records.history.Recorder`), the live view
(``snan-hil watch``, which reads the documents back from the database) and the JSON reports
(:class:`DocumentCollector`) are subscribers. A subscriber that raises is dropped with one
log warning; the run goes on (the recording policy of docs/bench.md).

A base module: it imports no layer.
"""

from __future__ import annotations

import json
import logging
import math
import time
import unicodedata
import uuid
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

from snan_hil.common.version import __version__

__all__ = ["DataKey", "RunMetadata", "STREAMS", "EXIT_STATUS", "PROGRESS_INTERVAL_S",
           "Subscriber", "RunPublisher", "DocumentCollector", "check_tag",
           "control_character"]

log = logging.getLogger(__name__)

Subscriber = Callable[[str, dict[str, Any]], None]
"""``fn(name, doc)``: name is ``start``, ``descriptor``, ``event`` or ``stop``."""

PROGRESS_INTERVAL_S = 0.25
"""Least time between two progress events of one task (s); notes and a task's last event are
always sent."""

EXIT_STATUS = {"complete": "success", "interrupted": "abort", "failed": "fail"}
"""The history's run status -> the stop document's ``exit_status``."""

SOURCE = "snan-hil"


@dataclass(frozen=True)
class DataKey:
    """One field of a data stream, as a descriptor's ``data_keys`` entry: ``dtype`` a JSON
    type (number, integer, string, boolean, array), ``shape`` [] for a scalar, ``units``
    (``S``, ``V``, ``us``, ...; None: dimensionless or text)."""

    dtype: Literal["number", "integer", "string", "boolean", "array"]
    shape: tuple[int, ...] = ()
    units: str | None = None
    source: str = SOURCE

    def to_doc(self) -> dict[str, Any]:
        d: dict[str, Any] = {"dtype": self.dtype, "shape": list(self.shape),
                             "source": self.source}
        if self.units is not None:
            d["units"] = self.units
        return d


def _keys(**fields: DataKey) -> dict[str, DataKey]:
    return dict(fields)


_S, _V, _US = "S", "V", "us"
STREAMS: dict[str, dict[str, DataKey]] = {
    # one applied write pulse and the read after it
    "pulses": _keys(row=DataKey("integer"), col=DataKey("integer"), n=DataKey("integer"),
                    polarity=DataKey("string"), amplitude_v=DataKey("number", units=_V),
                    width_us=DataKey("integer", units=_US),
                    g_before_s=DataKey("number", units=_S), g_after_s=DataKey("number", units=_S),
                    stage=DataKey("string")),
    # a cell's result in the job (detail: JSON text)
    "cells": _keys(row=DataKey("integer"), col=DataKey("integer"), outcome=DataKey("string"),
                   g_s=DataKey("number", units=_S), target_s=DataKey("number", units=_S),
                   pulses=DataKey("integer"), detail=DataKey("string")),
    # where a task of the job stands (snan_hil.common.progress)
    "progress": _keys(task=DataKey("string"), done=DataKey("integer"),
                      total=DataKey("integer"), detail=DataKey("string"),
                      note=DataKey("string")),
    # one launch of the agent (hardware or software scenario); path: the visited cells,
    # calcium_final: each grid cell's astrocyte calcium after the launch (model units)
    "launches": _keys(scenario=DataKey("string"), set_index=DataKey("integer"),
                      launch=DataKey("integer"), steps=DataKey("integer"),
                      success=DataKey("boolean"), path=DataKey("array", (-1,)),
                      calcium_final=DataKey("array", (-1,)), grid_rows=DataKey("integer"),
                      grid_cols=DataKey("integer"), ca_thr=DataKey("number")),
    # one command typed at the raw console and the decoded reply
    "console": _keys(command=DataKey("string"), request=DataKey("string"),
                     reply=DataKey("string"), ok=DataKey("boolean"),
                     adc=DataKey("integer"), g_s=DataKey("number", units=_S)),
    # a read of one cell (read-cell, plan read steps)
    "reads": _keys(row=DataKey("integer"), col=DataKey("integer"), adc=DataKey("integer"),
                   read_code=DataKey("integer"), read_v=DataKey("number", units=_V),
                   g_s=DataKey("number", units=_S), current_a=DataKey("number", units="A"),
                   step=DataKey("string")),
    # control requests the job acted on (pause / resume / stop from snan-hil watch)
    "control": _keys(action=DataKey("string"), detail=DataKey("string")),
}
"""The data streams of snan-hil runs and their fields (a descriptor is sent when a stream is
first used)."""


def control_character(text: str) -> str | None:
    """The first control character (Unicode category Cc: escape, tab, line break, NUL ...)
    in ``text``, or None. Metadata with one would be printed raw later (``history``): an
    escape sequence acts on the reader's terminal."""
    return next((ch for ch in text if unicodedata.category(ch) == "Cc"), None)


def check_tag(tag: str) -> str:
    """A tag as given (stripped); ValueError (its text names what is wrong, without the
    option) for a blank one, one with a comma or one with a control character."""
    t = str(tag).strip()
    if not t:
        raise ValueError("a blank tag; give a word, or leave --tag out")
    if "," in t:
        raise ValueError(f"{t!r} has a comma; give one tag per --tag")
    bad = control_character(t)
    if bad is not None:
        raise ValueError(f"{t!r} holds the control character {bad!r}; give plain text")
    return t


@dataclass(frozen=True)
class RunMetadata:
    """What the user says about a run (``--sample``, ``--operator``, ``--note``, ``--tag``)
    and its UUID (Bluesky's RunStart ``uid``, QCoDeS's GUID)."""

    sample: str | None = None
    operator: str | None = None
    note: str | None = None
    tags: tuple[str, ...] = ()
    uid: str = field(default_factory=lambda: str(uuid.uuid4()))

    def to_dict(self) -> dict[str, Any]:
        return {"uid": self.uid, "sample": self.sample, "operator": self.operator,
                "note": self.note, "tags": list(self.tags)}


def _clean(value: Any) -> Any:
    """JSON-safe: numpy scalars to Python, non-finite floats to None, tuples to lists."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, (str, int, bool)) or value is None:
        return value
    if isinstance(value, Mapping):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    item = getattr(value, "item", None)             # numpy scalar
    if callable(item) and getattr(value, "ndim", 1) == 0:
        return _clean(item())
    tolist = getattr(value, "tolist", None)         # numpy array
    if callable(tolist):
        return _clean(tolist())
    return str(value)


def _safe_keys(value: Any) -> Any:
    """Mapping keys without '.' and '/' (the event model's key pattern ``^([^./]+)$``, which
    holds at every level of a start document): both become '_'."""
    if isinstance(value, dict):
        return {str(k).replace(".", "_").replace("/", "_"): _safe_keys(v)
                for k, v in value.items()}
    if isinstance(value, list):
        return [_safe_keys(v) for v in value]
    return value


def _polarity(p: Any) -> str:
    name = getattr(p, "name", None)
    return str(name if name is not None else p)


class RunPublisher:
    """The documents of one run, handed to subscribers in order.

    ``metadata``: the user's metadata and uid; ``kind``: what the run is (program, screen,
    plan, ..., stored as the start's ``plan_name``); ``command``: its command line;
    ``start_fields``: more RunStart fields (board_id, port, protocol, seed, config, ...; None
    values are left out). ``clock`` gives UNIX seconds (document times), ``monotonic`` the
    throttle's clock. Nothing is sent before :meth:`start`."""

    def __init__(self, metadata: RunMetadata | None = None, *, kind: str, command: str = "",
                 clock: Callable[[], float] = time.time,
                 monotonic: Callable[[], float] = time.monotonic,
                 uid: Callable[[], str] = lambda: str(uuid.uuid4()),
                 **start_fields: Any) -> None:
        self.metadata = metadata or RunMetadata()
        self.kind = kind
        self.command = command
        self.clock, self.monotonic, self._uid = clock, monotonic, uid
        self.start_fields = start_fields
        self.subscribers: list[Subscriber] = []
        self.start_doc: dict[str, Any] | None = None
        self.stop_doc: dict[str, Any] | None = None
        self.descriptors: dict[str, dict[str, Any]] = {}
        self.seq: dict[str, int] = {}
        self._pulse_n: dict[tuple[int, int], int] = {}
        self._progress_last: dict[str, float] = {}

    # ------------------------------------------------------------------ subscribers
    def subscribe(self, fn: Subscriber) -> None:
        """Add a subscriber; one added after :meth:`start` first gets the start and the
        descriptors sent so far."""
        self.subscribers.append(fn)
        if self.start_doc is not None:
            self._send_one(fn, "start", self.start_doc)
            for desc in self.descriptors.values():
                self._send_one(fn, "descriptor", desc)

    def _send_one(self, fn: Subscriber, name: str, doc: dict[str, Any]) -> bool:
        try:
            fn(name, doc)
            return True
        except Exception:                 # a subscriber's failure never stops the run
            log.warning("run document subscriber %r failed; it gets no more documents", fn,
                        exc_info=True)
            return False

    def _send(self, name: str, doc: dict[str, Any]) -> None:
        for fn in list(self.subscribers):
            if not self._send_one(fn, name, doc):
                self.subscribers.remove(fn)

    # ------------------------------------------------------------------ documents
    @property
    def uid(self) -> str:
        return self.metadata.uid

    @property
    def started(self) -> bool:
        return self.start_doc is not None

    @property
    def stopped(self) -> bool:
        return self.stop_doc is not None

    def start(self) -> dict[str, Any]:
        """Send the RunStart document (once) and return it."""
        if self.start_doc is not None:
            return self.start_doc
        m = self.metadata
        doc: dict[str, Any] = {"uid": m.uid, "time": self.clock(), "plan_name": self.kind,
                               "command": self.command, "snan_hil_version": __version__}
        for key, value in (("sample", m.sample), ("operator", m.operator), ("note", m.note)):
            if value:
                doc[key] = value
        doc["tags"] = list(m.tags)
        for key, value in self.start_fields.items():
            if value is not None:                 # nested keys: no '.' or '/' (schema)
                doc[key] = _safe_keys(_clean(value))
        self.start_doc = doc
        self._send("start", doc)
        return doc

    def _descriptor(self, stream: str) -> dict[str, Any]:
        desc = self.descriptors.get(stream)
        if desc is not None:
            return desc
        keys = STREAMS.get(stream)
        if keys is None:
            raise KeyError(f"unknown data stream {stream!r} (not in STREAMS)")
        start = self.start()
        desc = {"uid": self._uid(), "run_start": start["uid"], "time": self.clock(),
                "name": stream, "data_keys": {k: v.to_doc() for k, v in keys.items()},
                "hints": {}, "configuration": {}, "object_keys": {SOURCE: list(keys)}}
        self.descriptors[stream] = desc
        self.seq[stream] = 0
        self._send("descriptor", desc)
        return desc

    def event(self, stream: str, data: Mapping[str, Any]) -> dict[str, Any]:
        """Send one Event of ``stream`` (its descriptor first, when new); fields missing from
        ``data`` are sent as None. Returns the event. After :meth:`stop` nothing is sent."""
        if self.stop_doc is not None:
            raise RuntimeError(f"run {self.uid} is stopped; no more events")
        desc = self._descriptor(stream)
        now = self.clock()
        keys = desc["data_keys"]
        unknown = set(data) - set(keys)
        if unknown:
            raise KeyError(f"stream {stream}: unknown fields {sorted(unknown)}")
        values = {k: _clean(data.get(k)) for k in keys}
        self.seq[stream] += 1
        doc = {"uid": self._uid(), "descriptor": desc["uid"], "seq_num": self.seq[stream],
               "time": now, "data": values, "timestamps": {k: now for k in keys},
               "filled": {}}
        self._send("event", doc)
        return doc

    def stop(self, status: str = "complete", reason: str = "",
             summary: Any = None) -> dict[str, Any]:
        """Send the RunStop (once): ``status`` complete / interrupted / failed (the history's
        words; the document's ``exit_status`` is success / abort / fail)."""
        if self.stop_doc is not None:
            return self.stop_doc
        start = self.start()
        doc: dict[str, Any] = {"uid": self._uid(), "run_start": start["uid"],
                               "time": self.clock(),
                               "exit_status": EXIT_STATUS.get(status, "fail"),
                               "reason": reason,
                               "num_events": {k: v for k, v in self.seq.items()}}
        if summary is not None:
            doc["summary"] = _safe_keys(_clean(summary))
        self.stop_doc = doc
        self._send("stop", doc)
        return doc

    # ------------------------------------------------------------------ adapters
    def on_pulses(self, events: Sequence[Any]) -> None:
        """Cell observer: applied pulses (``row``, ``col``, ``polarity``, ``amplitude_v``,
        ``width_us``, ``g_before_s``, ``g_after_s``, ``stage``) -> ``pulses`` events, ``n``
        counting each cell's pulses in this run."""
        if self.stopped:
            return
        for e in events:
            key = (int(e.row), int(e.col))
            n = self._pulse_n.get(key, 0) + 1
            self._pulse_n[key] = n
            stage = getattr(e, "stage", None)
            self.event("pulses", {"row": key[0], "col": key[1], "n": n,
                                  "polarity": _polarity(e.polarity),
                                  "amplitude_v": float(e.amplitude_v),
                                  "width_us": int(e.width_us), "g_before_s": e.g_before_s,
                                  "g_after_s": e.g_after_s,
                                  "stage": None if stage is None else str(stage)})

    def on_cell(self, event: Any) -> None:
        """Cell observer: one cell's result -> a ``cells`` event."""
        if self.stopped:
            return
        detail = getattr(event, "detail", None)
        self.event("cells", {"row": int(event.row), "col": int(event.col),
                             "outcome": str(event.outcome), "g_s": event.g_s,
                             "target_s": getattr(event, "target_s", None),
                             "pulses": getattr(event, "pulses", None),
                             "detail": None if not detail else json.dumps(
                                 _clean(detail), separators=(",", ":"))})

    def on_cells(self, events: Iterable[Any]) -> None:
        """Cell observer: results of many cells (a map, a retention run)."""
        for e in events:
            self.on_cell(e)

    def progress(self, event: Any) -> None:
        """Progress callback: a :class:`~snan_hil.common.progress.ProgressEvent` -> a
        ``progress`` event (throttled per task; notes and a task's last event always)."""
        if self.stopped:
            return
        now = self.monotonic()
        last = self._progress_last.get(event.task)
        done = event.total is not None and event.done >= event.total
        if not event.note and not done and last is not None and \
                now - last < PROGRESS_INTERVAL_S:
            return
        self._progress_last[event.task] = now
        self.event("progress", {"task": event.task, "done": int(event.done),
                                "total": event.total, "detail": event.detail,
                                "note": event.note})


class DocumentCollector:
    """A subscriber that keeps every document (for JSON reports and tests): ``start``,
    ``stop``, ``descriptors`` by stream, ``events`` by stream (their ``data``)."""

    def __init__(self) -> None:
        self.docs: list[tuple[str, dict[str, Any]]] = []
        self.start: dict[str, Any] | None = None
        self.stop: dict[str, Any] | None = None
        self.descriptors: dict[str, dict[str, Any]] = {}
        self._streams: dict[str, str] = {}
        self.events: dict[str, list[dict[str, Any]]] = {}

    def __call__(self, name: str, doc: dict[str, Any]) -> None:
        self.docs.append((name, doc))
        if name == "start":
            self.start = doc
        elif name == "stop":
            self.stop = doc
        elif name == "descriptor":
            self.descriptors[doc["name"]] = doc
            self._streams[doc["uid"]] = doc["name"]
        elif name == "event":
            stream = self._streams.get(doc["descriptor"], "?")
            self.events.setdefault(stream, []).append(doc["data"])

    def run_block(self) -> dict[str, Any]:
        """The run's identity for a JSON report: uid, metadata, exit status."""
        s = self.start or {}
        return {"uid": s.get("uid"), "sample": s.get("sample"), "operator": s.get("operator"),
                "note": s.get("note"), "tags": s.get("tags", []),
                "exit_status": (self.stop or {}).get("exit_status")}
