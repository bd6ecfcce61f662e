"""``thinfilm methods [--json]``: the reconstruction methods of the estimator registry, each
with its options (``reconstruct … --option NAME=VALUE``): name, type, default and help."""

from __future__ import annotations

import json

__all__ = ["cli_main"]


def cli_main(args) -> int:
    from thinfilm.core import registry

    found = registry.methods()
    if args.json:
        for m in found:
            print(json.dumps(m.as_dict(), sort_keys=True))
    else:
        rows = [("NAME", "KIND", "ROLE", "ALIASES", "SOURCE", "DESCRIPTION")]
        rows += [(m.name, m.kind, m.role, ",".join(m.aliases) or "-", m.source or "-", m.description)
                 for m in found]
        widths = [max(len(r[i]) for r in rows) for i in range(5)]
        for r, m in zip(rows, [None, *found]):
            print("  ".join(c.ljust(w) for c, w in zip(r[:5], widths)) + "  " + r[5])
            for o in (m.options if m is not None else ()):
                print(f"    --option {o.name}={o.default!s:<8} {o.describe()}: {o.help}")
    import sys

    for name, problem in registry.problems():
        print(f"thinfilm: warning: estimator entry point {name!r} could not be loaded: {problem}", file=sys.stderr)
    return 0
