"""The Net F/T sequence tracker alone (no sockets, no clock): order, losses, copies, restarts, bias."""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivers.netft.protocol import RECORD_DTYPE
from drivers.netft.sequence import EXPECT_RESTART_RECORDS, REORDER_WINDOW_S, SequenceTracker

RATE_HZ = 7000.0
PERIOD_S = 1.0 / RATE_HZ


def records(rdt, ft=None) -> np.ndarray:
    """Records with these rdt_sequence values; ft_sequence defaults to rdt (7 kHz: +1 per record)."""
    rdt = np.asarray(rdt, dtype=np.int64)
    out = np.zeros(len(rdt), dtype=RECORD_DTYPE)
    out["rdt_sequence"] = rdt & 0xFFFF_FFFF
    out["ft_sequence"] = (rdt if ft is None else np.asarray(ft, dtype=np.int64)) & 0xFFFF_FFFF
    out["counts"][:, 0] = np.arange(len(rdt))
    return out


class Feed:
    """Feeds a tracker batches with receive times; collects what it delivers."""

    def __init__(self, tracker: SequenceTracker | None = None) -> None:
        self.tracker = tracker or SequenceTracker(rate_hz=RATE_HZ)
        self.index = 0
        self.rdt: list[int] = []
        self.ft: list[int] = []

    def push(self, batch: np.ndarray, at_s: float, now_s: float | None = None) -> np.ndarray:
        times = np.full(len(batch), at_s)
        out, out_times = self.tracker.push(batch, times, self.index, at_s if now_s is None else now_s)
        self.index += len(batch)
        self.rdt += out["rdt_sequence"].astype(int).tolist()
        self.ft += out["ft_sequence"].astype(int).tolist()
        return out

    def tick(self, now_s: float) -> None:
        self.push(records([]), now_s, now_s)

    @property
    def counters(self):
        return self.tracker.counters


def test_in_order_stream_is_delivered_whole() -> None:
    feed = Feed()
    feed.push(records(range(1, 101)), 0.01)
    feed.push(records(range(101, 201)), 0.02)
    assert feed.rdt == list(range(1, 201))
    c = feed.counters
    assert (c.received, c.lost, c.gaps, c.duplicate, c.out_of_order, c.restarts) == (200, 0, 0, 0, 0, 0)


def test_swapped_records_are_put_back_in_order() -> None:
    feed = Feed()
    feed.push(records([1, 2, 3, 5, 4, 6, 7]), 0.01)
    assert feed.rdt == [1, 2, 3, 4, 5, 6, 7]
    assert (feed.counters.out_of_order, feed.counters.lost) == (1, 0)


def test_a_late_record_within_the_window_is_inserted_across_batches() -> None:
    feed = Feed()
    feed.push(records([1, 2, 4, 5]), 0.010)
    assert feed.rdt == [1, 2]  # 4 and 5 wait for 3
    assert feed.tracker.hold_deadline == 0.010 + REORDER_WINDOW_S
    feed.push(records([3, 6]), 0.012)
    assert feed.rdt == [1, 2, 3, 4, 5, 6]
    assert (feed.counters.lost, feed.counters.out_of_order, feed.counters.gaps) == (0, 1, 0)


def test_a_gap_not_filled_within_the_window_is_lost_once() -> None:
    feed = Feed()
    feed.push(records([1, 2, 6, 7]), 0.010)
    feed.tick(0.010 + REORDER_WINDOW_S + 1e-6)
    assert feed.rdt == [1, 2, 6, 7]
    assert (feed.counters.lost, feed.counters.gaps) == (3, 1)
    feed.push(records([4, 8]), 0.020)  # too late: stays lost, dropped, counted out of order
    assert feed.rdt == [1, 2, 6, 7, 8]
    assert (feed.counters.lost, feed.counters.out_of_order, feed.counters.duplicate) == (3, 1, 0)


def test_copies_are_dropped_and_counted() -> None:
    feed = Feed()
    feed.push(records([1, 2, 2, 3, 3, 4]), 0.01)
    feed.push(records([4, 5]), 0.02)
    assert feed.rdt == [1, 2, 3, 4, 5]
    assert feed.counters.duplicate == 3


def test_stalled_ft_sequence_is_counted_not_dropped() -> None:
    feed = Feed()
    feed.push(records([1, 2, 3, 4, 5], ft=[10, 11, 11, 11, 12]), 0.01)
    assert feed.rdt == [1, 2, 3, 4, 5] and feed.counters.stalled == 2


