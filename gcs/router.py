"""`python -m gcs.router`: a Zenoh router (zenoh-python in router mode), for a fleet without Eclipse's zenohd.

Each drone's daemon connects to it (config.yaml `zenoh.connect: ["tcp/ROUTER:7447"]`, its own
`zenoh.prefix`), and so does the web station (`--zenoh tcp/ROUTER:7447 --zenoh-mode client`): the
router forwards every drone's telemetry, status and preview to the station.

    python -m gcs.router --listen tcp/0.0.0.0:7447
"""
from __future__ import annotations

import argparse
import json
import signal
import sys
import threading

import zenoh


def router_config(listen: list[str], multicast_scouting: bool) -> zenoh.Config:
    """A router's zenoh.Config listening on `listen`."""
    config = zenoh.Config()
    config.insert_json5("mode", '"router"')
    config.insert_json5("listen/endpoints", json.dumps(listen))
    config.insert_json5("scouting/multicast/enabled", json.dumps(multicast_scouting))
    return config


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m gcs.router", description=__doc__.splitlines()[0])
    parser.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                        help="endpoint to listen on (repeat for several; default tcp/0.0.0.0:7447)")
    parser.add_argument("--multicast-scouting", action="store_true", help="answer multicast scouting too")
    args = parser.parse_args(argv)
    listen = args.listen or ["tcp/0.0.0.0:7447"]
    try:
        session = zenoh.open(router_config(listen, args.multicast_scouting))
    except Exception as exc:  # zenoh.ZError: address in use, bad endpoint
        print(f"gcs.router: cannot listen on {listen}: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    print(f"zenoh router listening on {', '.join(listen)}; Ctrl-C to stop", flush=True)
    try:
        while not stop.wait(0.5):  # wake now and then so a signal is handled promptly
            pass
    finally:
        session.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
