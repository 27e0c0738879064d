#!/usr/bin/env bash
# Container smoke test: build the image, then run brl through `docker run`: `--version` (the version brl reports
# outside the container), bytecode for every module `import brlcli.cli` loads (as a non-root uid with a read-only
# root filesystem and no tmpfs), preview into a fresh named volume as the image's user and as another uid, then as a
# non-root uid with a read-only root filesystem and a bind mount: preview, a 300-step train, a 10 % paper-suite
# bench, and one bad input (one line, exit 2). Needs a Docker engine. Not part of the default test suite.
#
#   scripts/docker-smoke.sh [IMAGE_TAG [DOCKER_BUILD_ARGS...]]
#   e.g. scripts/docker-smoke.sh brl:smoke --build-arg TORCH_INDEX= --build-arg EXTRA_CA_CERTS="$(cat ca.pem)"
#
# Environment: KEEP_OUT=1 keeps the output directory.
set -euo pipefail
cd "$(dirname "$0")/.."
tag=${1:-brl:smoke}
shift $(( $# > 0 ? 1 : 0 ))
out=$(mktemp -d "${TMPDIR:-/tmp}/brl-smoke.XXXXXX")
chmod 777 "$out"  # the container writes as another uid than the caller
volume=brl-smoke-$$
trap '[ "${KEEP_OUT:-0}" = 1 ] || rm -rf "$out"; docker volume rm -f "$volume" >/dev/null 2>&1 || true' EXIT
fail() { echo "smoke: FAIL: $*" >&2; exit 1; }

t0=$(date +%s)
docker build -q "$@" --build-arg GIT_COMMIT="$(git rev-parse HEAD 2>/dev/null || echo unknown)" -t "$tag" . >/dev/null
echo "smoke: built $tag in $(( $(date +%s) - t0 )) s, $(docker image inspect "$tag" --format '{{.Size}}' | awk '{printf "%.2f GB", $1/1e9}')"

run() {  # non-root uid, read-only root filesystem, a tmpfs for /tmp, the output directory mounted
    docker run --rm --user 4321:4321 --read-only --tmpfs /tmp:rw,exec,size=1g --shm-size=512m \
        -v "$out:/work/out" "$tag" "$@"
}

# the version brl reports outside the container (that of pyproject.toml where brl is not installed here)
want=$(python3 -c 'import brlcli; print(brlcli.__version__)' 2>/dev/null || true)
if [ -z "$want" ] || [ "$want" = 0.0.0+unknown ]; then
    want=$(python3 -c 'import tomllib; print(tomllib.load(open("pyproject.toml", "rb"))["project"]["version"])')
fi
got=$(docker run --rm "$tag" --version)
[ "$got" = "brl $want" ] || fail "--version printed '$got', not 'brl $want'"
echo "smoke: --version ok ($got)"

# bytecode for all that `import brlcli.cli` loads, usable by any uid: nothing compiled from source at start-up
verbose=$(docker run --rm --user 4321:4321 --read-only --entrypoint python3 "$tag" -v -c 'import brlcli.cli' 2>&1) \
    || fail "import brlcli.cli failed: $(printf '%s\n' "$verbose" | tail -n 3)"
from_source=$(printf '%s\n' "$verbose" | grep -c '^# code object from .*\.py$' || true)
[ "$from_source" = 0 ] || fail "import brlcli.cli compiled $from_source modules from source (no bytecode in the image)"
echo "smoke: bytecode ok"

# a fresh named volume: Docker copies /work/out's ownership and mode from the image into it
docker volume rm -f "$volume" >/dev/null 2>&1 || true
docker run --rm -v "$volume:/work/out" "$tag" preview town02 --weathers 1 --out /work/out/p >/dev/null \
    || fail "preview into a named volume as the image's user failed"
docker run --rm --user 4321:4321 --read-only --tmpfs /tmp -v "$volume:/work/out" "$tag" \
    preview town02 --weathers 1 --out /work/out/q >/dev/null || fail "preview into a named volume as uid 4321 failed"
docker run --rm -v "$volume:/work/out" --entrypoint sh "$tag" -c 'test -s /work/out/p/town02_topdown.png &&
    test -s /work/out/q/town02_topdown.png' || fail "preview wrote no picture into the named volume"
echo "smoke: named volume ok"

run preview town02 --weathers 1 --out /work/out/preview >/dev/null
[ -s "$out/preview/town02_topdown.png" ] || fail "preview wrote no picture"
grep -q '"git_commit": "'"$(git rev-parse HEAD 2>/dev/null || echo unknown)"'"' "$out/preview/run.json" \
    || fail "run.json does not record the build's git commit"
grep -q '"brl_version": "'"$want"'"' "$out/preview/run.json" || fail "run.json does not record brl $want"
echo "smoke: preview ok"

run train --steps 300 --no-evaluate --out /work/out/train >/dev/null
[ -s "$out/train/seed_0/model.npz" ] || fail "train wrote no model"
echo "smoke: train ok"

run bench --suite paper --model /work/out/train/seed_0 --episodes 0.1 --out /work/out/bench >/dev/null
[ "$(wc -l < "$out/bench/results.jsonl")" -ge 6 ] || fail "bench wrote fewer than 6 episodes"
echo "smoke: bench ok ($(wc -l < "$out/bench/results.jsonl") episodes)"

set +e
err=$(run train --steps abc --out /work/out/bad 2>&1 >/dev/null)
code=$?
set -e
[ "$code" = 2 ] || fail "bad input exited with $code, not 2"
[ "$(printf '%s\n' "$err" | wc -l)" = 1 ] && [[ "$err" == "brl: error:"* ]] || fail "bad input printed: $err"
[ ! -e "$out/bad" ] || fail "bad input wrote $out/bad"
echo "smoke: bad input ok ($err)"
echo "smoke: PASS in $(( $(date +%s) - t0 )) s"
