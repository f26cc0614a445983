"""ATI Net F/T (and Ethernet Axia) over RDT/UDP, TCP 49151 and HTTP: the driver and its parts.

- :mod:`drivers.netft.protocol`: commands, the 36-byte record, status bits (docs/protocols-ati.md).
- :mod:`drivers.netft.discovery`: scaling from HTTP and TCP, cross-checked; rate and buffer settings.
- :mod:`drivers.netft.sequence`: the pure sequence tracker (order, losses, restarts, bias).
- :mod:`drivers.netft.device_time`: the box's own sample time from its sample counter ``ft_sequence``.
- :mod:`drivers.netft.receiver`: the UDP socket, its receive thread and byte ring, the re-send schedule.
- :mod:`drivers.netft.driver`: :class:`NetFTSensor`, which puts them together behind the sensor contract.

``from drivers.netft import NetFTSensor`` is the public entry; ``open_sensor("netft://…")`` reaches it too.
"""

from drivers.netft.discovery import Scaling, parse_flat_xml
from drivers.netft.driver import NetFTSensor, parse_netft_url
from drivers.netft.protocol import status_text
from drivers.units import canonical_unit

__all__ = ["NetFTSensor", "Scaling", "parse_netft_url", "parse_flat_xml", "canonical_unit", "status_text"]
