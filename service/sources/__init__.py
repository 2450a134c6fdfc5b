"""Frame sources: V4L2 camera, video file / image folder, Zenoh."""
