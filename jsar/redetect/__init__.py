"""JSAR-Re: failure monitoring, EdgeBoxes re-detection and re-initialisation on top of JSAR.

- `edges`: gradient edge magnitude / orientation maps in the convention cv2.ximgproc.EdgeBoxes
  expects (optional OpenCV structured-edge model via `StructuredEdges`);
- `proposals`: EdgeBoxes proposals in the omega-square around the last position (full-frame boxes);
- `monitor`: the failure-monitor state machine (pure, no I/O);
- `jsar_re`: `JsarReTracker` (Algorithm 1) and the registry factory `make_jsar_re` ("jsar-re").
Re-detection cost and the re-initialisation size study: `python -m bench.redetect`.
"""
