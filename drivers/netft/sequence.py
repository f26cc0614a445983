"""RDT sequence tracking: which records to deliver, in which order, and what was lost. Pure: no sockets, no clock.

Facts it relies on (docs/protocols-ati.md, "RDT sequences"): ``rdt_sequence`` counts records of one stream from 1
and restarts at 1 whenever the box receives a start command (from anyone); ``ft_sequence`` is the box's sample
counter, which runs on across streams (+n per record at 7000/n Hz) and restarts only at power-up.

:class:`SequenceTracker` takes records in arrival order, in numpy batches, and returns them in sequence order:

- **Continuation** (``rdt_sequence`` steps forward): delivered. A forward gap is held for ``reorder_window_s``
  (measured from the arrival of the first record past the gap) so that late records are put back in order; when
  the window expires the missing records count as ``lost`` (one ``gap``; its host duration updates
  ``longest_gap_s``). A record later than its window stays lost, is counted ``out_of_order`` and is dropped
  (batches stay in order). A repeated record is a ``duplicate`` (dropped). ``ft_sequence`` equal to the previous
  one counts as ``stalled`` (the sample is still delivered).
- **Our restart.** After the driver sends a start (:meth:`expect_start`: a re-send during a silence, or a bias) the
  box restarts its stream, and the first record that reaches us may carry *any* sequence (the box may have been
  streaming into a dead link for seconds). Such a record is accepted as the new stream when it is not a plain
  continuation of the old one (judged by ``ft_sequence``: the old stream's next records advance it by at most
  ``step`` per record, a restarted stream by more; a stale copy of an older record carries an older one) and its
  ``rdt_sequence`` is no more than the box could have sent since the earliest start still unanswered
  (``elapsed × rate × 1.25 + 16``). The records the box produced meanwhile (from ``ft_sequence``) count as lost.
  A power-cycled box (``ft_sequence`` back near zero) answering our start is also our restart, counted in
  ``restarts``. A box that never restarts its sequence on a start is recognised after 256 continuing records.
  When several starts were sent before the restarted stream showed (re-sends during a long silence), the box may
  have started that stream for an earlier one and still restart once more for the last: the last stays expected.
- **The ``ft_sequence`` step per record** is learnt from consecutive records; until two have been delivered (a link
  that went quiet right after the first record) it is the nominal one, internal rate / RDT rate, so that a
  restart is still told from a continuation and its losses still counted from ``ft_sequence``.
- **Restart we did not ask for**: ``rdt_sequence`` back to a small value (≤ 16, from more than 128 ahead) or backwards with
  ``ft_sequence`` forwards (someone else sent a start): a ``restart``, accepted.
- **Bias**: after :meth:`expect_start` with ``bias=True`` the records of the old stream (sent before the box
  biased) are dropped until the restarted stream shows; :attr:`bias_restarted` tells the driver to discard what
  it decoded before.

The common case (one stream, each record +1, nothing held) is a handful of numpy operations per batch.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass

import numpy as np

from drivers.netft.protocol import HALF_RANGE, INTERNAL_RATE_HZ, RECORD_DTYPE, UINT32_MASK

REORDER_WINDOW_S = 0.005
"""How long records past a gap are held back waiting for the missing ones, seconds (35 records at 7 kHz)."""
RESTART_WINDOW = 16
"""An rdt_sequence at or below this after a backward step is a stream restart even without our start."""
LATE_LIMIT = 128
"""A record this many sequence numbers behind the newest is not a late one (a LAN reorders a datagram or two; a
buffered datagram holds at most 40 records): a step back this far to a sequence ≤ RESTART_WINDOW is a restart."""
RESTART_RATE_MARGIN = 1.25
"""A restarted stream's first record may carry at most elapsed × rate × this (+ RESTART_WINDOW) as sequence."""
EXPECT_RESTART_RECORDS = 256
"""After our start, records that continue the old sequence before a restart shows (the box does not reset)."""
MAX_TRACKED_MISSING = 4096
"""Missing sequence numbers remembered, so that a record later than its window is out of order, not new."""


@dataclass
class SequenceCounters:
    """What the tracker counted (monotonic)."""

    received: int = 0
    lost: int = 0
    gaps: int = 0
    longest_gap_s: float = 0.0
    duplicate: int = 0
    out_of_order: int = 0
    stalled: int = 0
    restarts: int = 0
    ft_backward: int = 0
    stale_before_bias: int = 0


