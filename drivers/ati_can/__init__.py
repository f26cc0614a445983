"""ATI NETCANOEM (F/T CAN Bus and Serial Bus Network Interface for OEM) over python-can: the driver and its parts.

- :mod:`drivers.ati_can.protocol`: opcodes, reply lengths, gage limits, status bits, the board's calibration.
- :mod:`drivers.ati_can.transport`: the bus: one request and its reply frames, the frame classifier.
- :mod:`drivers.ati_can.driver`: :class:`AtiCanSensor` (start-up, poll thread, host-side bias) and the ``can://`` URL.

``from drivers.ati_can import AtiCanSensor`` is the public entry; ``open_sensor("can://…")`` reaches it too. The
wire tables (opcodes, status bits) are imported from :mod:`drivers.ati_can.protocol`.
"""

from drivers.ati_can.driver import URL_FORM, AtiCanSensor, parse_can_url
from drivers.ati_can.protocol import CanCalibration, decode_status

__all__ = ["AtiCanSensor", "parse_can_url", "URL_FORM", "CanCalibration", "decode_status"]
