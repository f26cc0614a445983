"""procedures/realtime.py: the feed thread's real-time request and the kernel's network threads (ksoftirqd)."""

from __future__ import annotations

import os
import threading

import pytest

from procedures.realtime import KernelThread, ask_realtime, ask_realtime_all_threads, softirq_advice, softirq_threads


def test_ask_realtime_not_asked_and_refused(monkeypatch):
    assert ask_realtime(0) == "normal (real-time priority not asked)"

    def refuse(*_args):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr("os.sched_setscheduler", refuse)
    assert ask_realtime(70) == "normal (SCHED_FIFO 70 refused: Operation not permitted)"


def test_ask_realtime_applies_to_the_calling_thread_only():
    result = {}

    def worker():
        result["said"] = ask_realtime(10)
        result["policy"] = os.sched_getscheduler(threading.get_native_id())

    thread = threading.Thread(target=worker)
    thread.start()
    thread.join(5.0)
    if result["said"].startswith("normal"):
        pytest.skip(f"this machine refuses SCHED_FIFO: {result['said']}")
    assert result == {"said": "SCHED_FIFO 10", "policy": os.SCHED_FIFO}
    assert os.sched_getscheduler(0) == os.SCHED_OTHER  # the test's own thread is untouched


def test_softirq_threads_are_read_by_name_with_their_scheduling(tmp_path):
    """A /proc stand-in whose 'ksoftirqd/0' is this test process (normal scheduling) and whose other entries are
    not softirq threads, a vanished process and a non-process entry."""
    (tmp_path / str(os.getpid())).mkdir()
    (tmp_path / str(os.getpid()) / "comm").write_text("ksoftirqd/0\n")
    (tmp_path / "1").mkdir()
    (tmp_path / "1" / "comm").write_text("init\n")
    (tmp_path / "999999999").mkdir()  # no comm: gone while reading
    (tmp_path / "self").mkdir()
    assert softirq_threads(tmp_path) == [KernelThread(os.getpid(), "ksoftirqd/0", 0)]
    assert softirq_threads(tmp_path / "missing") == []


def test_softirq_advice_names_the_normal_priority_threads():
    threads = [KernelThread(14, "ksoftirqd/0", 0), KernelThread(24, "ksoftirqd/1", 60)]
    advice = softirq_advice(threads)
    assert advice is not None and "ksoftirqd/0" in advice and "ksoftirqd/1" not in advice
    assert "for p in 14; do chrt -f -p 60 $p; done" in advice
    assert softirq_advice([KernelThread(24, "ksoftirqd/1", 60)]) is None
    assert softirq_advice([]) is None


def test_ask_realtime_all_threads_asks_for_every_thread_of_the_process(tmp_path, monkeypatch):
    for tid in ("101", "102", "107"):
        (tmp_path / tid).mkdir()
    asked = []
    monkeypatch.setattr("os.sched_setscheduler", lambda tid, policy, param: asked.append((tid, param.sched_priority)))
    assert ask_realtime_all_threads(70, tasks=tmp_path) == "SCHED_FIFO 70"
    assert sorted(asked) == [(101, 70), (102, 70), (107, 70)]

    def refuse(*args):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr("os.sched_setscheduler", refuse)
    assert ask_realtime_all_threads(70, tasks=tmp_path) == "normal (SCHED_FIFO 70 refused: Operation not permitted)"
