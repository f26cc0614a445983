"""The simulated technician of ``ftacq monitor --sim`` and ``ftacq bridge --sim`` (and ``ftacq.open_cell(sim=...)``):
jogs the simulated arm, holds it still, pushes on the tool, swaps the tool, through the simulator's back door.

On a real cell the technician jogs the arm from the pendant; ftacq's live commands never move the robot.
"""

from __future__ import annotations

import threading
import time

import numpy as np

DEFAULT_SIM_MODEL = "UR5e"
SIM_SENSOR_RATE_HZ = 7000.0
SIM_JOG_RATE_HZ = 30.0
"""How often the simulated technician looks at the clock (pushes, tool swap, the next jog)."""
SIM_JOG_AMPLITUDE_RAD = np.array([0.35, 0.15, 0.2, 0.7, 0.7, 1.2])
"""Peak joint excursions (rad) of the simulated technician's jog around the start configuration."""
SIM_JOG_SPEED_RAD_S, SIM_JOG_ACCELERATION_RAD_S2 = 0.8, 2.0
"""The simulated technician jogs with moveJ moves from the pendant (the controller's motion profile), so the simulated
sensor reads the tool's inertial wrench as on a real arm."""
SIM_JOG_TARGETS = (1.0, -0.6, 0.3, -1.0, 0.6, -0.3)
"""The jog visits start + f × SIM_JOG_AMPLITUDE_RAD for these f in turn."""
SIM_PHASE_S = 8.0
"""The simulated technician jogs for this long, then holds the arm still for as long (the drift tracker learns only
while the arm is still)."""
SIM_CONTACT_START_S = 3.0
SIM_CONTACT_DURATION_S = 2.0
SIM_CONTACT_WRENCH = np.array([0.0, 6.0, -15.0, 0.3, 0.0, 0.0])
"""The simulated push on the tool (sensor frame, N and N·m), SIM_CONTACT_START_S into every still phase, held
SIM_CONTACT_DURATION_S with a hand's 5 % tremble at 4 Hz."""
SIM_WARMUP_TAU_S = 600.0
"""--sim-warmup: the simulated sensor's warm-up time constant, s (ATI asks for a 30 min warm-up: about 3 τ)."""
SIM_SWAPPED_TOOL = (1.0, (0.01, -0.005, 0.05))
"""--sim-swap-tool puts this tool (kg, centre of mass in the sensor frame, m) on the simulated sensor."""


class SimulatedTechnician:
    """Jogs the simulated arm, holds it still, pushes on the tool, and (``swap_after_s``) swaps the tool, through
    the simulator's own back door (``--sim`` only).

    On a real cell the technician jogs the arm from the pendant; the monitor itself never moves the robot.
    Owns the thread "ftacq-sim-technician" (started by :meth:`start`, joined by :meth:`close`).
    """

    def __init__(self, cell, period_s: float = 1.0 / SIM_JOG_RATE_HZ, jog: bool = True,
                 swap_after_s: float | None = None) -> None:
        self.cell = cell
        self.period_s = period_s
        self.jog = jog
        self.swap_after_s = swap_after_s
        self.swapped = False
        self.error: BaseException | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ftacq-sim-technician")

    def start(self) -> "SimulatedTechnician":
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop jogging, remove the push, join the thread."""
        self._stop.set()
        self._thread.join()
        self.cell.set_contact(np.zeros(6))

    def _run(self) -> None:
        q_start = np.asarray(self.cell.initial_q, dtype=float)
        start_s = time.monotonic()
        next_s = start_s
        move, move_end_s, q_now = 0, 0.0, q_start
        while not self._stop.wait(max(0.0, next_s - time.monotonic())):
            next_s += self.period_s
            t = time.monotonic() - start_s
            try:
                if self.swap_after_s is not None and not self.swapped and t >= self.swap_after_s:
                    self.cell.swap_tool(*SIM_SWAPPED_TOOL)
                    self.swapped = True
                if not self.jog:
                    continue
                phase_s = t % (2 * SIM_PHASE_S)
                if phase_s < SIM_PHASE_S:  # jogging: the next move if the previous one is over and this one fits
                    self.cell.set_contact(np.zeros(6))
                    if t < move_end_s:
                        continue
                    target = q_start + SIM_JOG_TARGETS[move % len(SIM_JOG_TARGETS)] * SIM_JOG_AMPLITUDE_RAD
                    if phase_s + jog_duration_s(q_now, target) <= SIM_PHASE_S:
                        move_end_s = t + self.cell.controller.jog(target, SIM_JOG_SPEED_RAD_S,
                                                                  SIM_JOG_ACCELERATION_RAD_S2)
                        q_now, move = target, move + 1
                else:  # holding still; a hand pushes on the tool for a while
                    hold_s = phase_s - SIM_PHASE_S
                    pushing = SIM_CONTACT_START_S <= hold_s < SIM_CONTACT_START_S + SIM_CONTACT_DURATION_S
                    tremble = 1.0 + 0.05 * np.sin(2 * np.pi * 4.0 * t)
                    self.cell.set_contact(SIM_CONTACT_WRENCH * tremble if pushing else np.zeros(6))
            except Exception as error:  # noqa: BLE001 - the demo stops jogging; the monitor goes on
                self.error = error
                return


def jog_duration_s(q_from: np.ndarray, q_to: np.ndarray) -> float:
    """Duration (s) of a moveJ at the simulated technician's speed and acceleration."""
    from ftacq.kinematics.trapezoid import move_duration_s

    return move_duration_s(q_from, q_to, SIM_JOG_SPEED_RAD_S, SIM_JOG_ACCELERATION_RAD_S2)



__all__ = ["SimulatedTechnician", "jog_duration_s", "DEFAULT_SIM_MODEL", "SIM_SENSOR_RATE_HZ", "SIM_WARMUP_TAU_S"]
