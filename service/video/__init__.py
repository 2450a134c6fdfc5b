"""Video out of the daemon: the tracked frames, handed off the tracking thread to encoders.

The loop offers each tracked frame (`LatestFrameWorker.offer`, a lock and an assignment); each
output runs its encoder on its own thread and only ever sees the newest frame (latest-frame-wins:
a frame replaced before the encoder took it is counted as dropped, never queued).
Outputs: `zenoh_preview` (JPEG on `<prefix>/camera/preview`) and `rtp_stream` (H.264 over RTP/UDP).
"""
