"""`jsar-service` / `python -m service`: run the onboard tracking daemon."""
from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading

from service.config import ConfigError, load_config
from service.logs import setup_logging

log = logging.getLogger("service")

STOP_SIGNALS = frozenset({signal.SIGTERM, signal.SIGINT})  # a clean stop: systemd, podman stop, Ctrl-C


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="jsar-service", description=__doc__,
                                     epilog="jsar-service keygen --out FILE [--force]: make a MAVLink 2 signing key "
                                            "for mavlink.signing.key_file (jsar-service keygen --help)")
    parser.add_argument("--config", required=True, help="YAML configuration (see config.yaml)")
    parser.add_argument("--source", help="override source: /dev/videoN, a video file or image folder, or 'zenoh'")
    parser.add_argument("--mavlink", help="override mavlink.url: udpout:HOST:PORT, udpin:HOST:PORT, tcp:HOST:PORT, "
                        "tcpin:HOST:PORT (each also as udpout://HOST:PORT etc.) or a serial device path")
    return parser.parse_args(argv)


def configuration_error(exc: ConfigError) -> int:
    """Report a configuration error in the one form for all of them (stderr, names the key); exit code 2."""
    print(f"jsar-service: configuration error: {exc}", file=sys.stderr, flush=True)
    return 2


def main(argv: list[str] | None = None) -> int:
    """Load and validate the config, run until SIGTERM / SIGINT; exit 2 on a config error.
    `jsar-service keygen ...` makes a MAVLink signing key instead (service.keygen)."""
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["keygen"]:
        from service.keygen import main as keygen

        return keygen(argv[1:])
    args = parse_args(argv)
    try:
        config = load_config(args.config, args.source, args.mavlink)
    except ConfigError as exc:
        return configuration_error(exc)
    setup_logging(config.logging)
    stop = threading.Event()
    # Blocked before any thread starts, so every thread inherits the mask and Service.run's main thread
    # takes SIGTERM / SIGINT synchronously (sigtimedwait): no handler runs in the middle of other code.
    signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    from service.app import Service  # heavy imports after the config is known to be good

    try:
        daemon = Service(config)
    except ConfigError as exc:  # found while building the parts (e.g. tracker.params the tracker refuses)
        return configuration_error(exc)
    except (ConnectionError, ValueError) as exc:
        log.error('event=startup_failed error="%s"', exc)
        return 1
    try:
        daemon.run(stop, STOP_SIGNALS)
    except RuntimeError as exc:
        log.error('event=exit reason="%s"', exc)
        return 1
    return 0


def entry() -> None:
    """The `jsar-service` command: main(), then exit without the interpreter's teardown.

    By the time main() returns the daemon has stopped its threads, closed its links and sessions and
    logged event=stopped. Finalising numpy, OpenCV, scipy and zenoh modules afterwards took 0.2-0.35 s
    on an x86-64 core and 2.5 s on aarch64 under emulation: time a Pi-class core would take out of the
    2 s a stop (SIGTERM from systemd or `podman stop`) is allowed.
    """
    code = main()
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":
    entry()
