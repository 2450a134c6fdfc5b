"""The ground side's Zenoh links: mutual TLS with the drones' CA (docs/security.md) for the web station and
the router; which links this node opened (to watch the link to a router).

The ground tools take the same three PEM files as the daemon's `zenoh.tls` (CA, own certificate, own key)
and set Zenoh's own TLS link from them (transport.link.tls, 1.x key names); connect and listen on
`tls/HOST:PORT` endpoints. Public Zenoh configuration only: nothing here comes from the service.
"""
from __future__ import annotations

import argparse
import ipaddress
import json
from dataclasses import dataclass
from pathlib import Path

import zenoh

ENCRYPTED_PROTOCOLS = ("tls", "quic")  # Zenoh links that run over TLS
LOCAL_PROTOCOLS = ("unixsock-stream", "unixpipe", "vsock")  # links that never leave the machine


@dataclass(frozen=True)
class ZenohTls:
    """PEM paths: the CA that signed every peer's certificate, this node's certificate and its private key;
    `option` names the command-line option prefix the files came from (for error messages)."""

    root_ca_certificate: str
    certificate: str
    private_key: str
    verify_name_on_connect: bool = True  # a connect endpoint's host must be named in the peer's certificate
    option: str = "--zenoh-tls"

    def __post_init__(self) -> None:
        for suffix, path in (("ca", self.root_ca_certificate), ("cert", self.certificate),
                             ("key", self.private_key)):
            name = f"{self.option}-{suffix}"
            if not path:
                raise ValueError(f"{name}: missing (TLS needs the CA, the certificate and the key)")
            try:
                head = Path(path).read_bytes()[:65536]
            except OSError as exc:
                raise ValueError(f"{name}: cannot read {path}: {exc.strerror}") from exc
            if b"-----BEGIN " not in head:
                raise ValueError(f"{name}: {path} is not a PEM file (no -----BEGIN line)")

    def section(self) -> dict[str, object]:
        """Zenoh's transport.link.tls keys: mutual TLS, one certificate for listening and connecting."""
        return {"root_ca_certificate": self.root_ca_certificate,
                "listen_certificate": self.certificate, "listen_private_key": self.private_key,
                "connect_certificate": self.certificate, "connect_private_key": self.private_key,
                "enable_mtls": True, "verify_name_on_connect": self.verify_name_on_connect}

    def insert_into(self, config: zenoh.Config) -> None:
        """Set the TLS link keys in a zenoh.Config."""
        for key, value in self.section().items():
            config.insert_json5(f"transport/link/tls/{key}", json.dumps(value))


def add_tls_options(parser: argparse.ArgumentParser, option: str = "--zenoh-tls") -> None:
    """`OPTION-ca`, `OPTION-cert`, `OPTION-key` (PEM files) and `OPTION-no-verify-name`."""
    group = parser.add_argument_group("Zenoh mutual TLS (docs/security.md); for tls/HOST:PORT endpoints")
    group.add_argument(f"{option}-ca", metavar="PEM", help="the CA certificate that signed the drones' certificates")
    group.add_argument(f"{option}-cert", metavar="PEM", help="this station's certificate (signed by that CA)")
    group.add_argument(f"{option}-key", metavar="PEM", help="its private key")
    group.add_argument(f"{option}-no-verify-name", action="store_true",
                       help="do not check that a connect endpoint's host is named in the peer's certificate")


def tls_from_args(args: argparse.Namespace, option: str = "--zenoh-tls") -> ZenohTls | None:
    """The ZenohTls the options give; None when none of the files is given; ValueError naming the option."""
    dest = option.lstrip("-").replace("-", "_")
    ca, cert, key = (getattr(args, f"{dest}_{s}") for s in ("ca", "cert", "key"))
    if not (ca or cert or key):
        return None
    return ZenohTls(ca or "", cert or "", key or "", not getattr(args, f"{dest}_no_verify_name"), option)


def is_loopback(host: str) -> bool:
    """True for 127.0.0.0/8, ::1 and localhost."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def endpoint_is_loopback(endpoint: str) -> bool:
    """True when a Zenoh endpoint `proto/HOST:PORT` (`?metadata`, `#config` allowed) names a loopback host."""
    address = endpoint.partition("/")[2].split("?")[0].split("#")[0]
    return is_loopback((address.rsplit(":", 1)[0] if ":" in address else address).strip("[]"))


def check_endpoints(endpoints: tuple[str, ...] | list[str], tls: ZenohTls | None, option: str) -> list[str]:
    """Warnings for endpoints reaching beyond loopback unencrypted; ValueError for a tls/ endpoint without
    certificates (`option` names where the TLS files are set)."""
    warnings = []
    for endpoint in endpoints:
        protocol = endpoint.partition("/")[0]
        if protocol == "tls" and tls is None:
            raise ValueError(f"{endpoint} is a TLS endpoint: give {option}-ca, {option}-cert and {option}-key")
        if protocol not in ENCRYPTED_PROTOCOLS + LOCAL_PROTOCOLS and not endpoint_is_loopback(endpoint):
            warnings.append(f"{endpoint} reaches beyond loopback without TLS: anyone on that network can read the "
                            f"telemetry and video; use tls/HOST:PORT with {option}-ca/-cert/-key")
    return warnings


def endpoint_port(endpoint: str) -> tuple[str, str] | None:
    """`tcp/127.0.0.1:7447` (`?metadata`, `#config` allowed) -> ("tcp", "7447"); None without a port."""
    protocol, _, address = endpoint.partition("/")
    address = address.split("?")[0].split("#")[0]
    return (protocol, address.rsplit(":", 1)[1]) if ":" in address else None


def is_outgoing(link_src: str, listen: tuple[str, ...]) -> bool:
    """Whether a Zenoh link was opened by this node (towards a connect endpoint) rather than accepted: an
    accepted link's local locator (`src`) has a listen endpoint's protocol and port."""
    return endpoint_port(link_src) not in {endpoint_port(e) for e in listen}
