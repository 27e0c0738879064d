"""Archive `brl bench` results without their frames, for reports built from them (docs/navigation-report/bench/).

    python scripts/archive_bench.py DEST SRC [SRC ...]
    python scripts/archive_bench.py --restore OUT ARCHIVE    # back to a directory `brl bench --resume` continues

Each SRC (a finished `brl bench` output) becomes DEST/<SRC's name>/ with its bench.json and its results.jsonl
gzipped (results.jsonl.gz, no timestamp: the same results give the same bytes). `brl report` reads such a directory
like the original; the per-frame files stay behind (a report's frame-based figures then say they are missing).
Written atomically; an existing archive of the same name is replaced.
"""

from __future__ import annotations

import argparse
import gzip
import shutil
import tempfile
from pathlib import Path


def _staging_dir(parent: Path, name: str) -> Path:
    """A fresh, readable temporary directory in `parent`, renamed into place once complete."""
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}.", dir=parent))
    tmp.chmod(0o755)
    return tmp


def archive(src: Path, dest_root: Path) -> Path:
    """Copy bench.json and a gzipped results.jsonl of `src` to dest_root/<src.name>; the archive's path."""
    for name in ("bench.json", "results.jsonl"):
        if not (src / name).is_file():
            raise SystemExit(f"{src} is not a brl bench results directory (no {name})")
    tmp = _staging_dir(dest_root, src.name)
    shutil.copyfile(src / "bench.json", tmp / "bench.json")
    with open(tmp / "results.jsonl.gz", "wb") as raw, gzip.GzipFile(fileobj=raw, mode="wb", mtime=0,
                                                                     filename="") as gz:
        gz.write((src / "results.jsonl").read_bytes())
    dest = dest_root / src.name
    if dest.exists():
        shutil.rmtree(dest)
    tmp.rename(dest)
    return dest


def restore(archived: Path, out: Path) -> Path:
    """An archive back to a results directory (bench.json, results.jsonl) at `out`, which must not exist: `brl bench
    --resume --out OUT` with the same options then runs the episodes it lacks."""
    if not (archived / "results.jsonl.gz").is_file() or not (archived / "bench.json").is_file():
        raise SystemExit(f"{archived} is not an archived results directory (bench.json, results.jsonl.gz)")
    if out.exists():
        raise SystemExit(f"{out} exists; restore into a new directory")
    tmp = _staging_dir(out.parent, out.name)
    shutil.copyfile(archived / "bench.json", tmp / "bench.json")
    (tmp / "results.jsonl").write_bytes(gzip.decompress((archived / "results.jsonl.gz").read_bytes()))
    tmp.rename(out)
    return out


def main() -> None:
    """Archive each SRC under DEST, or restore one archive."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--restore", action="store_true", help="restore ARCHIVE (the second argument) into OUT")
    ap.add_argument("dest", type=Path, help="where archives go (with --restore: the directory to create)")
    ap.add_argument("src", type=Path, nargs="+", help="bench results directories (with --restore: one archive)")
    args = ap.parse_args()
    if args.restore:
        if len(args.src) != 1:
            raise SystemExit("--restore takes one archive")
        print(restore(args.src[0], args.dest))
        return
    for src in args.src:
        print(archive(src, args.dest))


if __name__ == "__main__":
    main()
