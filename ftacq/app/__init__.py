"""The application layer: the ``ftacq`` CLI, its sub-commands, the CELL.toml configuration, the Rerun dashboard
and the simulated-cell launcher.

This is the top of the house: it may import :mod:`ftacq` core, :mod:`drivers` and :mod:`procedures`; nothing
below imports it. It is also the only code that imports the simulated devices in ``tests.fakes`` (through
:mod:`ftacq.app.simcell`).
"""
