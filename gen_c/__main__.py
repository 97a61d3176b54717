"""``python -m gen_c [--check] [--out DIR] [--vectors]``: (re)generate the C setpoint library;
``python -m gen_c px4-module --sdk SDK -o FILE``: build the onboard PX4 module (gen_c.px4module).

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


def px4_module_main(argv: list[str]) -> int:
    """``python -m gen_c px4-module --sdk SDK -o FILE``: build the onboard module (dyn)."""
    from gen_c import px4module

    parser = argparse.ArgumentParser(
        prog="python -m gen_c px4-module",
        description="Build the onboard PX4 module gen_c/px4_module/ecca_onboard.c as a shared "
        "object for PX4's dyn command, against a PX4 dyn SDK (e.g. ../shared/px4_sitl/sdk).")
    parser.add_argument("--sdk", type=Path, required=True, help="the PX4 dyn SDK folder")
    parser.add_argument("-o", "--out", type=Path, required=True,
                        help="the module file (outside /tmp when PX4 runs under with-px4)")
    args = parser.parse_args(argv)
    try:
        path = px4module.build_px4_module(args.sdk, args.out)
    except px4module.ModuleBuildError as exc:
        print(f"gen_c px4-module: {exc}", file=sys.stderr)
        return 2
    print(f"built {path}: load it with `dyn {path} start`")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point; returns the exit code."""
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["px4-module"]:
        return px4_module_main(argv[1:])
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
