"""The ground side: command-line (gcs.cli, mavsdk) and web (gcs.web) ground stations.

MAVLink for commands, sent to the camera component as QGroundControl sends them; Zenoh for the preview
video and the track telemetry. Only public wire formats: nothing here imports the service's code.
"""
