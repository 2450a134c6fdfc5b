"""`python -m gcs.web` / `jsar-gcs-web`: the web ground station.

    jsar-gcs-web --mavlink udpout:127.0.0.1:14550 --zenoh tcp/127.0.0.1:7447
    jsar-gcs-web --mavlink udpin:0.0.0.0:14550 --zenoh tcp/192.168.1.20:7447 --zenoh-mode client --port 8080

Serves on 127.0.0.1 unless --host says otherwise (docs/operator.md: exposing it safely). Another --host needs
a token (--token-file FILE or JSAR_GCS_TOKEN) or --behind-proxy (docs/security.md). Prints
`web station: http://HOST:PORT/` once it accepts connections.
"""
from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path

from gcs.drones import ZenohSettings
from gcs.web.auth import TOKEN_ENV, exposure_problem, load_token
from gcs.zenoh_tls import add_tls_options, is_loopback, tls_from_args

log = logging.getLogger("gcs.web")


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="jsar-gcs-web", description="Web ground station: live video with the "
                                     "track, click / drag to select, several drones")
    parser.add_argument("--mavlink", action="append", required=True, metavar="URL",
                        help="pymavlink URL of a link to the drones (repeat for several links): udpout:HOST:PORT "
                             "sends to an autopilot's ground-station port, udpin:HOST:PORT listens, tcp:HOST:PORT, "
                             "/dev/ttyUSB0,57600")
    parser.add_argument("--zenoh", action="append", default=[], metavar="ENDPOINT",
                        help="Zenoh endpoint to connect to: a daemon's listen endpoint or a router "
                             "(tcp/HOST:7447); repeat for several")
    parser.add_argument("--zenoh-listen", action="append", default=[], metavar="ENDPOINT",
                        help="Zenoh endpoint to listen on, for daemons that connect to the station")
    parser.add_argument("--zenoh-mode", choices=("peer", "client"), default="peer",
                        help="client: through a Zenoh router only (default peer)")
    parser.add_argument("--zenoh-scouting", action="store_true",
                        help="find daemons by multicast scouting on the local network (off: explicit endpoints)")
    add_tls_options(parser, "--zenoh-tls")
    parser.add_argument("--host", default="127.0.0.1",
                        help="address to serve on (default 127.0.0.1: this machine only; see docs/operator.md "
                             "before serving on another)")
    parser.add_argument("--port", type=int, default=8080, help="port to serve on (0: any free port)")
    parser.add_argument("--token-file", type=Path, metavar="FILE",
                        help=f"require this access token (the file's first line; or set {TOKEN_ENV}; never on "
                             "the command line): a login form for browsers, 'Authorization: Bearer' for scripts")
    parser.add_argument("--behind-proxy", action="store_true",
                        help="serve on a non-loopback --host without a token: an authenticating reverse proxy in "
                             "front checks every request (refused otherwise)")
    parser.add_argument("--signing-key", metavar="FILE",
                        help="MAVLink 2 signing key file (jsar-service keygen's): sign every command, for drones "
                             "that refuse unsigned ones")
    parser.add_argument("--system-id", type=int, default=255, help="this ground station's MAVLink system id")
    parser.add_argument("--component-id", type=int, default=190, help="its MAVLink component id")
    parser.add_argument("--log-level", default="INFO", choices=("DEBUG", "INFO", "WARNING", "ERROR"))
    args = parser.parse_args(argv)
    if not 0 <= args.port <= 65535:
        parser.error(f"--port must be 0..65535, got {args.port}")
    if not (1 <= args.system_id <= 255 and 1 <= args.component_id <= 255):
        parser.error("--system-id and --component-id must be 1..255")
    return args


def main(argv: list[str] | None = None) -> int:
    """Run the station until Ctrl-C / SIGTERM; exit status 2 when a link cannot be opened."""
    args = parse_args(argv)
    logging.basicConfig(level=args.log_level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        import uvicorn

        from gcs.mavlink_station import read_signing_key
        from gcs.web.server import build_hub, close_hub, create_app
    except ImportError as exc:
        print(f"jsar-gcs-web: {exc.name} is missing: install the web station's extra, "
              f"pip install 'jsar-tracking[gcs]'", file=sys.stderr)
        return 2
    try:
        token = load_token(args.token_file, os.environ)
        problem = exposure_problem(is_loopback(args.host), token, args.behind_proxy)
        if problem is not None:
            raise ValueError(problem)
        signing_key = read_signing_key(args.signing_key) if args.signing_key else None
        settings = ZenohSettings(connect=tuple(args.zenoh), listen=tuple(args.zenoh_listen), mode=args.zenoh_mode,
                                 multicast_scouting=args.zenoh_scouting, tls=tls_from_args(args, "--zenoh-tls"))
        for warning in settings.unencrypted():
            log.warning("event=zenoh_unencrypted key=--zenoh %s", warning)
        hub = build_hub(settings, args.mavlink, args.system_id, args.component_id, signing_key)
    except (ValueError, ConnectionError) as exc:
        print(f"jsar-gcs-web: {exc}", file=sys.stderr)
        return 2
    if not is_loopback(args.host) and token is None:
        log.warning("event=exposed host=%s: no built-in authentication (--behind-proxy): the proxy in front "
                    "must check every request, the WebSocket /ws included", args.host)

    class AnnouncingServer(uvicorn.Server):
        async def startup(self, sockets=None) -> None:  # type: ignore[override]
            await super().startup(sockets)
            if self.started:
                port = self.servers[0].sockets[0].getsockname()[1] if self.servers else args.port
                shown = f"[{args.host}]" if ":" in args.host else args.host
                print(f"web station: http://{shown}:{port}/", flush=True)

    config = uvicorn.Config(create_app(hub, token), host=args.host, port=args.port, log_level="warning",
                            ws="websockets-sansio", lifespan="on")
    server = AnnouncingServer(config)
    try:
        server.run()
    except SystemExit:  # uvicorn could not start (it said why: e.g. the address is taken)
        return 2
    finally:
        close_hub(hub)
    return 0 if server.started else 2


if __name__ == "__main__":
    raise SystemExit(main())
