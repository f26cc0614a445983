"""Device drivers: ATI force/torque sensors (Net F/T, CAN) and Universal Robots arms (ur-rtde)."""
