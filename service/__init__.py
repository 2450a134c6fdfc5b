"""Onboard tracking service: frames in, JSAR-Re track, MAVLink camera / gimbal / guidance out."""
import os

# pymavlink picks its dialect at import time; the camera and gimbal messages exist only in MAVLink 2.
# Set here, so that it holds before any service module imports pymavlink.
os.environ.setdefault("MAVLINK20", "1")
