"""MAVLink camera component: pure command parsing (commands.py), message building (messages.py),
the autopilot's state as heard on the link (autopilot.py) and the socket adapter (link.py, camera.py).
Numbers come from pymavlink's dialect modules (MAVLINK20 is set by the service package)."""
