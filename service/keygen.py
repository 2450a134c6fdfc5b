"""`jsar-service keygen --out FILE`: a MAVLink 2 signing key for `mavlink.signing.key_file`.

The key is the SHA-256 of a passphrase, as MAVProxy (`signing setup` / `signing key`) and QGroundControl
(MAVLink 2 signing key setting) make theirs from what the operator types: one secret, typed on the ground
and kept in a file on the drone, gives all three the same 32-byte key. The passphrase is 32 random bytes
from `secrets`, URL-safe base64 (43 characters, no spaces: MAVProxy takes it as one word); it is printed
once, the file keeps only the key (64 hex characters, mode 0600). docs/security.md has the whole workflow.
"""
from __future__ import annotations

import argparse
import hashlib
import os
import secrets
import sys
from pathlib import Path

PASSPHRASE_BYTES = 32  # random bytes in a new passphrase (256 bits, the key's own size)


def new_passphrase() -> str:
    """A fresh passphrase: PASSPHRASE_BYTES random bytes as URL-safe base64 text (ASCII, one word)."""
    return secrets.token_urlsafe(PASSPHRASE_BYTES)


def passphrase_key(passphrase: str) -> bytes:
    """The 32-byte signing key of a passphrase: SHA-256 of its ASCII bytes (MAVProxy's passphrase_to_key)."""
    if not passphrase or not passphrase.isascii() or any(c.isspace() for c in passphrase):
        raise ValueError("a signing passphrase must be non-empty ASCII without spaces (MAVProxy takes one word)")
    return hashlib.sha256(passphrase.encode("ascii")).digest()


def write_key_file(path: Path, key: bytes, force: bool = False) -> None:
    """Write key as 64 hex characters and a newline, readable by its owner only (0600); FileExistsError if
    path exists and not force (a key in use is not replaced by accident)."""
    flags = os.O_WRONLY | os.O_CREAT | (os.O_TRUNC if force else os.O_EXCL)
    descriptor = os.open(path, flags, 0o600)
    try:
        os.fchmod(descriptor, 0o600)  # an overwritten file keeps its old mode otherwise
        os.write(descriptor, (key.hex() + "\n").encode("ascii"))
    finally:
        os.close(descriptor)


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="jsar-service keygen", description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", required=True, type=Path, help="key file to write (mavlink.signing.key_file)")
    parser.add_argument("--force", action="store_true", help="replace an existing key file")
    parser.add_argument("--passphrase-file", type=Path,
                        help="derive the key from the passphrase in this file (first line) instead of making one: "
                             "for a fleet whose autopilots already sign with it")
    return parser.parse_args(argv)


def main(argv: list[str]) -> int:
    """Write the key file; print the new passphrase for the ground stations. Exit 1 on a refusal."""
    args = parse_args(argv)
    made = args.passphrase_file is None
    try:
        passphrase = new_passphrase() if made else args.passphrase_file.read_text().splitlines()[0].strip()
        write_key_file(args.out, passphrase_key(passphrase), args.force)
    except FileExistsError:
        print(f"jsar-service keygen: {args.out} exists; --force replaces it (every ground station then needs "
              "the new passphrase)", file=sys.stderr)
        return 1
    except (OSError, ValueError, IndexError) as exc:
        print(f"jsar-service keygen: {exc or 'empty passphrase file'}", file=sys.stderr)
        return 1
    print(f"signing key written to {args.out} (mode 0600): set mavlink.signing.key_file to it")
    if made:
        print(f"passphrase for the ground stations (MAVProxy `signing key`, QGroundControl's signing key): "
              f"{passphrase}")
    return 0
