"""Benchmarks and A/B studies, kept apart from the library packages they measure.

- `features`: feature-extraction stage timings, numpy vs compiled kernels (`python -m bench.features`);
- `colour_ab`: the tracker with and without colour channels (`python -m bench.colour_ab`);
- `tracking`: tracker fps against OpenCV's trackers on the real sequences (`python -m bench.tracking`);
- `redetect`: the cost of a JSAR-Re lost frame (the search) against a tracking frame (`python -m bench.redetect DATA_ROOT`);
- `service`: the daemon's frame-to-command latency and CPU against a recorded video (`python -m bench.service`);
- `scene`: the closed-loop synthetic scene's render cost (`python -m bench.scene`);
- `click`: a click's initial box (square or object proposal) and a loose drag's (fitted to the object or as dragged)
  against the true box (`python -m bench.click DATA_ROOT`).
"""
