"""`nod lab <tool>`: the lab's deployment tools."""

from __future__ import annotations

import sys

TOOLS = {"secure": "services.lab.secure"}


def main(argv: list[str] | None = None) -> int:
    """Dispatch `nod lab secure …`."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] not in TOOLS:
        print(f"usage: nod lab {{{','.join(TOOLS)}}} [options]  (--help for each)", file=sys.stderr)
        return 0 if args[:1] in (["-h"], ["--help"]) else 2
    if args[0] == "secure":
        from services.lab.secure import main as secure

        return secure(args[1:])
    return 2
