"""Write the bytecode of the dependency modules brl loads into the virtual environment, at image build time.

    python3 docker/precompile.py docker/precompile.txt

Each line of the list names a module: importing it here compiles every dependency file the import loaded;
`NAME.*` compiles the whole package NAME (for packages that load modules lazily). The .pyc files are written next
to their sources (`__pycache__/`) with unchecked hashes, so any uid uses them read-only, whatever the files' mtimes
after `COPY --from`; modules left out still work (Python compiles them in memory at each start). A module that
fails to import is reported and skipped: the image works as well (or as badly) without its bytecode.
"""

from __future__ import annotations

import compileall
import importlib
import os
import py_compile
import sys
import sysconfig
from pathlib import Path

MODE = py_compile.PycInvalidationMode.UNCHECKED_HASH


def main(list_file: str) -> None:
    site = Path(sysconfig.get_paths()["purelib"]).resolve()
    sys.dont_write_bytecode = True  # the imports write nothing; the compile below writes unchecked-hash .pyc
    names = [line.split("#", 1)[0].strip() for line in Path(list_file).read_text().splitlines()]
    names = [name for name in names if name]
    packages = [name[:-2] for name in names if name.endswith(".*")]
    for name in names:
        try:
            importlib.import_module(name.removesuffix(".*"))
        except Exception as exc:  # an optimisation only: report and go on
            print(f"precompile: cannot import {name}: {type(exc).__name__}: {exc}", file=sys.stderr)
    files = set()
    for module in list(sys.modules.values()):
        path = getattr(module, "__file__", None)
        if path and path.endswith(".py") and Path(path).resolve().is_relative_to(site):
            files.add(Path(path).resolve())
    for path in sorted(files):
        py_compile.compile(str(path), invalidation_mode=MODE, quiet=1)
    for package in packages:
        where = site / package.replace(".", "/")
        if where.is_dir():
            compileall.compile_dir(str(where), quiet=1, invalidation_mode=MODE, workers=os.cpu_count() or 1)
    size = sum(p.stat().st_size for p in site.rglob("*.pyc"))
    print(f"precompile: {len(files)} imported files and {len(packages)} whole packages,"
          f" {size / 1e6:.0f} MB of bytecode")


if __name__ == "__main__":
    main(sys.argv[1])
