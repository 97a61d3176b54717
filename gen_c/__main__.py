"""``python -m gen_c [--check] [--out DIR] [--vectors]``: (re)generate the C setpoint library.

Without options: regenerate ``gen_c/ecca_setpoint`` in place. ``--out DIR``: write a complete
copy of the library (generated + hand-written files) to DIR. ``--check``: regenerate into a
temporary folder and exit 1 with a unified diff if the checked-in (or DIR) copy differs.
``--vectors``: also write the golden vectors ``gen_c/tests/vectors.json`` from the Python path.
Exit codes: 0 ok, 1 check failed, 2 cannot generate (e.g. wrong CasADi version).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from gen_c import generate


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point; returns the exit code."""
    parser = argparse.ArgumentParser(
        prog="python -m gen_c",
        description="(Re)generate the freestanding C setpoint library gen_c/ecca_setpoint "
        "from companion.flatness (CasADi " + generate.CASADI_VERSION + ").")
    parser.add_argument("--check", action="store_true",
                        help="fail with a diff if the checked-in library is not up to date")
    parser.add_argument("--out", type=Path, default=None,
                        help=f"library folder (default {generate.LIB_DIR})")
    parser.add_argument("--vectors", action="store_true",
                        help=f"write the golden vectors {generate.VECTORS_PATH}")
    args = parser.parse_args(argv)
    lib_dir: Path = args.out if args.out is not None else generate.LIB_DIR
    try:
        if args.check:
            diff = generate.check_library(lib_dir)
            if diff:
                sys.stdout.write(diff)
                print(f"\n{lib_dir} is out of date: run `python -m gen_c`"
                      + (f" --out {lib_dir}" if args.out is not None else ""), file=sys.stderr)
                return 1
            print(f"{lib_dir}: up to date (CasADi {generate.CASADI_VERSION})")
        else:
            written = generate.write_library(lib_dir, copy_hand_written=args.out is not None)
            print(f"wrote {len(written)} files to {lib_dir}")
        if args.vectors:
            path = generate.write_vectors()
            print(f"wrote golden vectors to {path}")
    except generate.GeneratorError as exc:
        print(f"gen_c: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
