"""ftacq: calibrate a wrist-mounted ATI force/torque sensor on a UR arm and watch compensated wrenches.

Method: Yu, Shi & Lou, "Bias Estimation and Gravity Compensation for Wrist-Mounted Force/Torque Sensor",
IEEE Sensors J. 22(18), 2022 (doi 10.1109/JSEN.2021.3056943). Frame conventions: see README "Frames".
"""

__version__ = "0.1.0"

STANDARD_GRAVITY_M_S2 = 9.80665
"""Standard gravity g in m/s², used to turn the identified weight ‖gravity_base‖ (N) into a mass (kg)."""
