"""Feature extraction for the JSAR filters (float32, single-threaded, vectorised).

- `patches`: sample_patch / sample_patches: crop + resample regions, border replicated.
- `fhog`: Felzenszwalb HOG, 31 channels per cell (fhog, fhog_batch).
- `colour`: derived 10-channel colour-attribute table, loader for external tables.
- `translation`: extract_features: gray + fHOG + colour attributes per cell (42 / 32 channels).
"""
