"""Vehicle-link options shared by every command that talks to a vehicle (`fly`, `status`, and
any later one such as `serve`): ``add_signing_option(parser)`` adds ``--signing-key FILE``
(MAVLink 2 signing with a 32-byte key, 64 hex digits or 32 raw bytes; read and checked while
parsing, so a bad key file fails with exit code 2 before anything is sent), and
``link_config(args)`` turns the parsed link options (``--target-system``, ``--signing-key``) into
the :class:`companion.mavlink.LinkConfig` the link runs with.
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any

from companion.mavlink import LinkConfig, SigningConfig, SigningKeyError, load_signing_key


def signing_key_file(path: str) -> bytes:
    """argparse type: the key in a signing key file (see companion.mavlink.signing)."""
    try:
        return load_signing_key(path)
    except SigningKeyError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_signing_option(p: argparse.ArgumentParser) -> None:
    """``--signing-key FILE`` (dest ``signing_key``: the 32 key bytes or None)."""
    p.add_argument("--signing-key", type=signing_key_file, default=None, metavar="FILE",
                   help="MAVLink 2 signing key (64 hex digits or 32 raw bytes): sign every frame "
                        "sent, drop unsigned or wrongly signed frames received")


def signing_config(key: bytes | None) -> SigningConfig | None:
    """The link's signing configuration for a key from ``--signing-key`` (None: no signing)."""
    return None if key is None else SigningConfig(key)


def link_config(args: argparse.Namespace, **fields: Any) -> LinkConfig:
    """The LinkConfig of parsed link options; ``fields`` override or add LinkConfig fields."""
    base: dict[str, Any] = {"target_sysid": getattr(args, "target_system", 1),
                            "signing": signing_config(getattr(args, "signing_key", None))}
    return dataclasses.replace(LinkConfig(**base), **fields)
