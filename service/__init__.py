"""Onboard tracking service: frames in, JSAR-Re track, MAVLink camera / gimbal / guidance out."""
