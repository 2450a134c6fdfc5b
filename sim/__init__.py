"""Sim harness: mock autopilot, recorded-video replay, closed-loop synthetic scene, ground station."""
