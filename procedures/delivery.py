"""Deliver events to listeners without making the publisher wait: :class:`BackgroundListener`.

The live monitor's acquisition thread must never wait for a viewer (at 7 kHz a stalled viewer would cost
samples), and drawing must not slow the calibration procedure. A :class:`BackgroundListener` is itself a
listener: calling it queues the event and returns at once; its own thread delivers the events, in order, to the
listeners it wraps.

- :class:`~procedures.events.WrenchSamples` are the only events that may be dropped: while ``max_queued`` of them
  wait, a new one is discarded and counted (``dropped_batches``, ``dropped_samples``). Other events are rare and
  never dropped.
- The thread waits ``period_s`` after the first queued event, then takes everything queued and joins consecutive
  WrenchSamples into one (fewer, larger sends to the viewer: each send is one chunk of the recording).
- A listener that raises is logged, kept in ``errors`` and gets nothing more; the others go on.

A listener whose ``direct`` attribute is true is called by the publisher itself, not from the shared thread:
the live monitor (:class:`Fanout`) calls it in its acquisition thread, as soon as a read is compensated. Such a
listener only hands the event over: a ``BackgroundListener(..., direct=True)`` of its own (an unbounded one for a
consumer that must get every sample, period 0 for one that must get them at once: ROS 2 topics, an MCAP record).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from typing import Sequence

from procedures.events import Event, Listener, RobotState, WrenchSamples

log = logging.getLogger(__name__)

DEFAULT_MAX_QUEUED = 500
"""WrenchSamples events that may wait (≈ 5 s of 10 ms reads) before new ones are dropped."""
DEFAULT_PERIOD_S = 0.05
"""The thread delivers at most this often, joining the samples queued meanwhile."""
CLOSE_TIMEOUT_S = 10.0
"""How long :meth:`BackgroundListener.close` waits for the queue to drain."""


def coalesce(events: list[Event]) -> list[Event]:
    """Return ``events`` with each run of WrenchSamples (all with, or all without, a compensated wrench) joined
    into one. RobotState events do not break a run (they carry their own time; they follow the joined samples);
    every other event keeps its place, so a status or a procedure step still comes after the samples before it."""
    out: list[Event] = []
    run: list[WrenchSamples] = []
    held: list[Event] = []

    def flush() -> None:
        if run:
            out.append(WrenchSamples.join(run))
            run.clear()
        out.extend(held)
        held.clear()

    for event in events:
        if isinstance(event, WrenchSamples):
            if run and (run[-1].compensated is None) != (event.compensated is None):
                flush()
            run.append(event)
        elif isinstance(event, RobotState) and run:
            held.append(event)
        else:
            flush()
            out.append(event)
    flush()
    return out


class BackgroundListener:
    """A listener that hands events to its own thread, which calls ``listeners`` in order (see the module doc).

    Args:
        listeners: the listeners called from the thread.
        max_queued: WrenchSamples events that may wait before new ones are dropped.
        period_s: delivery period, s (0: deliver as soon as possible).
        name: the thread's name.
        direct: ask the publisher to call this listener itself (module docstring).
    """

    def __init__(self, listeners: Sequence[Listener], *, max_queued: int = DEFAULT_MAX_QUEUED,
                 period_s: float = DEFAULT_PERIOD_S, name: str = "ftacq-listeners", direct: bool = False) -> None:
        self.listeners: list[Listener] = list(listeners)
        self.direct = direct
        self.max_queued = int(max_queued)
        self.period_s = float(period_s)
        self.errors: list[tuple[Listener, Exception]] = []
        self.dropped_batches = 0
        self.dropped_samples = 0
        self.delivered_samples = 0
        self._queue: deque[Event] = deque()
        self._queued_samples = 0
        self._condition = threading.Condition()
        self._closing = False
        # Daemon: a listener stuck in a dead network connection must not keep the process alive after Ctrl-C;
        # close() still waits for it, with a deadline.
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def __call__(self, event: Event) -> None:
        with self._condition:
            if isinstance(event, WrenchSamples):
                if self._closing or not self.listeners or self._queued_samples >= self.max_queued:
                    self.dropped_batches += 1
                    self.dropped_samples += len(event)
                    return
                self._queued_samples += 1
            elif self._closing:
                log.warning("event %s after close: not delivered", type(event).__name__)
                return
            self._queue.append(event)
            if len(self._queue) == 1:
                self._condition.notify()

    def add(self, listener: Listener) -> None:
        """Add a listener: it receives the events delivered from now on (any thread)."""
        with self._condition:
            self.listeners.append(listener)

    @property
    def first_error(self) -> Exception | None:
        """The first exception a listener raised, or None."""
        return self.errors[0][1] if self.errors else None

    def close(self, timeout_s: float = CLOSE_TIMEOUT_S) -> None:
        """Deliver what is queued, then stop the thread, waiting at most ``timeout_s`` seconds (safe twice).

        Samples still queued after the deadline (a listener that hangs) are counted as dropped."""
        with self._condition:
            self._closing = True
            self._condition.notify()
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            log.warning("listeners did not finish within %.1f s; leaving them", timeout_s)
            with self._condition:
                for event in self._queue:
                    if isinstance(event, WrenchSamples):
                        self.dropped_batches += 1
                        self.dropped_samples += len(event)
                self._queue.clear()
                self._queued_samples = 0

    def _take(self) -> list[Event] | None:
        """Wait for events, then for the rest of the period; return them (None: closed and drained)."""
        with self._condition:
            while not self._queue and not self._closing:
                self._condition.wait()
            if not self._queue:
                return None
            deliver_at_s = time.monotonic() + self.period_s
            while not self._closing and (remaining_s := deliver_at_s - time.monotonic()) > 0:
                self._condition.wait(remaining_s)
            events = list(self._queue)
            self._queue.clear()
            self._queued_samples = 0
            return events

    def _run(self) -> None:
        while (events := self._take()) is not None:
            for event in coalesce(events):
                self._deliver(event)

    def _deliver(self, event: Event) -> None:
        if not self.listeners and isinstance(event, WrenchSamples):
            self.dropped_batches += 1
            self.dropped_samples += len(event)
            return
        for listener in list(self.listeners):
            try:
                listener(event)
            except Exception as error:  # noqa: BLE001 - kept in errors; a broken viewer never stops acquisition
                log.warning("listener %r failed on %s; it gets no more events: %s", listener, type(event).__name__,
                            error)
                self.errors.append((listener, error))
                self.listeners.remove(listener)
        if isinstance(event, WrenchSamples):
            if self.listeners:
                self.delivered_samples += len(event)
            else:  # the last listener just failed on it
                self.dropped_batches += 1
                self.dropped_samples += len(event)


__all__ = ["BackgroundListener", "coalesce"]


class Fanout:
    """A publisher's listeners: the ``direct`` ones (module docstring) called at once, the others through one
    :class:`BackgroundListener` (``background``). A direct listener that raises is logged, kept in ``errors`` and
    gets nothing more."""

    def __init__(self, listeners: Sequence[Listener], **background_options) -> None:
        self.direct = [listener for listener in listeners if getattr(listener, "direct", False)]
        self.background = BackgroundListener([listener for listener in listeners if listener not in self.direct],
                                             **background_options)
        self.errors: list[tuple[Listener, Exception]] = []

    def __call__(self, event: Event) -> None:
        self.background(event)
        for listener in self.direct:
            try:
                listener(event)
            except Exception as error:  # noqa: BLE001 - one failing consumer must not stop the others
                log.exception("listener %r failed; it gets no more events", listener)
                self.errors.append((listener, error))
                self.direct = [other for other in self.direct if other is not listener]

    def add(self, listener: Listener) -> None:
        """Add a listener (a direct one, or one for the background thread): it gets the events from now on."""
        if getattr(listener, "direct", False):
            self.direct = [*self.direct, listener]
        else:
            self.background.add(listener)

    def close(self, timeout_s: float = CLOSE_TIMEOUT_S) -> None:
        """Close the background thread (see :meth:`BackgroundListener.close`); direct listeners close themselves."""
        self.background.close(timeout_s)

    @property
    def dropped_batches(self) -> int:
        return self.background.dropped_batches

    @property
    def dropped_samples(self) -> int:
        return self.background.dropped_samples

    @property
    def first_error(self) -> Exception | None:
        errors = self.errors + self.background.errors
        return errors[0][1] if errors else None
