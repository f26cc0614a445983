"""The live Rerun dashboard, by idea:

- :mod:`~ftacq.app.dashboard.layout`: timelines, entity paths, colours (declared once) and the blueprint;
- :mod:`~ftacq.app.dashboard.arm`: the arm's link shapes and the force labels' placement, as numbers;
- :mod:`~ftacq.app.dashboard.recorder`: :class:`Dashboard`, which logs wrench batches, the arm, health and the
  calibration's results to a Rerun recording (numpy columns);
- :mod:`~ftacq.app.dashboard.listener`: :class:`DashboardListener`, which turns :mod:`procedures.events` (from the
  calibration procedure and the live monitor alike) into Dashboard calls;
- :mod:`~ftacq.app.dashboard.sinks`: the viewer flags and the viewer processes (spawn, connect, serve, save).

Reading a recording back is the tests' business (``tests/rrd_reader.py``).

Importing ``rerun`` takes over a second: the names below are loaded on first use, so ``ftacq --help`` and the
commands that draw nothing do not pay for it (rerun is a hard dependency all the same).
"""

from ftacq.lazy import lazy_names

_HOMES = {"APP_ID": "layout", "blueprint": "layout", "DashboardListener": "listener", "Dashboard": "recorder",
          "add_sink_args": "sinks", "close_recording": "sinks", "open_recording": "sinks"}

__getattr__, __dir__ = lazy_names(__name__, {name: f"{__name__}.{home}" for name, home in _HOMES.items()},
                                  globals())


__all__ = ["APP_ID", "Dashboard", "DashboardListener", "add_sink_args", "blueprint", "close_recording",
           "open_recording"]