class SequenceTracker:
    """Order and account for RDT records (see the module docstring).

    Args:
        reorder_window_s: hold time for records past a gap, seconds (0: deliver at once, count gaps lost).
        rate_hz: the box's streaming rate (0: unknown; the restart plausibility check is then skipped, and the
            ``ft_sequence`` step is only learnt from the records).
        internal_rate_hz: the box's internal sample rate, Hz (``ft_sequence`` counts at it).
    """

    def __init__(self, reorder_window_s: float = REORDER_WINDOW_S, rate_hz: float = 0.0,
                 internal_rate_hz: float = INTERNAL_RATE_HZ) -> None:
        self.reorder_window_s = float(reorder_window_s)
        self.rate_hz = float(rate_hz)
        self.internal_rate_hz = float(internal_rate_hz)
        self.counters = SequenceCounters()
        self.bias_restarted = False
        """Set when the stream restarted after a bias start; the driver clears it after discarding older data."""
        self._last_rdt: int | None = None  # last delivered record
        self._last_ft = 0
        self._last_time = 0.0
        self._head_rdt = 0  # highest record accepted into the current stream (delivered or held)
        self._head_ft = 0
        self._ft_step = 0  # learnt ft_sequence increment per record (0: unknown)
        self._missing: dict[int, None] = {}
        self._held = np.empty(0, dtype=RECORD_DTYPE)
        self._held_times = np.empty(0)
        self._starts: collections.deque[tuple[int, float, bool]] = collections.deque()
        self._active_since: float | None = None  # send time of the earliest start not yet answered
        self._latest_start_s: float | None = None  # send time of the latest start taken into account
        self._continuing = 0
        self._bias_pending = False
        self._fresh_stream = False
        self._stale_run = 0  # records dropped as pre-bias since the last delivered one

    # ------------------------------------------------------------------ inputs

    def expect_start(self, index: int, time_s: float, bias: bool = False) -> None:
        """The driver sent a start command at host time ``time_s`` when ``index`` records had been received."""
        self._starts.append((int(index), float(time_s), bool(bias)))

    def bias_timed_out(self) -> None:
        """The box did not restart after a bias: stop dropping old-stream records (a late restart is still ours)."""
        self._bias_pending = False

    @property
    def hold_deadline(self) -> float | None:
        """Host time when held records are released even if the gap is not filled (None: nothing held)."""
        if not len(self._held):
            return None
        return float(self._held_times.min()) + self.reorder_window_s

    @property
    def ft_step(self) -> int:
        """``ft_sequence`` increment per record: the one learnt from consecutive records, else the nominal
        round(internal rate / rate) (0: unknown)."""
        if self._ft_step > 0:
            return self._ft_step
        if self.rate_hz > 0 and self.internal_rate_hz > 0:
            return max(int(round(self.internal_rate_hz / self.rate_hz)), 0)
        return 0

    @property
    def held(self) -> int:
        """Records held back waiting for a gap to fill."""
        return int(len(self._held))

    def push(self, records: np.ndarray, times: np.ndarray, first_index: int, now: float) -> tuple[np.ndarray, np.ndarray]:
        """Take records (RECORD_DTYPE, arrival order) received at host ``times``; ``first_index`` is the count of
        records received before them. Return (records, times) to deliver, in sequence order (possibly held ones
        released now that their window expired at host time ``now``: a time by which every record that had
        arrived is among those pushed, i.e. the receive thread's, never the reader's clock)."""
        out: list[tuple[np.ndarray, np.ndarray]] = []
        n = len(records)
        self.counters.received += n
        if n == 0:
            if len(self._held):
                self._order(records, times, now, out, release_all=False)
            return _join(out)
        rdt = records["rdt_sequence"].astype(np.int64)
        if self._in_order(records, times, rdt, first_index + n):
            return records, times
        if self._fast(rdt, first_index + n):
            self._order(records, times, now, out, release_all=False)
        else:
            self._classify(records, times, rdt, records["ft_sequence"].astype(np.int64), first_index, now, out)
        return _join(out)

    # ------------------------------------------------------------------ stage 1: which stream a record belongs to

    def _in_order(self, records: np.ndarray, times: np.ndarray, rdt: np.ndarray, end_index: int) -> bool:
        """The common case, in a few numpy operations: each record +1 after the last delivered, nothing held, no
        start of ours in play. Deliver (update the stream) and return True; else change nothing, return False."""
        last = self._last_rdt
        if (last is None or len(self._held) or self._active_since is not None or self._bias_pending
                or self._fresh_stream or (self._starts and self._starts[0][0] < end_index)):
            return False
        if rdt[0] != ((last + 1) & UINT32_MASK) or (len(rdt) > 1 and np.count_nonzero(rdt[1:] - rdt[:-1] != 1)):
            return False
        ft = records["ft_sequence"].astype(np.int64)
        step = np.empty_like(ft)  # np.diff(ft, prepend=last ft), without its Python-level overhead
        step[0] = ft[0] - self._last_ft
        np.subtract(ft[1:], ft[:-1], out=step[1:])
        step &= UINT32_MASK
        counters = self.counters
        counters.stalled += int(np.count_nonzero(step == 0))
        backward = int(np.count_nonzero(step >= HALF_RANGE))
        if backward:
            counters.ft_backward += backward
        if 0 < step[-1] < HALF_RANGE:
            self._ft_step = int(step[-1])
        self._last_rdt = self._head_rdt = int(rdt[-1])
        self._last_ft = self._head_ft = int(ft[-1])
        self._last_time = float(times[-1])
        self._stale_run = 0
        return True

    def _fast(self, rdt: np.ndarray, end_index: int) -> bool:
        """Whether every record steps forward within the current stream and no start of ours is in play."""
        if self._last_rdt is None or self._active_since is not None or self._bias_pending:
            return False
        if self._starts and self._starts[0][0] < end_index:
            return False
        previous = np.empty_like(rdt)
        previous[0] = self._head_rdt
        previous[1:] = rdt[:-1]
        step = (rdt - previous) & UINT32_MASK
        return bool(np.all((step >= 1) & (step < HALF_RANGE)))

    def _classify(self, records: np.ndarray, times: np.ndarray, rdt: np.ndarray, ft: np.ndarray,
                  first_index: int, now: float, out: list) -> None:
        """Per record: part of the current stream (batched for stage 2), or the first of a new stream."""
        counters = self.counters
        run_start = 0
        keep = np.ones(len(records), dtype=bool)
        for i in range(len(records)):
            while self._starts and self._starts[0][0] <= first_index + i:
                _, sent_s, bias = self._starts.popleft()
                if self._active_since is None:
                    self._active_since = sent_s
                    self._continuing = 0
                self._latest_start_s = sent_s
                self._bias_pending = self._bias_pending or bias
            r, f, t = int(rdt[i]), int(ft[i]), float(times[i])
            if self._last_rdt is None:  # the first record: it answers our first start
                self._new_stream(r, f, t, lost=0)
                self._active_since = None
                self._bias_pending = False
                continue
            dr = (r - self._head_rdt) & UINT32_MASK
            df = (f - self._head_ft) & UINT32_MASK
            forward = 1 <= dr < HALF_RANGE
            step = self.ft_step
            active_since = self._active_since
            ours_pending = active_since is not None
            if forward:
                same_stream = df < HALF_RANGE and (not ours_pending or step == 0 or df <= dr * step)
            elif df == 0:
                same_stream = True  # a copy of a record already seen
            elif r <= RESTART_WINDOW and ((self._head_rdt - r) & UINT32_MASK) > LATE_LIMIT:
                same_stream = False  # far too late to be a reordered record: the box restarted its sequence
            elif df >= HALF_RANGE:  # ft_sequence behind: an older record of this stream, or a power cycle
                same_stream = step == 0 or ((self._head_ft - f) & UINT32_MASK) <= ((self._head_rdt - r) & UINT32_MASK) * step
            else:
                same_stream = False  # rdt_sequence behind, ft_sequence ahead: the stream restarted
            if same_stream:
                if forward and self._bias_pending:
                    keep[i] = False  # sent before the box biased
                    counters.stale_before_bias += 1
                    self._stale_run += 1
                    continue
                if forward:
                    self._head_rdt, self._head_ft = r, f
                    if ours_pending:
                        self._continuing += 1
                        if self._continuing >= EXPECT_RESTART_RECORDS:
                            self._active_since = None  # this box does not restart its sequence on a start
                continue  # stage 2 sorts out copies and late records
            ft_forward = 0 < df < HALF_RANGE
            ours = active_since is not None and (self.rate_hz <= 0 or r <= (t - active_since) * self.rate_hz
                                                 * RESTART_RATE_MARGIN + RESTART_WINDOW)
            if not ours and not ft_forward and r > RESTART_WINDOW:
                keep[i] = False  # a stale record of an older stream
                counters.duplicate += 1
                continue
            self._flush_run(records, times, keep, run_start, i, now, out, before_new_stream=True)
            run_start = i
            if ours and self._bias_pending:
                out.clear()  # everything before the biased stream is stale
                self.bias_restarted = True
                self._bias_pending = False
            if not ours or not ft_forward:
                counters.restarts += 1  # not our doing, or the box power-cycled
            if ft_forward and step > 0:
                lost = ((f - self._last_ft) & UINT32_MASK) // step - 1 - self._stale_run
            else:
                lost = r - 1
            self._new_stream(r, f, t, lost=max(lost, 0))
            latest = self._latest_start_s
            # a later start than the one this stream may answer can still restart the box: keep expecting it
            keep_expecting = ours and active_since is not None and latest is not None and latest > active_since
            self._active_since = latest if keep_expecting else None
            self._continuing = 0
        self._flush_run(records, times, keep, run_start, len(records), now, out, before_new_stream=False)

    def _flush_run(self, records: np.ndarray, times: np.ndarray, keep: np.ndarray, start: int, end: int,
                   now: float, out: list, before_new_stream: bool) -> None:
        """Hand records[start:end] (those kept) to stage 2; before a new stream, release everything held."""
        mask = keep[start:end]
        chunk, chunk_times = records[start:end][mask], times[start:end][mask]
        if len(chunk) or len(self._held):
            self._order(chunk, chunk_times, now, out, release_all=before_new_stream)

    def _new_stream(self, r: int, f: int, t: float, lost: int) -> None:
        """Make record (r, f) received at ``t`` the first of a new stream (stage 2 delivers it next)."""
        if lost > 0:
            self._count_gap(lost, t - self._last_time)
        self._missing.clear()
        self._last_rdt = (r - 1) & UINT32_MASK
        self._last_ft = (f - self.ft_step) & UINT32_MASK
        if self._last_time == 0.0:
            self._last_time = t
        self._head_rdt, self._head_ft = r, f
        self._fresh_stream = True
        self._stale_run = 0

    # ------------------------------------------------------------------ stage 2: order within a stream

    def _order(self, records: np.ndarray, times: np.ndarray, now: float, out: list, release_all: bool) -> None:
        """Deliver records of the current stream in sequence order, holding those past a gap (see the module)."""
        counters = self.counters
        last = self._last_rdt
        assert last is not None, "stage 2 runs once stage 1 has started a stream"
        held = len(self._held)
        if held:
            records = np.concatenate([self._held, records])
            times = np.concatenate([self._held_times, times])
            self._held = self._held[:0]
            self._held_times = self._held_times[:0]
        if not len(records):
            return
        rdt = records["rdt_sequence"].astype(np.int64)
        key = ((rdt - last + HALF_RANGE) & UINT32_MASK) - HALF_RANGE  # 1 = the record after the last delivered
        if not held and key[0] == 1 and (len(key) == 1 or bool(np.all(np.diff(key) == 1))):
            self._deliver(records, times, key, out)
            return
        # arrived after a later record (held ones were counted when they arrived)
        new_key = key[held:]
        prior = int(key[:held].max()) if held else 0
        late = new_key < np.maximum.accumulate(np.concatenate([[prior], new_key]))[:-1]
        old = key <= 0
        counters.out_of_order += int(np.count_nonzero(late & ~old[held:]))
        if old.any():
            for index in np.flatnonzero(old):
                sequence = int(rdt[index])
                if sequence in self._missing:
                    del self._missing[sequence]
                    counters.out_of_order += 1  # later than its window: stays lost, dropped
                else:
                    counters.duplicate += 1
            records, times, key = records[~old], times[~old], key[~old]
            if not len(key):
                return
        order = np.argsort(key, kind="stable")
        records, times, key = records[order], times[order], key[order]
        repeat = np.flatnonzero(key[1:] == key[:-1]) + 1
        if len(repeat):
            counters.duplicate += len(repeat)
            unique = np.ones(len(key), dtype=bool)
            unique[repeat] = False
            records, times, key = records[unique], times[unique], key[unique]
        # deliver up to each gap; a gap whose window expired is counted lost and passed
        breaks = np.flatnonzero(np.diff(np.concatenate([[0], key])) != 1)
        first_after = np.minimum.accumulate(times[::-1])[::-1]  # earliest arrival among the records from here on
        begin = 0
        for gap_at in breaks.tolist():
            if not release_all and now - float(first_after[gap_at]) < self.reorder_window_s:
                self._deliver(records[begin:gap_at], times[begin:gap_at], key[begin:gap_at], out)
                self._held = records[gap_at:].copy()
                self._held_times = times[gap_at:].copy()
                tail = records[-1]
                if ((int(tail["rdt_sequence"]) - self._head_rdt) & UINT32_MASK) < HALF_RANGE:
                    self._head_rdt, self._head_ft = int(tail["rdt_sequence"]), int(tail["ft_sequence"])
                return
            previous_key = int(key[gap_at - 1]) if gap_at > 0 else 0
            self._deliver(records[begin:gap_at], times[begin:gap_at], key[begin:gap_at], out)
            delivered = self._last_rdt  # advanced by _deliver (unchanged after an empty run): never None here
            assert delivered is not None
            self._note_missing(delivered, int(key[gap_at]) - previous_key - 1,
                               float(times[gap_at]) - self._last_time)
            begin = gap_at
        self._deliver(records[begin:], times[begin:], key[begin:], out)

    def _deliver(self, records: np.ndarray, times: np.ndarray, key: np.ndarray, out: list) -> None:
        """Append an in-order run (``key`` relative to the last delivered record before this stage-2 pass; every
        run after the first follows a gap) and advance the stream."""
        if not len(records):
            return
        ft = records["ft_sequence"].astype(np.int64)
        previous = np.empty_like(ft)
        previous[0] = self._last_ft
        previous[1:] = ft[:-1]
        consecutive = np.empty(len(key), dtype=bool)
        consecutive[0] = key[0] == 1 and not self._fresh_stream
        consecutive[1:] = np.diff(key) == 1
        step = (ft - previous) & UINT32_MASK
        self.counters.stalled += int(np.count_nonzero((step == 0) & consecutive))
        self.counters.ft_backward += int(np.count_nonzero((step >= HALF_RANGE) & consecutive))
        forward = np.flatnonzero((step > 0) & (step < HALF_RANGE) & consecutive)
        if len(forward):
            self._ft_step = int(step[forward[-1]])
        self._fresh_stream = False
        self._stale_run = 0
        last = int(records["rdt_sequence"][-1])
        self._last_rdt, self._last_ft, self._last_time = last, int(ft[-1]), float(times[-1])
        if ((last - self._head_rdt) & UINT32_MASK) < HALF_RANGE:
            self._head_rdt, self._head_ft = last, int(ft[-1])
        out.append((records, times))

    def _note_missing(self, last: int, gap: int, duration_s: float) -> None:
        self._count_gap(gap, duration_s)
        if gap > MAX_TRACKED_MISSING:
            return
        for k in range(1, gap + 1):
            self._missing[(last + k) & UINT32_MASK] = None
        while len(self._missing) > MAX_TRACKED_MISSING:
            del self._missing[next(iter(self._missing))]

    def _count_gap(self, lost: int, duration_s: float) -> None:
        self.counters.lost += lost
        self.counters.gaps += 1
        self.counters.longest_gap_s = max(self.counters.longest_gap_s, max(duration_s, 0.0))


def _join(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    if not parts:
        return np.empty(0, dtype=RECORD_DTYPE), np.empty(0)
    if len(parts) == 1:
        return parts[0]
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


__all__ = ["SequenceTracker", "SequenceCounters", "REORDER_WINDOW_S", "RESTART_WINDOW", "EXPECT_RESTART_RECORDS"]