def test_restart_after_our_resend_is_accepted_whatever_its_sequence() -> None:
    """The silence bug: 9000 records in, the link goes quiet, we re-send the start, the box restarts at 1 and
    streams into the dead link; the first record that gets through carries 3500 (below the last one seen)."""
    feed = Feed()
    feed.push(records(range(1, 9001)), 1.0)
    feed.tracker.expect_start(feed.index, 1.25)  # our re-send after 0.25 s of silence
    # the box got it at ~1.25 s, restarted at 1, and 0.5 s later the link is back: first record 3500
    first = 3500
    ft0 = 9000 + int(0.25 * RATE_HZ)  # ft_sequence ran on through the silence
    feed.push(records(range(first, first + 200), ft=range(ft0 + first, ft0 + first + 200)), 1.25 + first * PERIOD_S)
    assert feed.rdt[9000:] == list(range(first, first + 200))
    c = feed.counters
    assert c.duplicate == 0 and c.restarts == 0
    assert c.lost == ft0 + first - 9000 - 1 and c.gaps == 1
    assert abs(c.longest_gap_s - first * PERIOD_S - 0.25) < 1e-9


@pytest.mark.parametrize("first", [1, 2, 40])
def test_restart_after_a_silence_that_began_after_the_first_record_counts_every_record_lost(first) -> None:
    """Only one record came before the link went quiet, so no ft_sequence step was seen yet: the nominal one
    (internal rate / RDT rate) tells the restarted stream from a continuation and counts what was lost (the box
    produced 300 records into the dead link, then ``first`` - 1 more after our re-sent start)."""
    step = 7  # 1000 Hz
    feed = Feed(SequenceTracker(rate_hz=1000.0))
    feed.push(records([1], ft=[5 * step]), 1.0)
    feed.tracker.expect_start(feed.index, 1.3)
    ft_first = 5 * step + (300 + first) * step
    feed.push(records(range(first, first + 20), ft=range(ft_first, ft_first + 20 * step, step)), 1.3 + first / 1000)
    assert feed.rdt == [1] + list(range(first, first + 20))
    c = feed.counters
    assert (c.lost, c.gaps, c.restarts, c.duplicate) == (300 + first - 1, 1, 0, 0)


def test_a_start_re_sent_just_before_the_link_came_back_restarts_the_box_once_more_as_ours() -> None:
    """A 1 s silence: the driver re-sent its start at 0.25, 0.5 and 1.0 s (no record arrived in between). The box
    restarted for the second, so the first records through carry ~3500; then it hears the third and restarts
    again. Both restarts are ours: no restart counted, and the only loss is what the box streamed into the quiet
    link."""
    feed = Feed()
    feed.push(records(range(1, 7001)), 1.0)
    for sent_s in (1.25, 1.5, 2.0):
        feed.tracker.expect_start(feed.index, sent_s)
    ft_resume = 7000 + 7000  # ft_sequence ran on through the 1 s silence
    feed.push(records(range(3500, 3520), ft=range(ft_resume, ft_resume + 20)), 2.0005)
    feed.push(records(range(1, 101), ft=range(ft_resume + 20, ft_resume + 120)), 2.002)  # the third start heard
    assert feed.rdt[7000:] == list(range(3500, 3520)) + list(range(1, 101))
    c = feed.counters
    assert (c.restarts, c.duplicate, c.lost, c.gaps) == (0, 0, ft_resume - 7000 - 1, 1)


def test_restart_whose_first_record_is_above_the_last_is_still_a_new_stream() -> None:
    feed = Feed()
    feed.push(records(range(1, 501)), 1.0)
    feed.tracker.expect_start(feed.index, 1.25)
    ft0 = 500 + 1750
    feed.push(records(range(7000, 7100), ft=range(ft0 + 7000, ft0 + 7100)), 2.25)
    assert feed.rdt[500:] == list(range(7000, 7100))
    assert feed.counters.lost == ft0 + 7000 - 500 - 1 and feed.counters.restarts == 0


def test_a_record_too_far_ahead_for_the_time_since_our_start_is_not_taken_for_our_restart() -> None:
    feed = Feed()
    feed.push(records(range(1, 9001)), 1.0)
    feed.tracker.expect_start(feed.index, 1.25)
    feed.push(records([1000], ft=[5]), 1.26)  # 10 ms after the start the box cannot have sent 1000 records
    assert feed.rdt == list(range(1, 9001)) and feed.counters.duplicate == 1


def test_copy_of_an_old_record_while_our_start_is_pending_is_a_duplicate() -> None:
    feed = Feed()
    feed.push(records(range(1, 1001)), 1.0)
    feed.tracker.expect_start(feed.index, 1.25)
    feed.push(records([990]), 1.5)
    assert feed.rdt == list(range(1, 1001)) and feed.counters.duplicate == 1


