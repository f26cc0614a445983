"""Real-time scheduling on the bridge's computer (docs/bridge.md "Timing"): the feed thread's SCHED_FIFO request,
and how the kernel threads that deliver network packets (``ksoftirqd/N``, one per core) are scheduled.

Why the second matters: a packet's last step into a socket is the kernel's network softirq. Under load the kernel
hands that work to ``ksoftirqd``, a thread at normal priority, which then waits its turn behind every other busy
program. A controller package can then reach the feed thread milliseconds late however high the feed thread's own
priority: on the development machine, one-minute runs missed 0-11 cycles that way with ``ksoftirqd`` at normal
priority (5.3 on average), 0-3 with it at SCHED_FIFO 60 (0.4 on average; benchmarks/README.md, controller bridge).
A PREEMPT_RT kernel runs these threads (and the network card's interrupt threads) at SCHED_FIFO by default.
"""

from __future__ import annotations

import os
import threading
from dataclasses import dataclass
from pathlib import Path

SOFTIRQ_THREAD_PREFIX = "ksoftirqd/"
REALTIME_PRIORITY = 80
"""SCHED_FIFO priority asked for the bridge's feed thread (1-99; 0 keeps normal scheduling). The thread blocks on
the controller's socket between cycles, so it takes a core only for its ~0.3 ms of work per cycle."""


def ask_realtime(priority: int) -> str:
    """Ask SCHED_FIFO ``priority`` (1-99; 0 or less: not asked) for the calling thread; return how it is scheduled,
    e.g. ``"SCHED_FIFO 80"`` or ``"normal (SCHED_FIFO 80 refused: Operation not permitted)"``."""
    if priority <= 0:
        return "normal (real-time priority not asked)"
    if not hasattr(os, "sched_setscheduler"):
        return "normal (no SCHED_FIFO on this system)"
    try:
        os.sched_setscheduler(threading.get_native_id(), os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, ValueError) as error:  # EPERM without CAP_SYS_NICE / rtprio limit
        return f"normal (SCHED_FIFO {priority} refused: {getattr(error, 'strerror', None) or error})"
    return f"SCHED_FIFO {priority}"


def ask_realtime_all_threads(priority: int, tasks: Path = Path("/proc/self/task")) -> str:
    """Ask SCHED_FIFO ``priority`` for every thread of this process now running (threads they start later inherit
    it); return how it went, as :func:`ask_realtime`. For a process that holds simulated devices (``ftacq bridge
    --sim``): a thread at normal priority preempted while it holds the interpreter lock stalls every other one."""
    if priority <= 0 or not hasattr(os, "sched_setscheduler"):
        return ask_realtime(priority)
    try:
        for task in tasks.iterdir():
            os.sched_setscheduler(int(task.name), os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, ValueError) as error:
        return f"normal (SCHED_FIFO {priority} refused: {getattr(error, 'strerror', None) or error})"
    return f"SCHED_FIFO {priority}"


@dataclass(frozen=True)
class KernelThread:
    """One kernel thread: process id, name, real-time priority (0: normal scheduling)."""

    pid: int
    name: str
    realtime_priority: int


def softirq_threads(proc: Path = Path("/proc")) -> list[KernelThread]:
    """The ``ksoftirqd`` threads visible in ``proc`` with their real-time priority (empty where none is visible,
    e.g. in a container with its own process namespace, or where the system has no /proc)."""
    found = []
    try:
        entries = [entry for entry in proc.iterdir() if entry.name.isdigit()]
    except OSError:
        return []
    for entry in entries:
        try:
            name = (entry / "comm").read_text().strip()
        except OSError:
            continue  # gone, or not readable
        if not name.startswith(SOFTIRQ_THREAD_PREFIX):
            continue
        pid = int(entry.name)
        try:
            realtime = os.sched_getscheduler(pid) in (os.SCHED_FIFO, os.SCHED_RR)
            priority = os.sched_getparam(pid).sched_priority if realtime else 0
        except (OSError, AttributeError):
            continue
        found.append(KernelThread(pid, name, priority))
    return sorted(found, key=lambda thread: thread.pid)


def softirq_advice(threads: list[KernelThread]) -> str | None:
    """One line for the user when any ``ksoftirqd`` thread runs at normal priority (None when all are real-time or
    none is visible)."""
    normal = [thread for thread in threads if thread.realtime_priority == 0]
    if not normal:
        return None
    pids = " ".join(str(thread.pid) for thread in normal)
    return (f"the kernel's network threads ({', '.join(thread.name for thread in normal)}) run at normal priority: "
            "on a busy computer a controller package can wait behind other programs for milliseconds (a missed "
            f"cycle). As root: 'for p in {pids}; do chrt -f -p 60 $p; done' (until reboot; docs/bridge.md, Timing)")
