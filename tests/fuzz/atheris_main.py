"""Coverage-guided fuzzing of the targets in targets.py with atheris (libFuzzer), for long runs.

atheris is not a project dependency (it builds against libFuzzer; wheels exist for CPython
3.11 on x86-64 Linux): ``pip install atheris``, then, from the repository root::

    python -m tests.fuzz.atheris_main mission fuzz_corpus/mission -max_total_time=3600
    python -m tests.fuzz.atheris_main link -runs=1000000
    python -m tests.fuzz.atheris_main mock -max_len=2048 -timeout=2 -rss_limit_mb=2048

The first argument names the target (mission, link, mock); the rest go to libFuzzer (corpus
folders, -runs, -max_total_time, -timeout: an input slower than that many seconds is a failure,
-rss_limit_mb: the memory bound). A corpus folder starts empty or with the seed files that
``python -m tests.fuzz.atheris_main TARGET --write-seeds DIR`` writes. A crash is any `Finding`
or undocumented exception; libFuzzer saves the input as crash-<sha1> in the working folder.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path


def main(argv: list[str]) -> int:
    if len(argv) < 2 or argv[1] not in ("mission", "link", "mock"):
        print(__doc__, file=sys.stderr)
        return 2
    target = argv[1]
    if len(argv) == 4 and argv[2] == "--write-seeds":
        from tests.fuzz.campaign import _targets

        out = Path(argv[3])
        out.mkdir(parents=True, exist_ok=True)
        for i, seed in enumerate(_targets()[target][1]):
            (out / f"seed-{i:04d}").write_bytes(seed)
        return 0
    import atheris

    with atheris.instrument_imports(include=["companion", "sitl_mock"]):
        from tests.fuzz.targets import LinkTarget, MockTarget, mission_target

    logging.disable(logging.CRITICAL)
    fn = {"mission": mission_target, "link": LinkTarget(), "mock": None}[target]
    if fn is None:
        fn = MockTarget()

    def one_input(data: bytes) -> None:
        fn(data)

    atheris.Setup([argv[0], *argv[2:]], one_input)
    atheris.Fuzz()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
