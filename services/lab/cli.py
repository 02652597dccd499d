"""`nod lab <tool>`: the lab's deployment tools."""

from __future__ import annotations

import sys

from services.core.cli import Parser


def main(argv: list[str] | None = None) -> int:
    """Dispatch `nod lab secure …`, `nod lab status …`."""
    args = list(sys.argv[1:] if argv is None else argv)
    if args[:1] == ["secure"]:
        from services.lab.secure import main as secure

        return secure(args[1:])
    if args[:1] == ["status"]:
        from services.tools.lab_status import main as status

        return status(args[1:])
    p = Parser(prog="nod lab", description="A lab's deployment tools.")
    p.add_argument("tool", choices=("secure", "status"),
                   help="secure: mutual TLS and an ACL by rig and host; status: every rig on the "
                   "network")
    p.parse_args(args)  # --help, or a one-line error for anything else
    return 2
