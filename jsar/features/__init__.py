"""Feature extraction for the JSAR filters (float32, single-threaded).

- `patches`: sample_patch / sample_patches: crop + resample regions, border replicated.
- `fhog`: Felzenszwalb HOG, 31 channels per cell (fhog, fhog_batch).
- `colour`: derived 10-channel colour-attribute table, loader for external tables.
- `translation`: extract_features: gray + fHOG + colour attributes per cell (42 / 32 channels).
Benchmarks live in the top-level `bench` package (`python -m bench.features`, `bench.colour_ab`).
The hot loops are compiled from `_kernels.c` when the project is installed (`pip install -e .`);
each has a numpy reference in its module that the tests compare it with.
"""
