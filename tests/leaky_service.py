"""`python -m tests.leaky_service ARGS`: the daemon with a memory leak injected into every frame step,
for the soak test to show that its memory criterion catches a real per-frame leak."""
from __future__ import annotations

import sys

import service.__main__
from service.loop import TrackingLoop

LEAK_BYTES_PER_FRAME = 16384  # at 30 fps about 1690 MiB/h: 17 times the soak's bound


def leak_every_step() -> list[bytes]:
    """Patch TrackingLoop.step to keep LEAK_BYTES_PER_FRAME of written (resident) memory per frame;
    returns the list that holds it."""
    kept: list[bytes] = []
    step = TrackingLoop.step

    def leaking_step(self: TrackingLoop, frame):  # noqa: ANN001, ANN202 - same signature as step
        kept.append(bytes([len(kept) % 251 + 1]) * LEAK_BYTES_PER_FRAME)  # non-zero bytes: pages touched
        return step(self, frame)

    TrackingLoop.step = leaking_step
    return kept


if __name__ == "__main__":
    leak_every_step()
    sys.exit(service.__main__.main())
