"""Archive `brl bench` results without their frames, for reports built from them (docs/navigation-report/bench/).

    python scripts/archive_bench.py DEST SRC [SRC ...]
    python scripts/archive_bench.py --restore OUT ARCHIVE    # back to a directory `brl bench --resume` continues
    python scripts/archive_bench.py --rename seed_0=brl_nav/seed_0 DEST SRC   # a policy's name changed on the way

Each SRC (a finished `brl bench` output) becomes DEST/<SRC's name>/ with its bench.json and its results.jsonl
gzipped (results.jsonl.gz, no timestamp: the same results give the same bytes). `brl report` reads such a directory
like the original; the per-frame files stay behind (a report's frame-based figures then say they are missing).
Written atomically; an existing archive of the same name is replaced.

`--rename OLD=NEW` changes a policy's name in the archive (bench.json's policy list and every result's `policy` and
`frames_file`), nothing else: a model benched alone (`brl bench --model models/brl_nav/seed_0`, policy `seed_0`)
then reports as a member of its set (`brl_nav/seed_0`, the name `--models models/brl_nav/seed_0` gives, with which
a restored archive resumes), so that `brl report` gives the set its mean row. An episode's outcome does not depend on
its policy's name (its seed comes from the episode's identifier and the bench seed).
"""

from __future__ import annotations

import argparse
import gzip
import json
import shutil
import sys
import tempfile
from pathlib import Path

from brlcli.bench.runner import safe_name


class ArchiveInputError(Exception):
    """Bad input: one line saying what is wrong, exit code 2, nothing written."""


def _staging_dir(parent: Path, name: str) -> Path:
    """A fresh, readable temporary directory in `parent`, renamed into place once complete."""
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}.", dir=parent))
    tmp.chmod(0o755)
    return tmp


def _renamed(bench: bytes, results: bytes, old: str, new: str) -> tuple[bytes, bytes]:
    """bench.json and results.jsonl with policy `old` named `new` (refused when `old` is not a policy of them)."""
    meta = json.loads(bench)
    policies = meta["config"]["policies"]
    if old not in [p["name"] for p in policies]:
        raise ArchiveInputError(f"no policy named '{old}' in this bench (its policies: "
                                f"{', '.join(p['name'] for p in policies)})")
    if new in [p["name"] for p in policies]:
        raise ArchiveInputError(f"a policy named '{new}' is already in this bench")
    for p in policies:
        if p["name"] == old:
            p["name"] = new
    lines = []
    for line in results.decode().splitlines():
        row = json.loads(line)
        if row.get("policy") == old:
            row["policy"] = new
            if "frames_file" in row:
                row["frames_file"] = f"frames/{safe_name(new)}/{row['frames_file'].split('/', 2)[2]}"
        lines.append(json.dumps(row, sort_keys=True) + "\n")
    return (json.dumps(meta, indent=2, sort_keys=True) + "\n").encode(), "".join(lines).encode()


def check_source(src: Path) -> None:
    """Refuse `src` unless it is a `brl bench` results directory."""
    for name in ("bench.json", "results.jsonl"):
        if not (src / name).is_file():
            raise ArchiveInputError(f"{src} is not a brl bench results directory (no {name})")


def archive(src: Path, dest_root: Path, rename: tuple[str, str] | None = None) -> Path:
    """Copy bench.json and a gzipped results.jsonl of `src` to dest_root/<src.name> (with one policy renamed, OLD ->
    NEW, when `rename` is given); the archive's path."""
    check_source(src)
    bench, results = (src / "bench.json").read_bytes(), (src / "results.jsonl").read_bytes()
    if rename is not None:
        bench, results = _renamed(bench, results, *rename)
    tmp = _staging_dir(dest_root, src.name)
    (tmp / "bench.json").write_bytes(bench)
    with open(tmp / "results.jsonl.gz", "wb") as raw, gzip.GzipFile(fileobj=raw, mode="wb", mtime=0,
                                                                     filename="") as gz:
        gz.write(results)
    dest = dest_root / src.name
    if dest.exists():
        shutil.rmtree(dest)
    tmp.rename(dest)
    return dest


def restore(archived: Path, out: Path) -> Path:
    """An archive back to a results directory (bench.json, results.jsonl) at `out`, which must not exist: `brl bench
    --resume --out OUT` with the same options then runs the episodes it lacks."""
    if not (archived / "results.jsonl.gz").is_file() or not (archived / "bench.json").is_file():
        raise ArchiveInputError(f"{archived} is not an archived results directory (bench.json, results.jsonl.gz)")
    if out.exists():
        raise ArchiveInputError(f"{out} exists; restore into a new directory")
    tmp = _staging_dir(out.parent, out.name)
    shutil.copyfile(archived / "bench.json", tmp / "bench.json")
    (tmp / "results.jsonl").write_bytes(gzip.decompress((archived / "results.jsonl.gz").read_bytes()))
    tmp.rename(out)
    return out


def main() -> None:
    """Archive each SRC under DEST, or restore one archive; bad input is one line on stderr and exit code 2."""
    try:
        _run()
    except ArchiveInputError as e:
        print(f"archive_bench: error: {e}", file=sys.stderr)
        raise SystemExit(2) from None


def _run() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--restore", action="store_true", help="restore ARCHIVE (the second argument) into OUT")
    ap.add_argument("--rename", metavar="OLD=NEW", help="archive with policy OLD named NEW (one SRC)")
    ap.add_argument("dest", type=Path, help="where archives go (with --restore: the directory to create)")
    ap.add_argument("src", type=Path, nargs="+", help="bench results directories (with --restore: one archive)")
    args = ap.parse_args()
    if args.restore:
        if len(args.src) != 1:
            raise ArchiveInputError("--restore takes one archive")
        print(restore(args.src[0], args.dest))
        return
    rename = None
    if args.rename is not None:
        old, sep, new = args.rename.partition("=")
        if not sep or not old or not new:
            raise ArchiveInputError(f"--rename takes OLD=NEW, got '{args.rename}'")
        if len(args.src) != 1:
            raise ArchiveInputError("--rename takes one SRC")
        rename = (old, new)
    for src in args.src:  # every source checked before any is archived
        check_source(src)
    for src in args.src:
        print(archive(src, args.dest, rename))


if __name__ == "__main__":
    main()