def test_box_that_does_not_restart_on_a_start_keeps_its_stream() -> None:
    feed = Feed()
    feed.push(records(range(1, 101)), 1.0)
    feed.tracker.expect_start(feed.index, 1.01)
    feed.push(records(range(101, 101 + 2 * EXPECT_RESTART_RECORDS)), 1.02)
    assert feed.rdt == list(range(1, 101 + 2 * EXPECT_RESTART_RECORDS))
    assert feed.counters.lost == 0 and feed.counters.restarts == 0


def test_power_cycle_answering_our_start_is_a_counted_restart() -> None:
    feed = Feed()
    feed.push(records(range(1, 20001), ft=range(50_001, 70_001)), 5.0)
    feed.tracker.expect_start(feed.index, 5.25)
    feed.push(records(range(1, 101), ft=range(1, 101)), 8.0)
    assert feed.rdt[20000:] == list(range(1, 101))
    assert feed.counters.restarts == 1 and feed.counters.duplicate == 0


def test_unrequested_restart_to_a_small_sequence_is_counted() -> None:
    feed = Feed()
    feed.push(records(range(1, 301)), 1.0)
    feed.push(records(range(1, 51), ft=range(1, 51)), 1.1)  # aligned with the old stream: only the jump tells
    assert feed.rdt == list(range(1, 301)) + list(range(1, 51))
    assert feed.counters.restarts == 1 and feed.counters.duplicate == 0


def test_someone_elses_start_restarts_the_stream_with_ft_running_on() -> None:
    feed = Feed()
    feed.push(records(range(1, 1001)), 1.0)
    feed.push(records(range(300, 400), ft=range(1300, 1400)), 1.2)
    assert feed.rdt[1000:] == list(range(300, 400)) and feed.counters.restarts == 1


def test_bias_drops_the_old_stream_until_the_restarted_one_shows() -> None:
    feed = Feed()
    feed.push(records(range(1, 101)), 1.0)
    feed.tracker.expect_start(feed.index, 1.0, bias=True)
    feed.push(records(range(101, 111)), 1.001)  # in flight before the box biased
    assert feed.rdt == list(range(1, 101)) and not feed.tracker.bias_restarted
    feed.push(records(range(1, 21), ft=range(111, 131)), 1.002)
    assert feed.tracker.bias_restarted and feed.rdt[100:] == list(range(1, 21))
    assert feed.counters.lost == 0 and feed.counters.restarts == 0


def test_sequence_wraps_at_two_to_the_32() -> None:
    feed = Feed()
    top = 2**32 - 5
    feed.push(records(range(top, top + 10)), 1.0)
    assert feed.rdt == [(top + k) % 2**32 for k in range(10)] and feed.counters.lost == 0


class StalledReceiver:
    """Stands in for drivers/netft/receiver.RdtReceiver: batches the receive thread wrote, each with the host time
    by which it had drained the socket (``drained_at_s``)."""

    def __init__(self) -> None:
        self.batches: list[tuple[np.ndarray, float, float]] = []
        self.drained_at_s = 0.0
        self.index = 0

    def has_new(self) -> bool:
        return bool(self.batches)

    def take(self) -> tuple[np.ndarray, np.ndarray, int]:
        if not self.batches:
            return records([]), np.empty(0), self.index
        batch, at_s, self.drained_at_s = self.batches.pop(0)
        first, self.index = self.index, self.index + len(batch)
        return batch, np.full(len(batch), at_s), first


def test_the_reorder_window_runs_on_the_receive_threads_clock() -> None:
    """The reader decodes long after the receive thread drained record 4 (the machine stalled both threads); the
    late record 3, still in the socket then, is not lost: the window is measured up to when the socket was last
    found empty, never on the reader's clock."""
    from drivers.netft.driver import NetFTSensor

    sensor = NetFTSensor("192.0.2.1")  # never opened: the stand-in receiver feeds the decode side
    receiver = StalledReceiver()
    sensor._receiver = receiver
    drained_s = time.monotonic() - 1.0  # a second ago, then the receive thread stalled
    receiver.batches.append((records([1, 2]), drained_s - 0.001, drained_s - 0.001))
    receiver.batches.append((records([4]), drained_s, drained_s))
    sensor._decode()
    sensor._decode()
    assert sensor._tracker.held == 1 and sensor._tracker.counters.lost == 0
    receiver.batches.append((records([3, 5]), drained_s + 1.0, drained_s + 1.0))
    sensor._decode()
    counters = sensor._tracker.counters
    assert sensor._take().sequence.tolist() == [1, 2, 3, 4, 5]
    assert (counters.lost, counters.out_of_order) == (0, 1)
    receiver.batches.append((records([7]), drained_s + 1.001, drained_s + 1.001 + 2 * REORDER_WINDOW_S))
    sensor._decode()  # the receive thread found the socket empty past record 7's window: 6 is lost
    assert sensor._take().sequence.tolist() == [7] and counters.lost == 1
