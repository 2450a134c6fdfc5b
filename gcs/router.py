"""`python -m gcs.router`: a Zenoh router (zenoh-python in router mode), for a fleet without Eclipse's zenohd.

Every drone's daemon (`zenoh.connect: ["tcp/ROUTER:7447"]`, its own `zenoh.prefix`) and the web station
(`--zenoh tcp/ROUTER:7447 --zenoh-mode client`) connect to it; it forwards every drone's samples to the station.

    python -m gcs.router --listen tcp/0.0.0.0:7447
    python -m gcs.router --listen tls/0.0.0.0:7447 --tls-ca ca.crt --tls-cert router.crt --tls-key router.key \\
        --access router-access.yaml

TLS (docs/security.md): every peer shows a certificate from the same CA; `--access` is a YAML (or JSON) file
with Zenoh's access_control section (config.yaml's zenoh.access keys), checked at start.
"""
from __future__ import annotations

import argparse
import json
import signal
import sys
from typing import Any

import yaml
import zenoh

from gcs.zenoh_tls import ZenohTls, add_tls_options, check_endpoints, tls_from_args


def router_config(listen: list[str], multicast_scouting: bool, tls: ZenohTls | None = None,
                  access: dict[str, Any] | None = None) -> zenoh.Config:
    """A router's zenoh.Config listening on `listen`, with mutual TLS and Zenoh's access_control section if given
    (ValueError naming the bad key of the access section, as Zenoh reports it)."""
    config = zenoh.Config()
    config.insert_json5("mode", '"router"')
    config.insert_json5("listen/endpoints", json.dumps(listen))
    config.insert_json5("scouting/multicast/enabled", json.dumps(multicast_scouting))
    if tls is not None:
        tls.insert_into(config)
    if access is not None:
        try:
            config.insert_json5("access_control", json.dumps(access))
        except Exception as exc:  # zenoh.ZError: the message names the unknown key or value
            raise ValueError(f"--access: {str(exc).split(' at ')[0]}") from exc
    return config


def read_access(path: str) -> dict[str, Any]:
    """The access_control section from a YAML / JSON file; ValueError naming the file."""
    try:
        with open(path, encoding="utf-8") as handle:
            data = yaml.safe_load(handle)
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f"--access: cannot read {path}: {exc}") from exc
    if isinstance(data, dict) and set(data) == {"access_control"}:
        data = data["access_control"]
    if not isinstance(data, dict):
        raise ValueError(f"--access: {path} must hold a mapping (enabled, default_permission, rules, subjects, "
                         "policies)")
    return data


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m gcs.router", description=__doc__.splitlines()[0])
    parser.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                        help="endpoint to listen on (repeat for several; default tcp/0.0.0.0:7447)")
    parser.add_argument("--multicast-scouting", action="store_true", help="answer multicast scouting too")
    add_tls_options(parser, "--tls")
    parser.add_argument("--access", metavar="FILE", help="Zenoh access_control section (YAML / JSON)")
    args = parser.parse_args(argv)
    listen = args.listen or ["tcp/0.0.0.0:7447"]
    try:
        tls = tls_from_args(args, "--tls")
        for warning in check_endpoints(listen, tls, "--tls"):
            print(f"gcs.router: warning: --listen {warning}", file=sys.stderr, flush=True)
        config = router_config(listen, args.multicast_scouting, tls, read_access(args.access) if args.access else None)
    except ValueError as exc:
        print(f"gcs.router: {exc}", file=sys.stderr)
        return 2
    # Blocked before zenoh starts its threads (they inherit the mask); the main thread then takes them with
    # sigwait: a handler's stop.set() can deadlock when it lands inside a wait on the same event.
    stop_signals = {signal.SIGINT, signal.SIGTERM}
    signal.pthread_sigmask(signal.SIG_BLOCK, stop_signals)
    try:
        session = zenoh.open(config)
    except Exception as exc:  # zenoh.ZError: address in use, bad endpoint, an access list Zenoh refuses
        print(f"gcs.router: cannot start on {listen}: {str(exc).split(' at ')[0]}", file=sys.stderr)
        return 2
    print(f"zenoh router listening on {', '.join(listen)}; Ctrl-C to stop", flush=True)
    try:
        signal.sigwait(stop_signals)
    finally:
        session.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
