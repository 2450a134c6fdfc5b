"""MAVLink camera component: pure command parsing (commands.py), message building (messages.py),
the autopilot's state as heard on the link (autopilot.py) and the socket adapter (link.py, camera.py)."""
import os

# pymavlink picks its dialect at import time; the camera and gimbal messages exist only in MAVLink 2
os.environ.setdefault("MAVLINK20", "1")
